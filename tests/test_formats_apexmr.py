"""APEX-MR step files: layers (z - 1), build order, press and support cells,
env_setup pillars (only the unpicked bricks that touch the structure), errors."""
import json

import pytest

from stablelego_jax.formats.apexmr import env_setup_for, is_apex_seq, parse_apex_seq, read_apex_seq
from stablelego_jax.layout import LayoutError


def _step(x, y, z, bid=2, ori=0, px=None, py=None, pz=None, sx=-1, sy=-1, sz=0, seq=1):
    return {"x": x, "y": y, "z": z, "brick_id": bid, "ori": ori, "press_side": 1, "press_offset": 0,
            "press_x": x if px is None else px, "press_y": y if py is None else py,
            "press_z": z + 1 if pz is None else pz, "press_ori": ori, "support_x": sx, "support_y": sy,
            "support_z": sz, "support_ori": 0, "brick_seq": seq, "robot_id": 1, "sup_robot_id": 0}


SEQ = {
    "1": _step(10, 10, 3, seq=5),                       # on the pillar below
    "2": _step(10, 12, 4, bid=9, ori=1, px=11, seq=1),   # 1x2 turned: 2x1 along x
    "3": _step(10, 12, 2, bid=12, pz=1, seq=2),          # hung under brick 1, pressed from below
    "4": _step(11, 14, 5, bid=5, sx=11, sy=15, sz=3, seq=1),
}
ENV = {
    "b2_1": {"x": 10, "y": 10, "z": 1, "ori": 0},   # pillar, layer 0 ...
    "b2_2": {"x": 10, "y": 10, "z": 2, "ori": 1},   # ... and layer 1 (4x2), under brick 1
    "b2_5": {"x": 30, "y": 0, "z": 1, "ori": 0},    # picked by step 1
    "b2_3": {"x": 40, "y": 0, "z": 1, "ori": 0},    # storage, touches nothing
}


def test_layers_order_press_support():
    t = parse_apex_seq(SEQ, None, source="t_seq.json")
    assert t.order == ("1", "2", "3", "4") and t.fixed == ()
    lay = t.layout
    i = {k: j for j, k in enumerate(lay.keys)}
    assert lay.pos[i["1"]].tolist() == [10, 10, 2] and lay.size[i["1"]].tolist() == [2, 4]
    assert lay.size[i["2"]].tolist() == [2, 1]  # APEX ori 1 swaps height and width, as StableLego
    assert t.press["1"] == (10, 10, 3, 1, 2) and t.press["2"] == (11, 12, 4, 2, 1)
    assert t.press_from_below == {"3"} and "3" not in t.press
    assert t.support == {"4": (11, 15, 3)}
    assert lay.mass[i["1"]] == pytest.approx(2.16e-3)  # Table I by footprint


def test_pillars_are_unpicked_env_bricks_touching_the_structure():
    t = parse_apex_seq(SEQ, ENV, source="t_seq.json")
    assert set(t.fixed) == {"b2_1", "b2_2"}
    assert t.layout.n == 6 and t.layout.keys[:2] == ("b2_1", "b2_2")


def test_files_and_env_setup_beside(tmp_path):
    steps, env = tmp_path / "steps", tmp_path / "env_setup"
    steps.mkdir()
    env.mkdir()
    (steps / "demo_seq.json").write_text(json.dumps(SEQ))
    (env / "env_setup_demo.json").write_text(json.dumps(ENV))
    assert env_setup_for(str(steps / "demo_seq.json")) == str(env / "env_setup_demo.json")
    assert read_apex_seq(str(steps / "demo_seq.json")).fixed == ("b2_1", "b2_2")
    assert read_apex_seq(str(steps / "demo_seq.json"), None).fixed == ()
    assert is_apex_seq(SEQ) and not is_apex_seq({"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0}})


@pytest.mark.parametrize("change, msg", [
    ({"brick_id": 77}, "unknown APEX-MR brick_id 77"),
    ({"z": 0}, r"z=0 is below the plate"),
    ({"press_x": "a"}, r"field press_x='a' is not an integer"),
])
def test_errors_name_file_and_step(change, msg):
    bad = dict(SEQ, **{"2": dict(SEQ["2"], **change)})
    with pytest.raises(LayoutError, match=rf"t_seq.json: brick '2': {msg}"):
        parse_apex_seq(bad, None, source="t_seq.json")
