"""``stablelego sequence`` (text, --json, --order, --plan, --press, --html, an
APEX-MR step file with its pillars) and --html of analyze and repair."""
import json
import os

import pytest
from conftest import EXAMPLES

from stablelego_jax.cli import main
from stablelego_jax.formats.reader import write_layout
from stablelego_jax.layout import make_layout

STAIR = os.path.join(EXAMPLES, "stablelego", "stair_20.json")


@pytest.fixture
def lever(tmp_path):
    """A beam on a pillar; load A (0.5 kg) tips it alone, the counterweight B (0.25 kg) first holds it."""
    bricks = {"pillar": (0, 3, 0, "12"), "beam": (0, 0, 1, "2"), "A": (0, 0, 2, "12"), "B": (0, 6, 2, "12")}
    raw = {k: {"x": x, "y": y, "z": z, "brick_id": b, "ori": 0} for k, (x, y, z, b) in bricks.items()}
    raw["beam"]["brick_id"], raw["A"]["mass"], raw["B"]["mass"] = "28", 0.5, 0.25
    lib = {"12": {"height": 2, "width": 2, "mass": 0.00115}, "2": {"height": 2, "width": 4, "mass": 0.00216},
           "28": {"height": 2, "width": 8, "mass": 0.0043}}
    (tmp_path / "lib.json").write_text(json.dumps(lib))
    p = tmp_path / "lever.json"
    p.write_text(json.dumps(raw))
    return str(p)


def test_text_report_first_fall(lever, capsys):
    assert main(["sequence", lever, "--library", os.path.join(os.path.dirname(lever), "lib.json"), "--solver", "exact"]) == 1
    out = capsys.readouterr().out
    assert "4 steps (order layers)" in out and "first fall at step 3 (adding brick 'A'" in out
    assert out.count("FALLS") == 1


def test_json_order_file_and_plan(lever, tmp_path, capsys):
    order = tmp_path / "o.txt"
    order.write_text("pillar\nbeam\nB\nA\n")
    assert main(["sequence", lever, "--library", os.path.join(os.path.dirname(lever), "lib.json"), "--solver", "exact", "--order", str(order), "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["stable"] and rec["first_fall"] is None and [s["brick"] for s in rec["steps"]] == ["pillar", "beam",
                                                                                                "B", "A"]
    saved = tmp_path / "plan.json"
    assert main(["sequence", lever, "--library", os.path.join(os.path.dirname(lever), "lib.json"), "--solver", "exact", "--plan", "--json", "--save-order", str(saved)]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["plan_found"] and rec["order"] == "plan"
    assert json.loads(saved.read_text())["order"] == ["pillar", "beam", "B", "A"]


def test_press_flags_support(tmp_path, capsys):
    lay = make_layout(["base", "top"], [(0, 0, 0), (0, 0, 1)], [(2, 2), (2, 4)], [1.15e-3, 2.16e-3],
                      ["12", "2"], [0, 0])
    p = tmp_path / "o.json"
    write_layout(lay, str(p))
    assert main(["sequence", str(p), "--solver", "exact", "--press", "21.56"]) == 0  # every step stands unpressed
    out = capsys.readouterr().out
    assert "1 step(s) need a support" in out and "step 2 (brick 'top')" in out and "support at cell (" in out


def test_apex_mr_step_file_with_pillars(tmp_path, capsys):
    steps, env = tmp_path / "steps", tmp_path / "env_setup"
    steps.mkdir()
    env.mkdir()
    step = {"brick_id": 2, "ori": 0, "press_side": 1, "press_offset": 0, "press_ori": 0, "support_x": -1,
            "support_y": -1, "support_z": 0, "support_ori": -1}
    seq = {"1": dict(step, x=5, y=5, z=3, press_x=5, press_y=5, press_z=4, brick_seq=9),
           "2": dict(step, x=5, y=7, z=4, press_x=5, press_y=9, press_z=5, brick_seq=8,
                     support_x=5, support_y=10, support_z=2)}
    (steps / "t_seq.json").write_text(json.dumps(seq))
    (env / "env_setup_t.json").write_text(json.dumps({"b2_1": {"x": 5, "y": 5, "z": 1, "ori": 0},
                                                      "b2_2": {"x": 5, "y": 5, "z": 2, "ori": 0}}))
    assert main(["sequence", str(steps / "t_seq.json"), "--solver", "exact", "--press", "21.56", "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["order"] == "apex-mr" and rec["fixed"] == ["b2_1", "b2_2"] and rec["n_steps"] == 2
    assert rec["steps"][1]["press"] == "block" and rec["steps"][1]["ref_support"] == [5, 10, 2]
    assert rec["support_steps"] == [2] and rec["steps"][1]["support"] is not None


def test_bad_order_is_one_line_and_exit_2(lever, tmp_path, capsys):
    order = tmp_path / "o.txt"
    order.write_text("pillar\nbeam\n")
    assert main(["sequence", lever, "--library", os.path.join(os.path.dirname(lever), "lib.json"), "--order", str(order)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "o.txt: brick 'A' (and 1 more)" in err


def test_html_pages(lever, tmp_path, capsys):
    pytest.importorskip("plotly")
    page = tmp_path / "seq.html"
    main(["sequence", lever, "--library", os.path.join(os.path.dirname(lever), "lib.json"), "--solver", "exact", "--press", "2", "--html", str(page)])
    text = page.read_text()
    assert 'max="3"' in text and "step 4/4" in text and "press block" in text
    assert main(["analyze", STAIR, "--solver", "exact", "--html", str(tmp_path / "a.html")]) == 0
    assert "brick '2' " in (tmp_path / "a.html").read_text()
    assert main(["analyze", STAIR, lever, "--library", str(tmp_path / "lib.json"), "--solver", "exact",
                 "--html", str(tmp_path / "many")]) == 0
    assert sorted(os.listdir(tmp_path / "many")) == ["lever.html", "stair_20.html"]
    good = os.path.join(EXAMPLES, "stablelego", "stair_20_good.json")
    assert main(["repair", good, "--out", str(tmp_path / "r.json"), "--html", str(tmp_path / "r.html")]) == 0
    text = (tmp_path / "r.html").read_text()
    assert '"label":"before"' in text and '"label":"after"' in text
