import json
import os

import numpy as np
import pytest

from conftest import EXAMPLES
from stablelego_jax import load_layout, make_layout
from stablelego_jax.analysis import analyze, analyze_layout

LABELS = json.load(open(os.path.join(EXAMPLES, "labels_stablelego.json")))
REF = sorted(k for k in LABELS if not k.startswith("_"))


@pytest.mark.parametrize("name", REF)
def test_reference_outcomes_exact(name):
    a = analyze(os.path.join(EXAMPLES, "stablelego", name), solver="exact")
    assert a.converged
    assert a.stable == LABELS[name]["stable"]
    if not a.stable:
        assert a.weakest == LABELS[name]["collapses_at"]


@pytest.mark.parametrize("name", ["car.txt", "chair.txt", "guitar.txt", "ship.txt"])
def test_brickgpt_layouts_stable_exact(name):
    a = analyze(os.path.join(EXAMPLES, "brickgpt", name), solver="exact")
    assert a.stable and a.converged


def test_stair_20_fails_by_half_a_percent():
    a = analyze(os.path.join(EXAMPLES, "stablelego", "stair_20.json"), solver="exact")
    assert a.max_drag["2"] / 0.98 == pytest.approx(1.0055, abs=2e-4)
    assert np.abs(a.residual).max() < 1e-9


def test_floating_brick_gets_an_answer():
    lay = make_layout(["base", "float"], [(0, 0, 0), (0, 0, 2)], [(2, 4), (2, 4)], [0.00216, 0.00216])
    a = analyze_layout(lay, solver="exact")
    assert a.converged
    assert a.scores["float"] == 1.0 and a.scores["base"] < 1.0
    assert not a.stable and a.weakest == "float"
    # its residual is its own weight
    assert abs(a.residual[1, 2]) == pytest.approx(0.00216 * 9.8, rel=1e-6)


@pytest.mark.parametrize("name", REF)
def test_interior_point_method_same_outcome(name):
    a = analyze(os.path.join(EXAMPLES, "stablelego", name), solver="exact")
    for method, scale in (("highs-ipm", False), ("highs", True), ("highs-ipm", True)):
        b = analyze_layout(a.layout, solver="exact", exact_method=method, exact_scale=scale)
        assert b.converged
        assert b.stable == a.stable
        assert b.objective == pytest.approx(a.objective, rel=1e-6, abs=1e-12)
        if not a.stable:
            assert b.weakest == a.weakest


@pytest.mark.parametrize("name", REF)
def test_lp_by_clarabel_is_an_optimum_with_the_same_verdict(name):
    """solve_lp_interior (Eq. 9's LP by Clarabel, no canonical stage): the
    HiGHS optimal cost, and the same verdict on the reference structures."""
    from stablelego_jax.analysis import make_analysis
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.solvers.exact import solve_lp_interior

    a = analyze(os.path.join(EXAMPLES, "stablelego", name), solver="exact")
    model = compile_layout(a.layout, Params(ridge=0.0))
    r = solve_lp_interior(model)
    assert r.success and not r.canonical and r.status.startswith("Clarabel")
    assert r.objective == pytest.approx(a.objective, rel=1e-6, abs=1e-9)
    b = make_analysis(a.layout, model, r.f, "exact", r.success, 0.0)
    assert b.stable == a.stable


def test_lp_by_clarabel_falls_back_to_a_highs_vertex(monkeypatch):
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.solvers import exact

    lay = load_layout(os.path.join(EXAMPLES, "stablelego", REF[0]))
    model = compile_layout(lay, Params(ridge=0.0))
    monkeypatch.setattr(exact, "solve_qp", lambda *a, **k: (None, "MaxIterations"))
    r = exact.solve_lp_interior(model)
    assert r.success and not r.canonical and "after Clarabel: MaxIterations" in r.status
    assert r.objective == pytest.approx(exact.solve_exact(model, "highs-ipm", canonical=False).objective, rel=1e-9)


