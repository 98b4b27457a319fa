"""Soft layouts: candidates compiled against a layout into one fixed-shape problem."""
import os

import numpy as np
import pytest

from conftest import EXAMPLES
from stablelego_jax import load_layout, make_layout
from stablelego_jax.layout import LayoutError
from stablelego_jax.model import NORMAL, compile_layout
from stablelego_jax.soft import apply_candidates, candidate_brick, compile_soft, fresh_keys, soft_problem
from stablelego_jax.solvers.problem import pad_soft

STAIR20 = os.path.join(EXAMPLES, "stablelego", "stair_20.json")


def _signature(cb, coef, kind, keys_of):
    """Columns as a sorted list of (kind, brick names, rounded wrench) tuples."""
    out = []
    for j in range(len(kind)):
        names = tuple(keys_of(int(b)) for b in cb[j])
        out.append((int(kind[j]), names, tuple(np.round(coef[j].ravel(), 12))))
    return sorted(out)


def test_plain_layout_is_compile_layout():
    lay = load_layout(STAIR20)
    model = compile_layout(lay)
    prob = soft_problem(lay)
    assert prob.col_kind.shape[0] == model.m
    np.testing.assert_array_equal(prob.col_brick, model.col_brick)
    np.testing.assert_allclose(prob.col_coef, model.col_coef)
    np.testing.assert_allclose(prob.mass, lay.mass)
    np.testing.assert_array_equal(prob.unit, np.arange(lay.n))


def test_flat_and_from_flat_round_trip_the_fields_that_are_set():
    from stablelego_jax.soft import SoftProblem
    from stablelego_jax.solvers.problem import layer_soft

    for prob in (soft_problem(load_layout(STAIR20)), layer_soft(soft_problem(load_layout(STAIR20)))):
        fields, arrays = prob.flat()
        assert fields == tuple(f for f in SoftProblem._fields if getattr(prob, f) is not None)
        back = SoftProblem.from_flat(fields, arrays)
        for f in SoftProblem._fields:
            a, b = getattr(prob, f), getattr(back, f)
            assert (a is None and b is None) or a is b
    assert "slot" not in soft_problem(load_layout(STAIR20)).flat()[0]


def test_keep_only_pads_the_dropped_bricks_and_every_column_that_touches_them():
    import jax.numpy as jnp

    prob = soft_problem(load_layout(STAIR20))
    n = prob.mass.shape[0]
    keep = np.ones(n, bool)
    keep[[3, 7]] = False
    out = prob.keep_only(keep)
    np.testing.assert_array_equal(out.brick_mask, prob.brick_mask & keep)
    cb = np.asarray(prob.col_brick)
    touches = np.isin(cb, [3, 7]).any(axis=1)
    assert touches.any() and (prob.col_mask & ~touches).any()
    np.testing.assert_array_equal(out.col_mask, prob.col_mask & ~touches)
    for f in ("col_brick", "col_coef", "col_kind", "group", "mass", "unit", "level"):
        assert getattr(out, f) is getattr(prob, f)
    traced = prob.keep_only(jnp.asarray(keep), xp=jnp)
    np.testing.assert_array_equal(traced.col_mask, out.col_mask)
    np.testing.assert_array_equal(traced.brick_mask, out.brick_mask)


def test_candidate_columns_equal_those_of_the_layout_with_it():
    lay = load_layout(STAIR20)
    cands = [candidate_brick([(4, 21, 0, 1, 2)]), candidate_brick([(6, 21, 0, 2, 2), (6, 21, 1, 2, 2)]),
             candidate_brick([(0, 21, 1, 2, 2)])]
    soft = compile_soft(lay, cands)
    p = soft.problem
    assert soft.n == lay.n + 4
    np.testing.assert_array_equal(soft.unit_index, [20, 21, 23])
    np.testing.assert_array_equal(p.unit[20:], [20, 21, 21, 23])  # a pillar is one unit
    for k in range(len(cands)):
        full = soft.layout_with([k])
        m = compile_layout(full)
        bricks = list(range(lay.n)) + list(soft.unit_bricks[k])
        keep = np.isin(p.col_brick, bricks + [soft.n]).all(axis=1)
        names = {i: full.keys[i] for i in range(full.n)}
        glob = {g: full.keys[i] for i, g in enumerate(bricks)}
        mine = _signature(p.col_brick[keep], p.col_coef[keep], p.col_kind[keep],
                          lambda b: glob.get(b, "plate"))
        ref = _signature(m.col_brick[: m.m], m.col_coef[: m.m], m.col_kind[: m.m],
                         lambda b: names.get(b, "plate"))
        assert mine == ref
    # every NORMAL column is in its upper brick's group, once
    normal = np.nonzero(p.col_kind == NORMAL)[0]
    grouped = p.group[p.group < len(p.col_kind)]
    assert sorted(grouped.tolist()) == normal.tolist()
    for b in range(soft.n):
        g = p.group[b][p.group[b] < len(p.col_kind)]
        assert (p.col_brick[g, 0] == b).all()


