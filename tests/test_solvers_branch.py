"""cond_any: lax.cond alone; under vmap, the rare branch only when a member needs it."""
import jax
import jax.numpy as jnp
import numpy as np

from stablelego_jax.solvers.branch import cond_any


def _branches(calls):
    def rare(x, y):
        jax.debug.callback(lambda: calls.append(1))
        return {"a": x * 2.0 + y, "b": jnp.sum(x)}

    def usual(x, y):
        return {"a": x - y, "b": jnp.zeros((), x.dtype)}

    return rare, usual


def _expected(p, x, y):
    return ({"a": x * 2.0 + y, "b": np.sum(x)} if p else {"a": x - y, "b": 0.0})


def test_unbatched_is_the_plain_branch():
    calls = []
    rare, usual = _branches(calls)
    x, y = jnp.arange(3.0), jnp.float32(1.0)
    f = jax.jit(lambda p, x, y: cond_any(p, rare, usual, x, y))
    for p in (True, False):
        out = f(p, x, y)
        exp = _expected(p, np.arange(3.0), 1.0)
        np.testing.assert_allclose(out["a"], exp["a"])
        np.testing.assert_allclose(out["b"], exp["b"])
    jax.effects_barrier()
    assert len(calls) == 1  # the rare branch ran for the True call only


def test_batched_members_get_their_own_branch_and_the_rare_one_runs_only_when_needed():
    calls = []
    rare, usual = _branches(calls)
    xs = jnp.arange(12.0).reshape(4, 3)
    ys = jnp.array([0.5, 1.0, 1.5, 2.0])
    f = jax.jit(jax.vmap(lambda p, x, y: cond_any(p, rare, usual, x, y)))
    preds = np.array([True, False, False, True])
    out = f(preds, xs, ys)
    for i, p in enumerate(preds):
        exp = _expected(p, np.asarray(xs[i]), float(ys[i]))
        np.testing.assert_allclose(out["a"][i], exp["a"])
        np.testing.assert_allclose(out["b"][i], exp["b"])
    jax.effects_barrier()
    ran = len(calls)
    assert ran >= 1
    out = f(np.zeros(4, bool), xs, ys)  # no member needs it: JAX's own batched cond would run it
    np.testing.assert_allclose(out["a"], np.asarray(xs) - np.asarray(ys)[:, None])
    jax.effects_barrier()
    assert len(calls) == ran


def test_unbatched_operands_and_predicate_and_nested_vmap():
    calls = []
    rare, usual = _branches(calls)
    x = jnp.arange(3.0)
    ys = jnp.array([1.0, 2.0])
    # predicate and x shared by the batch, y batched
    out = jax.vmap(lambda y: cond_any(True, rare, usual, x, y))(ys)
    np.testing.assert_allclose(out["a"], np.arange(3.0)[None] * 2.0 + np.asarray(ys)[:, None])
    np.testing.assert_allclose(out["b"], [3.0, 3.0])
    # a batch of batches, predicates mixed in the inner one
    preds = np.array([[True, False], [False, False]])
    xs = jnp.arange(12.0).reshape(2, 2, 3)
    out = jax.jit(jax.vmap(jax.vmap(lambda p, x: cond_any(p, rare, usual, x, 1.0))))(preds, xs)
    for i in range(2):
        for j in range(2):
            exp = _expected(preds[i, j], np.asarray(xs[i, j]), 1.0)
            np.testing.assert_allclose(out["a"][i, j], exp["a"])
            np.testing.assert_allclose(out["b"][i, j], exp["b"])
