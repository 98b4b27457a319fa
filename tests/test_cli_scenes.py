"""Every command reads scenes (blocks, pallets, rotated bricks): analyze
(labels of the paper's Sec. IV.E cases, support scores, heat maps), score,
export (JSON as read, LDraw rotation matrices), sequence, repair
(refused); LDraw models with plates and parts that cannot be modelled
(--skip-unsupported)."""
import json
import os

import numpy as np
import pytest

from stablelego_jax import cli
from stablelego_jax.formats.ldraw import yaw_matrix
from stablelego_jax.formats.reader import load_layout

HERE = os.path.dirname(__file__)
EXT = os.path.join(HERE, "..", "examples", "extensions")
LABELS = json.load(open(os.path.join(HERE, "..", "examples", "labels_extensions.json")))
CASES = sorted(k for k in LABELS if not k.startswith("_"))


def test_paper_extension_cases_exact(capsys):
    rc = cli.main(["analyze", *[os.path.join(EXT, c) for c in CASES], "--solver", "exact", "--json"])
    recs = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    assert rc == 0 and len(recs) == len(CASES)
    for c, r in zip(CASES, recs):
        lab = LABELS[c]
        assert r["stable"] == lab["stable"], c
        if not lab["stable"]:
            assert r["scores"][lab["collapses_at"]] == 1.0, c
        if c.startswith(("stack", "blocks", "pallet")):
            assert set(r["support"]) == set(r["scores"])
            assert all(0 <= v <= 1 for v in r["support"].values())
        else:
            assert "support" not in r


def test_paper_extension_cases_jax(capsys):
    paths = [os.path.join(EXT, c) for c in ("pallet_top_moved.json", "lego_single_knob_load.json")]
    assert cli.main(["analyze", *paths, "--json", "--solver", "jax"]) == 0
    recs = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
    assert [r["stable"] for r in recs] == [False, False]
    assert recs[0]["scores"]["top"] == 1.0 and recs[1]["scores"]["arm"] == 1.0
    assert recs[0]["support"]["top"] == 1.0 and recs[0]["support"]["pallet"] < 1.0
    assert all(r["converged"] and r["solver"] == "jax" for r in recs)


