"""Differentiable stability loss: exactness of w = 0 / w = 1, implicit gradients vs
central finite differences, jit/vmap, and the zero-temperature limit (Eq. 10)."""
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from blas_threads import one_blas_thread  # noqa: F401  (module fixture: one BLAS thread)
from conftest import EXAMPLES
from stablelego_jax import load_layout
from stablelego_jax.analysis import analyze_layout
from stablelego_jax.loss import LossOptions, soft_report, stability_loss
from stablelego_jax.soft import candidate_brick, compile_soft, soft_problem
from stablelego_jax.solvers.problem import pad_soft, stack_soft

pytestmark = pytest.mark.usefixtures("x64")  # the tests jit and differentiate the loss themselves

REF = os.path.join(EXAMPLES, "stablelego")
LABELS = json.load(open(os.path.join(EXAMPLES, "labels_stablelego.json")))
SHAPE = (32, 1024, 32)  # every problem of this module: one compile per function
OPTS = LossOptions()


def _pad(prob):
    return pad_soft(prob, *SHAPE)


def _weights(soft, present=()):
    w = np.zeros(SHAPE[0])
    w[: soft.n] = soft.weights(present)
    return w


def _loss_fn(w, loads, prob):
    return stability_loss(w, loads, prob, opts=OPTS)


# three compiled functions for the whole module (compiling the solver dominates its time)
_report = jax.jit(lambda w, loads, prob, tau: soft_report(w, loads, prob, tau, opts=OPTS))
_grad = jax.jit(jax.value_and_grad(_loss_fn, argnums=(0, 1)))
_vgrad = jax.jit(jax.vmap(jax.grad(_loss_fn, argnums=(0, 1)), in_axes=(0, None, 0)))
ZERO = np.zeros(SHAPE[0])
TAU = OPTS.temperature


def _loss(w, loads, prob):
    return float(np.sum(_report(w, loads, prob, TAU).brick_loss))


def _scores(w, loads, prob):
    r = _report(w, ZERO if loads is None else loads, prob, TAU)
    return (r.scores, r.max_drag), r.converged


def _brick_loss(w, loads, prob):
    return _report(w, ZERO if loads is None else loads, prob, TAU).brick_loss


def _stair():
    lay = load_layout(os.path.join(REF, "stair_20.json"))
    cands = [candidate_brick([(4, 21, 0, 1, 2)]),  # the paper's repair
             candidate_brick([(12, 21, 0, 2, 2), (12, 21, 1, 2, 2), (12, 21, 2, 2, 2), (12, 21, 3, 2, 2),
                              (12, 21, 4, 2, 2)]),  # a pillar under brick '6'
             candidate_brick([(4, 19, 1, 2, 2)])]  # floating beside brick '2'
    return lay, compile_soft(lay, cands)


def test_weight_zero_is_exactly_absent():
    lay, soft = _stair()
    plain = _pad(soft_problem(lay))
    w0 = np.zeros(SHAPE[0])
    w0[: lay.n] = 1.0
    (s0, d0), c0 = _scores(w0, None, plain)
    (s1, d1), c1 = _scores(_weights(soft), None, _pad(soft.problem))
    assert bool(c0) and bool(c1)
    # the same solution to the solver's accuracy (the interior-point path differs)
    np.testing.assert_allclose(d1[: lay.n], d0[: lay.n], atol=1e-6)
    l0 = _brick_loss(w0, None, plain)
    l1 = _brick_loss(_weights(soft), None, _pad(soft.problem))
    np.testing.assert_allclose(l1[: lay.n], l0[: lay.n], rtol=1e-5, atol=1e-9)
    assert (np.asarray(l1)[lay.n:] == 0).all() and (np.asarray(s1)[lay.n:] == 0).all()
    # exactly: at weight 0 no candidate force enters a base brick's residual or drag maximum
    from stablelego_jax.solvers.soft_ipm import brick_residual, soft_context

    prob = _pad(soft.problem)
    ctx = soft_context(_weights(soft), None, prob, OPTS.params)
    cand_col = np.isin(np.asarray(prob.col_brick), np.arange(lay.n, soft.n)).any(axis=1)
    phi = np.random.default_rng(0).normal(size=SHAPE[1])
    phi2 = np.where(cand_col, phi + 10.0, phi)
    r1, r2 = np.asarray(brick_residual(ctx, jnp.asarray(phi))), np.asarray(brick_residual(ctx, jnp.asarray(phi2)))
    np.testing.assert_array_equal(r1[: lay.n], r2[: lay.n])
    base_group = np.asarray(ctx.owner)[cand_col] < lay.n  # candidate contacts under base bricks
    assert base_group.any() and (np.asarray(ctx.o0)[cand_col][base_group] == 0).all()
    assert (np.asarray(ctx.wcol)[cand_col] == 0).all() and (np.asarray(ctx.om)[lay.n:] == 0).all()


