"""Threads of the CPU backend: one OpenBLAS thread for JAX's CPU linear
algebra, and inline dispatch of JAX's CPU computations.

JAX's CPU LAPACK kernels (Cholesky, LU, triangular solves) call SciPy's
bundled OpenBLAS. Its worker threads spin while they wait, and on a busy
machine they fight the other processes for the cores: a batch of the
interior-point solver took 83.4 s instead of 10.8 s next to two busy
processes on the 2-core box (``benchmarks/blas_threads.py``, BENCHMARKS.md);
the small factorisations of the differentiable loss suffer the same way. On the
quiet machine one thread was faster too (5.5 s against 8.1 s). :func:`one_blas_thread`
sets the count to 1 for a block and restores it after; without SciPy's
OpenBLAS (another build) it does nothing.

:func:`inline_cpu_dispatch`, called by the command line before JAX's
backend starts, runs CPU computations inline on the calling thread
(JAX's ``jax_cpu_enable_async_dispatch`` off). Batched ``score`` runs hung
three times on this machine (0 CPU, the main thread waiting forever in
``device_get`` for an asynchronously dispatched computation: twice with
XLA's Eigen thread pool on, once with it off, so the Eigen flag is not the
cause); inline dispatch removes the waiting step. It did not remove the
cause, which session 17 found (below); it is kept as it was.

The hang itself (found in session 17, gdb on a hung ``analyze``): jaxlib
0.10's batched LAPACK kernels (``lapack_dtrsm_ffi``, ``dpotrf``, ...) split a
batch of more than 200000 matrix entries into chunks, queue every chunk on
XLA's intra-op pool and block until they are done. When the thunk executor
runs as many such kernels at once as the pool has threads (two on this 2-core
box), every thread waits for chunks that no thread is left to run: a
deadlock with no thread computing. It depends on the schedule, so it came
and went with unrelated changes to the solver's graph.
:func:`one_xla_pool_thread`, called when the package is imported, sizes that
pool to one thread (``PJRT_NPROC=1``) on the affected jaxlib versions; with
one thread the kernels run their batch inline. ``tests/test_blas.py`` keeps a
reproducer that hangs without it.

Only a kernel with a batch of two or more matrices splits its work: on the
2-core box four independent unbatched factorisations and triangular solves
of 720 x 720 in one program, 150 calls, three runs, and a batch of one
finished with a 2-thread pool; a batch of two hung (BENCHMARKS.md, issue
18, session 46). A process that solves one problem at a time (one soft
problem's loss and gradient, a layout solved alone) may therefore set
``PJRT_NPROC`` to its cores before importing the package: the 2000-placement
loss of ``benchmarks/loss_scale.py`` then uses both cores of that box.
On such a pool ``score`` and ``analyze`` solve one layout a call (their
planner's batch sizes, ``batch.batch_sizes``; small layouts still share a
call as one packed problem), and :func:`check_batched_linalg` turns a hang
into an error where the library batches anyway (training).
"""
from __future__ import annotations

import contextlib
import functools

__all__ = ["one_blas_thread", "openblas_library", "inline_cpu_dispatch", "one_xla_pool_thread", "widen_xla_pool",
           "lapack_pool_deadlock", "installed_jaxlib_version", "LAPACK_POOL_DEADLOCK", "pool_threads",
           "batched_linalg_hangs", "check_batched_linalg"]

#: jaxlib versions (from, up to but not including) whose CPU LAPACK kernels
#: block XLA's intra-op pool on their own batch chunks (jaxlib 0.10.2 seen
#: here; 0.11.2's open-source build no longer has the parallel path)
LAPACK_POOL_DEADLOCK = ((0, 10, 0), (0, 11, 2))


def _version_tuple(text: str) -> tuple:
    """(major, minor, patch) of a version string such as "0.10.2" or "0.11.0rc1"."""
    import re

    parts = [int(m) for m in re.findall(r"\d+", text)[:3]]
    return tuple(parts + [0] * (3 - len(parts)))


def one_xla_pool_thread(environ=None, jaxlib_version: str | None = None) -> bool:
    """Size XLA's CPU intra-op pool to one thread (``PJRT_NPROC=1`` in
    ``environ``, default ``os.environ``) when the installed jaxlib is one of
    :data:`LAPACK_POOL_DEADLOCK`'s and neither ``PJRT_NPROC`` nor ``NPROC`` is
    set already (a caller's own choice is kept). Takes effect only if JAX's
    CPU backend has not started yet. Returns whether it set the variable."""
    import os

    env = os.environ if environ is None else environ
    if "PJRT_NPROC" in env or "NPROC" in env or not lapack_pool_deadlock(jaxlib_version):
        return False
    env["PJRT_NPROC"] = "1"
    _POOL_SET_HERE.add(id(env))
    return True


#: the environments (by ``id``) whose ``PJRT_NPROC=1`` :func:`one_xla_pool_thread` set
_POOL_SET_HERE: set = set()


def widen_xla_pool(threads: int, environ=None) -> bool:
    """Size XLA's CPU intra-op pool to ``threads`` (``PJRT_NPROC``) where
    :func:`one_xla_pool_thread` set it to one in ``environ`` (default
    ``os.environ``; a caller's own ``PJRT_NPROC`` or ``NPROC`` is kept),
    for a program whose LAPACK calls each factorise one matrix, which a
    larger pool cannot deadlock (this module's docstring): ``stablelego
    train`` with subsets solved one per call. Call it only before JAX's
    CPU backend starts in a process of its own (the variable also reaches
    the processes it starts). Returns whether it set the variable."""
    import os

    env = os.environ if environ is None else environ
    if threads <= 1 or id(env) not in _POOL_SET_HERE or env.get("PJRT_NPROC") != "1":
        return False
    env["PJRT_NPROC"] = str(int(threads))
    return True


