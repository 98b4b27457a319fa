import os
import sys

import jax
import pytest

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "examples")

# the read-only shared data beside the checkout (reference layouts, meshes)
SHARED = os.path.join(os.path.dirname(__file__), "..", "..", "shared")
SHARED_REF = os.path.join(SHARED, "reference", "stablelego")
SHARED_BRICKGPT = os.path.join(SHARED, "reference", "brickgpt")
needs_shared = pytest.mark.skipif(not os.path.isdir(SHARED_REF), reason="shared reference folder absent")
