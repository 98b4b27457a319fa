"""Baselines of the paper's Sec. IV (stablelego_jax.solvers.baselines) and ``--method``."""
import inspect
import json
import os

import numpy as np
import pytest

from stablelego_jax import cli, make_layout
from stablelego_jax.analysis import analyze, analyze_layout
from stablelego_jax.solvers.baselines import METHODS, solve_baseline
from stablelego_jax.model import compile_layout

HERE = os.path.dirname(__file__)
STABLELEGO = os.path.join(HERE, "..", "examples", "stablelego")
LABELS = json.load(open(os.path.join(HERE, "..", "examples", "labels_stablelego.json")))

M24, M14, LOAD = 0.00216, 0.00157, 0.2  # 2x4 and 1x4 bricks, the 200 g load block (kg)


def _lay(*bricks):
    keys, pos, size, mass = zip(*bricks)
    return make_layout(keys, pos, size, mass)


# stable by hand: three 2x4 bricks stacked straight up
TOWER = _lay(("a", (0, 0, 0), (2, 4), M24), ("b", (0, 0, 1), (2, 4), M24), ("c", (0, 0, 2), (2, 4), M24))
# a brick hovering one empty layer above another: nothing can hold it
FLOATING = _lay(("base", (0, 0, 0), (2, 4), M24), ("float", (0, 0, 2), (2, 4), M24))
# two bricks clicked together, hovering: each holds the other's knobs
FLOATING_PAIR = _lay(("base", (0, 0, 0), (2, 4), M24), ("f1", (0, 0, 2), (2, 4), M24), ("f2", (0, 0, 3), (2, 4), M24))
# a 200 g block hooked on one corner knob: 1.96 N half a stud off its only
# knob needs a drag couple far above T = 0.98 N on the 3 contact points
HOOK = _lay(("base", (0, 0, 0), (2, 4), M24), ("load", (1, 3, 1), (2, 2), LOAD))
# 2x4 arm on one row of knobs (1 stud) of its base, the 200 g block on its tip
CANTILEVER = _lay(("base", (0, 0, 0), (4, 2), M24), ("arm", (3, 0, 1), (4, 2), M24), ("load", (5, 0, 2), (2, 2), LOAD))
# the same arm unloaded: its own 2 g are held easily
LIGHT_CANTILEVER = _lay(("base", (0, 0, 0), (4, 1), M14), ("arm", (3, 0, 1), (4, 1), M14))


def _all(layout):
    return {m: analyze_layout(layout, solver="exact", method=m) for m in METHODS}


def test_stable_tower_is_solvable_for_every_method():
    for m, a in _all(TOWER).items():
        assert a.stable and a.solvable and a.converged, m
        assert max(a.scores.values()) < 1e-9, m  # straight stack: no drag anywhere
        assert np.abs(a.residual).max() < 1e-9, m


def test_light_cantilever_agrees_and_uses_the_same_drag():
    r = _all(LIGHT_CANTILEVER)
    assert all(a.stable and a.solvable for a in r.values())
    # one knob under the arm, its weight 2.5 studs out: all three find the same least drag
    assert r["eb"].scores["arm"] == pytest.approx(r["ours"].scores["arm"], rel=1e-6)
    assert 0.0 < r["ours"].scores["arm"] < 0.1


@pytest.mark.parametrize("layout", [FLOATING, HOOK], ids=["floating", "hook"])
def test_no_equilibrium_within_capacity_is_unsolvable_for_both_baselines(layout):
    r = _all(layout)
    ours = r["ours"]
    assert ours.solvable and ours.converged and not ours.stable  # ours still answers
    assert ours.scores[ours.weakest] == 1.0 and ours.weakest in ("float", "load")
    for m in ("luo", "eb"):
        a = r[m]
        assert a.solvable is False and a.stable is False and a.converged, m
        assert a.scores == {} and a.weakest is None and a.forces is None, m


@pytest.mark.parametrize("layout", [FLOATING_PAIR, CANTILEVER], ids=["floating_pair", "cantilever"])
def test_luo_without_newtons_third_law_solves_what_eb_cannot(layout):
    """Without Eq. 5 every brick is balanced on its own; the loads never reach
    the bricks below, so a hovering pair or an overloaded cantilever is
    'solvable' (and called stable) by luo, unsolvable by eb, unstable by ours."""
    r = _all(layout)
    assert not r["ours"].stable
    assert r["luo"].solvable and r["luo"].stable
    assert r["eb"].solvable is False
    model = compile_layout(layout)
    luo = solve_baseline(model, "luo")
    assert luo.pair_mismatch > 1e-3  # action != reaction by over 1 mN (a 2x4 brick weighs 21 mN)
    assert np.abs(r["luo"].residual).max() < 1e-9  # yet every brick is in equilibrium


def test_eb_forces_obey_eq4_eq5_and_the_capacity():
    model = compile_layout(LIGHT_CANTILEVER)
    r = solve_baseline(model, "eb")
    assert r.solvable and r.pair_mismatch == 0.0
    from stablelego_jax.score import residual

    assert np.abs(residual(model, r.f)).max() < 1e-9
    assert r.max_drag.max() <= model.params.T + 1e-12


@pytest.mark.parametrize("layout", [TOWER, FLOATING, HOOK, CANTILEVER, LIGHT_CANTILEVER])
def test_eb_milp_with_complementarity_equals_its_lp_reduction(layout):
    model = compile_layout(layout)
    lp = solve_baseline(model, "eb")
    mi = solve_baseline(model, "eb", formulation="milp", time_limit=30)
    assert mi.solvable == lp.solvable
    if lp.solvable:
        assert mi.objective == pytest.approx(lp.objective, rel=1e-5, abs=1e-12)


