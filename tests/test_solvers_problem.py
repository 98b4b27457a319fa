"""The problem pytrees, the one size ladder and solve plans (stablelego_jax.solvers.problem)."""
import dataclasses
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import json

from conftest import EXAMPLES, hanging_scene
from stablelego_jax.formats.reader import load_layout
from stablelego_jax.generate.procedural import cuboid, pyramid, stairs, tower
from stablelego_jax.layout import brick_layout
from stablelego_jax.model import KNOB, NORMAL, compile_layout
from stablelego_jax.soft import candidate_brick, compile_soft
from stablelego_jax.solvers.problem import (ladder, 
    CHUNK,
    MIN_CHUNKS,
    NOT_LAYERED,
    batch_rung,
    bucket_shape,
    chunk_rows,
    fit_plan,
    gram_plan,
    layer_bucket,
    layer_plan,
    layered_problem,
    levels_ok,
    operators,
    pad_soft,
    pad_to_bucket,
    plan_problem,
    rung,
    slab_levels,
    soft_layer_plan,
    soft_levels,
    soft_plan,
    solve_plan,
    stack_soft,
    to_layered,
)


def test_rung_ladder():
    ks = range(1, 5000, 7)
    r = [rung(k) for k in ks]
    assert all(x >= k for x, k in zip(r, ks))
    assert all(x <= 1.25 * k + 8 for x, k in zip(r, ks))  # at most 25% padding (one step of 8 more)
    assert len(set(r)) < 40  # few distinct shapes
    assert [rung(k) for k in (1, 8, 9, 17, 41, 57)] == [8, 8, 16, 24, 56, 72]
    assert [rung(k, 64) for k in (1, 65, 81)] == [64, 80, 104]
    assert all(rung(v) == v for v in set(r))
    assert ladder(120) == [8, 16, 24, 32, 40, 56, 72, 96, 120] and ladder(64) == [8, 16, 24, 32, 40, 56, 64]
    assert all(rung(v) == v for v in ladder(2000)[:-1]) and ladder(8) == [8]
    assert layer_bucket(3, 5) == (4, 6) and layer_bucket(70, 130) == (80, 144)
    assert [batch_rung(k, 2, 64) for k in (1, 2, 3, 9, 200)] == [2, 2, 4, 16, 64]
    # small batches are padded to full: one compiled batch size, not 1, 2 and 4
    assert [batch_rung(k, 1, 4) for k in (1, 2, 3, 4)] == [4, 4, 4, 4]


def test_bucket_shape_and_padding_on_the_ladder():
    m = compile_layout(stairs(4))
    n, mm, p = bucket_shape(m.n, m.m, m.group.shape[1])
    assert (n, mm, p) == (rung(m.n, 8), rung(m.m, 64), rung(m.group.shape[1], 4))
    pm = pad_to_bucket(m)
    assert (pm.n_pad, pm.m_pad) == (n, mm)
    np.testing.assert_array_equal(pm.dense_A(), m.dense_A())


