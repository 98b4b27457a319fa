"""The interior-point iteration both interior points share (stablelego_jax.solvers.interior)."""
import jax
import jax.numpy as jnp
import numpy as np

from stablelego_jax.solvers.interior import boundary_step, centring, iterate


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


def test_iterate_stops_when_told_keeps_the_last_state_on_a_breakdown_and_vmaps():
    def step(x):  # halve until below 1; a breakdown (keep) once below 0.3
        new = x / 2
        return new, new < 1.0, new < 0.3

    with jax.enable_x64(True):
        x, it = iterate(step, jnp.asarray(5.0), 100)
        assert (float(x), int(it)) == (0.625, 3)
        x, it = iterate(step, jnp.asarray(5.0), 2)  # max_iter first
        assert (float(x), int(it)) == (1.25, 2)
        x, it = iterate(lambda x: step(x)[:2] + (x / 2 < 0.3,), jnp.asarray(0.5), 100)
        assert (float(x), int(it)) == (0.5, 1)  # the first step broke down: the start is kept
        # a pytree state, a batch: each problem stops on its own
        xs, its = jax.vmap(lambda v: iterate(lambda s: (dict(v=s["v"] / 2), s["v"] / 2 < 1.0, False), dict(v=v), 100)
                           )(jnp.asarray([5.0, 0.9, 40.0]))
        np.testing.assert_array_equal(np.asarray(xs["v"]), [0.625, 0.45, 0.625])
        np.testing.assert_array_equal(np.asarray(its), [3, 1, 6])