def test_weight_one_is_present():
    lay, soft = _stair()
    full = soft.layout_with([0])
    (s_full, d_full), _ = _scores(_weights(compile_soft(full, [])), None, _pad(soft_problem(full)))
    (s_soft, d_soft), conv = _scores(_weights(soft, [0]), None, _pad(soft.problem))
    assert bool(conv)
    idx = list(range(lay.n)) + [int(soft.unit_bricks[0][0])]
    np.testing.assert_allclose(np.asarray(d_soft)[idx], np.asarray(d_full)[: full.n], atol=2e-4)
    # with the paper's repair brick present the stair stands, without it brick '2' fails
    assert (np.asarray(s_soft)[idx] < 1).all()
    (s_abs, _), _ = _scores(_weights(soft), None, _pad(soft.problem))
    assert np.asarray(s_abs)[1] == 1.0


def _fd_check(f, g, x0, idx, h):
    """Central differences of scalar f at x0 along the unit vectors idx vs g (the
    implicit gradient); components smaller than 1e-3 of the largest are
    compared in absolute terms (their relative error is rounding noise)."""
    fds = []
    for i in idx:
        xp, xm = x0.copy(), x0.copy()
        xp[i] += h
        xm[i] -= h
        fds.append((float(f(xp)) - float(f(xm))) / (2 * h))
    fds = np.array(fds)
    gi = np.asarray(g)[idx]
    scale = np.abs(fds).max()
    big = np.abs(fds) > 1e-3 * scale
    rel = np.abs(gi - fds)[big] / np.abs(fds)[big]
    assert rel.max() < 0.05, (idx, gi, fds)
    assert np.abs(gi - fds)[~big].max(initial=0.0) < 1e-3 * scale
    return rel


def test_gradients_match_central_finite_differences():
    lay, soft = _stair()
    prob = _pad(soft.problem)
    w = _weights(soft)
    w[soft.n_base:soft.n] = 0.4  # candidates half faded in: a smooth point inside (0, 1)
    w[[5, 10]] = [0.8, 0.9]
    loads = np.zeros(SHAPE[0])
    loads[[5, 12]] = [0.01, 0.02]
    _, (gw, gl) = _grad(w, loads, prob)
    rels = [_fd_check(lambda v: _loss(v, loads, prob), gw, w, [5, 10, 20, 21, 26], 1e-4),
            _fd_check(lambda v: _loss(w, v, prob), gl, loads, [1, 3, 5, 12, 19], 1e-4)]
    assert max(r.max() for r in rels) < 0.05


def test_gradients_on_the_loaded_lever():
    lay = load_layout(os.path.join(REF, "stick_heavy.json"))
    prob = _pad(soft_problem(lay))
    w = np.zeros(SHAPE[0])
    w[: lay.n] = 1.0
    w[[4, 8]] = 0.7
    loads = np.zeros(SHAPE[0])
    loads[[11, 13]] = 0.05
    _, (gw, gl) = _grad(w, loads, prob)
    _fd_check(lambda v: _loss(w, v, prob), gl, loads, [1, 6, 11, 13], 1e-4)
    _fd_check(lambda v: _loss(v, loads, prob), gw, w, [4, 8], 1e-4)
    # physically: more load on the lever's tip (brick '14' on top of '12', '13') makes it worse
    assert float(gl[13]) > 0


def test_score_gradients_with_respect_to_loads():
    """Issue 18 item 2: how much closer to failing a brick gets per kilogram
    hung on any brick, d soft_scores[k] / d loads, by the implicit adjoint,
    against central differences of the scores themselves."""
    from stablelego_jax.loss import soft_scores

    lay = load_layout(os.path.join(REF, "stick_light.json"))
    prob = _pad(soft_problem(lay))
    w = np.zeros(SHAPE[0])
    w[: lay.n] = 1.0
    loads = np.zeros(SHAPE[0])
    loads[[3, 9]] = 0.001  # a gram on two bricks: still standing
    (s, _), ok = _scores(w, loads, prob)
    assert bool(ok)
    k = int(np.argmax(np.asarray(s)[: lay.n]))  # the weakest brick, stable (score < 1)
    assert 0.0 < float(s[k]) < 1.0
    grad = jax.jit(jax.grad(lambda w_, l_, p_: soft_scores(w_, l_, p_, opts=OPTS)[0][k], argnums=1))
    g = np.asarray(grad(w, loads, prob))
    assert np.isfinite(g).all() and np.abs(g[lay.n:]).max() == 0.0  # padding bricks carry no load
    top = [int(i) for i in np.argsort(-np.abs(g[: lay.n]))[:4]]
    _fd_check(lambda v: float(_scores(w, v, prob)[0][0][k]), g, loads, top, 1e-4)
    # weight on the bricks the weakest one holds up makes it weaker
    assert g[top[0]] > 0


