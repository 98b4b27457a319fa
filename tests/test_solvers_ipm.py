"""Interior-point solver: layering, and agreement with HiGHS."""
import json
import os

import jax
import numpy as np
import pytest
from conftest import EXAMPLES, SHARED_REF, hanging_scene, needs_shared

from stablelego_jax.analysis import analyze_layout, make_analysis
from stablelego_jax.formats.reader import load_layout
from stablelego_jax.generate.procedural import cuboid, lever, pyramid, stairs, tower
from stablelego_jax.model import compile_layout
from stablelego_jax.score import residual
from stablelego_jax.solvers import ipm
from stablelego_jax.solvers.exact import solve_exact
from stablelego_jax.layout import brick_layout
from stablelego_jax.model import NORMAL
from stablelego_jax.solvers.problem import (layer_bucket, layer_plan, layered_problem, levels_ok, plan_problem, rung,
                                           slab_levels, solve_plan, stack_problems, support_count,
                                           to_layered)

pytestmark = pytest.mark.usefixtures("x64")  # the tests jit the solver themselves


def test_layered_numbering_keeps_the_physics():
    """Renumbering bricks layer by layer moves rows, never columns: the same
    forces give the same per-brick residuals."""
    lay = stairs(6)
    m = compile_layout(lay)
    L, B = layer_plan(m)
    assert (L, B) == (6, 1)
    lm = to_layered(m, 8, 2)
    assert lm.n_pad == 16 and lm.m_pad == m.m_pad
    f = np.random.default_rng(0).normal(size=m.m_pad)
    r0 = residual(m, f)[: m.n]
    r1 = residual(lm, f)
    z = np.asarray(m.layer[: m.n]) - m.layer[: m.n].min()
    order = np.argsort(z, kind="stable")
    slot = np.empty(m.n, int)
    slot[order] = np.arange(m.n) - np.searchsorted(np.sort(z), np.sort(z))
    np.testing.assert_allclose(r1[z * 2 + slot], r0, atol=1e-12)
    assert not lm.brick_mask[[z * 2 + 1]].any()  # empty slots are padding
    with pytest.raises(ValueError, match="layer slots"):
        to_layered(m, 4, 1)


def _check_against_exact(lay, sol, model):
    ex = solve_exact(compile_layout(lay))
    a = make_analysis(lay, model, np.asarray(sol.f), "jax", bool(sol.converged), 0.0)
    b = make_analysis(lay, compile_layout(lay), ex.f, "exact", True, 0.0)
    assert bool(sol.converged)
    assert float(sol.objective) == pytest.approx(ex.objective, rel=1e-6, abs=1e-9)
    assert a.stable == b.stable
    return a, b


@pytest.mark.parametrize("make", [lambda: stairs(8), lambda: tower(5), lambda: lever(4, 2, 3)])
def test_dense_and_layered_agree_with_highs(make):
    lay = make()
    m = compile_layout(lay)
    f = jax.jit(ipm.solve)
    dense = f(layered_problem(m, 1))
    a, b = _check_against_exact(lay, dense, m)
    L, B = layer_plan(m)
    lm = to_layered(m, *layer_bucket(L, B))
    lay_sol = f(layered_problem(lm, layer_bucket(L, B)[0]))
    _check_against_exact(lay, lay_sol, m)
    assert float(lay_sol.objective) == pytest.approx(float(dense.objective), rel=1e-6, abs=1e-9)


def test_slabs_agree_with_highs():
    """Bricks numbered by vertical slabs (the plan of wide layouts): a
    leaning wall of 2x2 bricks whose every level is shifted one stud along
    x, so the largest drags are active and many bricks sit on bricks of the
    next slab up. The block-tridiagonal solve assembles each brick's term
    from its supports (``Problem.supports``) and gives HiGHS' optimum and
    the dense solve's scores; assembled as layers it does not converge."""
    pos = [(2 * i + z, 2 * j + z % 2, z) for z in range(8) for i in range(3) for j in range(3)]
    lay = brick_layout(pos, [(2, 2)] * len(pos))
    m = compile_layout(lay)
    lv = slab_levels(m)
    cb = m.col_brick[: m.m]
    sup = (m.col_kind[: m.m] == NORMAL) & (cb[:, 1] < m.n)
    assert (lv[cb[sup, 1]] > lv[cb[sup, 0]]).sum() > 50  # supports in the slab above
    assert support_count(m) == 4
    key = ("slabs",) + layer_bucket(len(np.unique(lv)), int(np.bincount(lv).max())) + (4,)
    m_pad, p_pad = rung(m.m, 64), rung(m.group.shape[1], 4)
    fm, prob = plan_problem(m, key, m_pad, p_pad)
    f = jax.jit(ipm.solve)
    sol = f(prob)
    a, b = _check_against_exact(lay, sol, fm)
    assert float(sol.objective) > 1e-5  # drags carry load
    dense = f(layered_problem(compile_layout(lay).pad(m.n, m_pad, p_pad), 1))
    np.testing.assert_allclose([a.scores[k] for k in lay.keys], [make_analysis(
        lay, fm, np.asarray(dense.f), "jax", True, 0.0).scores[k] for k in lay.keys], atol=1e-8)
    assert not bool(f(prob._replace(supports=None, col_slot=None)).converged)  # assembled as layers: wrong


