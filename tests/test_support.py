"""The support margin of plain blocks: the centre-of-pressure gauge against
the analytic values of block columns, 1 out of equilibrium, NaN for bricks."""
import numpy as np
import pytest

from stablelego_jax.generate.scenes import block_column, harmonic_stack, pallet
from stablelego_jax.model import compile_scene
from stablelego_jax.scene import BLOCK, BRICK, make_scene
from stablelego_jax.solvers.exact import solve_exact
from stablelego_jax.support import support_scores


def _support(scene):
    model = compile_scene(scene)
    return support_scores(scene, model, solve_exact(model).f)


@pytest.mark.parametrize("d", [0.0, 0.03, 0.06, 0.09])
def test_two_blocks_analytic(d):
    # top block offset d: its support is the overlap [d - 0.1, 0.1] (centre d / 2), its centre of mass at d;
    # the bottom block carries both on the ground: centre of pressure d / 2 in [-0.1, 0.1]
    s = _support(block_column([d]))
    assert s[1] == pytest.approx((d - d / 2) / (0.1 - d / 2), abs=1e-9)
    assert s[0] == pytest.approx((d / 2) / 0.1, abs=1e-9)


def test_knife_edge_and_out_of_equilibrium():
    s = _support(harmonic_stack(6, 0.999))
    assert 0.99 < s[-1] < 1.0
    assert (_support(harmonic_stack(6, 1.01)) == 1.0).any()


def test_straddling_box_uses_the_hull_of_both_patches():
    s = _support(pallet(2, 1, 1, gap=0.1, top=(0.0, 0.0, 0.0)))
    assert s[-1] == pytest.approx(0.0, abs=1e-9)  # centre of mass at the middle of the gap
    s = _support(pallet(2, 1, 1, gap=0.1, top=(0.1, 0.0, 0.0)))
    # hull x in [-0.1, 0.3] (vertex mean 0.1 in x as the patches are equal): centre of mass at its middle
    assert s[-1] == pytest.approx(0.0, abs=1e-9)


def test_bricks_get_nan():
    sc = make_scene(["a", "b"], [BLOCK, BRICK], [[0, 0, 0.05], [20, 20, 0]], [[0.1, 0.1, 0.1], [2, 4, 3]], [0, 0],
                    [1.0, 0.00216])
    s = _support(sc)
    assert s[0] == pytest.approx(0.0, abs=1e-9) and np.isnan(s[1])
