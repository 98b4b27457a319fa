"""Contacts from geometry: where bodies of a scene touch, and the Lego knob rule.

:func:`scene_contacts` finds every contact of a :class:`~stablelego_jax.scene.Scene`
(vectorised numpy; no loops over bodies) and returns it as points with
directions, in three groups that :func:`~stablelego_jax.model.compile_scene`
turns into force-model columns:

* ``lego``: contact points of Lego knob connections (SPEC: support S and
  drag D, one free ``NORMAL`` column each), where a part's bottom meets the
  top of a part below (or the baseplate) and their stud centres coincide
  within ``STUD_TOL`` studs. The points are fixed by the upper part
  (:func:`four_point_knobs`) and turned with its yaw.
* ``knob``: the knob centres of those connections (two free ``KNOB``
  presses each, along x and y).
* ``push``: non-negative contact forces of plain (non-Lego) contacts and of
  Lego side faces, one ``SIDE`` column per point and direction. Two faces
  touch when their planes coincide within ``PLANE_TOL_M`` and their overlap
  has positive area (wider than ``WIDTH_TOL_M``): the overlap polygon of
  two footprints (a bottom on a top or on the ground) or the overlap
  rectangle of two side faces; each vertex carries a normal force, and with
  a friction coefficient mu > 0 the force at a vertex is a non-negative
  combination of the edges ``n + mu t`` of the linearised Coulomb cone (four
  tangents t: an inscribed pyramid), so every column has normal component 1.
  Two Lego parts side by side press as in the grid model: one point per
  stud of the shared face, at mid-height, frictionless.

Units: metres (positions, points), unit directions.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .geometry import convex_intersection, rect_axes, rect_corners
from .scene import BLOCK, BRICK, PLATE_M, STUD_M, Scene, boxes, candidate_pairs, footprint_bounds

__all__ = ["PTS_4", "PTS_3", "STUD_TOL", "PLANE_TOL_M", "WIDTH_TOL_M", "Contacts", "four_point_knobs",
           "stud_centres", "scene_contacts", "contact_levels"]

#: Contact-point offsets (studs) from the knob centre, in the upper part's
#: frame: four points (1xN parts, inner knobs of parts 3 or more studs wide)
#: and three points (2xN parts, edge knobs of wider parts). SPEC / paper Sec. III.A.
PTS_4 = np.array([[0.0, -0.25], [-0.25, 0.0], [0.0, 0.25], [0.25, 0.0]])
PTS_3 = np.array([[0.125, -0.125], [-0.25, 0.0], [0.125, 0.125]])
#: Stud centres coincide when closer than this (studs).
STUD_TOL = 1e-6
#: Two faces are in one plane when closer than this (m).
PLANE_TOL_M = 1e-6
#: A contact region must be wider than this (m): a shared edge or corner is no contact.
WIDTH_TOL_M = 1e-9


def four_point_knobs(studs, cell) -> np.ndarray:
    """(k,) bool: the knob connection takes the four points PTS_4 (else the
    three PTS_3). studs (k, 2): the upper part's studs along its x and y;
    cell (k, 2): the knob's cell in the upper part (0 .. studs-1). A 1xN
    part: four; 2xN: three; Q x X with Q >= 3: three on the edge, four
    inside (paper Sec. III.A)."""
    studs = np.asarray(studs)
    cell = np.asarray(cell)
    q = studs.min(axis=1)
    inner = (cell > 0).all(axis=1) & (cell < studs - 1).all(axis=1)
    return (q < 2) | ((q >= 3) & inner)


def stud_centres(scene: Scene):
    """Every stud of every brick: (owner (s,), cell (s, 2) in the part,
    centre (s, 2) in studs, world frame)."""
    brick = np.nonzero(scene.kind == BRICK)[0]
    studs = scene.size[brick, :2].astype(np.int64)
    area = studs[:, 0] * studs[:, 1]
    owner = np.repeat(brick, area)
    start = np.cumsum(area) - area
    local = np.arange(int(area.sum())) - np.repeat(start, area)
    sy = np.repeat(studs[:, 1], area)
    cell = np.stack([local // sy, local % sy], 1)
    off = cell + 0.5 - scene.size[owner, :2] / 2  # studs, part frame
    ax = rect_axes(np.radians(scene.yaw[owner]))
    centre = scene.pos[owner, :2] + off[:, :1] * ax[:, 0] + off[:, 1:] * ax[:, 1]
    return owner, cell, centre


class Contacts(NamedTuple):
    """The contacts of a scene (metres). Slot 0 of a pair is the body the
    force pushes (the upper body; for side faces the body pushed along the
    direction), slot 1 the other one, ``n`` for the ground / baseplate.

    lego_pair (a, 2), lego_point (a, 3): Lego contact points (support +z on slot 0).
    knob_pair (b, 2), knob_point (b, 3): knob centres (presses along x and y).
    push_pair (c, 2), push_point (c, 3), push_dir (c, 3): plain and side
    contact forces >= 0 (direction on slot 0; normal component 1);
    push_bottom (c,): the point lies on slot 0's bottom face.
    """

    lego_pair: np.ndarray
    lego_point: np.ndarray
    knob_pair: np.ndarray
    knob_point: np.ndarray
    push_pair: np.ndarray
    push_point: np.ndarray
    push_dir: np.ndarray
    push_bottom: np.ndarray


def _cone(normal, t1, t2, mu: float):
    """Edges of the linearised friction cone at each contact: (k, e, 3),
    e = 1 (mu = 0: the normal) or 4 (normal + mu * (+-t1, +-t2))."""
    if mu == 0:
        return normal[:, None, :]
    return np.stack([normal + mu * t1, normal - mu * t1, normal + mu * t2, normal - mu * t2], 1)


def scene_contacts(scene: Scene, stud: float = STUD_M, plate: float = PLATE_M) -> Contacts:
    """All contacts of ``scene`` with studs of ``stud`` m and plate heights of
    ``plate`` m (see the module doc for the rules)."""
    n = scene.n
    centre, size, yaw = boxes(scene, stud, plate)
    bot = centre[:, 2] - size[:, 2] / 2
    top = centre[:, 2] + size[:, 2] / 2
    brick = scene.kind == BRICK
    mu = scene.friction
    lo, hi = footprint_bounds(centre, size, yaw)
    pairs = candidate_pairs(lo, hi, PLANE_TOL_M)
    corners = rect_corners(centre[:, :2], size[:, :2], yaw)
    ez = np.array([0.0, 0.0, 1.0])
    ex, ey = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])

    push = {"pair": [], "point": [], "dir": [], "bottom": []}

    def add_push(pair, point, normal, t1, t2, bottom, friction):
        cone = _cone(normal, t1, t2, friction)  # (k, e, 3)
        e = cone.shape[1]
        push["pair"].append(np.repeat(pair, e, axis=0))
        push["point"].append(np.repeat(point, e, axis=0))
        push["dir"].append(cone.reshape(-1, 3))
        push["bottom"].append(np.full(len(pair) * e, bottom))

    # ---- bottoms on tops (plain contacts): overlap polygons of the footprints
    i, j = pairs[:, 0], pairs[:, 1]
    up = np.where(np.abs(bot[i] - top[j]) <= PLANE_TOL_M, i, np.where(np.abs(bot[j] - top[i]) <= PLANE_TOL_M, j, -1))
    lo_b = np.where(up == i, j, i)
    stack = (up >= 0)
    plain = stack & ~(brick[i] & brick[j])
    u, l = up[plain], lo_b[plain]
    pts, valid, area = convex_intersection(corners[u], corners[l])
    diam = np.linalg.norm(pts[:, :, None, :] - pts[:, None, :, :], axis=-1)
    diam = np.where(valid[:, :, None] & valid[:, None, :], diam, 0.0).max((1, 2))
    ok = area > WIDTH_TOL_M * diam
    u, l, pts, valid = u[ok], l[ok], pts[ok], valid[ok]
    cnt = valid.sum(1)
    vu, vl = np.repeat(u, cnt), np.repeat(l, cnt)
    vxy = pts[valid]
    vz = bot[vu]
    k = len(vu)
    add_push(np.stack([vu, vl], 1), np.column_stack([vxy, vz]), np.tile(ez, (k, 1)), np.tile(ex, (k, 1)),
             np.tile(ey, (k, 1)), True, mu)
    # blocks on the ground: their footprint corners
    g = np.nonzero((scene.kind == BLOCK) & (np.abs(bot) <= PLANE_TOL_M))[0]
    k = 4 * len(g)
    add_push(np.stack([np.repeat(g, 4), np.full(k, n)], 1),
             np.column_stack([corners[g].reshape(-1, 2), np.repeat(bot[g], 4)]),
             np.tile(ez, (k, 1)), np.tile(ex, (k, 1)), np.tile(ey, (k, 1)), True, mu)

    # ---- Lego knob connections: coinciding stud centres, and the baseplate
    owner, cell, sc = stud_centres(scene)
    lego_pair, knob_xy, knob_cell, knob_up = _knob_matches(scene, owner, cell, sc, n)
    kz = bot[knob_up]
    four = four_point_knobs(scene.size[knob_up, :2].astype(np.int64), knob_cell)
    ax = rect_axes(yaw[knob_up])
    lp, lq = [], []
    for sel, offs in ((four, PTS_4), (~four, PTS_3)):
        if not sel.any():
            continue
        o = offs[None, :, 0:1] * ax[sel][:, None, 0, :] + offs[None, :, 1:2] * ax[sel][:, None, 1, :]  # (k, p, 2)
        xy = knob_xy[sel][:, None, :] + o
        p = len(offs)
        lq.append(np.column_stack([(xy * stud).reshape(-1, 2), np.repeat(kz[sel], p)]))
        lp.append(np.repeat(lego_pair[sel], p, axis=0))
    knob_point = np.column_stack([knob_xy * stud, kz])

    # ---- side faces
    _side_contacts(scene, pairs, centre, size, yaw, bot, top, brick, stud, add_push)

    def cat(parts, shape, dtype=np.float64):
        return np.concatenate(parts).astype(dtype) if parts else np.zeros(shape, dtype)

    return Contacts(
        lego_pair=cat(lp, (0, 2), np.int64), lego_point=cat(lq, (0, 3)),
        knob_pair=lego_pair.astype(np.int64), knob_point=knob_point,
        push_pair=cat(push["pair"], (0, 2), np.int64), push_point=cat(push["point"], (0, 3)),
        push_dir=cat(push["dir"], (0, 3)), push_bottom=cat(push["bottom"], (0,), bool),
    )


def _knob_matches(scene: Scene, owner, cell, sc, n: int):
    """Knob connections: (pair (k, 2) [upper, lower or n], knob centre
    (k, 2) studs, cell of the knob in the upper part (k, 2), upper (k,))."""
    from scipy.spatial import cKDTree

    level = scene.pos[owner, 2]
    toplev = level + scene.size[owner, 2]
    ups, los = [], []
    if len(owner):
        cav = np.column_stack([sc, level])  # cavities of each part, at its bottom level
        tip = np.column_stack([sc, toplev])  # studs of each part, at its top level
        m = cKDTree(cav).sparse_distance_matrix(cKDTree(tip), STUD_TOL, output_type="ndarray")
        ups.append(m["i"].astype(np.int64))
        los.append(owner[m["j"]])
        # the baseplate: studs at half-integer coordinates under parts at level 0
        frac = sc - np.floor(sc)
        on = (level == 0) & (np.abs(frac - 0.5) <= STUD_TOL).all(1)
        ups.append(np.nonzero(on)[0])
        los.append(np.full(int(on.sum()), n))
    s_up = np.concatenate(ups) if ups else np.zeros(0, np.int64)
    lower = np.concatenate(los) if los else np.zeros(0, np.int64)
    order = np.lexsort((lower, s_up))  # by cavity, so connections come in stud order
    s_up, lower = s_up[order], lower[order]
    return np.stack([owner[s_up], lower], 1), sc[s_up], cell[s_up], owner[s_up]


def _side_contacts(scene, pairs, centre, size, yaw, bot, top, brick, stud, add_push):
    """Contacts of coplanar side faces with opposite normals (see the module doc)."""
    if not len(pairs):
        return
    i, j = pairs[:, 0], pairs[:, 1]
    z0 = np.maximum(bot[i], bot[j])
    z1 = np.minimum(top[i], top[j])
    keep = z1 - z0 > WIDTH_TOL_M
    i, j, z0, z1 = i[keep], j[keep], z0[keep], z1[keep]
    if not len(i):
        return

    def faces(b):  # outward normals (p, 4, 2), face centres (p, 4, 2), half-lengths (p, 4)
        ax = rect_axes(yaw[b])  # (p, 2, 2)
        sgn = np.array([1.0, -1.0, 1.0, -1.0])
        which = np.array([0, 0, 1, 1])
        nrm = ax[:, which, :] * sgn[None, :, None]
        half_n = 0.5 * size[b][:, which]
        half_t = 0.5 * size[b][:, 1 - which]
        return nrm, centre[b][:, None, :2] + nrm * half_n[..., None], half_t

    ni, ci, hi_ = faces(i)
    nj, cj, hj = faces(j)
    dot = (ni[:, :, None, :] * nj[:, None, :, :]).sum(-1)  # (p, 4, 4)
    gap = ((cj[:, None, :, :] - ci[:, :, None, :]) * ni[:, :, None, :]).sum(-1)
    t = np.stack([-ni[..., 1], ni[..., 0]], -1)  # (p, 4, 2) tangent of i's faces
    si = (ci * t).sum(-1)  # (p, 4)
    sj = (cj[:, None, :, :] * t[:, :, None, :]).sum(-1)  # (p, 4, 4)
    s0 = np.maximum(si[:, :, None] - hi_[:, :, None], sj - hj[:, None, :])
    s1 = np.minimum(si[:, :, None] + hi_[:, :, None], sj + hj[:, None, :])
    hit = (dot < -1 + 1e-9) & (np.abs(gap) <= PLANE_TOL_M) & (s1 - s0 > WIDTH_TOL_M)
    p, fa, fb = np.nonzero(hit)
    if not len(p):
        return
    a, b = i[p], j[p]
    nrm2 = ni[p, fa]  # outward from a: pushes b along it
    tan2 = t[p, fa]
    base = ci[p, fa] - si[p, fa][:, None] * tan2  # point on a's face plane at tangent coordinate 0
    s0, s1 = s0[p, fa, fb], s1[p, fa, fb]
    za, zb = z0[p], z1[p]
    nrm = np.column_stack([nrm2, np.zeros(len(p))])
    tan = np.column_stack([tan2, np.zeros(len(p))])
    lego = brick[a] & brick[b]
    # Lego parts: one point per stud of the shared face, mid-height, frictionless
    if lego.any():
        q = np.nonzero(lego)[0]
        pieces = np.maximum(np.round((s1[q] - s0[q]) / stud).astype(np.int64), 1)
        r = np.repeat(q, pieces)
        k = np.arange(int(pieces.sum())) - np.repeat(np.cumsum(pieces) - pieces, pieces)
        s = s0[r] + (k + 0.5) * (s1[r] - s0[r]) / np.repeat(pieces, pieces)
        pt = np.column_stack([base[r] + s[:, None] * tan2[r], 0.5 * (za[r] + zb[r])])
        add_push(np.stack([b[r], a[r]], 1), pt, nrm[r], tan[r], np.tile([0.0, 0.0, 1.0], (len(r), 1)), False, 0.0)
    # plain faces: the four corners of the overlap rectangle
    q = np.nonzero(~lego)[0]
    if len(q):
        sc = np.stack([s0[q], s1[q], s1[q], s0[q]], 1)
        zc = np.stack([za[q], za[q], zb[q], zb[q]], 1)
        xy = base[q][:, None, :] + sc[..., None] * tan2[q][:, None, :]
        pt = np.column_stack([xy.reshape(-1, 2), zc.reshape(-1)])
        r = np.repeat(q, 4)
        add_push(np.stack([b[r], a[r]], 1), pt, nrm[r], tan[r], np.tile([0.0, 0.0, 1.0], (len(r), 1)), False,
                 scene.friction)


def contact_levels(pairs: np.ndarray, ground: np.ndarray, bottom: np.ndarray, n: int) -> np.ndarray:
    """(n,) int32 level of each body in the contact graph: its distance
    (in contacts) from the ground, counted from the bodies that touch the
    ground (level 0); a group of bodies not connected to the ground counts
    from its lowest body (smallest ``bottom``). Every contact joins bodies
    of one level or of adjacent levels (breadth-first distances), which is
    what the layered factorisation of the interior-point solver needs.
    pairs (c, 2): body pairs of the contacts (``n`` = ground); ground (n,)
    bool: the body touches the ground."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components, dijkstra

    real = (pairs < n).all(1) & (pairs[:, 0] != pairs[:, 1])
    a, b = pairs[real, 0], pairs[real, 1]
    adj = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)).tocsr()
    _, comp = connected_components(adj, directed=False)
    seeds = ground.copy()
    grounded = np.zeros(comp.max() + 1, bool)
    grounded[comp[ground]] = True
    free = ~grounded[comp]
    if free.any():  # lowest body of every component without ground contact
        idx = np.nonzero(free)[0]
        order = idx[np.lexsort((bottom[idx], comp[idx]))]
        first = np.ones(len(order), bool)
        first[1:] = comp[order][1:] != comp[order][:-1]
        seeds[order[first]] = True
    # multi-source breadth-first search: a virtual source joined to every seed
    s = np.nonzero(seeds)[0]
    big = sp.coo_matrix((np.ones(len(a) + len(s)), (np.concatenate([a, np.full(len(s), n)]), np.concatenate([b, s]))),
                        shape=(n + 1, n + 1)).tocsr()
    dist = dijkstra(big, directed=False, unweighted=True, indices=n)
    return (dist[:n] - 1).astype(np.int32)
