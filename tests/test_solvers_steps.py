"""The step rules both interior points share (stablelego_jax.solvers.steps)."""
import jax
import jax.numpy as jnp
import numpy as np

from stablelego_jax.solvers.steps import boundary_step, centring


def test_boundary_step_is_the_first_entry_to_reach_zero():
    with jax.enable_x64(True):
        v = jnp.array([1.0, 2.0, 0.5, 4.0])
        dv = jnp.array([-2.0, -1.0, 1.0, -8.0])
        on = jnp.array([True, True, True, False])  # the last entry does not count
        t = float(boundary_step(v, dv, on))
        assert t == 0.5
        assert float(jnp.min(jnp.where(on, v + t * dv, 1.0))) == 0.0
        # nothing decreasing: no limit
        assert np.isinf(float(boundary_step(v, jnp.abs(dv), on)))


def test_centring_is_mehrotras_cube_within_zero_and_one():
    with jax.enable_x64(True):
        assert float(centring(0.5, 1.0)) == 0.125
        assert float(centring(2.0, 1.0)) == 1.0  # a predictor that made things worse: full centring
        assert float(centring(0.0, 1.0)) == 0.0
