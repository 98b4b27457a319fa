"""Gradient-guided repair: the paper's repairs, constraints on what may change,
the baselines, and the ``stablelego repair`` command."""
import json
import os

import numpy as np
import pytest

from blas_threads import one_blas_thread  # noqa: F401  (module fixture: one BLAS thread)
from conftest import EXAMPLES
from stablelego_jax import load_layout
from stablelego_jax.analysis import analyze_layout
from stablelego_jax.cli import main
from stablelego_jax.layout import brick_layout, cells_of
from stablelego_jax.design.repair import RepairOptions, greedy_repair, propose, repair, rollback_repair

REF = os.path.join(EXAMPLES, "stablelego")
STAIR20 = os.path.join(REF, "stair_20.json")
LEVER = os.path.join(REF, "stick_heavy.json")  # the lever with three loads (breaks at brick '2')


def _same_bricks(before, after):
    """Every original brick is in ``after`` with the same key and place."""
    for i, k in enumerate(before.keys):
        j = after.keys.index(k)
        assert after.pos[j].tolist() == before.pos[i].tolist()
        assert after.size[j].tolist() == before.size[i].tolist()
        assert after.mass[j] == before.mass[i]


def _in_bbox(layout, new_pos, new_size):
    lo = layout.pos.min(axis=0)
    hi = (layout.pos + np.concatenate([layout.size, np.ones((layout.n, 1), np.int64)], axis=1)).max(axis=0)
    cells, _ = cells_of(np.asarray(new_pos), np.asarray(new_size))
    return ((cells[:, :2] >= lo[:2]) & (cells[:, :2] < hi[:2])).all() and (cells[:, 2] < hi[2]).all()


@pytest.mark.parametrize("path", [STAIR20, LEVER])
def test_paper_repairs_need_one_brick(path):
    lay = load_layout(path)
    r = repair(lay)
    assert not r.before.stable and r.before.weakest == "2"
    assert r.stable and r.added == 1 and r.removed == [] and r.kept == 1.0
    _same_bricks(lay, r.layout)
    new = [i for i, k in enumerate(r.layout.keys) if k not in lay.keys]
    assert len(new) == 1 and r.layout.keys[new[0]] not in lay.keys
    # the new brick stands under brick '2', on the baseplate, inside the bounding box
    assert r.layout.pos[new[0], 2] == 0
    assert _in_bbox(lay, r.layout.pos[new], r.layout.size[new])
    assert analyze_layout(r.layout, solver="exact").stable  # an independent check
    assert r.soft_calls == 1 and r.exact_calls <= 1 + RepairOptions().verify


def test_candidates_respect_region_and_remove():
    lay = load_layout(STAIR20)
    a = analyze_layout(lay, solver="exact")
    occ = set(map(tuple, cells_of(lay.pos, lay.size)[0].tolist()))
    columns = {(x, y) for x, y, _ in occ}
    zmax = int(lay.pos[:, 2].max())
    for region in ("bbox", "shape", "any"):
        cands = propose(lay, a, RepairOptions(region=region))
        assert cands and len(cands) <= 48  # one failing cluster: the automatic cap is 48
        for c in cands:
            cells = set(map(tuple, cells_of(c.pos, c.size)[0].tolist()))
            assert not cells & occ  # never overlaps the layout
            assert c.replaces == () and c.k <= RepairOptions().budget(lay.n) == 5  # 20 bricks: max(4, 20 / 4)
            if region == "bbox":
                assert _in_bbox(lay, c.pos, c.size)
            if region == "shape":
                assert all((x, y) in columns and z <= zmax for x, y, z in cells)
    assert not any(c.kind == "replace" for c in propose(lay, a, RepairOptions()))
    repl = [c for c in propose(lay, a, RepairOptions(allow_remove=True)) if c.kind == "replace"]
    assert repl and all(len(c.replaces) == 1 and c.k == 1 for c in repl)
    assert propose(lay, a, RepairOptions(max_add=0)) == []