def test_candidates_may_overlap_each_other_but_not_the_layout():
    lay = load_layout(STAIR20)
    a = candidate_brick([(4, 21, 0, 1, 2)])
    b = candidate_brick([(4, 21, 0, 2, 2)])  # overlaps a: alternatives
    soft = compile_soft(lay, [a, b])
    # no column joins two candidates
    cand = np.arange(lay.n, soft.n)
    both = np.isin(soft.problem.col_brick, cand).all(axis=1)
    assert not both.any()
    with pytest.raises(LayoutError, match="stair_20.json.*candidate 0.*overlaps"):
        compile_soft(lay, [candidate_brick([(2, 21, 1, 1, 2)])])  # inside brick '2'


def test_replacement_candidate_is_compiled_without_the_replaced_brick():
    lay = load_layout(STAIR20)
    # brick '2' (2x4 along x at (2,21,1)) replaced by a 2x6 reaching back over brick '1'
    c = candidate_brick([(0, 21, 1, 6, 2)], kind="replace", replaces=[1])
    soft = compile_soft(lay, [c])
    new = soft.unit_bricks[0][0]
    cb = soft.problem.col_brick
    assert not ((cb == new).any(axis=1) & (cb == 1).any(axis=1)).any()
    w = soft.weights([0])
    assert w[1] == 0.0 and w[new] == 1.0
    full = soft.layout_with([0])
    assert "2" not in full.keys and full.n == lay.n


def test_weights_and_layout_with_keep_every_original_brick():
    lay = load_layout(STAIR20)
    soft = compile_soft(lay, [candidate_brick([(4, 21, 0, 1, 2)]), candidate_brick([(0, 21, 1, 2, 2)])])
    w = soft.weights()
    assert (w[: lay.n] == 1).all() and (w[lay.n:] == 0).all()
    assert soft.weights([1])[lay.n + 1] == 1.0
    full = soft.layout_with([0, 1])
    assert full.keys[: lay.n] == lay.keys
    np.testing.assert_array_equal(full.pos[: lay.n], lay.pos)
    np.testing.assert_array_equal(full.size[: lay.n], lay.size)
    assert full.keys[lay.n:] == ("21", "22")
    assert full.brick_id[lay.n:] == ("9", "12")  # 1x2 and 2x2 of the StableLego library


def test_fresh_keys_and_apply_candidates():
    assert fresh_keys(["1", "2", "b"], 2) == ["3", "4"]
    assert fresh_keys(["x", "y"], 2) == ["3", "4"]
    assert fresh_keys(["1", "3"], 1) == ["4"]
    lay = make_layout(["a", "b"], [[0, 0, 0], [0, 0, 1]], [[2, 2], [2, 2]], [0.00115, 0.00115])
    out = apply_candidates(lay, [candidate_brick([(2, 0, 0, 1, 2)])], ["new"])
    assert out.keys == ("a", "b", "new")
    with pytest.raises(LayoutError, match="overlaps"):
        apply_candidates(lay, [candidate_brick([(1, 0, 1, 2, 2)])])
    with pytest.raises(ValueError, match="Table I"):
        candidate_brick([(0, 0, 0, 3, 3)])


# --------------------------------------------------------------------------
# compile_placements: placements that may overlap (the generator's soft layouts)


def _placements():
    from stablelego_jax.layout import TABLE_I_MASS_KG

    pos = [(0, 0, 0), (0, 0, 1), (0, 0, 2), (0, 0, 2), (1, 0, 2), (2, 0, 2), (0, 1, 1), (1, 0, 1), (0, 0, 0),
           (1, 0, 0), (3, 0, 1), (2, 0, 0)]
    size = [(1, 1), (1, 1), (1, 4), (1, 1), (1, 1), (1, 1), (1, 1), (1, 2), (2, 1), (1, 1), (1, 1), (2, 2)]
    mass = [TABLE_I_MASS_KG[tuple(sorted(s))] for s in size]
    return np.array(pos), np.array(size), np.array(mass)


