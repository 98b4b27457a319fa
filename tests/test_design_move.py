"""Moving blocks (issue 21): the contact points' translation Jacobian is exact,
the loss gradient with respect to positions matches central differences of
the loss of really moved scenes, and ``repair --move`` makes the paper's
8-level stack stand by moving one block."""
import json
import os

import numpy as np
import pytest

from stablelego_jax import cli
from stablelego_jax.formats.reader import load_layout
from stablelego_jax.model import point_jacobian, scene_columns, shifted

HERE = os.path.dirname(__file__)
EXT = os.path.join(HERE, "..", "examples", "extensions")
STACK8 = os.path.join(EXT, "stack8_moved.json")


def test_point_jacobian_predicts_moved_contact_points():
    sc = load_layout(os.path.join(EXT, "stack_pushed.json"))  # block '5' pushed out along x; y edges aligned
    pair, _, points, _, _ = scene_columns(sc)
    J, smooth = point_jacobian(sc)
    top = sc.keys.index("5")
    on_top = pair[:, 0] == top
    assert on_top.sum() == 4 and not smooth[on_top].any()  # aligned y edges: a kink
    d = np.zeros((sc.n, 2))
    d[top, 0] = -3e-3  # slide it back 3 mm: the same contact, its corners follow the edge that moved
    p2 = scene_columns(shifted(sc, d))[2]
    pred = points + np.einsum("kij,kj->ki", J[:, 0], d[np.minimum(pair[:, 0], sc.n - 1)])
    assert np.allclose(p2[on_top], pred[on_top], atol=1e-12)
    assert np.allclose(J[on_top, 0, 0, 0][np.argsort(points[on_top, 0])], [1, 1, 0, 0])  # its own corners move
    assert (J[pair[:, 0] == sc.keys.index("1"), 1] == 0).all()  # the ground never moves


@pytest.mark.slow
def test_position_gradient_matches_central_differences():
    import jax

    from stablelego_jax.loss import position_loss, stability_loss
    from stablelego_jax.soft import scene_positions, soft_problem

    sc = load_layout(STACK8)  # block '7' pushed out 12 cm, '8' on it: '8' falls
    prob, geo = soft_problem(sc), scene_positions(sc)
    w = np.ones(sc.n)
    zero = np.zeros((sc.n, 2))
    assert float(position_loss(zero, w, None, prob, geo)) == pytest.approx(float(stability_loss(w, None, prob)))
    g = np.asarray(jax.grad(lambda d: position_loss(d, w, None, prob, geo))(zero))
    h = 1e-4
    for b in (sc.keys.index("7"), sc.keys.index("8")):  # x edges not aligned: smooth along x
        vals = []
        for s in (1.0, -1.0):
            d = zero.copy()
            d[b, 0] = s * h
            vals.append(float(stability_loss(w, None, soft_problem(shifted(sc, d)))))
        fd = (vals[0] - vals[1]) / (2 * h)
        assert abs(fd) > 0.1 and g[b, 0] == pytest.approx(fd, rel=1e-2), (b, fd, g[b])
    # moving '7' back under the stack or '8' out over '7' relieves the overload; the others do not matter
    assert g[sc.keys.index("7"), 0] > 0 > g[sc.keys.index("8"), 0]
    assert np.abs(g[: sc.keys.index("7")]).max() < 1e-6


def test_repair_move_makes_the_8_level_stack_stand(tmp_path, capsys):
    out = tmp_path / "fixed.json"
    page = tmp_path / "move.html"
    assert cli.main(["repair", STACK8, "--move", "--out", str(out), "--json", "--html", str(page)]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["stable"] and not rec["stable_before"] and len(rec["moved"]) == 1
    assert rec["html"] == str(page) and f"moved block '{rec['moved'][0]['key']}' by" in page.read_text()
    before, after = load_layout(STACK8), load_layout(str(out))
    assert after.keys == before.keys and np.allclose(after.size, before.size) and np.allclose(after.mass, before.mass)
    changed = np.nonzero(np.abs(after.pos - before.pos).max(1) > 1e-9)[0]
    assert [after.keys[i] for i in changed] == [rec["moved"][0]["key"]]
    assert np.allclose((after.pos - before.pos)[changed[0], :2], rec["moved"][0]["shift_m"], atol=1e-6)
    assert cli.main(["analyze", str(out), "--solver", "exact", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["stable"]


def test_repair_move_needs_plain_blocks(tmp_path, capsys):
    grid = os.path.join(HERE, "..", "examples", "stablelego", "stair_20.json")
    assert cli.main(["repair", grid, "--move", "--out", str(tmp_path / "o.json")]) == 1
    assert "--move slides plain blocks, and this layout has none" in capsys.readouterr().err
    assert not (tmp_path / "o.json").exists()