def test_exact_falls_back_to_interior_point(monkeypatch):
    import scipy.optimize

    from stablelego_jax.solvers import exact
    from stablelego_jax.model import compile_layout

    lay = load_layout(os.path.join(EXAMPLES, "stablelego", "stair_19.json"))
    model = compile_layout(lay)
    calls = []
    real = scipy.optimize.linprog

    def flaky(*args, method, **kw):
        calls.append(method)
        if method != "highs-ipm":  # what HiGHS' simplex did on some big, unscaled layouts
            return scipy.optimize.OptimizeResult(x=None, fun=None, status=4, message="(HiGHS Status 0: Not Set)")
        return real(*args, method=method, **kw)

    monkeypatch.setattr(scipy.optimize, "linprog", flaky)  # exact.py imports it where it solves
    r = exact.solve_exact(model, canonical=False)
    assert calls == ["highs", "highs-ipm"]
    assert r.success and "scaled highs-ipm after highs" in r.status
    ref = exact.solve_exact(model, method="highs-ipm", scale=True, canonical=False)
    assert r.objective == pytest.approx(ref.objective)
    with pytest.raises(ValueError):
        exact.solve_exact(model, method="simplex")


def test_exact_falls_back_to_an_lp_vertex_when_clarabel_fails(monkeypatch):
    from stablelego_jax.model import compile_layout
    from stablelego_jax.solvers import exact

    model = compile_layout(load_layout(os.path.join(EXAMPLES, "stablelego", "stair_20.json")))
    monkeypatch.setattr(exact, "least_norm", lambda model, scale=True: (None, "NumericalError", float("nan")))
    r = exact.solve_exact(model)
    assert r.success and not r.canonical
    assert "canonical distribution failed: NumericalError" in r.status
    a = analyze_layout(load_layout(os.path.join(EXAMPLES, "stablelego", "stair_20.json")), solver="exact")
    assert not a.stable and a.weakest == "2"


def _scores(model, f):
    from stablelego_jax.score import brick_scores

    return np.asarray(brick_scores(model, f)[0])[: model.n]


def test_canonical_distribution_is_an_optimum_of_least_norm():
    """Each HiGHS method returns an optimal vertex of a tied layout; the
    canonical distribution is an optimum too (its Eq. 9 cost that of the
    LP), of smaller norm than any of them."""
    from stablelego_jax.model import NORMAL, compile_layout
    from stablelego_jax.score import brick_drag, residual
    from stablelego_jax.solvers.exact import EXACT_METHODS, solve_exact

    model = compile_layout(load_layout(os.path.join(EXAMPLES, "brickgpt", "car.txt")))
    r = solve_exact(model)
    assert r.canonical and r.success
    p, x = model.params, r.f[: model.m]
    # its cost, with drags and residuals at their least for these forces (residuals cost 1 per N and N m)
    cost = (np.abs(residual(model, r.f)[: model.n]).sum() + p.alpha * brick_drag(model, r.f)[: model.n].sum()
            + p.beta * np.where(model.col_kind[: model.m] == NORMAL, np.maximum(-x, 0.0), 0.0).sum())
    for method in EXACT_METHODS:
        v = solve_exact(model, method=method, canonical=False)
        assert v.success and not v.canonical
        assert cost == pytest.approx(v.objective, rel=1e-5)  # HiGHS' own tolerances
        assert np.linalg.norm(r.f) <= np.linalg.norm(v.f)


def test_canonical_scores_of_a_symmetric_layout_are_symmetric():
    """Two pillars with loaded arms out to either side, tied by a beam, all
    along y (the contact points of SPEC are symmetric under y -> -y, not
    under x -> -x): the canonical distribution is mirror-symmetric (an LP
    vertex need not be)."""
    from stablelego_jax.model import compile_layout
    from stablelego_jax.solvers.exact import solve_exact

    keys = ["l0", "l1", "la", "lh", "r0", "r1", "ra", "rh", "beam"]
    pos = [(0, 4, 0), (0, 4, 1), (0, 0, 2), (0, 0, 1), (0, 14, 0), (0, 14, 1), (0, 14, 2), (0, 18, 1), (0, 4, 3)]
    size = [(2, 2), (2, 2), (2, 6), (2, 2), (2, 2), (2, 2), (2, 6), (2, 2), (2, 12)]
    mass = [0.0011, 0.0011, 0.003, 0.02, 0.0011, 0.0011, 0.003, 0.02, 0.006]
    model = compile_layout(make_layout(keys, pos, size, mass))
    r = solve_exact(model)
    s = dict(zip(keys, _scores(model, r.f)))
    assert r.canonical
    for k in ("0", "1", "a", "h"):
        assert s["l" + k] == pytest.approx(s["r" + k], abs=1e-6)
    assert max(s.values()) > 0.01
