"""Soft layouts: a layout plus candidate bricks, compiled to one fixed-shape problem.

Every brick of a soft layout has an *existence weight* ``w`` in [0, 1]. The
meaning (the "scaled brick") is the one the differentiable loss
(:mod:`stablelego_jax.loss`) is built on:

* a brick of weight ``w`` weighs ``w (m + load) g``;
* every force through one of its contacts is ``w`` times the force per unit
  of existence that the solver chooses (a contact between bricks of weights
  ``w1`` and ``w2`` of different units carries ``w1 w2`` times it);
* each of its own Eq. 9 cost terms (its equilibrium residual, its largest
  drag) counts ``w`` times, evaluated on the forces per unit of existence.

So ``w = 0`` is exactly the absent brick: no weight, no force on any other
brick, nothing in any other brick's residual or drag maximum, no cost; and
``w = 1`` is exactly the present brick. In between the brick is faded in
smoothly, and the derivative at ``w = 0`` is the first-order effect of
adding it (see :mod:`stablelego_jax.loss`).

A *candidate* (:class:`Candidate`) is a unit of one or more bricks placed
together (e.g. a support pillar of several bricks); all bricks of a unit
share one weight, the weight of its first brick. Candidates are compiled
against the layout (the *base*) only: a candidate has contacts with base
bricks, the baseplate and bricks of its own unit, never with other
candidates, so candidates may overlap each other (they are alternatives).
A candidate may ``replace`` a base brick (``--allow-remove`` repairs): its
contacts are then computed without that brick.

Shapes: ``n`` bricks (base first, then candidate bricks in order), ``m``
force columns (the base layout's columns as :func:`~stablelego_jax.model.compile_layout`
makes them, then each candidate's), ``P`` contact points per brick bottom.
"""
from __future__ import annotations

import dataclasses
from typing import NamedTuple, Sequence

import numpy as np

from .layout import Layout, LayoutError, make_layout, table_i_bricks
from .model import ForceModel, Params, column_wrenches, compile_layout, normal_groups, point_jacobian, scene_columns
from .scene import BLOCK, Scene

__all__ = [
    "Candidate",
    "SoftProblem",
    "SoftLayout",
    "compile_soft",
    "soft_problem",
    "ScenePositions",
    "scene_positions",
    "shifted_wrenches",
    "candidate_brick",
    "compile_placements",
    "placement_pairs",
]


