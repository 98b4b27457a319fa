import numpy as np
import pytest

from stablelego_jax import make_layout
from stablelego_jax.model import KNOB, NORMAL, SIDE, Params, compile_layout


def _lay(bricks):
    pos = [b[:3] for b in bricks]
    size = [b[3:5] for b in bricks]
    return make_layout([str(i + 1) for i in range(len(bricks))], pos, size, [0.00216] * len(bricks))


def test_column_counts_single_2x4_on_baseplate():
    m = compile_layout(_lay([(0, 0, 0, 2, 4)]))
    kinds = np.bincount(m.col_kind, minlength=3)
    assert kinds[NORMAL] == 8 * 3  # 2xN upper brick: 3 points per knob
    assert kinds[KNOB] == 8 * 2
    assert kinds[SIDE] == 0
    assert (m.col_brick[:, 1] == m.n).all()  # all on the baseplate


def test_1xn_upper_brick_has_four_points_and_side_contacts():
    m = compile_layout(_lay([(0, 0, 0, 1, 4), (1, 0, 0, 1, 4), (0, 0, 1, 1, 2)]))
    normal_top = (m.col_kind == NORMAL) & (m.col_brick[:, 0] == 2)
    assert normal_top.sum() == 2 * 4
    assert ((m.col_kind == SIDE)).sum() == 4  # four cell faces shared along x


def test_internal_columns_are_equal_and_opposite():
    lay = _lay([(0, 0, 0, 2, 4), (1, 2, 1, 2, 4), (0, 6, 1, 2, 2), (3, 0, 0, 1, 4)])
    p = Params()
    m = compile_layout(lay, p)
    centre = np.stack([(lay.pos[:, 0] + lay.size[:, 0] / 2) * p.stud,
                       (lay.pos[:, 1] + lay.size[:, 1] / 2) * p.stud,
                       (lay.pos[:, 2] + 0.5) * p.layer], 1)
    both = m.col_brick[:, 1] < m.n
    assert both.any()
    for j in np.nonzero(both)[0]:
        w0, w1 = m.col_coef[j]
        b0, b1 = m.col_brick[j]
        # forces cancel; moments about the world origin cancel too
        np.testing.assert_allclose(w0[:3] + w1[:3], 0, atol=1e-15)
        tot = w0[3:] + np.cross(centre[b0], w0[:3]) + w1[3:] + np.cross(centre[b1], w1[:3])
        np.testing.assert_allclose(tot, 0, atol=1e-15)


def test_gravity_and_group_table():
    lay = _lay([(0, 0, 0, 2, 4), (0, 0, 1, 2, 4)])
    m = compile_layout(lay)
    np.testing.assert_allclose(m.gravity[:, 2], -0.00216 * 9.8)
    for b in range(m.n):
        cols = m.group[b][m.group[b] < m.m]
        assert (m.col_kind[cols] == NORMAL).all() and (m.col_brick[cols, 0] == b).all()
        assert len(cols) == 24


def test_dense_A_matches_columns_and_padding_is_inert():
    lay = _lay([(0, 0, 0, 2, 4), (1, 1, 1, 2, 2)])
    m = compile_layout(lay)
    A = m.dense_A()
    assert A.shape == (12, m.m)
    pm = m.pad(8, 256, 40)
    np.testing.assert_array_equal(pm.dense_A(), A)
    assert pm.col_mask.sum() == m.m and pm.brick_mask.sum() == 2


def test_compile_1000_bricks_is_vectorised():
    from stablelego_jax.generate.procedural import cuboid

    m = compile_layout(cuboid(10, 10, 10))
    assert m.n == 1000 and m.m == 1000 * (4 + 2) + 2 * 10 * 9 * 10


def test_pack_models_is_block_diagonal_and_keeps_each_models_columns():
    from stablelego_jax.generate.procedural import stairs, tower
    from stablelego_jax.model import pack_models

    models = [compile_layout(stairs(3)), compile_layout(tower(2)), compile_layout(stairs(2))]
    pack, cols = pack_models(models)
    assert (pack.n, pack.m) == (sum(m.n for m in models), sum(m.m for m in models))
    assert list(cols) == list(np.cumsum([0] + [m.m for m in models]))
    A = pack.dense_A()
    r = 0
    for j, m in enumerate(models):
        block = A[6 * r: 6 * (r + m.n), cols[j]: cols[j + 1]]
        np.testing.assert_array_equal(block, m.dense_A())
        assert not A[6 * r: 6 * (r + m.n)].any(axis=0)[np.r_[:cols[j], cols[j + 1]:pack.m]].any()
        np.testing.assert_array_equal(pack.gravity[r: r + m.n], m.gravity)
        # each brick's bottom columns are its model's, moved by the model's column offset
        g = pack.group[r: r + m.n, : m.group.shape[1]]
        np.testing.assert_array_equal(g, np.where(m.group >= m.m, pack.m, m.group + cols[j]))
        r += m.n
    assert (pack.col_brick[pack.col_brick >= pack.n] == pack.n).all()  # the ground
    assert list(pack.member) == [j for j, m in enumerate(models) for _ in range(m.n)]
    assert list(pack.pad(pack.n + 3, pack.m).member) == list(pack.member) + [0, 0, 0]
    with pytest.raises(ValueError, match="unpadded"):
        pack_models([models[0].pad(8, 128)])
    with pytest.raises(ValueError, match="not packs"):
        pack_models([pack, models[0]])