SUBSETS = ([0, 1, 2], [0, 1, 3, 7, 9], [8, 7, 4, 5], [0, 1, 6], [11, 10, 9, 1, 0], [11, 7, 0, 3])


def test_compile_placements_columns_of_a_subset_are_compile_layouts():
    from stablelego_jax.soft import compile_placements

    pos, size, mass = _placements()
    prob = compile_placements(pos, size, mass)
    k = len(pos)
    for sub in SUBSETS:
        lay = make_layout([str(i) for i in sub], pos[sub], size[sub], mass[sub])
        m = compile_layout(lay)
        ref = _signature(m.col_brick[: m.m], m.col_coef[: m.m], m.col_kind[: m.m],
                         lambda b: sub[b] if b < len(sub) else "ground")
        keep = np.isin(prob.col_brick, list(sub) + [k]).all(axis=1) & (prob.col_brick[:, 0] != k)
        mine = _signature(prob.col_brick[keep], prob.col_coef[keep], prob.col_kind[keep],
                          lambda b: b if b < k else "ground")
        assert mine == ref


def _subset_loss_check(subsets):
    import jax

    from stablelego_jax.loss import soft_report

    from stablelego_jax.soft import compile_placements

    @jax.jit
    def loss(w, pr):
        rep = soft_report(w, None, pr)
        return rep.brick_loss.sum(), rep.converged

    pos, size, mass = _placements()
    prob = compile_placements(pos, size, mass)
    # one padded size for every problem below: one compilation of the solver
    padded = pad_soft(prob)
    n, m, P = padded.mass.shape[0], padded.col_kind.shape[0], padded.group.shape[1]
    for sub in subsets:
        w = np.zeros(n)
        w[sub] = 1.0
        lay = make_layout([str(i) for i in sub], pos[sub], size[sub], mass[sub])
        ref_w = np.zeros(n)
        ref_w[: len(sub)] = 1.0
        ref, ok = loss(ref_w, pad_soft(soft_problem(lay), n, m, P))
        got, conv = loss(w, padded)
        ref, got = float(ref), float(got)
        assert bool(ok) and bool(conv)
        assert abs(got - ref) <= 1e-8 * max(1.0, abs(ref))


@pytest.mark.usefixtures("x64")  # the check jits the loss itself
def test_compile_placements_subset_loss_equals_layout_loss():
    """w = 1 on a non-overlapping subset, 0 elsewhere: the subset's own loss
    (the zero-weight placements and their columns have no effect)."""
    _subset_loss_check(SUBSETS[:5])


@pytest.mark.usefixtures("x64")
def test_compile_placements_subset_loss_hard_case():
    """Contacts between absent placements: the interior point used to blow up
    its complementarity gap here (opt_res 1.0 after 30 iterations); a step
    that more than doubles the gap is now shortened."""
    _subset_loss_check(SUBSETS[5:])


def test_compile_placements_overlapping_alternatives_have_no_contact():
    from stablelego_jax.soft import compile_placements, placement_pairs

    pos, size, mass = _placements()
    prob = compile_placements(pos, size, mass)
    cb = prob.col_brick
    for a, b in ((0, 8), (2, 3), (8, 9)):  # overlapping pairs in one layer
        assert not (((cb[:, 0] == a) & (cb[:, 1] == b)) | ((cb[:, 0] == b) & (cb[:, 1] == a))).any()
    vert, side, ground = placement_pairs(pos, size)
    assert sorted(ground.tolist()) == [0, 8, 9, 11]
    assert [1, 7] in side.tolist() and [6, 7] in side.tolist() and [2, 4] in side.tolist()
    assert [7, 10] not in side.tolist() and [0, 8] not in side.tolist() and [2, 3] not in side.tolist()
    assert [0, 1] in vert.tolist() and [7, 4] in vert.tolist() and [1, 2] in vert.tolist()
    np.testing.assert_array_equal(prob.unit, np.arange(len(pos)))
    with pytest.raises(ValueError):
        compile_placements(pos, size[:3], mass)