class SoftProblem(NamedTuple):
    """Array-only pytree of a soft layout (numpy or JAX arrays; ``vmap``-able
    after :func:`~stablelego_jax.solvers.problem.stack_soft`).

    col_brick: (m, 2) int32 bricks of each column (slot 0 upper / + side,
      slot 1 lower / - side); ``n`` = the baseplate (or nothing).
    col_coef: (m, 2, 6) wrench per unit force on each slot (N, N m), as
      :class:`~stablelego_jax.model.ForceModel`.
    col_kind: (m,) int8 NORMAL / KNOB / SIDE.
    col_mask: (m,) bool real columns.
    group: (n, P) int32 NORMAL columns on each brick's bottom (``m`` = none).
    mass: (n,) kg of each brick (without extra loads).
    brick_mask: (n,) bool real bricks.
    unit: (n,) int32 the unit of each brick: the index of the unit's first
      brick (a base brick is its own unit). Bricks of one unit share the
      weight of that first brick, and contacts inside a unit scale with it
      once.
    level: (n,) int32 layer (z) of each brick; -1 for padding.
    slot: (n,) int32 or None: the brick's place ``l B + s`` (layer l, slot
      s) in the layered factorisation of the solver, ``L B`` for padding;
      None: the dense one. Set by
      :func:`~stablelego_jax.solvers.problem.layer_soft`.
    layers: (L, B) int8 zeros or None: the layered factorisation's shape
      (L layers of B slots; only the shape is used).
    chunk: (C, 8) int32 or None (with ``slot``): the real columns grouped by
      brick pair, at most 8 per row (``m`` = none), so that the layered
      factorisation assembles one 12 x 12 block per row instead of one per
      column.
    cut: (L,) int32 or None (with ``slot``): each layer's used slots (its
      last used slot + 1). Set (by
      :func:`~stablelego_jax.solvers.problem.plan_soft`, for a problem
      solved many times), a solve factors each layer at its own size
      (:func:`~stablelego_jax.solvers.blocks.block_cholesky`'s ``live``):
      the same numbers, fewer flops, one compiled branch per size. Under
      ``vmap`` every branch would run, so
      :func:`~stablelego_jax.solvers.problem.stack_soft` drops it.
    """

    col_brick: np.ndarray
    col_coef: np.ndarray
    col_kind: np.ndarray
    col_mask: np.ndarray
    group: np.ndarray
    mass: np.ndarray
    brick_mask: np.ndarray
    unit: np.ndarray
    level: np.ndarray
    slot: np.ndarray | None = None
    layers: np.ndarray | None = None
    chunk: np.ndarray | None = None
    cut: np.ndarray | None = None

    def flat(self) -> tuple[tuple, tuple]:
        """(fields, arrays): the names and values of the fields that are not
        None, for a function of flat arrays
        (:func:`~stablelego_jax.solvers.compiled.compiled`); ``fields`` (static)
        and the arrays' shapes identify its compiled shape.
        :meth:`from_flat` rebuilds the problem."""
        fields = tuple(f for f in self._fields if getattr(self, f) is not None)
        return fields, tuple(getattr(self, f) for f in fields)

    @classmethod
    def from_flat(cls, fields: tuple, arrays) -> "SoftProblem":
        """The problem of :meth:`flat`'s ``(fields, arrays)`` (the rest None)."""
        return cls(**dict(zip(fields, arrays)))

    def keep_only(self, keep, xp=np) -> "SoftProblem":
        """The problem with only the bricks ``keep`` ((n,) bool, one value per
        unit): the others become padding and every column that touches one
        of them is dropped; shapes, slots and levels stay. ``xp``: numpy, or
        ``jax.numpy`` for a traced ``keep``."""
        ext = xp.concatenate([xp.asarray(keep, bool), xp.ones((1,), bool)])
        cb = self.col_brick
        return self._replace(brick_mask=self.brick_mask & ext[:-1],
                             col_mask=self.col_mask & ext[cb[:, 0]] & ext[cb[:, 1]])


@dataclasses.dataclass(frozen=True)
class Candidate:
    """A unit of bricks that a repair may add (all or none).

    pos: (k, 3) corner cells; size: (k, 2) extents (studs along x, y);
    mass: (k,) kg; brick_id: library ids ("" = the real brick of that size);
    ori: (k,) StableLego orientation; kind: "support", "bridge",
    "replace", "remerge", ... (for reports); replaces: indices of the base
    bricks this unit replaces (empty: none; only ``--allow-remove`` repairs
    use it);
    note: human-readable description.
    """

    pos: np.ndarray
    size: np.ndarray
    mass: np.ndarray
    brick_id: tuple
    ori: np.ndarray
    kind: str = "support"
    replaces: tuple = ()
    note: str = ""

    @property
    def k(self) -> int:
        return len(self.pos)

    def cells(self) -> set:
        out = set()
        for (x, y, z), (sx, sy) in zip(self.pos.tolist(), self.size.tolist()):
            for dx in range(sx):
                for dy in range(sy):
                    out.add((x + dx, y + dy, z))
        return out


def candidate_brick(bricks: Sequence[tuple], kind: str = "support", replaces: Sequence[int] = (),
                    note: str = "") -> Candidate:
    """A candidate of real (Table I) bricks given as ``(x, y, z, sx, sy)``
    tuples; masses, library ids and ori from the StableLego library;
    ``replaces``: indices of the base bricks it takes the place of."""
    arr = np.asarray(bricks, np.int64).reshape(-1, 5)
    mass, bids, oris = table_i_bricks(arr[:, 3:])
    return Candidate(
        pos=arr[:, :3], size=arr[:, 3:], mass=mass, brick_id=bids, ori=oris,
        kind=kind, replaces=tuple(sorted(int(i) for i in replaces)), note=note,
    )