def test_layered_plan_numbers_bricks_layer_by_layer():
    m = compile_layout(cuboid(7, 7, 6))
    key = solve_plan(m)
    assert key[0] == "layered" and key[1:] == layer_bucket(6, 49)
    fm, prob = plan_problem(m, key, rung(m.m, 64), rung(m.group.shape[1], 4))
    L, B = key[1:]
    assert prob.gravity.shape[0] == L * B and prob.layers.shape == (L,)
    lay = to_layered(fm, L, B)
    # every column joins one layer or two adjacent ones
    cb = lay.col_brick[: m.m]
    lo, hi = np.minimum(cb[:, 0], cb[:, 1]), np.maximum(cb[:, 0], cb[:, 1])
    real = hi < L * B
    assert (hi[real] // B - lo[real] // B <= 1).all()
    assert solve_plan(compile_layout(tower(3)))[0] == "dense"
    key = solve_plan(compile_layout(stairs(60)))
    assert key[0] == "layered" and key[1] >= 60


def test_wide_layouts_are_numbered_by_slabs():
    """A pyramid's bottom layer holds levels^2 bricks, a vertical slab
    about half as many: the plan numbers it by slabs (a narrower block),
    every column and every brick with its supports in one slab or two
    adjacent ones, bricks in input order for scoring. Narrow layouts keep
    their layers."""
    m = compile_layout(pyramid(12))
    assert layer_plan(m) == (12, 144)
    lv = slab_levels(m)
    assert levels_ok(m, lv) and not levels_ok(m, np.arange(m.n) % 3)  # levels 0 and 2 touch
    assert np.bincount(lv).max() == 78 and len(np.unique(lv)) == 12
    key = solve_plan(m)
    assert key == ("slabs",) + layer_bucket(12, 78) + (4,)  # each brick on up to 4
    fm, prob = plan_problem(m, key, rung(m.m, 64), rung(m.group.shape[1], 4))
    L, B = key[1:3]
    assert fm.n_pad == m.n and prob.gravity.shape[0] == L * B and prob.supports.shape == (L * B, 4)
    # each NORMAL column's lower brick sits in its owner's support slots, once
    sup, slot, cbp = np.asarray(prob.supports), np.asarray(prob.col_slot), np.asarray(prob.col_brick)
    nor = (np.asarray(prob.col_kind) == NORMAL) & np.asarray(prob.col_mask) & (cbp[:, 1] < L * B)
    assert (sup[cbp[nor, 0], slot[nor]] == cbp[nor, 1]).all() and (slot[~nor] == 4).all()
    real = sup < L * B
    assert all(len(set(r[k])) == k.sum() for r, k in zip(sup, real))
    cb = np.asarray(prob.col_brick)[: m.m]
    real = (cb < L * B).all(1)
    assert (np.abs(cb[real, 0] // B - cb[real, 1] // B) <= 1).all()
    # the same bricks, with their weights, in slab-major order
    assert np.isclose(np.asarray(prob.gravity)[:, 2].sum(), fm.gravity[:, 2].sum())
    assert np.asarray(prob.brick_mask).sum() == m.n
    assert solve_plan(compile_layout(cuboid(7, 7, 6)))[0] == "layered"  # 49 a layer: layers
    assert slab_levels(dataclasses.replace(m, centre=None)) is None


def test_one_large_layout_gets_a_plan_fitted_to_it():
    """A solve of one layout pads to its own size when the ladder's padding
    would cost more than a compile: the 10^3 unit cube takes 10 layers of
    104 slots instead of 12 of 128; a small layout keeps its rung."""
    m = compile_layout(cuboid(10, 10, 10))
    key = solve_plan(m)
    assert key == ("layered", 12, 128)
    fit = fit_plan(m, key, rung(m.m, 64))
    # and each brick's term from its one support (4 slots): 2 104^2 / 5^2 >= SUPPORTS_RATIO
    assert fit == ("layered", 10, 104, 4)
    fm, prob = plan_problem(m, fit, rung(m.m, 64), rung(m.group.shape[1], 4))
    assert prob.layers.shape == (10,) and prob.gravity.shape[0] == 1040 and prob.supports.shape == (1040, 4)
    # a solid shape's narrower layers (40 slots) keep the product per level
    solid = compile_layout(cuboid(8, 5, 20))
    sk = fit_plan(solid, solve_plan(solid), rung(solid.m, 64))
    assert sk[0] == "layered" and len(sk) == 3
    small = compile_layout(cuboid(4, 4, 4))
    assert fit_plan(small, solve_plan(small), rung(small.m, 64)) == solve_plan(small)


def test_contact_levels_that_do_not_layer_a_scene_are_not_used(tmp_path):
    """A scene's contact levels put a brick hanging from an arm above the
    arm, whose supports then span three levels: neither the verdict's
    plan nor the soft problem's numbers by them (one layer instead), while
    a grid layout's soft problem keeps its layers."""
    from stablelego_jax.soft import soft_problem

    path = tmp_path / "hang.json"
    path.write_text(json.dumps(hanging_scene(13)))
    m = compile_layout(load_layout(str(path)))
    assert len(np.unique(m.layer[: m.n])) == 4 and not levels_ok(m, m.layer[: m.n])
    assert layer_plan(m) == (NOT_LAYERED, 52) and solve_plan(m)[0] != "layered"
    with pytest.raises(ValueError, match="no layer-by-layer numbering"):
        to_layered(m, 4, 64)
    soft = soft_problem(load_layout(str(path)))
    assert not soft_levels(soft).any() and soft_layer_plan(soft) == (1, 52) and soft_plan(soft) == ("dense",)
    grid = soft_problem(cuboid(7, 7, 6))
    assert soft_layer_plan(grid) == (6, 49) and soft_plan(grid)[0] == "layered"
    # small problems stay dense: 3 levels of 48 bricks pad to 4 x 48 slots, 4 * 48^3 > 144^3 / 9
    # (the flop count), and layered would save ~0.06 s a solve by the time model, under a tenth of
    # a compile
    wide = soft_problem(cuboid(6, 8, 3))
    assert soft_layer_plan(wide) == (3, 48) and soft_plan(wide) == ("dense",)
    # uneven levels, as a training subset's (BENCHMARKS.md, issue 19, session 58): 5 levels of 99
    # bricks and a column of 5 above, 500 bricks in 10 levels pad to 12 x 128 slots, 12 * 128^3 >
    # 500^3 / 9, so the flop count says dense, yet the time model saves ~3.6 s a solve: layered
    pos = np.concatenate([cuboid(9, 11, 5).pos, [[0, 0, k] for k in range(5, 10)]])
    uneven = soft_problem(brick_layout(pos, np.ones((len(pos), 2), np.int64)))
    assert soft_layer_plan(uneven) == (10, 99) and soft_plan(uneven) == ("layered", 12, 128)


def test_pad_and_stack_soft():
    lay = load_layout(os.path.join(EXAMPLES, "stablelego", "stair_20.json"))
    soft = compile_soft(lay, [candidate_brick([(4, 21, 0, 1, 2)])])
    p = soft.problem
    q = pad_soft(p, 32, 1024, 32)
    assert q.mass.shape == (32,) and q.col_kind.shape == (1024,) and q.group.shape == (32, 32)
    assert not q.brick_mask[soft.n:].any() and not q.col_mask[p.col_kind.shape[0]:].any()
    assert (q.col_kind[p.col_kind.shape[0]:] == KNOB).all()
    assert (q.col_coef[p.col_kind.shape[0]:] == 0).all()
    assert (q.col_brick[p.col_kind.shape[0]:] == 32).all()
    assert (q.col_brick[: p.col_kind.shape[0]][p.col_brick == soft.n] == 32).all()  # baseplate moved to the new n
    np.testing.assert_array_equal(q.unit[soft.n:], np.arange(soft.n, 32))
    auto = pad_soft(p)
    assert auto.mass.shape[0] >= soft.n and auto.col_kind.shape[0] >= p.col_kind.shape[0]
    with pytest.raises(ValueError, match="cannot pad"):
        pad_soft(p, 8, 1024, 32)
    s = stack_soft([q, q])
    assert s.col_coef.shape == (2, 1024, 2, 6)


def test_merge_plans_moves_small_buckets_when_cheaper_than_a_compile():
    from stablelego_jax.solvers.problem import DENSE_COMPILE_S, merge_plans, plan_seconds

    sizes = {
        ("dense", 16): [(16, 3, 6)] * 1000,
        ("dense", 24): [(24, 4, 8)] * 3,  # few: join dense 32
        ("dense", 32): [(32, 5, 8)] * 100,
        ("layered", 12, 12): [(56, 9, 10)] * 2,  # few: join layered 16 x 16
        ("layered", 16, 16): [(96, 14, 16)] * 40,
        ("layered", 8, 40): [(200, 8, 33)] * 1,  # fits no other bucket: stays
    }
    into = merge_plans(sizes)
    assert into[("dense", 24)] == ("dense", 32)
    assert into[("layered", 12, 12)] == ("layered", 16, 16)
    assert into[("layered", 8, 40)] == ("layered", 8, 40)
    assert into[("dense", 16)] == ("dense", 16)  # 1000 layouts: moving them costs more than a compile
    assert 1000 * (plan_seconds(("dense", 32)) - plan_seconds(("dense", 16))) > DENSE_COMPILE_S
    # every target is a bucket that stays, and its layouts fit there
    for k, t in into.items():
        assert into[t] == t
    assert merge_plans(sizes, compile_s=0.0) == {k: k for k in sizes}
    assert len(sizes[("dense", 32)]) == 100  # the caller's dict is untouched


def test_merge_plans_joins_buckets_that_no_bucket_of_the_run_takes():
    """Two buckets of one layout each, neither of which takes the other's
    layout, are solved in the smallest bucket of the ladder that takes
    both (one compile instead of two, paid for by padding); not when
    padding their many layouts costs more than a compile, nor where a
    bucket would be estimated faster there (then :func:`solve_plan` and
    the time estimate disagree: no join for that)."""
    from stablelego_jax.solvers.problem import compile_seconds, merge_plans, plan_seconds

    a, b, d = ("layered", 6, 24), ("layered", 8, 20), ("dense", 24)
    sizes = {a: [(120, 5, 24)], b: [(120, 7, 17)], d: [(24, 4, 8)] * 300}
    into = merge_plans(sizes)
    j = into[a]
    assert j == into[b] and j not in sizes and into[j] == j and into[d] == d
    # the smallest dense bucket (120 bricks) or layered one (8 x 24) that takes both
    assert j in (("dense", 120), ("layered", 8, 24))
    saved = compile_seconds(a) + compile_seconds(b) - compile_seconds(j)
    assert 2 * plan_seconds(j) - plan_seconds(a) - plan_seconds(b) < saved
    assert plan_seconds(j) >= max(plan_seconds(a), plan_seconds(b))
    assert merge_plans({a: sizes[a] * 200, b: sizes[b] * 200}) == {a: a, b: b}
    assert merge_plans(sizes, compile_s=0.0) == {k: k for k in sizes}
    # a third bucket that the joined one takes follows it
    c = ("layered", 4, 16)
    into = merge_plans({**sizes, c: [(56, 4, 12)]})
    assert into[c] == into[a] == into[b]
    # a joined key whose solver is compiled already costs a load: 60 layouts each pay for that
    many = {a: sizes[a] * 60, b: sizes[b] * 60}
    lj = ("layered", 8, 24)  # the smallest layered bucket that takes both
    assert merge_plans(many) == {a: a, b: b}
    into = merge_plans(many, ready={lj})
    assert into[a] == into[b] == lj
    # a bucket of the run with the joined key takes both
    e = ("dense", 120)
    into = merge_plans({a: sizes[a], b: sizes[b], e: [(120, 9, 30)] * 3})
    assert into[a] == into[b] == into[e] == e


def test_merge_plans_keeps_ready_buckets_and_counts_columns():
    """A bucket whose solver is compiled already saves only a load by moving,
    so it stays; padded columns make a bucket's layouts cost more, and a
    target that must pad its own layouts to more columns counts that too."""
    from stablelego_jax.solvers.problem import DENSE_COMPILE_S, LOAD_S, merge_plans, plan_seconds

    assert plan_seconds(("dense", 16), 1000) > plan_seconds(("dense", 16), 500) > 0
    assert plan_seconds(("layered", 12, 12)) > plan_seconds(("layered", 12, 8))
    # 400 layouts: moving them costs more than a load (0.4 s), less than a compile
    sizes = {("dense", 24): [(24, 4, 8)] * 400, ("dense", 32): [(32, 5, 8)] * 100}
    assert LOAD_S < 400 * (plan_seconds(("dense", 32)) - plan_seconds(("dense", 24))) < DENSE_COMPILE_S
    assert merge_plans(sizes)[("dense", 24)] == ("dense", 32)
    assert merge_plans(sizes, ready={("dense", 24)})[("dense", 24)] == ("dense", 24)
    # the layouts of the small bucket have many columns: merging them
    # would pad the 100 of the target to those columns too
    m_pads = {("dense", 24): 8192, ("dense", 32): 1096}
    assert merge_plans(sizes, m_pads=m_pads)[("dense", 24)] == ("dense", 24)
    assert merge_plans(sizes, m_pads={("dense", 24): 872, ("dense", 32): 1096})[("dense", 24)] == ("dense", 32)


def test_layer_soft_places_bricks_layer_by_layer():
    from stablelego_jax.solvers.problem import layer_soft, plan_soft, soft_layer_plan, soft_plan

    lay = load_layout(os.path.join(EXAMPLES, "stablelego", "stair_20.json"))
    soft = compile_soft(lay, [candidate_brick([(12, 21, 0, 2, 2), (12, 21, 1, 2, 2), (12, 21, 2, 2, 2)])])
    p = soft.problem
    L, B = soft_layer_plan(p)
    z = p.level - p.level.min()
    assert L == z.max() + 1 and B == np.bincount(z).max()
    q = layer_soft(p)
    Lp, Bp = q.layers.shape
    assert (Lp, Bp) == layer_bucket(L, B)
    np.testing.assert_array_equal(q.slot // Bp, z)  # each brick in its own layer
    assert len(set(q.slot.tolist())) == p.mass.shape[0]  # one slot per brick
    np.testing.assert_array_equal(q.col_brick, p.col_brick)  # indices unchanged
    # every column joins one layer or two adjacent ones
    sl = np.concatenate([q.slot, [Lp * Bp]])[q.col_brick] // Bp
    real = sl[:, 1] < Lp
    assert (np.abs(sl[real, 0] - sl[real, 1]) <= 1).all()
    padded = pad_soft(q, 64, 2048, 32)
    assert (padded.slot[p.mass.shape[0]:] == Lp * Bp).all() and (padded.level[p.mass.shape[0]:] == -1).all()
    assert stack_soft([padded, padded]).slot.shape == (2, 64)
    with pytest.raises(ValueError, match="layer slots"):
        layer_soft(p, 4, 2)
    assert soft_plan(p) == ("dense",) and plan_soft(p).slot is None  # small: dense
    tall = compile_soft(cuboid(4, 4, 12))
    key = soft_plan(tall.problem)
    assert key[0] == "layered" and plan_soft(tall.problem).layers.shape == key[1:]


@pytest.mark.usefixtures("x64")
@pytest.mark.parametrize("layered", [False, True])
def test_layer_gram_blocks_are_the_dense_weighted_gram(layered):
    """LayerGram.blocks(e) holds A diag(e) A' (A the scaled equilibrium
    operator): its diagonal blocks, the blocks below them, nothing else."""
    m = compile_layout(cuboid(3, 2, 4))
    if layered:
        L, B = layer_bucket(*layer_plan(m))
        prob = layered_problem(to_layered(m, L, B), L)
    else:
        prob = layered_problem(m, 1)
    A, _, coef, _, _ = operators(prob, m.params)
    n, mm = prob.gravity.shape[0], prob.col_kind.shape[0]
    Ad = np.asarray(jax.jit(jax.vmap(A))(jnp.eye(mm))).reshape(mm, -1).T  # (6n, m): A applied to each column
    e = np.random.default_rng(1).uniform(0.5, 2.0, size=mm)
    M = (Ad * e) @ Ad.T
    # columns grouped by brick pair (the problem's chunks, several per pair here), or one piece per column
    assert prob.chunks is not None and (prob.chunks < mm).sum() == np.asarray(prob.col_mask).sum()
    for p in (prob, prob._replace(chunks=None)):
        gram = gram_plan(p.col_brick, coef, n, 1 if p.layers is None else p.layers.shape[0], p.chunks)
        assert (gram.L > 1) == layered and gram.L * gram.B == n and gram.k == 6 * gram.B
        D, E = (np.asarray(x) for x in gram.blocks(np.asarray(e)))
        k = gram.k
        for i in range(gram.L):
            np.testing.assert_allclose(D[i], M[i * k:(i + 1) * k, i * k:(i + 1) * k], atol=1e-12)
            if i + 1 < gram.L:
                np.testing.assert_allclose(E[i], M[(i + 1) * k:(i + 2) * k, i * k:(i + 1) * k], atol=1e-12)
            for j in range(i + 2, gram.L):  # block tridiagonal
                assert not M[j * k:(j + 1) * k, i * k:(i + 1) * k].any()
        # added in place to given blocks: the same Gram on top of them
        base = np.random.default_rng(2).normal(size=(2, gram.L, k, k))
        Db, Eb = (np.asarray(x) for x in gram.blocks(np.asarray(e), base=(base[0], base[1])))
        np.testing.assert_allclose(Db, base[0] + D, atol=1e-12)
        np.testing.assert_allclose(Eb, base[1] + E, atol=1e-12)


def test_layered_problem_pads_its_chunks():
    """A problem's column chunks pad to the ladder or to a given row count
    (a batch shares one), never below what its columns need."""
    m = compile_layout(cuboid(3, 2, 4))
    need = chunk_rows(m)
    assert need > 0 and layered_problem(m, 1).chunks.shape == (rung(need, MIN_CHUNKS), CHUNK)
    prob = layered_problem(m, 1, need + 5)
    assert prob.chunks.shape == (need + 5, CHUNK)
    assert (prob.chunks[need:] == prob.col_kind.shape[0]).all()  # padding rows name no column
    with pytest.raises(ValueError, match="cannot pad"):
        layered_problem(m, 1, need - 1)


def test_merge_plans_counts_batch_padding_and_batch_sizes():
    """A merge that pads the target's batch to the next power of two, or
    cuts it into a second batch size (one more compile), pays for that:
    the same moves that pay off unpadded are refused."""
    from stablelego_jax.solvers.problem import DENSE_COMPILE_S, LAYERED_COMPILE_S, batch_rung, merge_plans, plan_seconds

    def cut(cap):
        return lambda k, m, c: [batch_rung(min(cap, c - b0), 1, cap) for b0 in range(0, c, cap)]

    small, big = ("layered", 12, 12), ("layered", 16, 16)
    # 60 + 8 layouts: one batch of 64 becomes one of 128
    sizes = {small: [(56, 9, 10)] * 8, big: [(96, 14, 16)] * 60}
    unpadded = 8 * (plan_seconds(big) - plan_seconds(small))
    padded = 128 * plan_seconds(big) - 64 * plan_seconds(big) - 8 * plan_seconds(small)
    assert unpadded < LAYERED_COMPILE_S < padded
    assert merge_plans(sizes)[small] == big
    assert merge_plans(sizes, pieces=cut(128))[small] == small
    # 64 + 20 layouts at most 64 a batch: batches of 64 and 32 (two compiles, 96 solved)
    sizes = {("dense", 24): [(24, 4, 8)] * 20, ("dense", 32): [(32, 5, 8)] * 64}
    p24, p32 = plan_seconds(("dense", 24)), plan_seconds(("dense", 32))
    assert 20 * (p32 - p24) < DENSE_COMPILE_S
    assert 96 * p32 + 2 * DENSE_COMPILE_S > 64 * p32 + 32 * p24 + 2 * DENSE_COMPILE_S
    assert merge_plans(sizes)[("dense", 24)] == ("dense", 32)
    assert merge_plans(sizes, pieces=cut(64))[("dense", 24)] == ("dense", 24)
    # with room in the target's padding the move is free of padding and still made
    sizes = {("dense", 24): [(24, 4, 8)] * 4, ("dense", 32): [(32, 5, 8)] * 40}
    assert merge_plans(sizes, pieces=cut(64))[("dense", 24)] == ("dense", 32)


def test_merge_plans_cuts_the_dense_chain_at_least_cost():
    """The dense buckets are cut into runs of consecutive sizes, each solved
    in its largest bucket, at the least estimated time: the same cost as
    the best of every such cut, tried one by one."""
    import itertools

    from stablelego_jax.solvers.problem import DENSE_COMPILE_S, merge_plans, plan_seconds

    keys = [("dense", b) for b in (8, 16, 24, 32, 40, 56, 96)]
    rng = np.random.default_rng(3)
    for _ in range(20):
        count = dict(zip(keys, rng.integers(1, 400, len(keys)).tolist()))
        sizes = {k: [(k[1], 1, 1)] * c for k, c in count.items()}

        def cost(heads):  # each key solved in the first head at or above it
            into = {k: next(h for h in heads if h[1] >= k[1]) for k in keys}
            return sum(count[k] * plan_seconds(into[k]) for k in keys) + DENSE_COMPILE_S * len(set(into.values()))

        best = min(cost([k for k, on in zip(keys, cut) if on] + [keys[-1]])
                   for cut in itertools.product([0, 1], repeat=len(keys) - 1))
        into = merge_plans(sizes)
        heads = sorted(set(into.values()), key=lambda k: k[1])
        assert all(into[k][1] >= k[1] and into[into[k]] == into[k] for k in keys)
        assert cost(heads) == pytest.approx(best, rel=1e-12)


def _box_with_a_long_top_brick():
    """The soft problem of a box of 6 layers of 16 unit bricks with a 1 x 8
    brick on top sticking 6 studs out (the tests hang 0.5 kg on it)."""
    from stablelego_jax.layout import brick_layout

    box = cuboid(4, 4, 6)
    return compile_soft(brick_layout(np.concatenate([box.pos, [[2, 0, 6]]]),
                                     np.concatenate([box.size, [[8, 1]]]))).problem


def test_plan_soft_fits_the_padding_when_the_solves_pay_for_a_compile():
    """One solve: the shape its rung shares (soft_bucket, on the ladder's
    layers and slots); a caller that solves the problem many times gets a
    padding fitted to it (its own layer count, fewer bricks and columns).
    Its loss in the three paddings: the slow test below."""
    from stablelego_jax.solvers.problem import layer_soft, plan_soft, soft_bucket, soft_layer_plan

    p = _box_with_a_long_top_brick()
    L, B = soft_layer_plan(p)
    n, m = p.mass.shape[0], p.col_kind.shape[0]
    ladder, fitted = plan_soft(p), plan_soft(p, calls=10 ** 6)
    assert (L, B) == (7, 16) and ladder.layers.shape == layer_bucket(L, B) == (8, 16)
    shared = soft_bucket(n, m, p.group.shape[1], (8, 16), len(layer_soft(p).chunk))
    assert (ladder.mass.shape[0], ladder.col_kind.shape[0], ladder.group.shape[1], len(ladder.chunk)) == shared
    assert fitted.layers.shape == (7, 16)
    assert fitted.mass.shape[0] == -(-n // 8) * 8 < ladder.mass.shape[0]
    assert fitted.col_kind.shape[0] == -(-m // 64) * 64 < ladder.col_kind.shape[0]
    assert plan_soft(p, calls=2).layers.shape == (8, 16)  # a few solves do not pay for a compile


@pytest.mark.slow
def test_the_fitted_shared_and_ladder_paddings_give_the_same_loss():
    """test_plan_soft_fits_the_padding_when_the_solves_pay_for_a_compile's
    problem in its three paddings (three compiles): the same loss."""
    from stablelego_jax.loss import stability_loss
    from stablelego_jax.solvers.problem import layer_soft, plan_soft

    p = _box_with_a_long_top_brick()
    n = p.mass.shape[0]
    ladder, fitted = plan_soft(p), plan_soft(p, calls=10 ** 6)
    losses = []
    for q in (ladder, fitted, pad_soft(layer_soft(p))):
        w, loads = np.zeros(q.mass.shape[0]), np.zeros(q.mass.shape[0])
        w[:n], loads[n - 1] = 1.0, 0.5
        losses.append(float(stability_loss(w, loads, q)))
    assert losses[0] > 1.0  # the long brick is pulled off: far above the barrier's floor
    np.testing.assert_allclose(losses[1:], losses[0], rtol=1e-7)


@pytest.mark.usefixtures("x64")
def test_small_soft_problems_of_one_brick_rung_share_one_shape():
    """Soft problems of one brick rung but different column and contact-slot
    rungs (a one-layer slab, a stair with a block hung on its tip), and two
    layered towers of one (layers, slots) rung, get one padded shape
    (soft_bucket) where the ladder gives each its own; many solves keep the
    ladder's tighter shape; the loss is the same either way."""
    from stablelego_jax.loss import stability_loss
    from stablelego_jax.solvers.problem import SOFT_SLOTS, layer_soft, plan_soft, soft_bucket

    probs = [compile_soft(cuboid(3, 3, 1)).problem, compile_soft(stairs(10)).problem]
    dims = [(p.mass.shape[0], p.col_kind.shape[0], p.group.shape[1]) for p in probs]
    assert len({bucket_shape(*d) for d in dims}) == 2 and len({soft_bucket(*d) for d in dims}) == 1
    shapes = {(q.mass.shape[0], q.col_kind.shape[0], q.group.shape[1]) for q in map(plan_soft, probs)}
    assert shapes == {soft_bucket(*dims[0])[:3]} and soft_bucket(*dims[0])[2] == SOFT_SLOTS
    # layered: two towers of one (layers, slots) rung, 1720 and 1376 columns on the ladder, one shape
    towers = [plan_soft(compile_soft(cuboid(4, 4, k)).problem) for k in (12, 11)]
    assert {q.layers.shape for q in towers} == {(12, 16)}
    assert len({(q.mass.shape[0], q.col_kind.shape[0], q.group.shape[1], len(q.chunk)) for q in towers}) == 1
    assert len({pad_soft(layer_soft(compile_soft(cuboid(4, 4, k)).problem)).col_kind.shape[0] for k in (12, 11)}) == 2
    # a caller that solves one problem many times does not pay for the shared shape
    many = plan_soft(probs[1], calls=1000)
    assert many.col_kind.shape[0] <= bucket_shape(*dims[1])[1] < soft_bucket(*dims[1])[1]
    p, n = probs[1], dims[1][0]
    losses = []
    for q in (plan_soft(p), pad_soft(p)):
        w, loads = np.zeros(q.mass.shape[0]), np.zeros(q.mass.shape[0])
        w[:n], loads[n - 1] = 1.0, 0.3
        losses.append(float(stability_loss(w, loads, q)))
    assert losses[0] > 1e-3  # the hung block tips the stair: far above the barrier's floor
    np.testing.assert_allclose(losses[0], losses[1], rtol=1e-7)


def test_plan_soft_shared_gives_the_rungs_one_cut_shape():
    """``shared=True`` (training's subsets: shapes that recur over many
    problems, each solved once): the shape the rung shares whatever
    ``calls`` (never a fitted one), and a layered problem always cut, so one
    executable serves the rung; a dense problem stays uncut."""
    from stablelego_jax.layout import brick_layout
    from stablelego_jax.solvers.problem import cut_layers, layer_soft, plan_soft, soft_bucket

    towers = [compile_soft(cuboid(4, 4, k)).problem for k in (12, 11)]
    planned = [plan_soft(t, shared=True) for t in towers]
    assert {q.layers.shape for q in planned} == {(12, 16)}
    assert len({(q.mass.shape[0], q.col_kind.shape[0], q.group.shape[1], len(q.chunk)) for q in planned}) == 1
    assert all(q.cut is not None for q in planned)
    np.testing.assert_array_equal(planned[1].cut, cut_layers(planned[1]).cut)
    assert planned[1].cut.tolist() == [16] * 11 + [0]
    # many solves of one problem fit it (its own 11 layers); shared keeps the rung's shape
    assert plan_soft(towers[1], calls=10 ** 6).layers.shape == (11, 16)
    big = plan_soft(towers[1], calls=10 ** 6, shared=True)
    t = towers[1]
    assert big.layers.shape == (12, 16) and big.col_kind.shape[0] == soft_bucket(
        t.mass.shape[0], t.col_kind.shape[0], t.group.shape[1], (12, 16), len(layer_soft(t).chunk))[1]
    dense = plan_soft(compile_soft(brick_layout([(0, 0, 0), (0, 0, 1)], [(2, 2), (2, 2)])).problem, shared=True)
    assert dense.layers is None and dense.cut is None


def test_plan_soft_cuts_layers_when_many_solves_pay_for_the_branches():
    """A layered problem whose layers are not full (a tower of unit bricks
    narrowing from 6 x 6 to 4 x 4 to 2 x 2, four layers each): many solves
    get each layer's used slots in ``cut`` (its last used slot + 1), one
    solve does not; ``pad_soft`` keeps it, ``stack_soft`` drops it (a batch
    never cuts), ``layer_soft`` clears it, and a dense problem cannot be
    cut."""
    from stablelego_jax.layout import brick_layout
    from stablelego_jax.solvers.blocks import layer_cuts
    from stablelego_jax.solvers.problem import (CUT_BRANCH_S, cut_layers, cut_saving, layer_soft, plan_soft,
                                                stack_soft)

    widths = [6] * 4 + [4] * 4 + [2] * 4
    pos = [(x, y, z) for z, w in enumerate(widths) for x in range(3 - w // 2, 3 + w // 2)
           for y in range(3 - w // 2, 3 + w // 2)]
    p = compile_soft(brick_layout(pos, np.ones((len(pos), 2), np.int64))).problem
    one = plan_soft(p)
    assert one.layers is not None and one.cut is None
    # pays for the branches' compile after this many solves (fitted: the same layers and slots here)
    calls = int(CUT_BRANCH_S * len(layer_cuts(one.layers.shape[1])) / cut_saving(one)) + 1
    many = plan_soft(p, calls=calls)
    L, B = many.layers.shape
    assert (L, B) == one.layers.shape and many.cut.tolist() == [w * w for w in widths]
    assert plan_soft(p, calls=calls // 2).cut is None
    slot = np.asarray(many.slot)
    for l, u in enumerate(many.cut):  # bricks fill each layer's first slots
        used = np.sort(slot[(slot // B == l) & (slot < L * B)] % B)
        assert used.tolist() == list(range(u))
    assert pad_soft(many, many.mass.shape[0] + 8).cut is many.cut
    assert stack_soft([many, many]).cut is None
    assert layer_soft(many).cut is None
    with pytest.raises(ValueError, match="layered"):
        cut_layers(compile_soft(cuboid(2, 2, 1)).problem)


@pytest.mark.slow
@pytest.mark.usefixtures("x64")
def test_padded_scene_positions_give_the_same_position_gradient():
    """pad_positions pads a scene's positions as plan_soft pads its soft
    problem: the loss and its gradient with respect to the blocks' moves are
    the same as unpadded (repair --move's gradient, scenes of one rung
    sharing a compile); padding bodies get no gradient."""
    from stablelego_jax.loss import position_loss
    from stablelego_jax.solvers.problem import pad_positions, plan_soft
    from stablelego_jax.soft import scene_positions, soft_problem

    sc = load_layout(os.path.join(EXAMPLES, "extensions", "stack8_moved.json"))
    prob, geo = soft_problem(sc), scene_positions(sc)
    shared, n = plan_soft(prob), sc.n
    assert shared.col_kind.shape[0] > prob.col_kind.shape[0]
    n_pad = n + 5  # padding bodies too
    q = pad_soft(prob, n_pad, shared.col_kind.shape[0], shared.group.shape[1])
    gq = pad_positions(geo, n_pad, q.col_kind.shape[0])
    assert gq.pair.max() == n_pad and len(gq.pair) == q.col_kind.shape[0]
    w = np.zeros(n_pad)
    w[:n] = 1.0
    loss, g = jax.value_and_grad(lambda d: position_loss(d, w, None, q, gq))(np.zeros((n_pad, 2)))
    loss0, g0 = jax.value_and_grad(lambda d: position_loss(d, np.ones(n), None, prob, geo))(np.zeros((n, 2)))
    assert float(loss0) > 1e-3  # block '8' falls: far above the barrier's floor
    np.testing.assert_allclose(float(loss), float(loss0), rtol=1e-7)
    np.testing.assert_allclose(np.asarray(g)[:n], np.asarray(g0), rtol=1e-5, atol=1e-9 * np.abs(g0).max())
    assert not np.asarray(g)[n:].any()
    with pytest.raises(ValueError, match="cannot pad"):
        pad_positions(geo, n - 1, q.col_kind.shape[0])
