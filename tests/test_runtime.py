"""float64 in a scope, and compiled solvers cached in and across processes
(stablelego_jax.runtime, stablelego_jax.solvers.compiled)."""
import glob
import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stablelego_jax.runtime import cache_dir, float64, x64, x64_differentiable
from stablelego_jax.solvers import compiled as C

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
STAIR20 = os.path.join(ROOT, "examples", "stablelego", "stair_20.json")


def _python(code: str, env=None, base=None) -> dict:
    """Run ``code`` in a fresh interpreter (from the repository root), in
    ``base`` (default: this process's environment) with ``env`` added; it
    prints one JSON object as its last line."""
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600,
                       env=dict(os.environ if base is None else base, PYTHONPATH=ROOT, **(env or {})))
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_float64_scope_is_restored():
    assert not jax.config.jax_enable_x64  # the test process runs in float32, as a user's does
    with float64():
        assert jnp.zeros(2).dtype == jnp.float64
    assert jnp.zeros(2).dtype == jnp.float32

    @x64
    def f():
        return jnp.ones(3).dtype

    assert f() == jnp.float64 and jnp.ones(3).dtype == jnp.float32


def test_library_leaves_the_users_jax_in_float32():
    """After import, analyze (JAX solver), a loss and its gradient taken in
    the user's float32 program: the user's arrays are still float32, the
    gradient comes back in the caller's precision and equals the one taken
    in float64 (the library computed it in float64)."""
    out = _python(f"""
import json, jax, jax.numpy as jnp, numpy as np
import stablelego_jax as sl
a = sl.analyze({STAIR20!r})
lay = sl.load_layout({STAIR20!r})
soft = sl.compile_soft(lay, [sl.candidate_brick([(4, 21, 0, 1, 2)])])
prob = sl.pad_soft(soft.problem)
w = np.zeros(prob.mass.shape[0]); w[:soft.n] = soft.weights()
g32 = jax.grad(sl.stability_loss)(jnp.asarray(w, jnp.float32), None, prob)
with jax.enable_x64(True):
    g64 = np.asarray(jax.grad(sl.stability_loss)(w, None, prob))
print(json.dumps({{"stable": a.stable, "weakest": a.weakest, "converged": a.converged,
                  "user_dtype": str(jnp.zeros(3).dtype), "x64": bool(jax.config.jax_enable_x64),
                  "grad_dtype": str(g32.dtype), "cand": float(g32[soft.unit_index[0]]),
                  "err": float(np.abs(np.asarray(g32, np.float64) - g64).max() / np.abs(g64).max())}}))
""")
    assert out["user_dtype"] == "float32" and out["x64"] is False
    assert (out["stable"], out["weakest"], out["converged"]) == (False, "2", True)
    assert out["grad_dtype"] == "float32" and out["cand"] < 0  # the paper's support helps
    assert out["err"] < 1e-6  # float32 only in the returned numbers


def test_x64_differentiable_compiles_once_per_shape():
    """Eager calls and gradients of a decorated function compile once per
    argument shape and static option, not on every call; a float argument
    is traced (a new value compiles nothing), an option is static, and the
    values and gradients are those of the undecorated function in float64."""
    seen = []

    def listener(name, secs, **kw):
        if name == "/jax/core/compile/backend_compile_duration":
            seen.append(secs)

    jax.monitoring.register_event_duration_secs_listener(listener)

    def f(w, prob, scale=1.0, power=2):
        w = jnp.asarray(w, jnp.float64)  # as the library's functions cast their inputs

        def body(i, v):  # a loop, as the interior points have
            return v * 0.5 + prob["a"] * w ** power

        return scale * jax.lax.fori_loop(0, 5, body, w).sum()

    g = x64_differentiable("w")(f)
    w, prob = np.linspace(0.1, 1.0, 4), {"a": np.arange(4.0)}
    with float64():
        want = np.asarray(jax.grad(lambda v: f(v, prob, 0.3))(w))
        value = float(f(w, prob, 0.3))
    for scale in (0.3, 0.3, 0.7):
        assert float(g(w, prob, scale)) == pytest.approx(value * scale / 0.3, rel=1e-12)
        assert np.allclose(jax.grad(g)(w, prob, scale), want * scale / 0.3, rtol=1e-6)
    before = len(seen)
    for scale in (0.3, 0.9):  # compiled already: nothing compiles again
        g(w, prob, scale)
        jax.grad(g)(w, prob, scale)
    assert len(seen) == before
    g(w, prob, 0.3, power=3)  # a new static option compiles
    assert len(seen) > before


