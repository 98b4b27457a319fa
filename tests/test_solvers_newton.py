"""The reduced Newton matrix of both interior points (stablelego_jax.solvers.newton)."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stablelego_jax.generate.procedural import cuboid
from stablelego_jax.layout import brick_layout
from stablelego_jax.model import NORMAL, compile_layout
from stablelego_jax.solvers.newton import reduced_matrix
from stablelego_jax.solvers.problem import (layer_bucket, layer_plan, layered_problem, operators, plan_problem, rung,
                                            slab_levels)

pytestmark = pytest.mark.usefixtures("x64")


def _leaning_wall():
    """2x2 bricks, every level shifted one stud: supports in the slab above (slabs)."""
    pos = [(2 * i + z, 2 * j + z % 2, z) for z in range(5) for i in range(3) for j in range(2)]
    return compile_layout(brick_layout(pos, [(2, 2)] * len(pos)))


def _problem(kind):
    if kind == "dense":
        m = compile_layout(cuboid(3, 2, 4))
        return m, layered_problem(m, 1)
    if kind == "layers":
        m = compile_layout(cuboid(3, 2, 4))
        key = ("layered",) + layer_bucket(*layer_plan(m))
    else:
        m = _leaning_wall()
        lv = slab_levels(m)
        key = ("slabs",) + layer_bucket(len(np.unique(lv)), int(np.bincount(lv).max())) + (4,)
    _, prob = plan_problem(m, key, rung(m.m, 64), rung(m.group.shape[1], 4))
    return m, prob


@pytest.mark.parametrize("kind", ["dense", "layers", "slabs"])
def test_blocks_hold_the_reduced_matrix(kind):
    """assemble(e, q, rho, dr) holds A diag(e) A' + sum_b rho_b (A q_b)(A q_b)'
    + diag(dr), q_b: q on brick b's NORMAL columns, in its diagonal blocks
    and the blocks below them; the rest of the matrix is zero (block
    tridiagonal), whichever of the three assemblies the problem gets. The
    layered assembly's diagonal blocks are exact in their lower triangle,
    the part the block Cholesky reads."""
    m, prob = _problem(kind)
    A, _, coef, _, _ = operators(prob, m.params)
    n, mm = prob.gravity.shape[0], prob.col_kind.shape[0]
    L = 1 if prob.layers is None else prob.layers.shape[0]
    assert (kind == "dense") == (L == 1) and (kind == "slabs") == (prob.supports is not None)
    Ad = np.asarray(jax.jit(jax.vmap(A))(jnp.eye(mm))).reshape(mm, -1).T  # (6n, m): A applied to each column
    rng = np.random.default_rng(3)
    e, q = rng.uniform(0.5, 2.0, mm), rng.uniform(-1.0, 1.0, mm)
    rho, dr = rng.uniform(0.5, 2.0, n), rng.uniform(0.5, 2.0, 6 * n)
    normal = (np.asarray(prob.col_kind) == NORMAL) & np.asarray(prob.col_mask)
    owner = np.asarray(prob.col_brick)[:, 0]
    M = (Ad * e) @ Ad.T + np.diag(dr)
    for b in range(n):
        v = Ad @ np.where(normal & (owner == b), q, 0.0)
        M += rho[b] * np.outer(v, v)
    assert np.abs(M - M.T).max() < 1e-9
    asm = reduced_matrix(prob.col_brick, coef, normal, n, L, prob.chunks, prob.supports, prob.col_slot)
    D, E = (np.asarray(x) for x in jax.jit(asm)(e, q, rho, dr))
    k = 6 * (n // L)
    assert D.shape == E.shape == (L, k, k)
    for i in range(L):
        Mi = M[i * k:(i + 1) * k, i * k:(i + 1) * k]
        if kind == "layers":
            np.testing.assert_allclose(np.tril(D[i]), np.tril(Mi), atol=1e-9)
        else:
            np.testing.assert_allclose(D[i], Mi, atol=1e-9)
        if i + 1 < L:
            np.testing.assert_allclose(E[i], M[(i + 1) * k:(i + 2) * k, i * k:(i + 1) * k], atol=1e-9)
        for j in range(i + 2, L):
            assert not M[j * k:(j + 1) * k, i * k:(i + 1) * k].any()
    if kind != "dense":
        assert np.abs(E[:-1]).max() > 0.1  # the layers are coupled
