"""Plane geometry of rotated rectangles and convex polygons, batched.

Pure functions on arrays with a leading batch axis ``k``; every shape is
fixed (masks mark the valid entries), and the array module is a parameter
(``xp``: numpy by default; ``jax.numpy`` works too: no in-place writes, no
data-dependent shapes), so the contact geometry can later be traced and
differentiated. Lengths in any one unit (the callers use metres).

* :func:`rect_corners`: the corners of rotated rectangles;
* :func:`separation`: penetration depth of two convex quadrilaterals
  (separating-axis test);
* :func:`convex_intersection`: the overlap polygon of two convex
  quadrilaterals (vertices in counter-clockwise order, area);
* :func:`hull_gauge`: where a point lies in the convex hull of a point set
  (0 at the hull's centroid, 1 on its boundary).
"""
from __future__ import annotations

import numpy as np

__all__ = ["rect_corners", "rect_axes", "separation", "convex_intersection", "polygon_area", "hull_gauge",
           "MAX_OVERLAP_VERTICES"]

#: Candidate vertices of the overlap of two quadrilaterals: 4 + 4 corners and
#: 16 edge crossings (at most 8 are vertices).
MAX_OVERLAP_VERTICES = 24


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def rect_axes(yaw, xp=np):
    """(..., 2, 2) unit axes of rectangles turned by ``yaw`` (radians, about
    +z): row 0 the local x axis, row 1 the local y axis."""
    c, s = xp.cos(yaw), xp.sin(yaw)
    return xp.stack([xp.stack([c, s], -1), xp.stack([-s, c], -1)], -2)