def test_text_summary_and_heat_map(tmp_path, capsys):
    png = tmp_path / "p.png"
    assert cli.main(["analyze", os.path.join(EXT, "stack_pushed.json"), "--solver", "exact", "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert "UNSTABLE" in out and "support margin" in out and png.read_bytes()[:4] == b"\x89PNG"


def test_score_reads_scenes(tmp_path, capsys):
    out = tmp_path / "r.jsonl"
    assert cli.main(["score", EXT, "--out", str(out), "--solver", "exact", "--quiet"]) == 0
    recs = {os.path.basename(r["file"]): r for r in map(json.loads, out.read_text().splitlines())}
    assert set(recs) == set(CASES)
    assert all(recs[c]["stable"] == LABELS[c]["stable"] for c in CASES)
    capsys.readouterr()


def test_export_json_as_read_and_ldr_rotations(tmp_path, capsys):
    src = os.path.join(EXT, "lego_single_knob_load.json")
    js, ldr = tmp_path / "a.json", tmp_path / "a.ldr"
    assert cli.main(["export", src, "--json", str(js), "--ldr", str(ldr)]) == 0
    assert json.loads(js.read_text()) == json.load(open(src))
    lines = [ln.split() for ln in ldr.read_text().splitlines() if ln.startswith("1 ")]
    arm = np.array([float(v) for v in lines[1][5:14]]).reshape(3, 3)
    np.testing.assert_allclose(arm, yaw_matrix(45.0 + 90.0), atol=1e-9)  # a 1x8 turned 45 degrees: long side on y
    assert np.allclose(arm @ arm.T, np.eye(3), atol=1e-8)
    assert lines[1][-1] == "3008.dat" and lines[2][-1] == "3003.dat"
    capsys.readouterr()


def test_export_refuses_what_a_format_cannot_hold(tmp_path, capsys):
    src = os.path.join(EXT, "pallet_stands.json")
    assert cli.main(["export", src, "--ldr", str(tmp_path / "p.ldr")]) == 1
    assert "block 'pallet': plain blocks have no LDraw part" in capsys.readouterr().err
    assert cli.main(["export", src, "--txt", str(tmp_path / "p.txt")]) == 1
    assert "no text form" in capsys.readouterr().err
    assert os.listdir(tmp_path) == []


def test_repair_adds_no_bricks_to_scenes(tmp_path, capsys):
    src = os.path.join(EXT, "stack_pushed.json")
    assert cli.main(["repair", src, "--out", str(tmp_path / "o.json")]) == 1
    assert "cannot be repaired by adding bricks yet (--move slides plain blocks)" in capsys.readouterr().err
    assert not (tmp_path / "o.json").exists()


# a 2x4 brick, a 2x4 plate on it, a 2x4 plate half over its edge, a 1x4 plate turned on the first plate
PLATES = """1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 4 0 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
1 4 40 -16 0 1 0 0 0 1 0 0 0 1 3020.dat
1 4 -30 -16 0 0 0 1 0 1 0 -1 0 0 3710.dat
"""


def test_sequence_of_scenes(tmp_path, capsys):
    # the paper's 8-level stack with a block pushed out: the step that adds it is the first to fall
    src = os.path.join(EXT, "stack8_moved.json")
    assert cli.main(["sequence", src, "--solver", "exact", "--json"]) == 1
    rec = json.loads(capsys.readouterr().out)
    stand = [st["stable"] for st in rec["steps"]]
    assert rec["n_steps"] == 8 and not rec["stable"] and rec["first_fall"] == stand.index(False) + 1
    exact = cli.main(["analyze", src, "--solver", "exact", "--json"])
    assert exact == 0 and not json.loads(capsys.readouterr().out)["stable"]
    # plates from LDraw: ordered by the height of their bottoms; the plate half over the edge is held by its
    # knobs; pressed hard at its far end it falls, and no support pillar is tried in a scene
    ldr = tmp_path / "plates.ldr"
    ldr.write_text(PLATES)
    assert cli.main(["sequence", str(ldr), "--solver", "exact", "--json", "--html", str(tmp_path / "s.html")]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert [st["brick"] for st in rec["steps"]] == ["1", "2", "3", "4"] and rec["stable"]
    assert (tmp_path / "s.html").exists() and "plate '3' 4x2" in (tmp_path / "s.html").read_text()
    assert cli.main(["sequence", str(ldr), "--solver", "exact", "--press", "500"]) == 0
    out = capsys.readouterr().out
    assert "no support pillar tried (pillars are tried in grid layouts only)" in out
    # --plan finds an order; --skip-unsupported leaves out what cannot be modelled
    assert cli.main(["sequence", str(ldr), "--solver", "exact", "--plan", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["plan_found"]
    ldr.write_text(PLATES + "1 4 0 -40 0 1 0 0 0 1 0 0 0 1 3039.dat\n")
    assert cli.main(["sequence", str(ldr), "--solver", "exact"]) == 2
    assert "1 part cannot be modelled: 3039 x1 (line 5)" in capsys.readouterr().err
    assert cli.main(["sequence", str(ldr), "--solver", "exact", "--skip-unsupported", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["n_steps"] == 4 and err.startswith(f"warning: {ldr}: left out, 1 part")


def test_analyze_html_draws_scenes(tmp_path, capsys):
    src = os.path.join(EXT, "lego_single_knob.json")
    assert cli.main(["analyze", src, "--solver", "exact", "--html", str(tmp_path / "p.html"), "--json"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and json.loads(out)["html"] == str(tmp_path / "p.html")
    text = (tmp_path / "p.html").read_text()
    lay = load_layout(src)
    assert all(f"'{k}'" in text for k in lay.keys) and "yaw" in text


# a 2x4 brick, a 2x4 plate on it, a brick on the plate, two slopes and a tile beside
MODEL = """0 FILE main.ldr
1 4 0 0 0 1 0 0 0 1 0 0 0 1 3001.dat
1 4 0 -8 0 1 0 0 0 1 0 0 0 1 3020.dat
1 4 0 -32 0 1 0 0 0 1 0 0 0 1 3001.dat
1 4 100 0 0 1 0 0 0 1 0 0 0 1 3039.dat
1 4 140 0 0 1 0 0 0 1 0 0 0 1 3039.dat
1 4 180 0 0 1 0 0 0 1 0 0 0 1 3068b.dat
"""


def test_ldraw_model_with_unsupported_parts(tmp_path, capsys):
    src = tmp_path / "model.mpd"
    src.write_text(MODEL)
    assert cli.main(["analyze", str(src), "--solver", "exact"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "3 parts cannot be modelled: 3039 x2 (line 5), 3068b x1 (line 7)" in err
    assert cli.main(["analyze", str(src), "--solver", "exact", "--skip-unsupported", "--json"]) == 0
    out, err = capsys.readouterr()
    rec = json.loads(out)
    assert rec["stable"] and sorted(rec["scores"]) == ["1", "2", "3"]
    assert err == f"warning: {src}: left out, 3 parts cannot be modelled: 3039 x2 (line 5), 3068b x1 (line 7)\n"
    ldr = tmp_path / "back.ldr"
    assert cli.main(["export", str(src), "--ldr", str(ldr)]) == 1
    assert not ldr.exists()
    capsys.readouterr()
    assert cli.main(["export", str(src), "--ldr", str(ldr), "--skip-unsupported"]) == 0
    assert "left out, 3 parts" in capsys.readouterr().err
    back = load_layout(str(ldr))
    assert back.size[:, 2].tolist() == [3, 1, 3] and back.pos[:, 2].tolist() == [0, 3, 4]


def test_score_skips_unsupported_parts_only_when_asked(tmp_path, capsys):
    src = tmp_path / "model.mpd"
    src.write_text(MODEL)
    out = tmp_path / "r.jsonl"
    assert cli.main(["score", str(src), "--out", str(out), "--solver", "exact", "--quiet"]) == 1
    rec = json.loads(out.read_text())
    assert "3 parts cannot be modelled: 3039 x2 (line 5), 3068b x1 (line 7)" in rec["error"]
    capsys.readouterr()
    out2 = tmp_path / "r2.jsonl"
    assert cli.main(["score", str(src), "--out", str(out2), "--solver", "exact", "--quiet",
                     "--skip-unsupported"]) == 0
    rec = json.loads(out2.read_text())
    assert rec["stable"] and sorted(rec["scores"]) == ["1", "2", "3"]
    assert rec["left_out"] == {"3039": 2, "3068b": 1}
    err = capsys.readouterr().err
    assert f"warning: {src}: left out, 3 parts cannot be modelled" in err
    assert "1 scored (1 without unsupported parts)" in err


@pytest.mark.parametrize("name", ["stack8_moved.json", "lego_single_knob.json"])
def test_examples_read_as_scenes(name):
    sc = load_layout(os.path.join(EXT, name))
    assert sc.n >= 2 and sc.source.endswith(name)
