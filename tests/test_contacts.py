"""Contacts from geometry, and the analytic references of plain block
stacking solved exactly (HiGHS): the centre-of-mass rule of a column, the
harmonic stack at 0.99 and 1.01 of its offsets for n = 2..20 (straight and
turned), a box straddling two boxes of a pallet, a frictionless block
pressed sideways between two others, and Lego knobs of rotated and wide
bricks."""
import math

import numpy as np
import pytest

from stablelego_jax.contacts import contact_levels, four_point_knobs, scene_contacts
from stablelego_jax.generate.scenes import block_column, harmonic_stack, pallet
from stablelego_jax.model import compile_scene
from stablelego_jax.scene import BLOCK, BRICK, make_scene
from stablelego_jax.score import brick_scores
from stablelego_jax.solvers.exact import solve_exact


def _stands(scene):
    model = compile_scene(scene)
    r = solve_exact(model)
    assert r.success
    s, bad, _ = brick_scores(model, r.f)
    return not bad[: scene.n].any(), s[: scene.n]


def test_four_point_rule_of_wide_bricks():
    cells = np.array([[i, j] for i in range(4) for j in range(4)])
    four = four_point_knobs(np.tile([4, 4], (16, 1)), cells)
    assert four.sum() == 4 and four.reshape(4, 4)[1:3, 1:3].all()  # inner 2x2 of a 4x4
    assert four_point_knobs([[1, 6]] * 6, [[0, j] for j in range(6)]).all()
    assert not four_point_knobs([[2, 4]] * 8, [[i, j] for i in range(2) for j in range(4)]).any()
    three = four_point_knobs([[3, 3]] * 9, [[i, j] for i in range(3) for j in range(3)])
    assert three.tolist() == [False] * 4 + [True] + [False] * 4


def test_block_on_a_turned_block_touches_on_an_octagon():
    sc = make_scene(["a", "b"], [BLOCK] * 2, [[0, 0, 0.05], [0, 0, 0.15]], [[0.2, 0.2, 0.1]] * 2, [0, 45], [1, 1])
    c = scene_contacts(sc)
    up = c.push_pair[:, 0] == 1
    assert up.sum() == 8 and c.push_bottom[up].all()
    np.testing.assert_allclose(c.push_point[up, 2], 0.1)
    ground = c.push_pair[:, 1] == 2
    assert ground.sum() == 4 and len(c.lego_pair) == 0 and len(c.knob_pair) == 0


def test_side_faces_and_friction_cone():
    sc = make_scene(["a", "b"], [BLOCK] * 2, [[0, 0, 0.05], [0.2, 0.05, 0.05]], [[0.2, 0.2, 0.1]] * 2, [0, 0],
                    [1, 1], friction=0.5)
    c = scene_contacts(sc)
    side = ~c.push_bottom
    assert side.sum() == 16  # 4 corners x 4 cone edges
    np.testing.assert_allclose(np.unique(c.push_point[side, 0]), [0.1])
    np.testing.assert_allclose(sorted(np.unique(c.push_point[side, 1])), [-0.05, 0.1])
    np.testing.assert_allclose(c.push_dir[side, 0], 1.0)  # normal component 1, pushes b (+x)
    assert (c.push_pair[side] == [1, 0]).all()
    np.testing.assert_allclose(np.abs(c.push_dir[side, 1:]).sum(1), 0.5)


def test_rotated_brick_on_a_single_knob():
    th = 45.0
    c, s = math.cos(math.radians(th)), math.sin(math.radians(th))
    # a 1x4 whose first stud (cell 0, 0) sits on the 2x4's stud at (1.5, 3.5)
    ox, oy = 0.0, -1.5
    centre = (1.5 - (c * ox - s * oy), 3.5 - (s * ox + c * oy))
    sc = make_scene(["base", "arm"], [BRICK] * 2, [[1, 2, 0], [centre[0], centre[1], 3]], [[2, 4, 3], [1, 4, 3]],
                    [0, th], [0.00216, 0.00157])
    k = scene_contacts(sc)
    on_base = k.knob_pair[:, 0] == 1
    assert on_base.sum() == 1 and (k.knob_pair[on_base] == [1, 0]).all()
    pts = k.lego_point[k.lego_pair[:, 0] == 1]
    assert len(pts) == 4  # a 1xN part: four points, turned with it
    d = pts[:, :2] / 0.0078 - [1.5, 3.5]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 0.25)
    np.testing.assert_allclose(np.abs(d[0]), [0.25 * s, 0.25 * c], atol=1e-12)
    assert (k.knob_pair[:, 0] == 0).sum() == 8  # the base on the baseplate
    stands, scores = _stands(sc)
    assert stands and 0 < scores[1] < 1


