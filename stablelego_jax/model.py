"""Force model compiler: Layout -> fixed-shape arrays (paper Sec. III).

Each *column* is one scalar force variable acting on at most two bricks
(slot 0: the upper / +side brick, slot 1: the lower / -side brick, or the
baseplate sink). Three kinds:

* ``NORMAL``: one contact point of a knob connection, ``n = S - D`` (free);
  pushes slot 0 up (+z) and slot 1 down at the interface plane. Its drag is
  ``D = max(-n, 0)``, loading the upper brick (its ``group``).
  Merging the S/D pair into one free variable is exact for the LP because
  only ``S - D`` enters equilibrium and D has positive cost (so S*D = 0).
* ``KNOB``: knob press along x or y at the knob centre on the interface plane
  (the +/- pair merged into one free variable).
* ``SIDE``: press H >= 0 between side-by-side cells, +x (or +y) on slot 0,
  applied at the centre of the shared face.

Equilibrium of brick b is ``(A f + g)[b] = 0`` with 6 rows per brick:
force x, y, z (N) and torque about x, y, z at the brick centre (N m).
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from .contacts import PTS_3, PTS_4, contact_levels, four_point_knobs, scene_contacts
from .layout import Layout, cell_owner, cells_of
from .scene import BLOCK, Scene, boxes

__all__ = ["Params", "ForceModel", "compile_layout", "compile_scene", "scene_columns", "shifted", "point_jacobian",
           "column_wrenches", "normal_groups", "pack_models",
           "NORMAL", "KNOB", "SIDE"]

NORMAL, KNOB, SIDE = 0, 1, 2


@dataclasses.dataclass(frozen=True)
class Params:
    """Physical and scoring parameters (SPEC defaults, SI units).

    stud: stud pitch (m); layer: layer height (m); g: gravity (m/s^2);
    T: friction capacity per contact point (N); alpha, beta: Eq. 9 weights;
    eq_tol: residual tolerance (N) below which a brick is in equilibrium
    (torques are compared against ``eq_tol * stud`` N m); drag_rtol: a
    largest drag within ``drag_rtol * T`` of T counts as reaching T (a drag
    exactly at capacity, as in knife-edge levers, comes out of any solver a
    few ulps to either side of T); ridge: weight of the term
    ``ridge / (2 W) |f|^2`` (W: total weight, N) that the JAX solver adds to
    Eq. 9's cost so that it returns the canonical force distribution, the
    least-norm optimum, which the exact solvers compute in two stages (see
    ``solvers/exact.py``), so that every score is unique; 0: the plain LP
    (every solver returns an optimum of its own).
    """

    stud: float = 0.0078
    layer: float = 0.0096
    g: float = 9.8
    T: float = 0.98
    alpha: float = 1e-3
    beta: float = 1e-6
    eq_tol: float = 1e-4
    drag_rtol: float = 1e-6
    ridge: float = 1e-8


@dataclasses.dataclass(frozen=True)
class ForceModel:
    """Compiled force model of one layout (numpy arrays; padded if asked).

    n: bricks (rows 0..n-1 real); n_pad >= n; m: real columns; m_pad >= m.
    col_brick: (m_pad, 2) int32 brick of each slot; ``n_pad`` = none/baseplate.
    col_coef: (m_pad, 2, 6) wrench on each slot per unit force (N, N m).
    col_kind: (m_pad,) int8 NORMAL/KNOB/SIDE; padding columns are KNOB with
      zero coefficients (free, cost-free, inert).
    col_mask: (m_pad,) bool real columns.
    group: (n_pad, P) int32 NORMAL columns on each brick's bottom, ``m_pad``
      where empty (for the per-brick max drag).
    gravity: (n_pad, 6) constant wrench (weight) on each brick.
    brick_mask: (n_pad,) bool real bricks.
    layer: (n_pad,) int32 layer (z) of each brick, -1 for padding; every
      column joins bricks of one layer (side presses) or of adjacent layers
      (knob connections), which the interior-point solver's block-tridiagonal
      factorisation uses. None for models built by hand.
    centre: (n_pad, 3) float64 centre of each brick (m), zeros for padding;
      the solver plans may number bricks by slabs along x or y instead of
      by layer (:func:`~stablelego_jax.solvers.problem.slab_levels`). None
      for models built by hand.
    member: (n_pad,) int32 which layout of a pack (:func:`pack_models`) each
      brick belongs to (0 for padding); None for one layout. Each layout's
      canonical term is normalised by its own weight.
    """

    n: int
    m: int
    col_brick: np.ndarray
    col_coef: np.ndarray
    col_kind: np.ndarray
    col_mask: np.ndarray
    group: np.ndarray
    gravity: np.ndarray
    brick_mask: np.ndarray
    params: Params
    layer: np.ndarray | None = None
    centre: np.ndarray | None = None
    member: np.ndarray | None = None

    @property
    def n_pad(self) -> int:
        return self.gravity.shape[0]

    @property
    def m_pad(self) -> int:
        return self.col_kind.shape[0]

    def dense_A(self) -> np.ndarray:
        """(6 n, m) dense equilibrium matrix of the real rows and columns."""
        A = np.zeros((self.n_pad + 1, 6, self.m_pad))
        cols = np.arange(self.m_pad)
        for s in range(2):
            np.add.at(A, (self.col_brick[:, s], slice(None), cols), self.col_coef[:, s, :])
        return A[: self.n].reshape(6 * self.n, self.m_pad)[:, : self.m]

    def pad(self, n_pad: int, m_pad: int, p_pad: int | None = None) -> "ForceModel":
        """Pad to (n_pad bricks, m_pad columns, p_pad points per group)."""
        if n_pad < self.n or m_pad < self.m:
            raise ValueError(f"cannot pad ({self.n}, {self.m}) to ({n_pad}, {m_pad})")
        P = self.group.shape[1] if p_pad is None else p_pad
        if P < self.group.shape[1]:
            raise ValueError(f"cannot pad group width {self.group.shape[1]} to {P}")
        dm = m_pad - self.m_pad
        cb = np.where(self.col_brick >= self.n_pad, n_pad, self.col_brick)
        cb = np.concatenate([cb, np.full((dm, 2), n_pad, np.int32)])
        coef = np.concatenate([self.col_coef, np.zeros((dm, 2, 6))])
        kind = np.concatenate([self.col_kind, np.full(dm, KNOB, np.int8)])
        mask = np.concatenate([self.col_mask, np.zeros(dm, bool)])
        grp = np.full((n_pad, P), m_pad, np.int32)
        old = self.group
        grp[: old.shape[0], : old.shape[1]] = np.where(old >= self.m_pad, m_pad, old)
        return dataclasses.replace(
            self.bricks_moved(n_pad, np.arange(self.n_pad)), col_brick=cb.astype(np.int32), col_coef=coef,
            col_kind=kind, col_mask=mask, group=grp,
        )

    def bricks_moved(self, n_new: int, rows: np.ndarray) -> "ForceModel":
        """The per-brick arrays (gravity, brick_mask, layer, centre, member)
        in a numbering of ``n_new`` bricks: brick ``i`` at ``rows[i]`` (the
        first ``len(rows)`` bricks; the others dropped), every other place a
        padding brick (no weight, not real, layer -1). Columns and groups
        are the caller's to renumber (:meth:`pad`,
        :func:`~stablelego_jax.solvers.problem.to_layered`)."""

        def moved(a, fill, dtype):
            if a is None:
                return None
            out = np.full((n_new,) + a.shape[1:], fill, dtype)
            out[rows] = a[: len(rows)]
            return out

        return dataclasses.replace(
            self, gravity=moved(self.gravity, 0.0, float), brick_mask=moved(self.brick_mask, False, bool),
            layer=moved(self.layer, -1, np.int32), centre=moved(self.centre, 0.0, float),
            member=moved(self.member, 0, np.int32),
        )


def pack_models(models: Sequence[ForceModel]) -> tuple[ForceModel, np.ndarray]:
    """Several unpadded models as one (block diagonal: no column joins two
    of them), so that one solve answers them all; the Eq. 9 problem of the
    pack is the sum of theirs. Bricks and columns follow in the order of
    ``models``; the ground stays the index past the last brick. Returns the
    pack and ``cols`` ((len(models) + 1,) int): model j's forces are the
    pack's ``f[cols[j]:cols[j + 1]]``. All models share one ``Params``. The
    pack's ``member`` numbers its layouts, so that each one's canonical term
    is normalised by its own weight (the pack's optimum is then each
    layout's own: its problem is the sum of theirs)."""
    if not models:
        raise ValueError("pack_models: no models")
    for fm in models:
        if fm.n_pad != fm.n or fm.m_pad != fm.m or fm.params != models[0].params or fm.member is not None:
            raise ValueError("pack_models: models must be unpadded, not packs, and share their Params")
    ns = np.cumsum([0] + [fm.n for fm in models])
    cols = np.cumsum([0] + [fm.m for fm in models])
    N, M = int(ns[-1]), int(cols[-1])
    P = max(fm.group.shape[1] for fm in models)
    group = np.full((N, P), M, np.int32)
    cb = []
    for fm, b0, c0 in zip(models, ns, cols):
        cb.append(np.where(fm.col_brick >= fm.n, N, fm.col_brick + b0))
        g = fm.group
        group[b0: b0 + fm.n, : g.shape[1]] = np.where(g >= fm.m, M, g + c0)

    def cat(name, dtype=None):
        parts = [getattr(fm, name) for fm in models]
        if any(p is None for p in parts):
            return None
        out = np.concatenate(parts)
        return out if dtype is None else out.astype(dtype)

    pack = ForceModel(
        n=N, m=M, col_brick=np.concatenate(cb).astype(np.int32), col_coef=cat("col_coef"),
        col_kind=cat("col_kind", np.int8), col_mask=cat("col_mask", bool), group=group,
        gravity=cat("gravity"), brick_mask=cat("brick_mask", bool), params=models[0].params,
        layer=cat("layer", np.int32), centre=cat("centre"),
        member=np.repeat(np.arange(len(models), dtype=np.int32), np.diff(ns)))
    return pack, cols


def normal_groups(col_brick: np.ndarray, col_kind: np.ndarray, n: int) -> np.ndarray:
    """(n, P) int32 table of the NORMAL columns on each brick's bottom (``m`` = none)."""
    m = len(col_kind)
    normal = np.nonzero(col_kind == NORMAL)[0]
    owner = col_brick[normal, 0]
    order = np.argsort(owner, kind="stable")
    normal, owner = normal[order], owner[order]
    counts = np.bincount(owner, minlength=n)
    P = max(int(counts.max()) if counts.size else 1, 1)
    slot = np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)
    group = np.full((n, P), m, np.int32)
    group[owner, slot] = normal
    return group


