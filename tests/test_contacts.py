

def _canon(m):
    """Columns as sorted rows (kind, bodies, wrench), a side press written
    with its +direction on slot 0 (either way round is the same column)."""
    cb, co = m.col_brick[: m.m].copy(), m.col_coef[: m.m].copy()
    flip = (co[:, 0, :3].sum(1) < 0) & (m.col_kind[: m.m] == 2)
    cb[flip], co[flip] = cb[flip][:, ::-1], co[flip][:, ::-1]
    key = np.concatenate([m.col_kind[: m.m, None], cb, np.round(co.reshape(m.m, -1), 12)], 1).astype(float)
    return key[np.lexsort(key.T[::-1])]


@pytest.mark.parametrize("name", ["stablelego/stair_20.json", "stablelego/stick_heavy_good.json", "brickgpt/car.txt"])
def test_scene_compiler_rebuilds_the_grid_model(name):
    import os

    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.model import compile_layout
    from stablelego_jax.scene import scene_from_layout

    lay = load_layout(os.path.join(os.path.dirname(__file__), "..", "examples", name))
    a, b = _canon(compile_layout(lay)), _canon(compile_scene(scene_from_layout(lay)))
    assert a.shape == b.shape and np.abs(a - b).max() == 0.0


def test_wide_bricks_on_the_grid_take_the_edge_and_inner_rule():
    from stablelego_jax.layout import make_layout
    from stablelego_jax.model import NORMAL, compile_layout

    lay = make_layout(["a", "b"], [[0, 0, 0], [0, 0, 1]], [[4, 4], [3, 3]], [0.01, 0.005])
    m = compile_layout(lay)
    per_brick = np.bincount(m.col_brick[m.col_kind == NORMAL, 0], minlength=2)
    assert per_brick.tolist() == [12 * 3 + 4 * 4, 8 * 3 + 1 * 4]