def test_contact_levels_join_adjacent_levels_only():
    sc = harmonic_stack(6, 0.5)
    lev = contact_levels(np.array([[1, 0], [2, 1], [0, 6], [3, 2], [4, 3], [5, 4]]), np.eye(6, dtype=bool)[0],
                         np.arange(6.0), 6)
    assert lev.tolist() == [0, 1, 2, 3, 4, 5]
    m = compile_scene(pallet(3, 2, 2, top=(0.2, 0.0, 30.0)))
    real = (m.col_brick < m.n).all(1)
    gaps = np.abs(np.diff(m.layer[m.col_brick[real]], axis=1))
    assert gaps.max() <= 1
    # a floating group counts from its lowest body
    lev = contact_levels(np.array([[1, 0]]), np.zeros(2, bool), np.array([0.5, 0.6]), 2)
    assert lev.tolist() == [0, 1] and sc.n == 6


@pytest.mark.parametrize("yaw", [0.0, 30.0])
def test_harmonic_stack_stands_at_099_and_falls_at_101(yaw):
    for n in range(2, 21):
        assert _stands(harmonic_stack(n, 0.99, yaw=yaw))[0], n
        assert not _stands(harmonic_stack(n, 1.01, yaw=yaw))[0], n


def test_column_rule_with_turned_blocks():
    """A frictionless column stands iff at every interface the centre of mass
    of the blocks above lies in both footprints (their overlap polygon),
    checked with each footprint's own axes, not with the clipping code."""
    rng = np.random.default_rng(7)
    L, W, H = 0.2, 0.12, 0.05
    seen = {True: 0, False: 0}
    for _ in range(60):
        n = int(rng.integers(2, 7))
        off = rng.uniform(-1.1, 1.1, n - 1) * L / 2
        yaw = rng.uniform(-40, 40, n)
        sc = block_column(off, (L, W, H), 0.3, yaw)
        xy, th = sc.pos[:, :2], np.radians(yaw)

        def inside(p, i, shrink):
            d = p - xy[i]
            u = d[0] * math.cos(th[i]) + d[1] * math.sin(th[i])
            v = -d[0] * math.sin(th[i]) + d[1] * math.cos(th[i])
            return abs(u) <= L / 2 * shrink and abs(v) <= W / 2 * shrink

        verdicts = []
        for k in range(1, n):  # interface between block k-1 and block k
            com = xy[k:].mean(0)
            verdicts.append((inside(com, k - 1, 0.98) and inside(com, k, 0.98),
                             inside(com, k - 1, 1.02) and inside(com, k, 1.02)))
        sure_in = all(a for a, _ in verdicts)
        sure_out = not all(b for _, b in verdicts)
        if not (sure_in or sure_out):
            continue  # within 2 % of a knife edge
        assert _stands(sc)[0] == sure_in
        seen[sure_in] += 1
    assert seen[True] >= 5 and seen[False] >= 5


def test_box_straddling_two_boxes_of_a_pallet():
    # two boxes with a 0.1 m gap; the top box spans it
    assert _stands(pallet(2, 1, 1, gap=0.1, top=(0.0, 0.0, 0.0)))[0]
    assert _stands(pallet(2, 1, 1, gap=0.1, top=(0.2, 0.0, 20.0)))[0]
    # the knife edge: the top box's centre over the right box's outer edge (0.25 + 0.4 / 2 = 0.45)
    assert not _stands(pallet(2, 1, 1, gap=0.1, top=(0.45 + 0.01, 0.0, 0.0)))[0]
    assert _stands(pallet(2, 1, 1, gap=0.1, top=(0.45 - 0.01, 0.0, 0.0)))[0]


def test_frictionless_block_pressed_sideways_falls():
    keys = ["left", "mid", "right"]
    size = [[0.1, 0.1, 0.1]] * 3
    # the middle block hangs between its neighbours, 1 cm above the ground
    pos = [[-0.1, 0, 0.05], [0.0, 0, 0.06], [0.1, 0, 0.05]]
    hanging = make_scene(keys, [BLOCK] * 3, pos, size, [0] * 3, [1, 1, 1])
    stands, scores = _stands(hanging)
    assert not stands and scores[1] == 1.0 and scores[0] == 0.0
    # with friction the neighbours can clamp it, if they are held too: not asserted,
    # but on the ground it stands
    pos[1][2] = 0.05
    assert _stands(make_scene(keys, [BLOCK] * 3, pos, size, [0] * 3, [1, 1, 1]))[0]