def test_second_process_reuses_the_compiled_solver(tmp_path):
    """A second process neither traces nor compiles the solver again: it
    loads the exported function and hits XLA's persistent cache."""
    code = f"""
import json, jax
events = []
jax.monitoring.register_event_listener(lambda name, **kw: events.append(name))
import stablelego_jax as sl
from stablelego_jax.solvers.compiled import STATS
a = sl.analyze({STAIR20!r})
print(json.dumps({{"stable": a.stable, "loaded": STATS.loaded, "compiles": STATS.compiles,
                  "hits": events.count("/jax/compilation_cache/cache_hits"),
                  "misses": events.count("/jax/compilation_cache/cache_misses")}}))
"""
    env = {"STABLELEGO_CACHE_DIR": str(tmp_path / "cache")}
    first = _python(code, env)
    second = _python(code, env)
    assert first["stable"] is second["stable"] is False
    assert first["loaded"] == 0 and first["misses"] >= 1
    assert second["loaded"] == 1 and second["hits"] >= 1 and second["misses"] == 0
    assert os.listdir(tmp_path / "cache" / "exported") and os.listdir(tmp_path / "cache" / "xla")


@pytest.mark.slow
def test_the_suites_xla_level_gives_the_shipped_answers():
    """The suite compiles at XLA's optimisation level 0 (tests/conftest.py);
    the shipped library at XLA's defaults. On the paper's examples both give
    the same labels, weakest bricks and iteration counts, and scores within
    1e-9 (6.7e-12 measured)."""
    from conftest import shipping_env

    from stablelego_jax.analysis import analyze

    files = sorted(glob.glob(os.path.join(ROOT, "examples", "stablelego", "*.json")))
    code = f"""
import json
from stablelego_jax.analysis import analyze
out = {{}}
for f in {files!r}:
    a = analyze(f, solver="jax")
    out[f] = [a.stable, a.weakest, a.converged, a.iters, a.scores]
print(json.dumps(out))
"""
    shipped = _python(code, base=shipping_env())
    assert len(files) == 8
    for f in files:
        a = analyze(f, solver="jax")
        stable, weakest, converged, iters, scores = shipped[f]
        assert (a.stable, a.weakest, a.converged, a.iters) == (stable, weakest, converged, iters), f
        assert max(abs(a.scores[k] - scores[k]) for k in scores) < 1e-9, f