def test_scene_with_hanging_bricks_gets_a_plan_that_converges(tmp_path):
    """A scene's contact levels count from the ground, so a brick hanging
    under a rotated arm has a level above the arm it hangs from, and the
    arm's supports span three levels: no block-tridiagonal numbering by
    those levels exists (numbered so, the solve did not converge in 80
    iterations). 13 such groups (52 bodies, past the dense limit) get
    another plan, which converges, without the exact fallback, to HiGHS'
    scores."""
    path = tmp_path / "hang.json"
    path.write_text(json.dumps(hanging_scene(13)))
    lay = load_layout(str(path))
    m = compile_layout(lay)
    assert m.n == 52 and not levels_ok(m, m.layer[: m.n])
    assert solve_plan(m)[0] != "layered"
    a = analyze_layout(lay, solver="jax", fallback=False)
    b = analyze_layout(lay, solver="exact")
    assert a.converged and a.stable == b.stable
    assert max(abs(a.scores[k] - b.scores[k]) for k in lay.keys) < 1e-6


def test_vmap_batch_equals_single_solves():
    lays = [stairs(4), tower(4), lever(3, 1, 2)]
    models = [compile_layout(l).pad(16, 512, 32) for l in lays]
    probs = [layered_problem(m, 1) for m in models]
    batch = jax.jit(jax.vmap(ipm.solve))(stack_problems(probs))
    single = jax.jit(ipm.solve)
    for i, p in enumerate(probs):
        one = single(p)
        assert bool(batch.converged[i])
        np.testing.assert_allclose(np.asarray(batch.objective[i]), np.asarray(one.objective), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("make", [lambda: cuboid(4, 4, 3), lambda: pyramid(4)])
def test_a_dense_problem_alone_factors_its_real_bricks_only_with_the_same_answer(make):
    """``cut``: 48 and 30 bricks padded to 120 factor 56 and 40 bricks'
    rows; the iterates are the full factor's, to round-off."""
    m = compile_layout(make()).pad(120, 1024, 32)
    p = layered_problem(m, 1)
    full = jax.jit(ipm.solve)(p)
    cut = jax.jit(lambda p: ipm.solve(p, opts=ipm.IPMOptions(cut=True)))(p)
    assert bool(full.converged) and bool(cut.converged)
    assert int(cut.iters) == int(full.iters)
    np.testing.assert_allclose(np.asarray(cut.f), np.asarray(full.f), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(float(cut.objective), float(full.objective), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("bricks", [pytest.param(120, marks=pytest.mark.slow), 40])  # 120: the cut factor
def test_dense_problems_assemble_the_rank_one_terms_from_supports_with_the_same_answer(bricks):
    """plan_problem gives a dense problem a support table (8 slots a brick;
    16 for a 2 x 6 brick on 12 unit bricks, each under one of its studs,
    with a brick on its corner). Solved alone, with its factor cut (120
    bricks) or not (40), it gives the same forces as the dense product of
    the rank-one terms."""
    from stablelego_jax.solvers.problem import DENSE_SUPPORTS, dense_supports

    pos = [(x, y, 0) for x in range(6) for y in range(2)] + [(0, 0, 1), (5, 1, 2)]
    size = [(1, 1)] * 12 + [(6, 2), (1, 1)]
    wide = brick_layout(pos, size)
    opts = ipm.IPMOptions(cut=True)  # alone
    for lay, K in ((pyramid(4), DENSE_SUPPORTS), (wide, 16)):
        model = compile_layout(lay)
        fm, p = plan_problem(model, ("dense", bricks), 1024, 64)
        assert dense_supports(fm) == K and p.supports.shape == (bricks, K)
        plain = layered_problem(fm, 1, p.chunks.shape[0])
        a, b = (jax.jit(lambda q: ipm.solve(q, opts=opts))(q) for q in (p, plain))
        assert bool(a.converged) and bool(b.converged)
        np.testing.assert_allclose(np.asarray(a.f), np.asarray(b.f), rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(float(a.objective), float(b.objective), rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_layered_problems_assembled_from_supports_give_the_per_level_products_answer():
    """A layered key with support slots (``("layered", L, B, K)``, what
    ``fit_plan`` gives a lone unit cube) assembles each brick's
    largest-drag term from its supports' pieces instead of one product per
    level: the same forces and objective, on a block of unit bricks and on
    a staircase (bricks on two supports, its steps held by drags)."""
    costs = []
    for lay in (cuboid(4, 4, 5), stairs(60)):
        model = compile_layout(lay)
        key = solve_plan(model)
        assert key[0] == "layered"
        m_pad, p_pad = rung(model.m, 64), rung(model.group.shape[1], 4)
        _, plain = plan_problem(model, key, m_pad, p_pad)
        fm, sup = plan_problem(model, key + (4,), m_pad, p_pad)
        assert plain.supports is None and sup.supports.shape == (key[1] * key[2], 4)
        a, b = (jax.jit(ipm.solve)(q) for q in (sup, plain))
        assert bool(a.converged) and bool(b.converged)
        np.testing.assert_allclose(np.asarray(a.f), np.asarray(b.f), rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(float(a.objective), float(b.objective), rtol=1e-9, atol=1e-12)
        costs.append(float(b.objective))
    assert costs[1] > 0.1  # the staircase's drags carry its steps: the rank-one terms matter


def test_analyze_uses_the_interior_point():
    lay = stairs(5)
    a = analyze_layout(lay)
    assert a.solver == "jax" and a.converged and 0 < a.iters < 80


def test_reference_outcomes_match_labels_and_exact():
    """The bundled paper structures in one batched call (one compiled solver
    per bucket): every JAX solve converged, the physical outcome and the
    brick that collapses first, the exact solver's objective (1e-3
    relative) and every per-brick score (2e-3)."""
    from stablelego_jax.batch import analyze_many

    with open(os.path.join(EXAMPLES, "labels_stablelego.json")) as fh:
        labels = {k: v for k, v in json.load(fh).items() if not k.startswith("_")}
    names = sorted(labels)
    lays = [load_layout(os.path.join(EXAMPLES, "stablelego", n)) for n in names]
    for name, lay, a in zip(names, lays, analyze_many(lays, "jax")):
        e = analyze_layout(lay, solver="exact")
        assert a.solver == "jax" and a.converged, name
        assert a.stable == labels[name]["stable"], name
        if not a.stable:
            assert a.weakest == labels[name]["collapses_at"], name
        assert a.objective == pytest.approx(e.objective, rel=1e-3), name
        for k in a.scores:
            assert a.scores[k] == pytest.approx(e.scores[k], abs=2e-3), (name, k)


@needs_shared
def test_paper_structures_match_labels_and_highs(tmp_path):
    """Batched interior point on the paper's structures: the physical outcome,
    HiGHS's label and weakest brick, scores within 1e-3 of HiGHS's."""
    from stablelego_jax.batch import score_files

    with open(os.path.join(SHARED_REF, "labels.json")) as fh:
        labels = {k: v for k, v in json.load(fh).items() if not k.startswith("_")}
    paths = [os.path.join(SHARED_REF, name) for name in labels]
    out = tmp_path / "r.jsonl"
    st = score_files(paths, str(out), progress=False)
    assert (st.scored, st.not_converged) == (len(paths), 0)
    with open(out) as fh:
        recs = {os.path.basename(r["file"]): r for r in map(json.loads, fh)}
    for name, lab in labels.items():
        r = recs[name]
        ex = analyze_layout(load_layout(os.path.join(SHARED_REF, name)), solver="exact")
        assert r["stable"] == lab["stable"] == ex.stable, name
        if not lab["stable"]:
            assert r["weakest"] == lab["collapses_at"] == ex.weakest, name
        else:
            assert max(abs(r["scores"][k] - ex.scores[k]) for k in ex.scores) < 1e-3, name


def test_least_norm_term_gives_the_exact_canonical_scores():
    """The JAX interior point with its least-norm term (IPMOptions.ridge)
    returns the exact solver's canonical distribution on a tied layout."""
    lay = load_layout(os.path.join(EXAMPLES, "brickgpt", "ship.txt"))
    ex = analyze_layout(lay, solver="exact")
    jx = analyze_layout(lay, solver="jax", fallback=False)
    assert jx.converged and jx.weakest == ex.weakest
    np.testing.assert_allclose([jx.scores[k] for k in lay.keys], [ex.scores[k] for k in lay.keys], atol=1e-3)
    assert jx.objective == pytest.approx(ex.objective, rel=1e-5)


@pytest.mark.parametrize("name", ["lever_0342.json", "vox_floating_0215.json", "vox_overhang_0076.json"])
def test_polished_jax_reaches_the_two_stage_least_norm_optimum(name):
    """On layouts whose optimal set is wide (a one-stage ridge QP left 0.016
    between solvers), the polished JAX interior point and the exact two-stage
    least-norm optimum give the same scores within 1e-3 (on the overhang:
    the same failing set, which hangs on a 3e-5 N m torque residual)."""
    lay = load_layout(os.path.join(os.path.dirname(__file__), "data", name))
    r = solve_exact(compile_layout(lay))
    assert r.canonical and "least norm Clarabel Solved" in r.status
    ex = analyze_layout(lay, solver="exact")
    jx = analyze_layout(lay, solver="jax", fallback=False)
    assert jx.converged and jx.weakest == ex.weakest and jx.stable == ex.stable
    np.testing.assert_allclose([jx.scores[k] for k in lay.keys], [ex.scores[k] for k in lay.keys], atol=1e-3)


def test_polishing_keeps_a_converged_answer():
    """A polishing tolerance that cannot be reached ends at a breakdown,
    a lost tolerance or max_iter, and the answer stays converged."""
    from stablelego_jax.solvers.ipm import IPMOptions

    lay = load_layout(os.path.join(os.path.dirname(__file__), "data", "lever_0342.json"))
    a = analyze_layout(lay, solver="jax", fallback=False)
    b = analyze_layout(lay, solver="jax", opts=IPMOptions(polish_gap_abs=0.0, polish_gap_rel=0.0, max_iter=40),
                       fallback=False)
    assert a.converged and b.converged and b.iters >= a.iters
    np.testing.assert_allclose([b.scores[k] for k in lay.keys], [a.scores[k] for k in lay.keys], atol=1e-4)


def test_refinement_steps_do_not_change_the_answer():
    """Iterative refinement of the Newton solves (IPMOptions.refine, off by
    default) gives the same scores and the same distance to HiGHS on a
    loaded layout with a wide optimal set."""
    lay = load_layout(os.path.join(os.path.dirname(__file__), "data", "lever_0342.json"))
    ex = analyze_layout(lay, solver="exact")
    a = analyze_layout(lay, solver="jax", fallback=False)
    b = analyze_layout(lay, solver="jax", opts=ipm.IPMOptions(refine=2), fallback=False)
    assert ipm.IPMOptions().refine == 0
    assert a.converged and b.converged and abs(a.iters - b.iters) <= 1
    np.testing.assert_allclose([b.scores[k] for k in lay.keys], [a.scores[k] for k in lay.keys], atol=1e-8)
    np.testing.assert_allclose([a.scores[k] for k in lay.keys], [ex.scores[k] for k in lay.keys], atol=1e-3)


@pytest.mark.slow
def test_layers_factored_with_sparse_couplings_give_the_same_answer():
    """IPMOptions.below (ipm.options_for): a layered problem of 64 slots a
    layer whose supports table holds every coupling between levels (an
    8 x 8 x 4 block of unit bricks, each on the one below) forms each
    layer's G from its pivot's inverse and the supports' blocks: the same
    iterations, the same objective and forces as the dense step, and
    scores as the exact solver's. A problem that cannot is refused: no
    supports table, slots below BELOW_MIN_SLOTS, or a coupling between
    levels missing from the table."""
    from stablelego_jax.solvers.problem import MIN_COLUMNS, MIN_SLOTS

    lay = cuboid(8, 8, 4)
    model = compile_layout(lay)
    m_pad, p_pad = rung(model.m, MIN_COLUMNS), rung(model.group.shape[1], MIN_SLOTS)
    fm, prob = plan_problem(model, ("layered", 4, 64, 4), m_pad, p_pad)
    opts = ipm.options_for(ipm.IPMOptions(), prob)
    assert opts.below and ipm.below_ok(prob)
    sols = [jax.jit(lambda p, o=o: ipm.solve(p, opts=o))(prob) for o in (ipm.IPMOptions(), opts)]
    (f0, it0, ok0), (f1, it1, ok1) = [(np.asarray(s.f), int(s.iters), bool(s.converged)) for s in sols]
    assert ok0 and ok1 and it0 == it1
    assert np.abs(f1 - f0).max() <= 1e-9 * np.abs(f0).max()
    a = make_analysis(lay, fm, f1, "jax", ok1, 0.0)
    ex = analyze_layout(lay, solver="exact")
    assert a.stable == ex.stable and max(abs(a.scores[k] - ex.scores[k]) for k in lay.keys) < 1e-6
    # refused: no supports table; fewer slots; a coupling between levels not in the table
    assert not ipm.below_ok(prob._replace(supports=None, col_slot=None))
    _, small = plan_problem(compile_layout(cuboid(4, 4, 4)), ("layered", 4, 16, 4), m_pad, p_pad)
    assert not ipm.below_ok(small)
    sup = np.array(prob.supports)
    sup[64 + 5] = sup.shape[0]  # brick 5 of level 1 loses its support: its columns to level 0 now cross outside
    assert not ipm.below_ok(prob._replace(supports=sup))
