import pytest

from stablelego_jax.blas import one_blas_thread, openblas_library


def test_one_blas_thread_sets_and_restores():
    lib = openblas_library()
    if lib is None:
        pytest.skip("SciPy without its bundled OpenBLAS")
    lib.scipy_openblas_set_num_threads(2)
    before = lib.scipy_openblas_get_num_threads()
    with one_blas_thread():
        assert lib.scipy_openblas_get_num_threads() == 1
    assert lib.scipy_openblas_get_num_threads() == before


def test_restored_after_an_error():
    lib = openblas_library()
    if lib is None:
        pytest.skip("SciPy without its bundled OpenBLAS")
    before = lib.scipy_openblas_get_num_threads()
    with pytest.raises(RuntimeError):
        with one_blas_thread():
            raise RuntimeError("inside")
    assert lib.scipy_openblas_get_num_threads() == before


# --- XLA's CPU pool and jaxlib 0.10's batched LAPACK kernels -----------------

import os  # noqa: E402
import subprocess  # noqa: E402

from lapack_calls import command  # noqa: E402
from stablelego_jax.blas import LAPACK_POOL_DEADLOCK, lapack_pool_deadlock, one_xla_pool_thread  # noqa: E402

ROOT = os.path.join(os.path.dirname(__file__), "..")

#: the reproducer: four independent batched triangular solves of 8 x 160 x
#: 160 (more than 200000 entries each, so jaxlib 0.10 splits each batch over
#: XLA's pool) in one jitted function, 100 times. On jaxlib 0.10.2 with a
#: 2-thread pool this hung on its first calls in every try on the 2-core box.
REPRODUCER = dict(batch=8, n=160, calls=100, factorise=False)


def test_the_pool_guard_sets_one_thread_on_affected_jaxlib_only():
    env = {}
    assert one_xla_pool_thread(env, "0.10.2") and env == {"PJRT_NPROC": "1"}
    for version in ("0.9.2", "0.11.2", "0.12.0"):
        env = {}
        assert not one_xla_pool_thread(env, version) and env == {}
    assert LAPACK_POOL_DEADLOCK[0] <= (0, 11, 1) < LAPACK_POOL_DEADLOCK[1]


def test_the_affected_versions():
    assert lapack_pool_deadlock("0.10.2") and lapack_pool_deadlock("0.11.1")
    assert not lapack_pool_deadlock("0.9.2") and not lapack_pool_deadlock("0.11.2")


def test_the_installed_jaxlib_version_is_read_without_importing_it():
    from importlib.metadata import version

    from stablelego_jax.blas import installed_jaxlib_version

    assert installed_jaxlib_version() == version("jaxlib")


def test_the_pool_guard_keeps_a_callers_own_setting():
    for var in ("PJRT_NPROC", "NPROC"):
        env = {var: "4"}
        assert not one_xla_pool_thread(env, "0.10.2") and env == {var: "4"}


def test_the_pool_is_widened_only_where_the_guard_set_it():
    from stablelego_jax.blas import widen_xla_pool

    env = {}
    assert one_xla_pool_thread(env, "0.10.2")
    assert not widen_xla_pool(1, env) and env == {"PJRT_NPROC": "1"}
    assert widen_xla_pool(2, env) and env == {"PJRT_NPROC": "2"}
    assert not widen_xla_pool(3, env) and env == {"PJRT_NPROC": "2"}  # once
    for own in ({"PJRT_NPROC": "1"}, {"NPROC": "1"}, {}):  # a caller's own setting, or no guard at all
        before = dict(own)
        assert not widen_xla_pool(2, own) and own == before


def test_batched_lapack_calls_side_by_side_finish_after_importing_the_package():
    """The reproducer finishes when the package was imported first (its
    guard sizes the pool); a hang here is the deadlock of stablelego_jax.blas."""
    env = {k: v for k, v in os.environ.items() if k not in ("PJRT_NPROC", "NPROC")}
    _finishes(REPRODUCER, env, "batched LAPACK calls deadlocked XLA's CPU pool")


def _finishes(case: dict, env: dict, hang: str) -> None:
    """Run ``lapack_calls``' program for ``case`` with ``env`` (the package on
    its path); fail with ``hang`` if it has not finished in 240 s."""
    env = dict(env, PYTHONPATH=ROOT + os.pathsep + env.get("PYTHONPATH", ""))
    try:
        out = subprocess.run(command(**case), env=env, cwd=ROOT, capture_output=True, text=True, timeout=240)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{hang} (no answer in 240 s)")
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "done"


def test_pool_threads_reads_the_pool_variables_then_the_cores():
    from stablelego_jax.blas import pool_threads

    assert pool_threads({"PJRT_NPROC": "3", "NPROC": "5"}) == 3
    assert pool_threads({"NPROC": "5"}) == 5
    assert pool_threads({"PJRT_NPROC": " "}) == pool_threads({}) >= 1
    with pytest.raises(ValueError, match="PJRT_NPROC='two'"):
        pool_threads({"PJRT_NPROC": "two"})


def test_batched_linalg_on_a_larger_pool_is_an_error_on_affected_jaxlib_only():
    from stablelego_jax.blas import check_batched_linalg

    two = {"PJRT_NPROC": "2"}
    with pytest.raises(RuntimeError, match="deadlock such a pool on a batch of 2"):
        check_batched_linalg(2, two, "0.10.2")
    check_batched_linalg(1, two, "0.10.2")  # one matrix a call: never split over the pool
    check_batched_linalg(64, {"PJRT_NPROC": "1"}, "0.10.2")
    check_batched_linalg(64, two, "0.11.2")
    check_batched_linalg(64, two, "0.10.2", cpu=False)  # an accelerator's kernels are not these


#: four independent unbatched factorisations and triangular solves of
#: 720 x 720 in one program, 40 times: the kind of calls one soft problem's
#: loss makes. On jaxlib 0.10.2 with a 2-thread pool this finished in every
#: try; the same with a batch of two matrices a call hung (session 46).
UNBATCHED = dict(batch=0, n=720, calls=40)


def test_unbatched_lapack_calls_side_by_side_finish_on_a_two_thread_pool():
    """What lets a process that solves one problem at a time use every core:
    kernels of one matrix do not split over the pool (stablelego_jax.blas)."""
    _finishes(UNBATCHED, dict(os.environ, PJRT_NPROC="2"), "unbatched LAPACK calls deadlocked a 2-thread pool")