def test_cache_dir_settings(monkeypatch, tmp_path):
    monkeypatch.setenv("STABLELEGO_CACHE_DIR", str(tmp_path))
    assert cache_dir() == str(tmp_path)
    monkeypatch.setenv("STABLELEGO_CACHE", "0")
    assert cache_dir() is None
    monkeypatch.delenv("STABLELEGO_CACHE")
    monkeypatch.delenv("STABLELEGO_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == str(tmp_path / "xdg" / "stablelego-jax")


def test_executables_are_bounded(monkeypatch):
    """The in-process cache holds at most its limit; the least recently used go first."""
    monkeypatch.setenv("STABLELEGO_CACHE", "0")  # in-process only
    C.clear()
    C.set_limit(2)
    try:
        def f(x):
            return (x * 2.0,)

        exes = [C.compiled("double", f, None, (np.zeros(k),)) for k in (3, 4, 5)]
        assert C.cache_size() == 2
        ev = C.STATS.evicted
        assert ev >= 1
        np.testing.assert_allclose(np.asarray(exes[2](np.ones(5))[0]), 2.0)
        before = C.STATS.compiles
        C.compiled("double", f, None, (np.zeros(5),))  # still held: no compile
        assert C.STATS.compiles == before
        C.compiled("double", f, None, (np.zeros(3),))  # evicted: compiled again
        assert C.STATS.compiles == before + 1
        with pytest.raises(ValueError):
            C.set_limit(0)
    finally:
        C.set_limit(32)
        C.clear()


def test_compiled_from_threads_compiles_each_key_once(monkeypatch):
    """Threads asking for one key while it compiles wait for that compile
    (one trace, one executable); other keys compile beside it; shapes may
    be given as ``jax.ShapeDtypeStruct``."""
    import threading
    import time
    from concurrent.futures import ThreadPoolExecutor

    monkeypatch.setenv("STABLELEGO_CACHE", "0")  # in-process only
    C.clear()
    traces = []
    lock = threading.Lock()

    def f(x):
        with lock:
            traces.append(x.shape)
        time.sleep(0.3)  # a slow trace: the other threads arrive while it is in flight
        return (x + 1.0,)

    before = C.STATS.compiles
    spec = lambda k: (jax.ShapeDtypeStruct((k,), np.float64),)  # noqa: E731
    try:
        with ThreadPoolExecutor(4) as ex:
            exes = list(ex.map(lambda k: C.compiled("plus", f, None, spec(k)), [3, 3, 3, 4]))
        assert C.STATS.compiles == before + 2
        assert sorted(traces) == [(3,), (4,)]
        assert exes[0] is exes[1] is exes[2]
        np.testing.assert_allclose(np.asarray(exes[3](np.zeros(4))[0]), 1.0)
        assert C.compiled("plus", f, None, (np.zeros(3),)) is exes[0]  # arrays or specs: one key
        assert C.available("plus", None, spec(4), export=False)
    finally:
        C.clear()


def test_available_says_whether_compiled_would_compile(monkeypatch, tmp_path):
    """``available``: held in this process, or exported on disk by an
    earlier compile (another process); a new shape or setting is not."""
    import jax

    monkeypatch.setenv("STABLELEGO_CACHE_DIR", str(tmp_path))
    C.clear()

    def f(x):
        return (x * 6.0,)

    spec = [jax.ShapeDtypeStruct((4,), np.float64)]
    assert not C.available("sextuple", None, spec)
    C.compiled("sextuple", f, None, (np.zeros(4),))
    assert C.available("sextuple", None, spec)
    C.clear()  # as a new process would start: only the disk knows it
    assert C.available("sextuple", None, spec)
    assert not C.available("sextuple", None, spec, export=False)
    assert not C.available("sextuple", None, [jax.ShapeDtypeStruct((5,), np.float64)])
    assert not C.available("sextuple", "other settings", spec)
    before = C.STATS.loaded
    C.compiled("sextuple", f, None, (np.zeros(4),))
    assert C.STATS.loaded == before + 1  # read from disk, as available said
    C.clear()


def test_executables_are_let_go_when_memory_mappings_run_short(monkeypatch):
    """Past the mapping budget (half of vm.max_map_count) the cache keeps
    only the newest executable, whatever its count limit."""
    monkeypatch.setenv("STABLELEGO_CACHE", "0")
    C.clear()
    held = C.mappings()
    if held is None:
        pytest.skip("no /proc/self/maps on this system")
    assert C.map_budget() is None or C.map_budget() > 1000
    try:
        def f(x):
            return (x * 3.0,)

        C.compiled("triple", f, None, (np.zeros(3),))
        C.compiled("triple", f, None, (np.zeros(4),))
        assert C.cache_size() == 2
        monkeypatch.setattr(C, "map_budget", lambda: 10)  # fewer than this process holds
        ev = C.STATS.evicted
        exe = C.compiled("triple", f, None, (np.zeros(5),))
        assert C.cache_size() == 1 and C.STATS.evicted == ev + 2
        np.testing.assert_allclose(np.asarray(exe(np.ones(5))[0]), 3.0)
    finally:
        C.clear()


def test_compiled_keeps_float64_inputs_float64(monkeypatch):
    monkeypatch.setenv("STABLELEGO_CACHE", "0")
    exe = C.compiled("plus-tiny", lambda x: (x + 1e-12,), None, (np.zeros(2),))
    out = np.asarray(exe(np.zeros(2))[0])
    assert out.dtype == np.float64 and out[0] == 1e-12  # float32 would give 9.9999998e-13
    assert jnp.zeros(1).dtype == jnp.float32


def test_each_compile_empties_jax_tracing_caches_and_answers_stay(monkeypatch):
    """After each compile that traced the function JAX's tracing caches are
    emptied (a first run that traces many shapes would otherwise keep every
    jaxpr); executables compiled before and after still answer, and eager
    operations still work."""
    monkeypatch.setenv("STABLELEGO_CACHE", "0")
    C.clear()
    try:
        before = C.STATS.dropped
        a = C.compiled("triple", lambda x: (x * 3.0,), None, (np.zeros(5),))
        if C.STATS.dropped == before:
            pytest.skip("this JAX has no tracing caches to empty where we look")
        b = C.compiled("triple", lambda x: (x * 3.0,), None, (np.zeros(7),))
        assert C.STATS.dropped == before + 2
        C.compiled("triple", lambda x: (x * 3.0,), None, (np.zeros(7),))  # held: nothing emptied
        assert C.STATS.dropped == before + 2
        np.testing.assert_array_equal(np.asarray(a(np.ones(5))[0]), np.full(5, 3.0))
        np.testing.assert_array_equal(np.asarray(b(np.ones(7))[0]), np.full(7, 3.0))
        assert float(jnp.arange(4.0).sum()) == 6.0
    finally:
        C.clear()


def test_each_compile_hands_freed_memory_back(monkeypatch):
    """After a compile, the heap memory that compiling and evicting freed
    goes back to the system (glibc's malloc_trim), so a run that keeps
    compiling new shapes does not keep growing."""
    monkeypatch.setenv("STABLELEGO_CACHE", "0")
    if not C.release_memory():
        pytest.skip("no glibc malloc_trim on this system")
    C.clear()
    try:
        before = C.STATS.released
        C.compiled("quadruple", lambda x: (x * 4.0,), None, (np.zeros(6),))
        assert C.STATS.released == before + 1
        C.compiled("quadruple", lambda x: (x * 4.0,), None, (np.zeros(6),))  # held: no compile, no trim
        assert C.STATS.released == before + 1
    finally:
        C.clear()


def test_a_solver_read_from_disk_leaves_jax_tracing_caches_alone(monkeypatch, tmp_path):
    """Only a compile that traced empties JAX's caches: a warm run, which
    reads every solver from disk, keeps them (emptying cost it seconds)."""
    monkeypatch.setenv("STABLELEGO_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("STABLELEGO_CACHE", raising=False)
    C.clear()
    try:
        before = C.STATS.dropped
        C.compiled("quintuple", lambda x: (x * 5.0,), None, (np.zeros(3),))
        if C.STATS.dropped == before:
            pytest.skip("this JAX has no tracing caches to empty where we look")
        C.clear()  # a new process, as far as the in-memory cache knows
        loaded = C.STATS.loaded
        exe = C.compiled("quintuple", lambda x: (x * 5.0,), None, (np.zeros(3),))
        assert C.STATS.loaded == loaded + 1 and C.STATS.dropped == before + 1
        np.testing.assert_array_equal(np.asarray(exe(np.ones(3))[0]), np.full(3, 5.0))
    finally:
        C.clear()


def expected_cpu_options() -> dict:
    """CPU_COMPILER_OPTIONS where this jaxlib's XLA still knows them (jaxlib
    0.10 does; 0.11 dropped the LLVM IR emitters: then XLA's defaults)."""
    from stablelego_jax.runtime import CPU_COMPILER_OPTIONS

    try:
        jax.jit(lambda v: v * 2).lower(np.zeros(2)).compile(compiler_options=CPU_COMPILER_OPTIONS)
    except Exception:  # noqa: BLE001 - jaxlib raises its own error types
        return {}
    return CPU_COMPILER_OPTIONS


def test_compiler_options_on_cpu_and_how_to_turn_them_off(monkeypatch):
    from stablelego_jax import runtime

    assert jax.default_backend() == "cpu"
    expected = expected_cpu_options()
    assert runtime.compiler_options() == expected
    monkeypatch.setenv("STABLELEGO_XLA_DEFAULTS", "1")
    assert runtime.compiler_options() == {}
    monkeypatch.delenv("STABLELEGO_XLA_DEFAULTS")
    # an XLA that does not know an option: compile with its defaults, no error
    monkeypatch.setattr(runtime, "CPU_COMPILER_OPTIONS", {"xla_cpu_no_such_option": False})
    assert runtime.compiler_options() == {}
    monkeypatch.undo()
    assert runtime.compiler_options() == expected


def test_compiled_solvers_get_the_compiler_options(monkeypatch):
    seen = []
    real = jax.stages.Lowered.compile

    def spy(self, compiler_options=None, **kw):
        seen.append(compiler_options)
        return real(self, compiler_options, **kw)

    monkeypatch.setenv("STABLELEGO_CACHE", "0")
    monkeypatch.setattr(jax.stages.Lowered, "compile", spy)
    exe = C.compiled("test_options", lambda v: (v * 2,), None, (np.ones(3),), export=False)
    np.testing.assert_allclose(exe(np.ones(3))[0], 2.0)
    assert seen[-1] == expected_cpu_options()


def test_a_process_with_one_core_compiles_in_one_split():
    """``one_core_compiles`` (a pool worker with a core to itself) adds
    XLA's one-split code generation to the CPU options, from then on; a
    program compiled with them gives the same numbers."""
    out = _python(
        "import json, jax, numpy as np;"
        "from stablelego_jax.runtime import compiler_options, one_core_compiles, CPU_COMPILER_OPTIONS;"
        "a = compiler_options(); one_core_compiles(); b = compiler_options();"
        "f = lambda v: (v * 2.0 + 1.0).sum();"
        "x = np.arange(5.0);"
        "r = [float(jax.jit(f).lower(x).compile(o)(x)) for o in (a, b)];"
        "print(json.dumps(dict(a=a, b=b, r=r, cpu=jax.default_backend() == 'cpu')))")
    if out["cpu"] and out["a"]:  # an XLA that accepts the library's options
        assert out["a"] == {"xla_cpu_use_fusion_emitters": False}
        assert out["b"] == dict(out["a"], xla_cpu_parallel_codegen_split_count=1)
    assert out["r"][0] == out["r"][1] == 25.0