@dataclasses.dataclass
class SoftLayout:
    """A base layout, its candidates and their compiled :class:`SoftProblem`.

    Bricks ``0 .. n_base-1`` are the base layout's (in its order), then the
    bricks of candidate 0, candidate 1, ... ``unit_bricks[k]`` holds the
    brick indices of candidate ``k``; ``unit_index[k]`` its first brick
    (where its weight lives).
    """

    base: Layout
    candidates: tuple
    problem: SoftProblem
    params: Params
    unit_bricks: list
    unit_index: np.ndarray

    @property
    def n(self) -> int:
        return int(self.problem.mass.shape[0])

    @property
    def n_base(self) -> int:
        return self.base.n

    def weights(self, present: Sequence[int] = ()) -> np.ndarray:
        """(n,) weights: base bricks 1, candidates 0 except those in ``present``
        (a candidate that replaces a base brick sets that brick to 0)."""
        w = np.zeros(self.n)
        w[: self.n_base] = 1.0
        for k in present:
            w[self.unit_bricks[k]] = 1.0
            w[list(self.candidates[k].replaces)] = 0.0
        return w

    def layout_with(self, chosen: Sequence[int], keys: Sequence[str] | None = None) -> Layout:
        """The real layout: base plus the chosen candidates (minus the bricks
        they replace). New bricks get ``keys`` (default: fresh integer keys
        after the largest integer key of the base)."""
        return apply_candidates(self.base, [self.candidates[k] for k in chosen], keys)


def fresh_keys(existing: Sequence[str], count: int) -> list[str]:
    """``count`` keys not in ``existing``: integers after the largest integer key."""
    used = set(existing)
    nums = [int(k) for k in existing if k.isdigit()]
    nxt = (max(nums) + 1) if nums else len(existing) + 1
    out = []
    while len(out) < count:
        if str(nxt) not in used:
            out.append(str(nxt))
            used.add(str(nxt))
        nxt += 1
    return out


def apply_candidates(base: Layout, cands: Sequence[Candidate], keys: Sequence[str] | None = None) -> Layout:
    """``base`` plus the bricks of ``cands`` (minus the base bricks they replace),
    validated (LayoutError on overlap). Base bricks keep their keys and
    data; new bricks get ``keys`` or fresh keys."""
    drop = {r for c in cands for r in c.replaces}
    keep = [i for i in range(base.n) if i not in drop]
    k_new = sum(c.k for c in cands)
    if keys is None:
        keys = fresh_keys(base.keys, k_new)
    if len(keys) != k_new:
        raise ValueError(f"need {k_new} keys, got {len(keys)}")
    pos = [base.pos[keep]] + [c.pos for c in cands]
    size = [base.size[keep]] + [c.size for c in cands]
    mass = [base.mass[keep]] + [c.mass for c in cands]
    bids = [base.brick_id[i] for i in keep] + [b for c in cands for b in c.brick_id]
    ori = [base.ori[keep]] + [c.ori for c in cands]
    return make_layout(
        [base.keys[i] for i in keep] + list(keys),
        np.concatenate(pos), np.concatenate(size), np.concatenate(mass), bids, np.concatenate(ori),
        source=base.source, fmt=base.fmt,
    )


def _columns(model: ForceModel):
    m = model.m
    return (model.col_brick[:m].copy(), model.col_coef[:m].copy(), model.col_kind[:m].copy())