def test_jit_vmap_grad():
    lay, soft = _stair()
    prob = _pad(soft.problem)
    lever = load_layout(os.path.join(REF, "stick_heavy.json"))
    lprob = _pad(soft_problem(lever))
    # a batch of weights and layouts (stacked problems): vmap of grad == one by one
    w = np.zeros((3, SHAPE[0]))
    w[0], w[1] = _weights(soft), _weights(soft, [0])
    w[2, : lever.n] = 1.0
    gb, _ = _vgrad(w, ZERO, stack_soft([prob, prob, lprob]))
    for i, p in enumerate([prob, prob, lprob]):
        val, (g, _) = _grad(w[i], ZERO, p)
        # batched rounding only: 1.5e-12 of the largest with the centring steps and the
        # adjoint refined, 3.5e-6 before (session 49)
        np.testing.assert_allclose(gb[i], g, atol=1e-9 * np.abs(g).max())
        np.testing.assert_allclose(float(val), _loss(w[i], ZERO, p), rtol=1e-6)
    assert _loss(w[1], ZERO, prob) < _loss(w[0], ZERO, prob)  # the repair brick lowers the loss
    # at weight 0 the paper's repair brick and the pillar help, the floating brick does not
    i_fix, i_pillar, i_float = soft.unit_index
    assert gb[0][i_fix] < 0 and gb[0][i_pillar] < 0 and gb[0][i_float] > 0


@pytest.mark.parametrize("name", sorted(k for k in LABELS if not k.startswith("_")))
def test_zero_temperature_recovers_eq10(name):
    lay = load_layout(os.path.join(REF, name))
    prob = _pad(soft_problem(lay))
    w = np.zeros(SHAPE[0])
    w[: lay.n] = 1.0
    (s, drag), conv = _scores(w, None, prob)
    assert bool(conv)
    ex = analyze_layout(lay, solver="exact")
    exd = np.array([ex.max_drag[k] for k in lay.keys])
    np.testing.assert_allclose(np.asarray(drag)[: lay.n], exd, atol=2e-3)
    assert bool((np.asarray(s)[: lay.n] < 1).all()) == LABELS[name]["stable"] == ex.stable
    # the per-brick loss tends to max(D/T - 1, 0) (+ residual): positive exactly where Eq. 10 says 1
    r = _report(w, ZERO, prob, 1e-5)
    lb, p = np.asarray(r.brick_loss)[: lay.n], np.asarray(r.fail_prob)[: lay.n]
    hinge = np.maximum(exd / ex.model.params.T - 1.0, 0.0)
    np.testing.assert_allclose(lb, hinge, atol=3e-4)
    failing = np.array([ex.scores[k] >= 1.0 for k in lay.keys])
    assert (lb[failing] > 1e-4).all() and (lb[~failing] < 1e-4).all()
    np.testing.assert_array_equal(p > 0.5, failing)


@pytest.mark.slow
def test_layers_factored_at_their_own_size_give_the_same_loss_and_gradients():
    """A pyramid's layers (36 ... 1 bricks in 40 slots) each factored at the
    smallest cut that holds it and its neighbours (``cut_layers``) give the
    full factorisation's loss and gradients, with a 1 x 8 brick on top, 6
    studs out, a load hung on it, and interior weights."""
    from stablelego_jax.generate.procedural import pyramid
    from stablelego_jax.layout import brick_layout
    from stablelego_jax.solvers.problem import cut_layers, layer_soft

    pyr = pyramid(6, lean=(1, 0))
    soft = compile_soft(brick_layout(np.concatenate([pyr.pos, [[5, 0, 6]]]), np.concatenate([pyr.size, [[8, 1]]])))
    p = pad_soft(layer_soft(soft.problem))
    n, N = soft.n, p.mass.shape[0]
    L, B = p.layers.shape
    assert L >= 7 and B >= 36 and 36 + 25 + 16 + 9 + 4 + 1 + 1 == n
    cut = cut_layers(p)
    assert cut.cut.tolist()[:7] == [36, 25, 16, 9, 4, 1, 1]
    w, loads = np.zeros(N), np.zeros(N)
    w[:n] = 1.0
    w[[20, 40, 50]] = [0.6, 0.8, 0.3]
    loads[n - 1] = 0.4
    f = jax.jit(jax.value_and_grad(lambda w, l, q: stability_loss(w, l, q, opts=OPTS), argnums=(0, 1)))
    (v0, (gw0, gl0)), (v1, (gw1, gl1)) = f(w, loads, p), f(w, loads, cut)
    assert float(v0) > 1e-3  # the load pulls the top brick off: above the barrier's floor
    # the "same loss" (1e-8 relative): another summation order moves where the
    # interior point stops by more than 1e-9 here (session 42's code, cut against uncut,
    # outside pytest: 6.6e-9 with one BLAS thread, 4.7e-9 with the default threads)
    assert abs(float(v1) - float(v0)) <= 1e-8 * abs(float(v0))
    # gradients: 7e-9 of the largest apart (4.8e-7 before the adjoint's refinement step)
    scale = max(np.abs(gw0).max(), np.abs(gl0).max())
    np.testing.assert_allclose(gw1, gw0, atol=1e-7 * scale)
    np.testing.assert_allclose(gl1, gl0, atol=1e-7 * scale)