def pool_threads(environ=None) -> int:
    """Threads of XLA's CPU intra-op pool in a process started with
    ``environ`` (default ``os.environ``): ``PJRT_NPROC``, else ``NPROC``,
    else the cores this process may run on."""
    import os

    env = os.environ if environ is None else environ
    for var in ("PJRT_NPROC", "NPROC"):
        text = env.get(var, "").strip()
        if text:
            try:
                return max(1, int(text))
            except ValueError:
                raise ValueError(f"{var}={text!r}: not a thread count") from None
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def batched_linalg_hangs(environ=None, jaxlib_version: str | None = None) -> bool:
    """Whether a CPU LAPACK call on a batch of two or more matrices can
    deadlock this process: a jaxlib of :data:`LAPACK_POOL_DEADLOCK`'s and
    more than one pool thread (:func:`pool_threads`; ``environ`` and
    ``jaxlib_version``: as :func:`one_xla_pool_thread`)."""
    return lapack_pool_deadlock(jaxlib_version) and pool_threads(environ) > 1


def check_batched_linalg(batch: int, environ=None, jaxlib_version: str | None = None,
                         cpu: bool | None = None) -> None:
    """Raise ``RuntimeError`` (one line) before a program factorises
    ``batch`` matrices in one LAPACK call where that would deadlock
    (:func:`batched_linalg_hangs`, a batch of two or more) on the CPU
    (``cpu``; default: whether JAX's default backend is the CPU: an
    accelerator's kernels are not these)."""
    if batch < 2 or not batched_linalg_hangs(environ, jaxlib_version):
        return
    if cpu is None:
        import jax

        cpu = jax.default_backend() == "cpu"
    if cpu:
        raise RuntimeError(
            f"XLA's CPU pool has {pool_threads(environ)} threads and this jaxlib's batched LAPACK kernels "
            f"deadlock such a pool on a batch of {batch}: unset PJRT_NPROC (or set it to 1) for batched work")


def lapack_pool_deadlock(jaxlib_version: str | None = None) -> bool:
    """Whether jaxlib ``jaxlib_version`` (default: the installed one) is one of
    :data:`LAPACK_POOL_DEADLOCK`'s. On those, several CPU devices in one
    process deadlock too: each device runs its LAPACK kernels on a pool
    thread of its own (seen with 2 host devices: both threads in
    ``lapack_dpotrf_ffi``, waiting), so the library runs one CPU device per
    process and uses worker processes for the other cores."""
    if jaxlib_version is None:
        jaxlib_version = installed_jaxlib_version()
        if jaxlib_version is None:
            return False
    lo, hi = LAPACK_POOL_DEADLOCK
    return lo <= _version_tuple(jaxlib_version) < hi


@functools.lru_cache(maxsize=1)
def installed_jaxlib_version() -> str | None:
    """Version of the installed jaxlib (None when absent), without importing
    it: read from the name of its ``jaxlib-VERSION.dist-info`` folder beside
    the package, else from ``importlib.metadata`` (whose import alone costs
    ~30 ms, too much for every command's start)."""
    import glob
    import importlib.util
    import os

    spec = importlib.util.find_spec("jaxlib")
    if spec is None or not spec.origin:
        return None
    site = os.path.dirname(os.path.dirname(spec.origin))
    found = glob.glob(os.path.join(site, "jaxlib-*.dist-info"))
    if len(found) == 1:
        return os.path.basename(found[0])[len("jaxlib-"): -len(".dist-info")]
    try:
        from importlib.metadata import PackageNotFoundError, version

        return version("jaxlib")
    except (ImportError, PackageNotFoundError):
        return None


def inline_cpu_dispatch() -> None:
    """Run JAX's CPU computations inline on the calling thread
    (``jax_cpu_enable_async_dispatch`` off) unless the environment sets
    ``JAX_CPU_ENABLE_ASYNC_DISPATCH=true``. Imports JAX; takes effect only
    before JAX's backend starts."""
    import os

    if os.environ.get("JAX_CPU_ENABLE_ASYNC_DISPATCH", "false").lower() in ("0", "false"):
        import jax

        jax.config.update("jax_cpu_enable_async_dispatch", False)


@contextlib.contextmanager
def one_blas_thread():
    """Context manager: one thread in SciPy's OpenBLAS inside, the previous
    count restored after."""
    lib = openblas_library()
    if lib is None:
        yield
        return
    old = lib.scipy_openblas_get_num_threads()
    lib.scipy_openblas_set_num_threads(1)
    try:
        yield
    finally:
        lib.scipy_openblas_set_num_threads(old)


@functools.lru_cache(maxsize=1)
def openblas_library():
    """ctypes handle of SciPy's bundled OpenBLAS (None when not found)."""
    import ctypes
    import glob
    import os

    import scipy

    pattern = os.path.join(os.path.dirname(os.path.dirname(scipy.__file__)), "scipy.libs", "libscipy_openblas*.so*")
    for path in glob.glob(pattern):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        if hasattr(lib, "scipy_openblas_set_num_threads") and hasattr(lib, "scipy_openblas_get_num_threads"):
            return lib
    return None
