"""Build sequences: every prefix scored in one call, the first fall, the press
(a load block or a load on the brick), support pillars that make a pressed
step stand, orders from files, and a plan where layer order falls."""
import json

import numpy as np
import pytest

from stablelego_jax.analysis import analyze_layout
from stablelego_jax.layout import LayoutError, brick_layout, make_layout
from stablelego_jax.sequence import (
    PRESS_KEY,
    BuildOrder,
    analyze_sequence,
    layer_order,
    plan_order,
    prefix_layouts,
    press_layout,
    read_order,
    support_candidates,
)


@pytest.fixture
def lever():
    """A beam on a pillar with a heavy load (A, 0.5 kg) and a lighter counterweight (B, 0.25 kg):
    A alone tips the beam, B alone does not, both stand."""
    return make_layout(["pillar", "beam", "A", "B"], [(0, 3, 0), (0, 0, 1), (0, 0, 2), (0, 6, 2)],
                       [(2, 2), (2, 8), (2, 2), (2, 2)], [1.15e-3, 4.3e-3, 0.5, 0.25])


@pytest.fixture
def overhang():
    """A 2x4 brick half over a 2x2 base: stands, but not under a press on its free end."""
    return brick_layout([(0, 0, 0), (0, 0, 1)], [(2, 2), (2, 4)], ["base", "top"])


def test_layer_order_and_prefixes(lever):
    o = layer_order(lever)
    assert o.keys == ("pillar", "beam", "A", "B")
    pre = prefix_layouts(lever, BuildOrder(("beam", "A", "B"), fixed=("pillar",)))
    assert [p.keys for p in pre] == [("pillar", "beam"), ("pillar", "beam", "A"), ("pillar", "beam", "A", "B")]


def test_first_fall_and_weakest_of_every_step(lever):
    r = analyze_sequence(lever, solver="exact")
    assert [s.stable for s in r.steps] == [True, True, False, True]
    assert r.first_fall == 3 and r.steps[2].weakest == "beam" and r.steps[2].score == 1.0
    for s in r.steps:  # each step is the prefix layout, scored as analyze would
        ex = analyze_layout(s.analysis.layout, solver="exact")
        assert (ex.stable, ex.weakest) == (s.stable, s.weakest)
    rec = r.to_json()
    assert rec["first_fall"] == 3 and [st["brick"] for st in rec["steps"]] == ["pillar", "beam", "A", "B"]
    json.dumps(rec)


def test_jax_solver_agrees_with_exact(lever, x64):
    rj = analyze_sequence(lever, solver="jax", press=2.0)
    re = analyze_sequence(lever, solver="exact", press=2.0)
    assert [(s.stable, s.weakest, s.pressed_stable) for s in rj.steps] == \
           [(s.stable, s.weakest, s.pressed_stable) for s in re.steps]
    assert rj.n_solved == re.n_solved == 8


def test_plan_finds_an_order_that_stands(lever):
    order, found = plan_order(lever, solver="exact")
    assert found and order.keys == ("pillar", "beam", "B", "A")
    assert analyze_sequence(lever, order, solver="exact").first_fall is None


def test_press_block_and_press_on_brick(overhang):
    o = BuildOrder(("base", "top"), press_at={"top": (0, 3, 2, 2, 1)})
    pre = prefix_layouts(overhang, o)[1]
    lay, mode = press_layout(pre, "top", 9.8, o)
    assert mode == "block" and lay.keys[-1] == PRESS_KEY and lay.mass[-1] == pytest.approx(1.0)
    assert lay.pos[-1].tolist() == [0, 3, 2] and lay.size[-1].tolist() == [2, 1]
    lay, mode = press_layout(pre, "top", 9.8, BuildOrder(("base", "top")))
    assert mode == "brick" and lay.mass[1] == pytest.approx(pre.mass[1] + 1.0) and lay.n == 2
    assert press_layout(pre, "top", 9.8, BuildOrder(("base", "top"), no_press=frozenset({"top"}))) == (None, "none")


def test_pressed_overhang_needs_a_support_under_its_free_end(overhang):
    o = BuildOrder(("base", "top"), press_at={"top": (0, 3, 2, 2, 1)})
    light = analyze_sequence(overhang, o, press=0.5, solver="exact")
    assert light.support_steps == [] and light.steps[1].pressed_stable
    r = analyze_sequence(overhang, o, press=21.56, solver="exact")
    top = r.steps[1]
    assert top.stable and not top.pressed_stable and top.needs_support and r.support_steps == [2]
    x, y, z = top.support
    assert z == 0 and y >= 2  # under the overhang, not under the base
    assert top.support_tried == 4  # the four free columns under the overhang
    cands = dict(support_candidates(top.pressed.layout, "top"))
    assert analyze_layout(cands[top.support], solver="exact").stable
    assert np.all(cands[top.support].mass[-1:] == 0.0)  # pillars weigh nothing


def test_order_files(lever, tmp_path):
    p = tmp_path / "order.txt"
    p.write_text("# bottom first\npillar\nbeam\nB\nA\n")
    assert read_order(str(p), lever).keys == ("pillar", "beam", "B", "A")
    p.write_text(json.dumps({"fixed": ["pillar"], "order": ["beam", "B", "A"]}))
    o = read_order(str(p), lever)
    assert o.fixed == ("pillar",) and o.keys == ("beam", "B", "A")
    for text, msg in [('["pillar", "beam", "A"]', r"brick 'B' of .* is not in the order"),
                      ('["pillar", "beam", "A", "B", "C"]', r"brick 'C' is not in"),
                      ('["pillar", "beam", "A", "A", "B"]', r"brick 'A' appears twice"),
                      ('["pillar", ', "order is not valid JSON")]:
        p.write_text(text)
        with pytest.raises(LayoutError, match=rf"order.txt: {msg}"):
            read_order(str(p), lever)


def test_exact_steps_on_two_workers_are_the_steps_on_one():
    """``jobs=2``: the exact solver's steps spread over two worker
    processes (a build of at least ``batch.POOL_MIN`` steps) give every
    step's verdict, weakest brick and scores as one process does."""
    from stablelego_jax.batch import POOL_MIN

    n = POOL_MIN + 2
    # a 2x2 tower with a 2x8 arm on top and a heavy brick at the arm's far end: the last step falls
    pos = [(0, 0, z) for z in range(n - 2)] + [(0, 0, n - 2), (0, 6, n - 1)]
    size = [(2, 2)] * (n - 2) + [(2, 8), (2, 2)]
    lay = make_layout([f"b{i}" for i in range(n)], pos, size, [1.15e-3] * (n - 2) + [4.3e-3, 0.5])
    one = analyze_sequence(lay, solver="exact", jobs=1)
    two = analyze_sequence(lay, solver="exact", jobs=2)
    assert one.first_fall == two.first_fall == n and one.n_solved == two.n_solved == n
    for a, b in zip(one.steps, two.steps):
        assert (a.stable, a.weakest, a.score) == (b.stable, b.weakest, b.score)
        assert a.analysis.scores == b.analysis.scores