def rect_corners(center, size, yaw, xp=np):
    """(..., 4, 2) corners of rectangles, counter-clockwise from the local
    (-x, -y) corner. center (..., 2), size (..., 2) full extents along the
    local axes, yaw (...) radians about +z."""
    ax = rect_axes(yaw, xp)
    sign = xp.asarray([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    half = 0.5 * xp.asarray(size)[..., None, :] * sign  # (..., 4, 2) local
    return xp.asarray(center)[..., None, :] + half[..., 0:1] * ax[..., None, 0, :] + half[..., 1:2] * ax[..., None, 1, :]


def separation(pa, pb, xp=np):
    """(k,) penetration depth of convex quadrilaterals ``pa``, ``pb`` (k, 4, 2),
    by the separating-axis test over their 8 edge normals: the smallest
    overlap of their projections (> 0: the interiors overlap by that much;
    <= 0: they are apart or only touch)."""
    def normals(p):
        e = xp.roll(p, -1, axis=-2) - p
        n = xp.stack([e[..., 1], -e[..., 0]], -1)
        return n / xp.maximum(xp.linalg.norm(n, axis=-1, keepdims=True), 1e-300)

    axes = xp.concatenate([normals(pa), normals(pb)], axis=-2)  # (k, 8, 2)
    qa = xp.einsum("kvd,kad->kav", pa, axes)
    qb = xp.einsum("kvd,kad->kav", pb, axes)
    overlap = xp.minimum(qa.max(-1), qb.max(-1)) - xp.maximum(qa.min(-1), qb.min(-1))
    return overlap.min(-1)


def polygon_area(pts, valid, xp=np):
    """(k,) area of polygons whose valid vertices (``valid`` (k, K)) come
    first, in counter-clockwise order (shoelace)."""
    cnt = valid.sum(-1)
    idx = xp.arange(pts.shape[-2])
    nxt = xp.where(idx[None, :] + 1 < cnt[:, None], idx[None, :] + 1, 0)
    q = xp.take_along_axis(pts, nxt[..., None], axis=-2)
    return 0.5 * xp.where(valid, _cross(pts, q), 0.0).sum(-1)


def convex_intersection(pa, pb, tol: float = 1e-9, xp=np):
    """Overlap of convex quadrilaterals ``pa``, ``pb`` ((k, 4, 2), counter-clockwise).

    Returns (pts (k, K, 2), valid (k, K) bool, area (k,)) with
    K = MAX_OVERLAP_VERTICES: the polygon's vertices first, counter-clockwise,
    without duplicates (closer than ``tol``) or points inside an edge; an
    empty or degenerate overlap has area <= ``tol`` times its size and may
    keep up to two vertices. The candidates are each polygon's corners inside
    the other and the crossings of their edges; the overlap of two convex
    polygons is their convex hull.
    """
    def inside(p, poly):  # (k, V, 2) points in (k, 4, 2) convex polygon
        e = xp.roll(poly, -1, axis=-2) - poly
        d = p[:, :, None, :] - poly[:, None, :, :]
        ln = xp.linalg.norm(e, axis=-1)[:, None, :]
        return (_cross(e[:, None, :, :], d) >= -tol * ln).all(-1)

    ea = xp.roll(pa, -1, axis=-2) - pa  # (k, 4, 2)
    eb = xp.roll(pb, -1, axis=-2) - pb
    d = ea[:, :, None, :]
    e = eb[:, None, :, :]
    w = pb[:, None, :, :] - pa[:, :, None, :]
    den = _cross(d, e)
    ok = xp.abs(den) > 1e-12 * xp.linalg.norm(d, axis=-1) * xp.linalg.norm(e, axis=-1)
    safe = xp.where(ok, den, 1.0)
    s = _cross(w, e) / safe
    t = _cross(w, d) / safe
    eps_s = tol / xp.maximum(xp.linalg.norm(d, axis=-1), 1e-300)
    eps_t = tol / xp.maximum(xp.linalg.norm(e, axis=-1), 1e-300)
    hit = ok & (s >= -eps_s) & (s <= 1 + eps_s) & (t >= -eps_t) & (t <= 1 + eps_t)
    cross_pts = (pa[:, :, None, :] + s[..., None] * d).reshape(pa.shape[0], 16, 2)
    cand = xp.concatenate([pa, pb, cross_pts], axis=1)  # (k, 24, 2)
    valid = xp.concatenate([inside(pa, pb), inside(pb, pa), hit.reshape(pa.shape[0], 16)], axis=1)
    K = cand.shape[1]
    # drop duplicates: a candidate closer than tol to an earlier valid one
    dist = xp.linalg.norm(cand[:, :, None, :] - cand[:, None, :, :], axis=-1)
    earlier = xp.arange(K)[None, :] < xp.arange(K)[:, None]  # [i, j]: j < i
    dup = ((dist <= tol) & earlier[None] & valid[:, None, :]).any(-1)
    valid = valid & ~dup
    pts, valid = _ccw(cand, valid, xp)
    # drop points inside an edge (collinear with their neighbours)
    cnt = valid.sum(-1)[:, None]
    idx = xp.arange(K)[None, :]
    prev = xp.take_along_axis(pts, xp.where(valid, (idx - 1) % xp.maximum(cnt, 1), 0)[..., None], axis=1)
    nxt = xp.take_along_axis(pts, xp.where(valid, (idx + 1) % xp.maximum(cnt, 1), 0)[..., None], axis=1)
    span = xp.linalg.norm(nxt - prev, axis=-1)
    flat = xp.abs(_cross(nxt - prev, pts - prev)) <= tol * span
    valid = valid & ~(flat & (cnt > 2))
    pts, valid = _ccw(pts, valid, xp)
    return pts, valid, polygon_area(pts, valid, xp)


def _ccw(pts, valid, xp):
    """Valid points first, counter-clockwise about their mean."""
    cnt = xp.maximum(valid.sum(-1, keepdims=True), 1)
    c = xp.where(valid[..., None], pts, 0.0).sum(1) / cnt
    rel = pts - c[:, None, :]
    ang = xp.where(valid, xp.arctan2(rel[..., 1], rel[..., 0]), xp.inf)
    order = xp.argsort(ang, axis=-1)
    return xp.take_along_axis(pts, order[..., None], axis=1), xp.take_along_axis(valid, order, axis=1)


def hull_gauge(pts, valid, p, tol: float = 1e-12, xp=np):
    """Where points ``p`` (k, 2) lie in the convex hulls of point sets ``pts``
    (k, K, 2) (``valid`` (k, K) marks the members).

    Returns (k,) the gauge ``max_e n_e . (p - c) / (h_e - n_e . c)`` over the
    hull's edges e (outward normal n_e, ``n_e . x <= h_e`` inside) about the
    hull's vertex mean c: 0 at c, growing linearly along every ray from c, 1
    on the boundary, > 1 outside. NaN where the hull has no interior (fewer
    than three points not on one line). The hull edges are the pairs of
    members with every member on their left or between them (O(K^3) per row).
    """
    scale = xp.maximum(xp.where(valid[..., None], xp.abs(pts), 0.0).max((1, 2)), 1e-300)
    eps = tol * scale  # (k,)
    a = pts[:, :, None, :]
    b = pts[:, None, :, :]
    e = b - a  # (k, i, j, 2)
    ln = xp.linalg.norm(e, axis=-1)
    rel = pts[:, None, None, :, :] - a[:, :, :, None, :]  # (k, i, j, m, 2)
    cr = _cross(e[:, :, :, None, :], rel)  # (k, i, j, m)
    dot = (e[:, :, :, None, :] * rel).sum(-1)
    on = xp.abs(cr) <= eps[:, None, None, None] * ln[..., None]
    ok_m = ~valid[:, None, None, :] | (cr > eps[:, None, None, None] * ln[..., None]) | (
        on & (dot >= -eps[:, None, None, None] * ln[..., None]) & (dot <= ln[..., None] ** 2 + eps[:, None, None, None] * ln[..., None]))
    # duplicates: only the first copy of a point forms edges
    K = pts.shape[1]
    dist = xp.linalg.norm(pts[:, :, None, :] - pts[:, None, :, :], axis=-1)
    earlier = xp.arange(K)[None, :] < xp.arange(K)[:, None]
    first = valid & ~((dist <= eps[:, None, None]) & earlier[None] & valid[:, None, :]).any(-1)
    edge = first[:, :, None] & first[:, None, :] & (ln > eps[:, None, None]) & ok_m.all(-1)
    vertex = edge.any(2) | edge.any(1)
    cnt = xp.maximum(vertex.sum(-1), 1)
    c = xp.where(vertex[..., None], pts, 0.0).sum(1) / cnt[:, None]
    n = xp.stack([e[..., 1], -e[..., 0]], -1) / xp.maximum(ln, 1e-300)[..., None]  # outward for ccw edges
    h = (n * a).sum(-1)
    nc = (n * c[:, None, None, :]).sum(-1)
    npc = (n * (p - c)[:, None, None, :]).sum(-1)
    depth = h - nc
    solid = edge & (depth > eps[:, None, None])
    g = xp.where(solid, npc / xp.where(solid, depth, 1.0), -xp.inf).max((1, 2))
    has_area = edge.sum((1, 2)) >= 3
    return xp.where(has_area & (edge == solid).all((1, 2)), g, xp.nan)
