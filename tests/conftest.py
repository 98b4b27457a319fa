import atexit
import os
import re
import shutil
import subprocess
import sys
import tempfile

# The suite compiles with XLA's CPU backend at optimisation level 0 (its
# processes, xdist's workers and every subprocess a test starts inherit it):
# the suite is mostly compiling, and LLVM's passes are most of a compile. On a
# 2-core CPU the suite took 6.5-7.8 min instead of 10.7 (BENCHMARKS.md, "The
# test suite's compiles"). The level changes no HLO, only the machine code; the
# answers are the shipped build's to rounding, which
# tests/test_runtime.py checks against a run at XLA's defaults, and the
# tests whose claim is bitwise equality run at the defaults
# (:func:`rerun_at_shipping_xla`). ``STABLELEGO_TEST_XLA=default make test``
# runs the whole suite at XLA's defaults. Set before JAX starts its backend.
# SHIPPING_XLA_FLAGS: the user's own XLA_FLAGS, for subprocesses at the
# defaults (xdist's workers inherit the suite's flags: the first process
# records the user's).
SHIPPING_XLA_FLAGS = os.environ.setdefault("STABLELEGO_SHIPPING_XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))
SUITE_XLA_FLAG = "--xla_backend_optimization_level=0"
# whether this process compiles at the suite's level 0 (not asked for the defaults, and
# no level of the user's own)
LEVEL_0 = (os.environ.get("STABLELEGO_TEST_XLA", "").strip().lower() != "default"
           and "xla_backend_optimization_level" not in SHIPPING_XLA_FLAGS)
if LEVEL_0:
    os.environ["XLA_FLAGS"] = f"{SHIPPING_XLA_FLAGS} {SUITE_XLA_FLAG}".strip()

import jax  # noqa: E402 (after XLA_FLAGS)
import pytest  # noqa: E402

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))


def shipping_env() -> dict:
    """The environment of a subprocess that compiles as the shipped library
    does (XLA's default optimisation, the user's own ``XLA_FLAGS`` kept)."""
    env = dict(os.environ, STABLELEGO_TEST_XLA="default", XLA_FLAGS=SHIPPING_XLA_FLAGS)
    if not SHIPPING_XLA_FLAGS:
        env.pop("XLA_FLAGS")
    return env


def rerun_at_shipping_xla(request) -> bool:
    """For a test whose claim holds bit for bit only in the shipped build
    (level 0's machine code rounds differently with the pool workers' one-split
    code generation): when this process compiles at the suite's level 0, run
    the test again in a pytest subprocess at XLA's defaults, assert that it
    passed, and return True (the caller returns); False when this process
    compiles at the defaults already (the caller runs its body)."""
    if not LEVEL_0:
        return False
    root = str(request.config.rootpath)
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:xdist",
                        request.node.nodeid], cwd=root, env=shipping_env(), capture_output=True, text=True,
                       timeout=900)
    assert r.returncode == 0, (r.stdout + r.stderr)[-4000:]
    assert re.search(r"\b1 passed\b", r.stdout), r.stdout[-2000:]
    return True

# The library's disk caches (compiled solvers) go to a folder of this test run,
# never to the user's ~/.cache; subprocesses started by tests (and xdist's
# workers) inherit it; the process that made it removes it at exit.
if "STABLELEGO_CACHE_DIR" not in os.environ:
    _cache = tempfile.mkdtemp(prefix="stablelego-test-cache-")
    os.environ["STABLELEGO_CACHE_DIR"] = _cache
    atexit.register(shutil.rmtree, _cache, ignore_errors=True)

EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "examples")

# the read-only shared data beside the checkout (reference layouts, meshes)
SHARED = os.path.join(os.path.dirname(__file__), "..", "..", "shared")
SHARED_REF = os.path.join(SHARED, "reference", "stablelego")
SHARED_BRICKGPT = os.path.join(SHARED, "reference", "brickgpt")
needs_shared = pytest.mark.skipif(not os.path.isdir(SHARED_REF), reason="shared reference folder absent")


@pytest.fixture
def x64():
    """64-bit JAX types for a test's own JAX code (the library switches them on
    for its own work; the test process, like a user's, runs in float32)."""
    with jax.enable_x64(True):
        yield


def raises_layout_error(fn, *must_contain):
    """The LayoutError ``fn()`` raises, after checking that its message holds
    each of ``must_contain``."""
    from stablelego_jax.layout import LayoutError

    with pytest.raises(LayoutError) as ei:
        fn()
    msg = str(ei.value)
    for s in must_contain:
        assert s in msg, f"{s!r} not in {msg!r}"
    return ei.value


def hanging_scene(groups: int) -> dict:
    """A scene (JSON dict) of ``groups`` copies of: a two-brick column, an
    arm on it rotated 45 degrees, and a 1x1 hanging from the arm's far end
    over nothing. Contact levels count from the ground, so the hanging
    brick's level is above the arm it hangs from."""
    scene = {}
    for k in range(groups):
        dx = 12 * k
        scene[f"base{k}"] = {"x": dx, "y": 0, "z": 0, "brick_id": 2, "ori": 0}
        scene[f"mid{k}"] = {"x": dx, "y": 0, "z": 1, "brick_id": 2, "ori": 0}
        scene[f"arm{k}"] = {"center": [dx - 0.974873734, 5.974873734], "yaw": 45.0, "z": 2, "brick_id": 4}
        scene[f"hang{k}"] = {"center": [dx - 2.742640687, 8.449747468], "yaw": 45.0, "z": 1, "brick_id": 1}
    return scene
