"""Analysis of one layout (stablelego_jax.analysis): every solver and method
through one entry point, one Analysis type, one-line errors."""
import os

import numpy as np
import pytest

from conftest import EXAMPLES
from stablelego_jax.analysis import Analysis, analyze, analyze_baseline, analyze_layout, error_message, pick_solver
from stablelego_jax.formats.reader import load_layout
from stablelego_jax.layout import LayoutError
from stablelego_jax.model import compile_layout

STAIR20 = os.path.join(EXAMPLES, "stablelego", "stair_20.json")


def test_analyze_path_or_layout_same_answer():
    a = analyze(STAIR20, solver="exact")
    b = analyze_layout(load_layout(STAIR20), solver="exact")
    assert isinstance(a, Analysis) and a.scores == b.scores and (a.stable, a.weakest) == (False, "2")
    rec = a.to_json()
    assert set(rec) == {"file", "stable", "weakest", "scores", "n_bricks", "solver", "converged", "time_s"}
    assert a.forces.shape == (a.model.m,) and a.residual.shape == (a.layout.n, 6)


def test_jax_and_exact_agree_on_the_paper_stairs():
    j = analyze(STAIR20)  # the JAX interior point by default
    e = analyze(STAIR20, solver="exact")
    assert (j.solver, j.converged, j.stable, j.weakest) == ("jax", True, e.stable, e.weakest)
    assert j.objective == pytest.approx(e.objective, rel=1e-6)
    assert max(abs(j.scores[k] - e.scores[k]) for k in e.scores) < 1e-3


def test_baseline_analysis_is_built_here_from_the_solvers_result():
    lay = load_layout(STAIR20)
    a = analyze_baseline(lay, compile_layout(lay), "eb")
    assert a.method == "eb" and a.solver == "exact" and a.solvable is not None
    assert a.to_json()["method"] == "eb"
    with pytest.raises(ValueError, match="exact solver only"):
        analyze_layout(lay, solver="jax", method="luo")
    with pytest.raises(ValueError, match="unknown solver"):
        analyze_layout(lay, solver="cplex")


def test_pick_solver_is_the_one_rule_for_solver_and_method():
    assert pick_solver("jax") == "jax" and pick_solver("auto") == "auto"
    # a baseline runs on the exact solver: auto picks it, exact keeps it
    assert pick_solver("auto", "luo") == "exact" and pick_solver("exact", "eb") == "exact"
    with pytest.raises(ValueError, match="exact solver only .*not 'jax'"):
        pick_solver("jax", "eb")
    with pytest.raises(ValueError, match="unknown solver 'cplex'"):
        pick_solver("cplex")
    # every solver gives the canonical distribution; the first-order ADMM, which could not, is gone
    with pytest.raises(ValueError, match="solver 'admm': the first-order ADMM solver was removed in version 0.3.*use jax"):
        pick_solver("admm")
    with pytest.raises(ValueError, match="unknown method 'bogus'"):
        pick_solver("exact", "bogus")


def test_error_message_names_the_file_once(tmp_path):
    p = str(tmp_path / "x.json")
    assert error_message(p, LayoutError(p, "bad")) == f"{p}: bad"
    assert error_message(p, RuntimeError("boom")) == f"{p}: RuntimeError: boom"
    assert np.isfinite(analyze(STAIR20, solver="exact").objective)


def test_auto_picks_highs_for_a_small_layout_and_jax_where_highs_is_slow(monkeypatch):
    """``solver="auto"``: a small layout goes to HiGHS (its estimate is below
    the interior point's, even with the executable ready); when HiGHS is
    estimated slower than a compile and a solve, the interior point; a
    baseline method always runs on HiGHS."""
    from stablelego_jax import analysis
    from stablelego_jax.solvers import exact

    lay = load_layout(STAIR20)
    model = compile_layout(lay)
    assert analysis.auto_solver(model) == "exact"
    a = analyze_layout(lay, solver="auto")
    e = analyze_layout(lay, solver="exact")
    assert a.solver == "exact" and a.scores == e.scores
    monkeypatch.setattr(exact, "estimated_seconds", lambda m: 60.0)
    assert analysis.auto_solver(model) == "jax"
    assert analyze_layout(lay, solver="auto", method="luo").solver == "exact"
