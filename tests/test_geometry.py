"""Plane geometry: rotated rectangles, their overlap polygons, penetration
depth and the hull gauge, against independent computations."""
import math

import numpy as np
import pytest

from stablelego_jax.geometry import convex_intersection, hull_gauge, polygon_area, rect_corners, separation


def _clip(subject, clip):
    """Sutherland-Hodgman in plain Python: the independent reference."""
    out = [tuple(p) for p in subject]
    for k in range(len(clip)):
        a, b = clip[k], clip[(k + 1) % len(clip)]
        inp, out = out, []
        if not inp:
            break

        def side(p):
            return (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])

        for i in range(len(inp)):
            p, q = inp[i], inp[(i + 1) % len(inp)]
            sp, sq = side(p), side(q)
            if sp >= 0:
                out.append(p)
            if (sp >= 0) != (sq >= 0):
                t = sp / (sp - sq)
                out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
    if len(out) < 3:
        return 0.0
    return 0.5 * sum(out[i][0] * out[(i + 1) % len(out)][1] - out[(i + 1) % len(out)][0] * out[i][1]
                     for i in range(len(out)))


def test_rect_corners_counter_clockwise_and_rotated():
    c = rect_corners(np.array([[1.0, 2.0]]), np.array([[4.0, 2.0]]), np.array([math.pi / 2]))[0]
    np.testing.assert_allclose(c, [[2, 0], [2, 4], [0, 4], [0, 0]], atol=1e-12)
    assert polygon_area(c[None], np.ones((1, 4), bool))[0] == pytest.approx(8.0)


def test_overlap_area_matches_an_independent_clipper():
    rng = np.random.default_rng(3)
    k = 300
    ca, cb = rng.uniform(-1, 1, (k, 2)), rng.uniform(-1, 1, (k, 2))
    sa, sb = rng.uniform(0.2, 2, (k, 2)), rng.uniform(0.2, 2, (k, 2))
    ya, yb = rng.uniform(-math.pi, math.pi, k), rng.uniform(-math.pi, math.pi, k)
    yb[:50] = ya[:50]  # parallel edges
    yb[50:80] = ya[50:80] + math.pi / 4
    pa, pb = rect_corners(ca, sa, ya), rect_corners(cb, sb, yb)
    pts, valid, area = convex_intersection(pa, pb)
    ref = np.array([_clip(pa[i], pb[i]) for i in range(k)])
    np.testing.assert_allclose(area, ref, atol=1e-9)
    assert (valid.sum(1) <= 8).all()
    # every vertex lies in both rectangles
    for i in np.nonzero(area > 1e-6)[0][:50]:
        for p in pts[i][valid[i]]:
            for poly in (pa[i], pb[i]):
                e = np.roll(poly, -1, 0) - poly
                assert ((e[:, 0] * (p[1] - poly[:, 1]) - e[:, 1] * (p[0] - poly[:, 0])) >= -1e-9).all()


def test_overlap_of_a_square_and_its_45_degree_turn_is_an_octagon():
    a = rect_corners(np.zeros((1, 2)), np.full((1, 2), 2.0), np.zeros(1))
    b = rect_corners(np.zeros((1, 2)), np.full((1, 2), 2.0), np.full(1, math.pi / 4))
    pts, valid, area = convex_intersection(a, b)
    assert valid.sum() == 8
    assert area[0] == pytest.approx(8 * (math.sqrt(2) - 1))


def test_touching_and_disjoint_rectangles_have_no_area():
    a = rect_corners(np.zeros((2, 2)), np.ones((2, 2)), np.zeros(2))
    b = rect_corners(np.array([[1.0, 0.3], [3.0, 0.0]]), np.ones((2, 2)), np.zeros(2))
    _, _, area = convex_intersection(a, b)
    assert np.all(np.abs(area) < 1e-12)
    np.testing.assert_allclose(separation(a, b), [0.0, -2.0], atol=1e-12)
    c = rect_corners(np.array([[0.5, 0.0]]), np.ones((1, 2)), np.zeros(1))
    assert separation(a[:1], c)[0] == pytest.approx(0.5)


def test_hull_gauge():
    sq = np.array([[[0, 0], [2, 0], [2, 2], [0, 2], [1, 0], [2, 2], [0, 0], [9, 9]]], float)
    valid = np.array([[True] * 7 + [False]])  # a point on an edge, two duplicates, one padding entry
    p = np.array([[1.0, 1.0], [2.0, 1.0], [1.5, 1.0], [3.0, 1.0]])
    g = hull_gauge(np.repeat(sq, 4, 0), np.repeat(valid, 4, 0), p)
    np.testing.assert_allclose(g, [0.0, 1.0, 0.5, 2.0], atol=1e-12)
    line = np.array([[[0, 0], [1, 0], [2, 0]]], float)
    assert np.isnan(hull_gauge(line, np.ones((1, 3), bool), np.array([[1.0, 0.0]]))[0])


def test_jax_numpy_gives_the_same_answers(x64):
    """Traced with jax.numpy (jit: fixed shapes, no in-place writes): the same numbers."""
    import jax
    import jax.numpy as jnp

    rng = np.random.default_rng(0)
    pa = rect_corners(rng.uniform(-1, 1, (20, 2)), rng.uniform(0.5, 2, (20, 2)), rng.uniform(-3, 3, 20))
    pb = rect_corners(rng.uniform(-1, 1, (20, 2)), rng.uniform(0.5, 2, (20, 2)), rng.uniform(-3, 3, 20))
    q = rng.uniform(-0.5, 0.5, (20, 2))

    @jax.jit
    def both(pa, pb, q):
        pts, valid, area = convex_intersection(pa, pb, xp=jnp)
        return valid, area, hull_gauge(pts, valid, q, xp=jnp)

    pts, valid, area = convex_intersection(pa, pb)
    valid_j, area_j, gauge_j = both(pa, pb, q)
    np.testing.assert_allclose(np.asarray(area_j), area, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(valid_j), valid)
    np.testing.assert_allclose(np.asarray(gauge_j), hull_gauge(pts, valid, q), atol=1e-12)