def compile_soft(layout: Layout, candidates: Sequence[Candidate] = (), params: Params = Params()) -> SoftLayout:
    """Compile ``layout`` and ``candidates`` into one :class:`SoftLayout`.

    The base columns are exactly :func:`~stablelego_jax.model.compile_layout`'s;
    each candidate's columns are those of the layout "base neighbourhood +
    candidate" (minus a replaced brick) that touch a candidate brick, so a
    soft layout with one candidate at weight 1 is the layout with that brick
    added. Raises LayoutError (naming the layout's source) when a candidate
    overlaps a base brick or its own bricks overlap.
    """
    base_model = compile_layout(layout, params)
    nb = layout.n
    cb, coef, kind = _columns(base_model)
    cb = np.where(cb >= nb, -1, cb)  # -1: baseplate for now
    cols_b, cols_c, cols_k = [cb], [coef], [kind]
    masses = [np.asarray(layout.mass, np.float64)]
    unit = [np.arange(nb)]
    unit_bricks, unit_index = [], []
    start = nb
    lo_all = layout.pos
    hi_all = layout.pos + np.concatenate([layout.size, np.ones((nb, 1), np.int64)], axis=1)
    for ci, c in enumerate(candidates):
        k = c.k
        if k == 0:
            raise ValueError(f"candidate {ci} has no bricks")
        cpos, csize = np.asarray(c.pos, np.int64), np.asarray(c.size, np.int64)
        lo = cpos.min(axis=0) - 1
        hi = (cpos + np.concatenate([csize, np.ones((k, 1), np.int64)], axis=1)).max(axis=0) + 1
        near = np.nonzero(((hi_all > lo) & (lo_all < hi)).all(axis=1))[0]
        near = near[~np.isin(near, c.replaces)]
        sub_keys = [f"b{i}" for i in near] + [f"c{j}" for j in range(k)]
        try:
            sub = make_layout(
                sub_keys,
                np.concatenate([layout.pos[near], cpos]),
                np.concatenate([layout.size[near], csize]),
                np.concatenate([layout.mass[near], c.mass]),
                source=layout.source,
            )
        except LayoutError as exc:
            raise LayoutError(layout.source, f"candidate {ci} ({c.note or c.kind}): {exc.message}") from None
        sm = compile_layout(sub, params)
        scb, scoef, skind = _columns(sm)
        ns = sub.n
        # global index of each sub brick; -1 for the baseplate
        gidx = np.concatenate([near, start + np.arange(k), [-1]])
        scb = np.where(scb >= ns, ns, scb)
        touches = (scb >= len(near)) & (scb < ns)
        keep = touches.any(axis=1)
        cols_b.append(gidx[scb[keep]])
        cols_c.append(scoef[keep])
        cols_k.append(skind[keep])
        masses.append(np.asarray(c.mass, np.float64))
        unit.append(np.full(k, start))
        unit_bricks.append(start + np.arange(k))
        unit_index.append(start)
        start += k
    n = start
    col_brick = np.concatenate(cols_b).astype(np.int64)
    col_brick = np.where(col_brick < 0, n, col_brick)
    prob = _problem(col_brick, np.concatenate(cols_c), np.concatenate(cols_k), np.concatenate(masses),
                    np.concatenate(unit), np.concatenate([layout.pos[:, 2]] + [np.asarray(c.pos)[:, 2]
                                                                               for c in candidates]))
    return SoftLayout(
        base=layout, candidates=tuple(candidates), problem=prob, params=params,
        unit_bricks=unit_bricks, unit_index=np.asarray(unit_index, np.int64),
    )


def placement_pairs(pos, size):
    """Contact pairs of a set of placements that may overlap (alternatives).

    pos: (k, 3) corner cells; size: (k, 2) extents. Returns (vertical (p, 2)
    [lower, upper] pairs in adjacent layers with overlapping footprints,
    side (q, 2) pairs in one layer that do not overlap but share a face,
    ground (r,) placements on layer 0).
    """
    pos = np.asarray(pos, np.int64).reshape(-1, 3)
    size = np.asarray(size, np.int64).reshape(-1, 2)
    lo, hi = pos[:, :2], pos[:, :2] + size
    # per axis: overlap length (> 0: overlap, == 0: touching, < 0: apart)
    ov = np.minimum(hi[:, None], hi[None, :]) - np.maximum(lo[:, None], lo[None, :])  # (k, k, 2)
    z = pos[:, 2]
    dz = z[None, :] - z[:, None]
    foot = (ov > 0).all(axis=-1)
    vert = np.argwhere(foot & (dz == 1))
    touch = ((ov[..., 0] == 0) & (ov[..., 1] > 0)) | ((ov[..., 1] == 0) & (ov[..., 0] > 0))
    side = np.argwhere(touch & (dz == 0))
    side = side[side[:, 0] < side[:, 1]]
    return vert, side, np.nonzero(z == 0)[0]