@pytest.mark.parametrize("name", ["stair_20.json", "stick_heavy.json", "external_weight_fail.json",
                                  "external_weight_good.json"])
def test_reference_structures(name):
    """Physical outcomes: eb solvable exactly when the structure stood; luo
    solves all of them (it never sees the load on brick 2)."""
    path = os.path.join(STABLELEGO, name)
    stood = LABELS[name]["stable"]
    eb = analyze(path, solver="exact", method="eb")
    luo = analyze(path, solver="exact", method="luo")
    assert eb.solvable == stood and eb.converged
    assert luo.solvable is True
    model = compile_layout(eb.layout)
    assert solve_baseline(model, "eb", formulation="milp", time_limit=30).solvable == stood


def test_bad_arguments_give_clear_errors():
    with pytest.raises(ValueError, match="exact solver only"):
        analyze_layout(TOWER, solver="jax", method="luo")
    with pytest.raises(ValueError, match="unknown method 'bogus'"):
        analyze_layout(TOWER, solver="exact", method="bogus")
    model = compile_layout(TOWER)
    with pytest.raises(ValueError, match="baseline method"):
        solve_baseline(model, "ours")
    with pytest.raises(ValueError, match="eb.*only"):
        solve_baseline(model, "luo", formulation="milp")
    with pytest.raises(ValueError, match="formulation"):
        solve_baseline(model, "eb", formulation="qp")


# ---------------------------------------------------------------- command line


def _analyze(capsys, *args):
    rc = cli.main(["analyze", *args])
    out, err = capsys.readouterr()
    return rc, out, err


def test_cli_unsolvable_is_a_result_in_json(capsys):
    stair20 = os.path.join(STABLELEGO, "stair_20.json")
    stair19 = os.path.join(STABLELEGO, "stair_19.json")
    rc, out, err = _analyze(capsys, stair20, stair19, "--method", "eb", "--json")
    assert rc == 0, err
    r20, r19 = (json.loads(line) for line in out.splitlines())
    assert r20 == {**r20, "file": stair20, "method": "eb", "solvable": False, "stable": False,
                   "weakest": None, "scores": {}, "solver": "exact", "converged": True}
    assert r19["solvable"] is True and r19["stable"] is True and r19["method"] == "eb"
    assert set(r19["scores"]) == {str(k) for k in range(1, 20)} and r19["weakest"] == "2"


def test_cli_default_method_output_is_unchanged(capsys):
    rc, out, _ = _analyze(capsys, os.path.join(STABLELEGO, "stair_19.json"), "--solver", "exact", "--json")
    r = json.loads(out)
    assert rc == 0 and r["stable"] is True and "method" not in r and "solvable" not in r


def test_cli_text_summary_and_png(capsys, tmp_path):
    png = tmp_path / "h.png"
    rc, out, err = _analyze(capsys, os.path.join(STABLELEGO, "stick_heavy.json"), "--method", "luo", "--png", str(png))
    assert rc == 0 and "SOLVABLE (stable)" in out and "method luo" in out and png.exists()
    png2 = tmp_path / "h2.png"
    rc, out, err = _analyze(capsys, os.path.join(STABLELEGO, "stick_heavy.json"), "--method", "eb", "--png", str(png2))
    assert rc == 0 and "UNSOLVABLE" in out and "no heat map" in err and not png2.exists()


def test_cli_method_errors(capsys, tmp_path):
    rc, out, err = _analyze(capsys, os.path.join(STABLELEGO, "stair_19.json"), "--method", "luo", "--solver", "jax")
    assert rc == 2 and "exact solver only" in err and out == ""
    with pytest.raises(SystemExit):
        cli.main(["analyze", "x.json", "--method", "gurobi"])
    capsys.readouterr()
    bad = tmp_path / "bad.json"
    bad.write_text('{"1": {"x": 0, "y": 0, "z": 0, "brick_id": 99, "ori": 0}}')
    rc, out, err = _analyze(capsys, str(bad), os.path.join(STABLELEGO, "stair_19.json"), "--method", "eb", "--json")
    first, second = (json.loads(line) for line in out.splitlines())
    assert rc == 1 and set(first) == {"file", "error"} and "99" in first["error"]
    assert second["solvable"] is True


def test_cli_score_method(capsys, tmp_path):
    from stablelego_jax.batch import score_files

    src = tmp_path / "in"
    src.mkdir()
    for name in ("stair_19.json", "stair_20.json"):
        (src / name).write_text(open(os.path.join(STABLELEGO, name)).read())
    out = tmp_path / "r.jsonl"
    rc = cli.main(["score", str(src), "--out", str(out), "--method", "eb", "--quiet"])
    assert rc == 0
    assert "method" in inspect.signature(score_files).parameters
    recs = {os.path.basename(r["file"]): r for r in map(json.loads, open(out))}
    assert recs["stair_20.json"]["solvable"] is False and recs["stair_19.json"]["solvable"] is True


def test_enhanced_baseline_gives_the_canonical_scores_of_a_stable_layout():
    """On a stable layout eb's optimal set is Eq. 9's, and with the same
    canonical term both give the same scores (HiGHS' vertices differ)."""
    from conftest import EXAMPLES

    from stablelego_jax.formats.reader import load_layout

    lay = load_layout(os.path.join(EXAMPLES, "brickgpt", "car.txt"))
    ours = analyze_layout(lay, solver="exact")
    eb = analyze_layout(lay, solver="exact", method="eb")
    assert ours.stable and eb.solvable
    assert "canonical distribution: Clarabel" in solve_baseline(compile_layout(lay), "eb").status
    np.testing.assert_allclose([eb.scores[k] for k in lay.keys], [ours.scores[k] for k in lay.keys], atol=1e-3)
    assert eb.weakest == ours.weakest
