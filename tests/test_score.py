"""Eq. 10: the one equilibrium operator, largest drag, equilibrium test and verdict
(stablelego_jax.score), the same on numpy and JAX arrays."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stablelego_jax.generate.procedural import stairs
from stablelego_jax.model import NORMAL, Params, compile_layout
from stablelego_jax.score import (bottom_sum, brick_drag, brick_scores, eq9_cost, equilibrium, equilibrium_t,
                                  largest_drag, residual, residual_bad, verdict)
from stablelego_jax.solvers.exact import solve_exact


def test_largest_drag_and_bottom_sum_over_each_bricks_bottom_contacts():
    v = np.array([0.1, 0.5, 0.25, 0.3])
    group = np.array([[0, 1, 4], [2, 3, 4], [4, 4, 4]])  # 4 = empty slot
    for fn, want in ((largest_drag, [0.5, 0.3, 0.0]), (bottom_sum, [0.6, 0.55, 0.0])):
        np.testing.assert_allclose(fn(v, group), want)
        with jax.enable_x64(True):
            np.testing.assert_allclose(np.asarray(fn(jnp.asarray(v), jnp.asarray(group))), want)


def test_equilibrium_operator_by_hand_and_its_transpose():
    """Column 0 presses brick 0 up and brick 1 down; column 1 joins brick 1
    and the baseplate (slot n = 2, dropped): A f by hand, <A f, y> = <f, A' y>,
    and numpy and JAX give the same arrays."""
    coef = np.zeros((2, 2, 6))
    coef[0, 0, 2], coef[0, 1, 2], coef[0, 0, 3] = 1.0, -1.0, 0.5
    coef[1, 0, 2], coef[1, 1, 2] = 2.0, 7.0
    cb = np.array([[0, 1], [1, 2]])
    f = np.array([3.0, -1.0])
    want = np.zeros((2, 6))
    want[0, 2], want[0, 3] = 3.0, 1.5
    want[1, 2] = -3.0 - 2.0
    np.testing.assert_allclose(equilibrium(coef, cb, f, 2), want)
    y = np.random.default_rng(0).normal(size=(2, 6))
    np.testing.assert_allclose((equilibrium(coef, cb, f, 2) * y).sum(), f @ equilibrium_t(coef, cb, y))
    with jax.enable_x64(True):
        np.testing.assert_array_equal(np.asarray(equilibrium(jnp.asarray(coef), jnp.asarray(cb), jnp.asarray(f), 2)),
                                      equilibrium(coef, cb, f, 2))
        np.testing.assert_array_equal(np.asarray(equilibrium_t(jnp.asarray(coef), jnp.asarray(cb), jnp.asarray(y))),
                                      equilibrium_t(coef, cb, y))


def test_verdict_is_eq10_with_the_drag_tolerance():
    p = Params()
    dmax = np.array([0.0, 0.49, p.T * (1 - 1e-7), p.T * 1.5, 0.2])
    bad = np.array([False, False, False, False, True])
    np.testing.assert_allclose(verdict(dmax, bad, p), [0.0, 0.49 / p.T, 1.0, 1.0, 1.0])
    # just outside the tolerance is not failing
    assert verdict(np.array([p.T * (1 - 1e-5)]), np.array([False]), p)[0] < 1.0


def test_residual_bad_compares_forces_and_torques_with_their_own_tolerance():
    p = Params()
    r = np.zeros((3, 6))
    r[0, 2] = 2 * p.eq_tol  # a force beyond the tolerance
    r[1, 4] = 0.5 * p.eq_tol  # a torque of eq_tol/2 N m: beyond eq_tol * stud
    r[2, 4] = 0.5 * p.eq_tol * p.stud  # within
    np.testing.assert_array_equal(residual_bad(r, p), [True, True, False])


def test_brick_scores_numpy_and_jax_agree():
    model = compile_layout(stairs(5, load_kg=0.2))
    f = solve_exact(model).f
    s_np, bad_np, d_np = brick_scores(model, f)
    with jax.enable_x64(True):
        s_j, bad_j, d_j = jax.jit(lambda x: brick_scores(model, x))(jnp.asarray(f))
    np.testing.assert_allclose(np.asarray(s_j), s_np, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(bad_j), bad_np)
    np.testing.assert_allclose(np.asarray(d_j), d_np, atol=1e-12)
    # the largest drag is the largest max(-n, 0) over the brick's own NORMAL columns
    i = int(np.argmax(d_np))
    cols = np.nonzero((model.col_kind == NORMAL) & (model.col_brick[:, 0] == i))[0]
    assert d_np[i] == pytest.approx(np.maximum(-f[cols], 0).max())
    assert brick_drag(model, f)[i] == d_np[i]
    assert np.abs(residual(model, f)[: model.n]).max() < 1e-6  # a stable-by-equilibrium solution


def test_floating_bricks_follow_vertical_contacts_to_the_ground():
    from stablelego_jax import make_layout
    from stablelego_jax.score import floating_bricks

    # a grounded pair, a brick beside it held by side presses only, a floating stack of two
    lay = make_layout(["a", "b", "side", "c", "d"], [(0, 0, 0), (0, 0, 1), (2, 0, 1), (0, 0, 4), (0, 0, 5)],
                      [(2, 4)] * 5, [0.00216] * 5)
    model = compile_layout(lay)
    np.testing.assert_array_equal(floating_bricks(model)[: model.n], [False, False, True, True, True])
    padded = model.pad(8, model.m + 5)
    np.testing.assert_array_equal(floating_bricks(padded), [False, False, True, True, True, False, False, False])


def test_every_brick_of_a_floating_group_fails_with_every_solver():
    """Eq. 9 may put a floating stack's whole residual on one of its bricks;
    the verdict fails all of them, whatever the solver."""
    from stablelego_jax import make_layout
    from stablelego_jax.analysis import analyze_layout

    lay = make_layout(["base", "c", "d"], [(0, 0, 0), (0, 0, 4), (0, 0, 5)], [(2, 4)] * 3, [0.00216] * 3)
    for solver in ("exact", "jax"):
        a = analyze_layout(lay, solver=solver)
        assert a.scores["c"] == 1.0 and a.scores["d"] == 1.0, solver
        assert a.scores["base"] < 1.0 and not a.stable


def test_weakest_brick_breaks_ties_by_drag_then_input_order():
    from stablelego_jax.score import weakest_brick

    T = 0.98
    # scores within 1e-6 of the highest tie; the larger drag wins, then the first
    assert weakest_brick([0.5, 0.9, 0.9 - 1e-9, 0.2], [0.1, 0.3, 0.4, 0.0], T) == 2
    assert weakest_brick([0.5, 0.9, 0.9 - 1e-9, 0.2], [0.1, 0.4, 0.4 + 1e-9, 0.0], T) == 1
    assert weakest_brick([1.0, 1.0, 0.3], [0.0, 0.0, 0.1], T) == 0  # two floating bricks: the first
    assert weakest_brick([0.3, 0.5 + 2e-6, 0.5], [0.1, 0.0, 0.4], T) == 1  # beyond the tie: the score decides


def test_eq9_cost_is_the_exact_solvers_objective():
    # a stair that fails: residuals, drags and the largest drags all cost
    model = compile_layout(stairs(6))
    r = solve_exact(model)
    assert r.success
    assert eq9_cost(model, r.f) == pytest.approx(r.objective, rel=1e-6)
    f = np.zeros(model.m_pad)  # no forces: every brick's weight is residual
    assert eq9_cost(model, f) == pytest.approx(np.abs(model.gravity[: model.n]).sum())