def column_wrenches(pair: np.ndarray, forces: np.ndarray, points: np.ndarray, centre: np.ndarray,
                    xp=np) -> np.ndarray:
    """(k, 2, 6) wrench per unit force of columns acting on body ``pair[:, 0]``
    with ``forces`` (k, 3) at ``points`` (k, 3) (m) and oppositely on
    ``pair[:, 1]`` (zero where it is ``n`` = ``len(centre)``, the ground);
    torques about each body's centre ``centre`` (n, 3) (m). ``xp``: numpy
    or jax.numpy (differentiable in points and centres)."""
    n = len(centre)
    c0 = centre[pair[:, 0]]
    c1 = xp.where(pair[:, 1:2] < n, centre[xp.minimum(pair[:, 1], n - 1)], 0.0)
    w0 = xp.concatenate([forces, xp.cross(points - c0, forces)], axis=1)
    w1 = xp.concatenate([-forces, xp.cross(points - c1, -forces)], axis=1)
    w1 = xp.where(pair[:, 1:2] < n, w1, 0.0)
    return xp.stack([w0, w1], axis=1)


def compile_layout(layout: Layout | Scene, params: Params = Params()) -> ForceModel:
    """Build the force model of ``layout`` (vectorised numpy, no brick loops).

    A :class:`~stablelego_jax.scene.Scene` (bodies beyond the stud grid) is
    compiled by :func:`compile_scene`."""
    if isinstance(layout, Scene):
        return compile_scene(layout, params)
    L, Hl = params.stud, params.layer
    n = layout.n
    pos, size = layout.pos, layout.size
    owner_at = cell_owner(layout)  # sparse: bricks far apart need no giant grid
    centre = np.stack(
        [(pos[:, 0] + size[:, 0] / 2) * L, (pos[:, 1] + size[:, 1] / 2) * L, (pos[:, 2] + 0.5) * Hl],
        axis=1,
    )  # (n, 3) m
    cells, owner = cells_of(pos, size)
    cx, cy, cz = cells.T

    # --- knob connections: cell of an upper brick over a lower brick or the baseplate
    below = np.where(cz > 0, owner_at(np.stack([cx, cy, cz - 1], axis=1)), n)
    conn = below >= 0
    c_up, c_lo = owner[conn], below[conn]
    kx, ky = (cx[conn] + 0.5) * L, (cy[conn] + 0.5) * L  # knob centre (m)
    kz = cz[conn] * Hl  # interface plane (m)

    cols_brick, cols_force, cols_point, cols_kind = [], [], [], []

    def add(bricks_pair, forces, points, kind):
        # forces: (k, 3) unit force on slot 0 (slot 1 gets the opposite); points (k, 3) m
        cols_brick.append(bricks_pair)
        cols_force.append(forces)
        cols_point.append(points)
        cols_kind.append(np.full(len(forces), kind, np.int8))

    pair = np.stack([c_up, c_lo], axis=1)
    four = four_point_knobs(size[c_up], cells[conn, :2] - pos[c_up, :2])
    for sel, offs in ((four, PTS_4), (~four, PTS_3)):
        k, p = int(sel.sum()), len(offs)
        if k == 0:
            continue
        pts = np.stack(
            [
                (kx[sel, None] + offs[None, :, 0] * L),
                (ky[sel, None] + offs[None, :, 1] * L),
                np.broadcast_to(kz[sel, None], (k, p)),
            ],
            axis=-1,
        ).reshape(k * p, 3)
        bp = np.repeat(pair[sel], p, axis=0)
        up = np.tile([0.0, 0.0, 1.0], (k * p, 1))
        add(bp, up, pts, NORMAL)
    knob_pts = np.stack([kx, ky, kz], axis=1)
    for axis in (0, 1):
        f = np.zeros((len(c_up), 3))
        f[:, axis] = 1.0
        add(pair, f, knob_pts, KNOB)

    # --- side presses between neighbouring cells of different bricks in one layer
    for axis in (0, 1):
        shifted = np.array(cells)
        shifted[:, axis] += 1
        nb = owner_at(shifted)
        side = (nb >= 0) & (nb != owner)
        a, b = owner[side], nb[side]  # a on the - side, b on the + side
        face = (cells[side] + 0.5) * [L, L, Hl]
        face[:, axis] += 0.5 * L
        f = np.zeros((len(a), 3))
        f[:, axis] = 1.0
        add(np.stack([b, a], axis=1), f, face, SIDE)

    col_brick = np.concatenate(cols_brick).astype(np.int32)
    # the wrenches of all columns at once (small layouts: numpy's per-call cost, not the arithmetic)
    col_coef = column_wrenches(col_brick, np.concatenate(cols_force), np.concatenate(cols_point), centre)
    col_kind = np.concatenate(cols_kind)
    m = len(col_kind)

    # per-brick table of the NORMAL columns on its bottom
    group = normal_groups(col_brick, col_kind, n)

    gravity = np.zeros((n, 6))
    gravity[:, 2] = -layout.mass * params.g
    return ForceModel(
        n=n,
        m=m,
        col_brick=col_brick,
        col_coef=col_coef,
        col_kind=col_kind,
        col_mask=np.ones(m, bool),
        group=group,
        gravity=gravity,
        brick_mask=np.ones(n, bool),
        params=params,
        layer=np.asarray(pos[:, 2], np.int32),
        centre=centre,
    )