def compile_placements(pos, size, mass, params: Params = Params()) -> SoftProblem:
    """:class:`SoftProblem` over ``k`` brick placements that may overlap.

    pos: (k, 3) corner cells; size: (k, 2) extents (studs); mass: (k,) kg.
    Overlapping placements are alternatives (no contact between them);
    every pair in adjacent layers with overlapping footprints gets the knob
    connection (NORMAL + KNOB columns), every non-overlapping pair sharing a
    face in one layer the side presses, and each layer-0 placement its
    baseplate connection, each exactly as :func:`~stablelego_jax.model.compile_layout`
    makes them for the layout of just those bricks (it is called once on a
    layout holding every pair, translated into its own slot: wrench
    coefficients are translation invariant). So a non-overlapping subset at
    weight 1 and the rest at weight 0 is that subset's layout. Every
    placement is its own unit.
    """
    pos = np.asarray(pos, np.int64).reshape(-1, 3)
    size = np.asarray(size, np.int64).reshape(-1, 2)
    mass = np.asarray(mass, np.float64).reshape(-1)
    k = len(pos)
    if len(size) != k or len(mass) != k:
        raise ValueError(f"pos, size and mass must have one row per placement ({k}), got {len(size)}, {len(mass)}")
    if k == 0:
        raise ValueError("no placements")
    vert, side, ground = placement_pairs(pos, size)
    # slots: (members, z of each member in the slot)
    members = [np.stack([ground, np.full(len(ground), -1)], 1), vert, side]
    zs = [np.stack([np.zeros(len(ground)), np.full(len(ground), -1)], 1),
          np.tile([1, 2], (len(vert), 1)), np.ones((len(side), 2))]
    mem = np.concatenate(members).astype(np.int64)
    zsl = np.concatenate(zs).astype(np.int64)
    col_brick, col_coef, col_kind = np.zeros((0, 2), np.int32), np.zeros((0, 2, 6)), np.zeros(0, np.int8)
    if len(mem):
        real = mem >= 0
        mi = np.where(real, mem, 0)
        blo = np.where(real[..., None], pos[mi, :2], 10**9).min(axis=1)  # (s, 2) slot bbox corner
        bhi = np.where(real[..., None], pos[mi, :2] + size[mi], -1).max(axis=1)
        stride = int((bhi - blo).max()) + 1  # one empty cell between slots: no side contact
        ncol = int(np.ceil(np.sqrt(len(mem))))
        sidx = np.arange(len(mem))
        origin = np.stack([sidx % ncol, sidx // ncol], 1) * stride
        sl, mslot = np.nonzero(real)
        bp = np.concatenate([pos[mem[sl, mslot], :2] - blo[sl] + origin[sl], zsl[sl, mslot][:, None]], 1)
        gidx = mem[sl, mslot]
        big = make_layout([str(i) for i in range(len(gidx))], bp, size[gidx], mass[gidx])
        cb, coef, kind = _columns(compile_layout(big, params))
        gmap = np.concatenate([gidx, [k]])
        col_brick = gmap[np.minimum(cb, big.n)].astype(np.int32)
        col_coef, col_kind = coef.astype(np.float64), kind.astype(np.int8)
    return SoftProblem(
        col_brick=col_brick, col_coef=col_coef, col_kind=col_kind,
        col_mask=np.ones(len(col_kind), bool), group=normal_groups(col_brick, col_kind, k),
        mass=mass, brick_mask=np.ones(k, bool), unit=np.arange(k, dtype=np.int32),
        level=pos[:, 2].astype(np.int32),
    )


class ScenePositions(NamedTuple):
    """What moving a scene's bodies does to its columns (all m columns of
    :func:`~stablelego_jax.model.compile_scene`, in its order).

    pair: (m, 2) int32 bodies (n = ground); force: (m, 3) direction on slot
    0; point: (m, 3) point of application, m; jac: (m, 2, 3, 2) its
    derivative with respect to the (x, y) translation of each slot's body
    (:func:`~stablelego_jax.model.point_jacobian`); smooth: (m,) bool, False
    at a kink; centre: (n, 3) body centres, m; movable: (n,) bool plain
    blocks (Lego parts keep their place: their knobs hold only on the grid).
    """

    pair: np.ndarray
    force: np.ndarray
    point: np.ndarray
    jac: np.ndarray
    smooth: np.ndarray
    centre: np.ndarray
    movable: np.ndarray


def scene_positions(scene: Scene, params: Params = Params()) -> ScenePositions:
    """The :class:`ScenePositions` of ``scene`` (see :func:`shifted_wrenches`)."""
    cols = scene_columns(scene, params)
    pair, force, point, _, centre = cols
    jac, smooth = point_jacobian(scene, params, columns=cols)
    return ScenePositions(pair=pair.astype(np.int32), force=force, point=point, jac=jac, smooth=smooth,
                          centre=centre, movable=scene.kind == BLOCK)


def shifted_wrenches(geo: ScenePositions, shift, xp=np):
    """(m, 2, 6) column wrenches (``SoftProblem.col_coef``) with every movable
    body moved horizontally by ``shift`` (n, 2) m, to first order in the
    contact points (exact while no contact changes: they are affine in the
    translations) and exactly in the bodies' centres. ``xp``: numpy or
    jax.numpy (then differentiable in ``shift``)."""
    n = len(geo.centre)
    d = xp.where(xp.asarray(geo.movable)[:, None], xp.asarray(shift), 0.0)
    d_ext = xp.concatenate([d, xp.zeros((1, 2))])
    move = (xp.einsum("kij,kj->ki", geo.jac[:, 0], d_ext[geo.pair[:, 0]])
            + xp.einsum("kij,kj->ki", geo.jac[:, 1], d_ext[geo.pair[:, 1]]))  # row n: the ground
    centre = geo.centre + xp.concatenate([d, xp.zeros((n, 1))], axis=1)
    return column_wrenches(geo.pair, geo.force, geo.point + move, centre, xp=xp)


def _problem(col_brick, col_coef, col_kind, mass, unit, level) -> SoftProblem:
    """A SoftProblem of real columns and bricks (``n`` = ``len(mass)``, the
    baseplate / ground in ``col_brick``)."""
    n, m = len(mass), len(col_kind)
    col_brick = np.asarray(col_brick, np.int32)
    col_kind = np.asarray(col_kind, np.int8)
    return SoftProblem(
        col_brick=col_brick, col_coef=np.asarray(col_coef, np.float64), col_kind=col_kind,
        col_mask=np.ones(m, bool), group=normal_groups(col_brick, col_kind, n),
        mass=np.asarray(mass, np.float64), brick_mask=np.ones(n, bool), unit=np.asarray(unit, np.int32),
        level=np.asarray(level, np.int32),
    )


def soft_problem(layout: Layout | Scene, params: Params = Params()) -> SoftProblem:
    """The :class:`SoftProblem` of a plain layout or a
    :class:`~stablelego_jax.scene.Scene` (every brick or body its own unit;
    a scene's columns are :func:`~stablelego_jax.model.compile_scene`'s and
    its levels those of its contact graph)."""
    if isinstance(layout, Scene):
        model = compile_layout(layout, params)
        cb, coef, kind = _columns(model)
        return _problem(cb, coef, kind, layout.mass, np.arange(layout.n), model.layer)
    return compile_soft(layout, (), params).problem