def test_baselines():
    lay = load_layout(STAIR20)
    g = greedy_repair(lay)
    assert g.stable and g.added == 1 and g.soft_calls == 0
    assert g.exact_calls > 5 * 4  # every candidate is solved
    _same_bricks(lay, g.layout)
    rb = rollback_repair(lay)
    # brick '2' (the second in input order) fails: everything from it on is removed
    assert rb.stable and rb.layout.keys == ("1",) and rb.kept == pytest.approx(1 / 20)
    stable = load_layout(os.path.join(REF, "stair_19.json"))
    for fn in (repair, greedy_repair, rollback_repair):
        r = fn(stable)
        assert r.stable and r.added == 0 and r.kept == 1.0 and r.exact_calls == 1


def test_max_add_zero_and_option_errors():
    lay = load_layout(STAIR20)
    r = repair(lay, RepairOptions(max_add=0))
    assert not r.stable and r.added == 0
    with pytest.raises(ValueError, match="region"):
        RepairOptions(region="sphere")
    with pytest.raises(ValueError, match="verify"):
        RepairOptions(verify=0)
    with pytest.raises(ValueError, match="time_s"):
        RepairOptions(time_s=0)
    with pytest.raises(ValueError, match="max_candidates"):
        RepairOptions(max_candidates=0)


def test_budget_and_candidate_cap_scale_with_the_layout():
    auto, fixed = RepairOptions(), RepairOptions(max_add=3, max_candidates=10)
    assert [auto.budget(n) for n in (1, 16, 17, 800)] == [4, 4, 5, 200]
    assert fixed.budget(800) == 3
    assert [auto.candidate_cap(c) for c in (0, 1, 2, 3, 30)] == [48, 48, 48, 72, 480]
    assert fixed.candidate_cap(30) == 10


def test_time_budget_stops_the_search():
    lay = load_layout(STAIR20)
    r = repair(lay, RepairOptions(time_s=1e-9))
    assert not r.stable and r.added == 0 and r.exact_calls == 1 and r.soft_calls == 0


def test_separate_failing_parts_are_fixed_together():
    # a floor of 2x4 bricks with two 2x2 bricks hovering over opposite ends (a
    # layer of air between): each needs its own pillar, no single unit saves both
    floor = [((x, 0, 0), (4, 2)) for x in range(0, 16, 4)]
    lay = brick_layout([p for p, _ in floor] + [(0, 0, 2), (14, 0, 2)], [s for _, s in floor] + [(2, 2), (2, 2)])
    a = analyze_layout(lay, solver="exact")
    assert sorted(k for k, v in a.scores.items() if v >= 1.0) == ["5", "6"]
    r = repair(lay)
    assert r.stable and r.kept == 1.0 and r.soft_calls == 1
    assert r.added == 2 and len(r.changes) == 2  # one 1-brick pillar under each, in one step
    below = [{(x, y, 1) for x in xs for y in (0, 1)} for xs in ((0, 1), (14, 15))]  # under the two hovering bricks
    assert all(sum(bool(c.candidate.cells() & cells) for c in r.changes) == 1 for cells in below)
    # without combining, one unit per step: the same two pillars, one more differentiable solve
    r1 = repair(lay, RepairOptions(combine=False))
    assert r1.stable and r1.added == 2 and r1.soft_calls == 2