def test_gradients_do_not_depend_on_the_bricks_numbering():
    """The heavy stick (a lever near its limit) with its bricks numbered in
    reverse: the same loss, and gradients within 1e-8 of the largest. The
    adjoint's reduced solve alone leaves its residual-price rows off by ~1%
    where their curvature is large; without the refinement step the two
    numberings' gradients were 6.6e-6 of the largest apart."""
    from stablelego_jax.layout import make_layout

    lay = load_layout(os.path.join(REF, "stick_heavy.json"))
    n = lay.n
    rev = np.arange(n)[::-1]
    other = make_layout([lay.keys[i] for i in rev], lay.pos[rev], lay.size[rev], lay.mass[rev])
    w = np.zeros(SHAPE[0])
    w[:n] = 1.0
    v0, (gw0, gl0) = _grad(w, ZERO, _pad(soft_problem(lay)))
    v1, (gw1, gl1) = _grad(w, ZERO, _pad(soft_problem(other)))
    assert float(v0) > 1e-3 and abs(float(v1) - float(v0)) <= 1e-9 * float(v0)
    back = np.argsort(rev)
    scale = max(np.abs(gw0).max(), np.abs(gl0).max())
    np.testing.assert_allclose(np.asarray(gw1)[:n][back], np.asarray(gw0)[:n], atol=1e-8 * scale)
    np.testing.assert_allclose(np.asarray(gl1)[:n][back], np.asarray(gl0)[:n], atol=1e-8 * scale)


def test_layered_factorisation_gives_the_dense_loss_and_gradients():
    """The block-tridiagonal factorisation (bricks placed layer by layer) and
    the dense one solve the same Newton systems: same loss and gradients to
    rounding, with candidates at weight 0 (a five-brick pillar spanning five
    layers, a floating brick), interior weights and extra loads, and on
    overlapping placements with contacts between absent ones."""
    from stablelego_jax.layout import TABLE_I_MASS_KG
    from stablelego_jax.soft import compile_placements
    from stablelego_jax.solvers.problem import layer_bucket, layer_soft, soft_layer_plan

    lay, soft = _stair()
    pos = np.array([(0, 0, 0), (0, 0, 1), (0, 0, 2), (0, 0, 2), (1, 0, 2), (2, 0, 2), (0, 1, 1), (1, 0, 1),
                    (0, 0, 0), (1, 0, 0), (3, 0, 1), (2, 0, 0)])
    size = np.array([(1, 1), (1, 1), (1, 4), (1, 1), (1, 1), (1, 1), (1, 1), (1, 2), (2, 1), (1, 1), (1, 1), (2, 2)])
    place = compile_placements(pos, size, [TABLE_I_MASS_KG[tuple(sorted(s))] for s in size])
    rng = np.random.default_rng(3)
    w1 = _weights(soft, [1])
    inner = rng.choice(lay.n, 6, replace=False)
    w1[inner] = rng.uniform(0.3, 0.9, 6)
    loads1 = np.zeros(SHAPE[0])
    loads1[rng.choice(lay.n, 5, replace=False)] = rng.uniform(0.0, 0.05, 5)
    w2 = np.zeros(SHAPE[0])
    w2[[11, 7, 0, 3]] = 1.0
    w2[[1, 10]] = 0.4
    cases = [(soft.problem, w1, loads1), (place, w2, ZERO)]
    plans = [soft_layer_plan(p) for p, _, _ in cases]
    LB = layer_bucket(max(p[0] for p in plans), max(p[1] for p in plans))
    for p, w, loads in cases:
        layered = _pad(layer_soft(p, *LB))
        assert layered.layers.shape == LB and layered.slot[p.mass.shape[0]:].min() == LB[0] * LB[1]
        v0, (gw0, gl0) = _grad(w, loads, _pad(p))
        v1, (gw1, gl1) = _grad(w, loads, layered)
        assert abs(float(v1) - float(v0)) <= 1e-9 * abs(float(v0))
        scale = max(np.abs(gw0).max(), np.abs(gl0).max())
        np.testing.assert_allclose(gw1, gw0, atol=1e-7 * scale)
        np.testing.assert_allclose(gl1, gl0, atol=1e-7 * scale)