def scene_columns(scene: Scene, params: Params = Params()):
    """The columns of :func:`compile_scene` before their wrenches: (pair (m, 2)
    int64 bodies, n = ground; force direction on slot 0 (m, 3); point of
    application (m, 3) m; kind (m,) int8; body centres (n, 3) m)."""
    centre, _, _ = boxes(scene, params.stud, params.layer / 3)
    c = scene_contacts(scene, params.stud, params.layer / 3)
    a, b, k = len(c.lego_pair), len(c.knob_pair), len(c.push_pair)
    ez = np.tile([0.0, 0.0, 1.0], (a, 1))
    ex, ey = np.tile([1.0, 0.0, 0.0], (b, 1)), np.tile([0.0, 1.0, 0.0], (b, 1))
    pair = np.concatenate([c.lego_pair, c.knob_pair, c.knob_pair, c.push_pair]).astype(np.int64)
    forces = np.concatenate([ez, ex, ey, c.push_dir])
    points = np.concatenate([c.lego_point, c.knob_point, c.knob_point, c.push_point])
    kind = np.concatenate([np.full(a, NORMAL), np.full(2 * b, KNOB), np.full(k, SIDE)]).astype(np.int8)
    return pair, forces, points, kind, centre


def shifted(scene: Scene, shift: np.ndarray, params: Params = Params()) -> Scene:
    """``scene`` with every body moved horizontally by ``shift`` (n, 2) metres
    (bricks: by shift / stud studs). Not validated (overlaps are not checked)."""
    unit = np.where(scene.kind == BLOCK, 1.0, 1.0 / params.stud)[:, None]
    pos = scene.pos.copy()
    pos[:, :2] = pos[:, :2] + np.asarray(shift, np.float64) * unit
    return dataclasses.replace(scene, pos=pos)