def test_cli_json_png(tmp_path, capsys):
    out, png = tmp_path / "fixed.json", tmp_path / "ba.png"
    assert main(["repair", STAIR20, "--out", str(out), "--png", str(png)]) == 0
    text = capsys.readouterr().out
    assert "UNSTABLE" in text and "STABLE with 1 added brick" in text and str(out) in text
    orig = json.load(open(STAIR20))
    fixed = json.load(open(out))
    assert {k: fixed[k] for k in orig} == orig and len(fixed) == len(orig) + 1
    new_key = next(k for k in fixed if k not in orig)
    assert f"brick '{new_key}'" in text
    assert png.stat().st_size > 1000 and open(png, "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    assert analyze_layout(load_layout(str(out)), solver="exact").stable
    # --json
    assert main(["repair", STAIR20, "--out", str(out), "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["stable"] and not rec["stable_before"] and len(rec["added"]) == 1 and rec["soft_calls"] == 1


def test_cli_text_keeps_lines(tmp_path, capsys):
    lay = load_layout(STAIR20)
    lines = ["# stair_20 as text"] + [f"{sx}x{sy} ({x},{y},{z})" for (x, y, z), (sx, sy) in
                                     zip(lay.pos.tolist(), lay.size.tolist())]
    src = tmp_path / "stair.txt"
    src.write_text("\n".join(lines) + "\n")
    out = tmp_path / "fixed.txt"
    assert main(["repair", str(src), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    new = out.read_text().splitlines()
    assert new[: len(lines)] == lines and len(new) == len(lines) + 1
    assert f"brick '{len(lines) + 1}'" in text  # text keys are line numbers
    fixed = load_layout(str(out))
    _same_bricks(load_layout(str(src)), fixed)
    assert analyze_layout(fixed, solver="exact").stable


def test_cli_errors_and_stable_input(tmp_path, capsys):
    out = tmp_path / "o.json"
    assert main(["repair", str(tmp_path / "missing.json"), "--out", str(out)]) == 1
    assert "missing.json" in capsys.readouterr().err and not out.exists()
    bad = tmp_path / "bad.json"
    bad.write_text('{"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2}}')
    assert main(["repair", str(bad), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "bad.json" in err and "ori" in err and not out.exists()
    # not repairable within the budget: nothing written, non-zero exit
    assert main(["repair", STAIR20, "--out", str(out), "--max-add", "0"]) == 1
    assert "still UNSTABLE" in capsys.readouterr().out and not out.exists()
    for bad_arg in (["--max-add", "-1"], ["--max-add", "many"], ["--time", "0"], ["--time", "soon"]):
        with pytest.raises(SystemExit):
            main(["repair", STAIR20, "--out", str(out)] + bad_arg)
        assert bad_arg[1] in capsys.readouterr().err
    # an explicit automatic budget and a time budget are accepted
    assert main(["repair", STAIR20, "--out", str(out), "--max-add", "auto", "--time", "600", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["stable"] and out.exists()
    out.unlink()
    # a stable input is written unchanged
    assert main(["repair", os.path.join(REF, "stair_19.json"), "--out", str(out)]) == 0
    assert "nothing to repair" in capsys.readouterr().out
    assert json.load(open(out)) == json.load(open(os.path.join(REF, "stair_19.json")))


def test_remerge_joins_a_hanging_brick_into_its_row():
    # a 1x1 post carries a 2x1 brick; a second 2x1 hangs beside it, held by
    # nothing (side contacts carry no weight); with 1x4 bricks only and the
    # bounding box, no support or bridge fits: only re-merging the row helps
    lay = brick_layout([(1, 0, 0), (0, 0, 1), (2, 0, 1)], [(1, 1), (2, 1), (2, 1)])
    only4 = ((1, 4), (4, 1))
    r = repair(lay, RepairOptions(allow_remove=True, sizes=only4))
    assert r.stable and [c.candidate.kind for c in r.changes] == ["remerge"] and r.removed == ["2", "3"]
    new = r.layout.subset([r.layout.keys.index(k) for k in r.changes[0].keys])
    assert new.pos.tolist() == [[0, 0, 1]] and new.size.tolist() == [[4, 1]]
    assert not repair(lay, RepairOptions(sizes=only4)).stable  # without --allow-remove nothing fits


def test_remerge_candidates_cover_the_row_exactly_with_new_joints():
    # two layers of three 2x1 bricks, joints stacked at x = 2 and 4
    pos = [(x, 0, z) for z in (0, 1) for x in (0, 2, 4)]
    lay = brick_layout(pos, [(2, 1)] * 6)
    a = analyze_layout(lay, solver="exact")
    rem = [c for c in propose(lay, a, RepairOptions(allow_remove=True, weak=6)) if c.kind == "remerge"]
    assert rem
    for c in rem:
        old = set(map(tuple, cells_of(lay.pos[list(c.replaces)], lay.size[list(c.replaces)])[0].tolist()))
        assert c.cells() == old and len(c.replaces) >= 2  # the same cells, several bricks
        assert sorted(c.pos[:, 0].tolist()) != sorted(lay.pos[list(c.replaces), 0].tolist())  # other joints
    # the whole top row as one 6x1 brick (no joint left) is among them
    assert any(c.replaces == (3, 4, 5) and c.size.tolist() == [[6, 1]] for c in rem)
