import atexit
import os
import shutil
import sys
import tempfile

import jax
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

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