_MAX_POINT_RATE = 100.0  # m per m: faster than this, a contact point was renumbered, not moved


def point_jacobian(scene: Scene, params: Params = Params(), h: float = 1e-6, columns=None):
    """How the columns' points of application move when bodies move
    horizontally: (J (m, 2, 3, 2), smooth (m,) bool), ``J[c, s]`` the
    derivative of column c's point (m) with respect to the (x, y)
    translation (m) of the body in its slot s (zero for the ground).

    While no contact appears, vanishes or changes its vertices, every point
    is an affine function of the two bodies' translations (a corner of one
    footprint, a crossing of two edges, a knob of the upper part, an end of
    a side overlap), so its derivative is read exactly off
    :func:`scene_columns` at shifted copies of the scene: the bodies of one
    colour of the contact graph (no two touching) move together, by +h and
    -h along x and along y. Only plain blocks move (J is zero for Lego
    parts, whose knob connections hold only where studs coincide). ``smooth`` is False for a column whose two
    one-sided derivatives differ (a kink, e.g. aligned edges: the contact
    polygon changes which body's corner it follows) or whose contacts
    change within h; J is then their mean. ``columns``: the scene's
    :func:`scene_columns`, when the caller has them already."""
    n = scene.n
    pair, force, points, kind, _ = columns if columns is not None else scene_columns(scene, params)
    m = len(pair)
    J = np.zeros((m, 2, 3, 2))
    smooth = np.ones(m, bool)
    if m == 0:
        return J, smooth

    def groups(pr, f, k):  # the columns of one contact: same bodies, kind and direction, in their order
        out: dict = {}
        for c, key in enumerate(zip(pr[:, 0].tolist(), pr[:, 1].tolist(), k.tolist(),
                                    map(tuple, np.round(f, 6).tolist()))):
            out.setdefault(key, []).append(c)
        return out

    base = groups(pair, force, kind)

    def moved_points(d):  # each column's point in the shifted scene (NaN: its contact changed)
        p2, f2, q2, k2, _ = scene_columns(shifted(scene, d, params), params)
        out = np.full((m, 3), np.nan)
        other = groups(p2, f2, k2)
        for key, idx in base.items():
            idx2 = other.get(key, [])
            if len(idx2) == len(idx):
                out[idx] = q2[idx2]
        return out
    # greedy colouring of the contact graph: bodies of one colour share no column
    nbr = [set() for _ in range(n)]
    for a, b in pair.tolist():
        if b < n and a != b:
            nbr[a].add(b)
            nbr[b].add(a)
    colour = np.full(n, -1)
    for i in np.argsort([-len(v) for v in nbr], kind="stable"):
        if scene.kind[i] != BLOCK:
            continue  # Lego parts join where studs coincide: any move off the stud lattice breaks that
        used = {colour[j] for j in nbr[i]}
        colour[i] = next(c for c in range(n + 1) if c not in used)
    for c in range(int(colour.max()) + 1):
        moved = colour == c
        for axis in range(2):
            side = []
            for sign in (1.0, -1.0):
                d = np.zeros((n, 2))
                d[moved, axis] = sign * h
                dp = (moved_points(d) - points) / (sign * h)
                dp[(np.abs(dp) > _MAX_POINT_RATE).any(1)] = np.nan  # vertices renumbered: the contact changed
                side.append(dp)
            hit = moved[np.minimum(pair, n - 1)] & (pair < n)  # (m, 2): the slot's body moved
            ok = ~np.isnan(side[0]).any(1), ~np.isnan(side[1]).any(1)
            mean = np.where((ok[0] & ok[1])[:, None], (side[0] + side[1]) / 2,
                            np.where(ok[0][:, None], side[0], np.where(ok[1][:, None], side[1], 0.0)))
            kink = ~(ok[0] & ok[1]) | (np.abs(np.nan_to_num(side[0] - side[1])).max(1) > 1e-6)
            smooth &= ~(hit.any(1) & kink)
            for s in range(2):
                J[:, s, :, axis] = np.where(hit[:, s:s + 1], mean, J[:, s, :, axis])
    return J, smooth


