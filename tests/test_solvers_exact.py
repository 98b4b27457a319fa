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
    r = exact.solve_exact(model)
    assert calls == ["highs", "highs-ipm"]
    assert r.success and "scaled highs-ipm after highs" in r.status
    ref = exact.solve_exact(model, method="highs-ipm", scale=True)
    assert r.objective == pytest.approx(ref.objective)
    with pytest.raises(ValueError):
        exact.solve_exact(model, method="simplex")