def compile_scene(scene: Scene, params: Params = Params()) -> ForceModel:
    """Build the force model of a :class:`~stablelego_jax.scene.Scene` from the
    contacts of :func:`~stablelego_jax.contacts.scene_contacts` (studs of
    ``params.stud``, plate heights of ``params.layer / 3``).

    Columns, in this order: one ``NORMAL`` per Lego contact point, one
    ``KNOB`` along x per knob connection, then one along y, and one ``SIDE``
    per plain or side contact force (the model's last columns, in the order
    of ``Contacts.push_*``). Gravity acts at each body's centre. ``layer``
    holds the bodies' levels in the contact graph
    (:func:`~stablelego_jax.contacts.contact_levels`), so every column joins
    one level or two adjacent ones.
    """
    n = scene.n
    pair, forces, points, kind, centre = scene_columns(scene, params)
    coef = column_wrenches(pair, forces, points, centre) if len(pair) else np.zeros((0, 2, 6))
    m = len(kind)
    col_brick = pair.astype(np.int32)
    gravity = np.zeros((n, 6))
    gravity[:, 2] = -scene.mass * params.g
    ground = np.zeros(n, bool)
    ground[pair[pair[:, 1] == n, 0]] = True
    bottom = centre[:, 2] - np.where(scene.kind == BLOCK, scene.size[:, 2], scene.size[:, 2] * params.layer / 3) / 2
    return ForceModel(
        n=n, m=m, col_brick=col_brick, col_coef=coef, col_kind=kind, col_mask=np.ones(m, bool),
        group=normal_groups(col_brick, kind, n), gravity=gravity, brick_mask=np.ones(n, bool), params=params,
        layer=contact_levels(pair, ground, bottom, n), centre=np.asarray(centre, np.float64),
    )
