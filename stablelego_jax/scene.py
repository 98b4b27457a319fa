"""Scenes: bodies beyond the stud grid, validated (paper Sec. IV.E, SPEC "Extensions").

A :class:`Scene` holds ``n`` bodies of two kinds, as flat numpy arrays:

* ``BRICK``: a Lego part (brick or plate) with studs, turned by any yaw
  about +z: ``pos`` = (centre x, centre y) in studs and the bottom height in
  plate heights (one third of a layer; a brick on layer z has bottom 3 z);
  ``size`` = studs along its own x and y and its height in plate heights
  (3 for a brick, 1 for a plate). It joins the parts above and below only
  where their stud centres coincide and its bottom meets their top; on the
  ground (bottom 0) it joins the baseplate's studs, which sit at
  half-integer stud coordinates. Bottoms are whole plate heights in files of
  this project; an LDraw model may put a part between them (on a part that
  cannot be modelled, a bracket), and it then joins only parts at its own
  heights.
* ``BLOCK``: a plain box (a block, a box of a pallet, the pallet itself):
  ``pos`` = its centre and ``size`` = its extents along its own axes, in
  metres. The ground is the plane z = 0.

``yaw`` is in degrees about +z, ``mass`` in kg, ``friction`` the Coulomb
coefficient of plain (non-Lego) contacts. :func:`boxes` converts every body
to metres; it is the one place where studs and plate heights become lengths.
A grid :class:`~stablelego_jax.layout.Layout` converts with
:func:`scene_from_layout`.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from .geometry import rect_corners, separation
from .layout import MAX_COORD, MAX_SIZE, Layout, LayoutError

__all__ = ["BRICK", "BLOCK", "STUD_M", "PLATE_M", "OVERLAP_TOL_M", "Scene", "make_scene", "boxes",
           "scene_from_layout", "body_word", "candidate_pairs", "footprint_bounds", "overlapping_pairs"]

BRICK, BLOCK = 0, 1
#: SPEC stud pitch and plate height (a third of the 9.6 mm layer), metres:
#: the lengths at which overlaps of bricks and blocks are checked.
STUD_M = 0.0078
PLATE_M = 0.0096 / 3
#: Volumes may interpenetrate by at most this much (m) before they overlap.
OVERLAP_TOL_M = 1e-9


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """A validated scene of bricks and blocks (see the module doc for units).

    keys: (n,) names as the input gave them; kind: (n,) int8 BRICK/BLOCK;
    pos, size: (n, 3) float64 (bricks: studs and plate heights; blocks: m);
    yaw: (n,) degrees; mass: (n,) kg; brick_id: (n,) library id or part
    number of bricks ("" for blocks); friction: Coulomb coefficient of plain
    contacts (>= 0); source: file; fmt: input format ("blocks", "json",
    "ldr", "memory").
    """

    keys: tuple[str, ...]
    kind: np.ndarray
    pos: np.ndarray
    size: np.ndarray
    yaw: np.ndarray
    mass: np.ndarray
    brick_id: tuple[str, ...]
    friction: float = 0.0
    source: str = "<memory>"
    fmt: str = "memory"

    @property
    def n(self) -> int:
        return len(self.keys)

    @property
    def is_brick(self) -> np.ndarray:
        return self.kind == BRICK

    def subset(self, idx: Sequence[int]) -> "Scene":
        idx = np.asarray(idx, dtype=np.int64)
        return dataclasses.replace(
            self, keys=tuple(self.keys[i] for i in idx), kind=self.kind[idx], pos=self.pos[idx],
            size=self.size[idx], yaw=self.yaw[idx], mass=self.mass[idx],
            brick_id=tuple(self.brick_id[i] for i in idx),
        )


def body_word(kind: int) -> str:
    """"brick" or "block": how errors name a body of ``kind``."""
    return "brick" if int(kind) == BRICK else "block"


def boxes(scene: Scene, stud: float = STUD_M, plate: float = PLATE_M):
    """Every body as a box in metres: (centre (n, 3), size (n, 3), yaw (n,)
    radians). Bricks: studs of ``stud`` m, plate heights of ``plate`` m."""
    b = scene.kind == BRICK
    p, s = scene.pos, scene.size
    centre = np.where(b[:, None], np.stack([p[:, 0] * stud, p[:, 1] * stud, (p[:, 2] + s[:, 2] / 2) * plate], 1), p)
    size = np.where(b[:, None], s * np.array([stud, stud, plate]), s)
    return centre, size, np.radians(scene.yaw)


def candidate_pairs(lo: np.ndarray, hi: np.ndarray, tol: float, chunk: int = 512) -> np.ndarray:
    """(p, 2) index pairs i < j whose axis-aligned boxes [lo, hi] ((n, d))
    overlap or lie within ``tol`` of each other (all pairs tested in chunks
    of rows: the broad phase of the overlap and contact searches)."""
    n = len(lo)
    out = []
    for r0 in range(0, n, chunk):
        r = np.arange(r0, min(r0 + chunk, n))
        near = ((lo[r, None, :] <= hi[None, :, :] + tol) & (lo[None, :, :] <= hi[r, None, :] + tol)).all(-1)
        near &= np.arange(n)[None, :] > r[:, None]
        i, j = np.nonzero(near)
        out.append(np.stack([r[i], j], 1))
    return np.concatenate(out) if out else np.zeros((0, 2), np.int64)


def footprint_bounds(centre: np.ndarray, size: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned (lo, hi) (n, 3) bounds of boxes (metres, yaw radians)."""
    c, s = np.abs(np.cos(yaw)), np.abs(np.sin(yaw))
    hx = 0.5 * (size[:, 0] * c + size[:, 1] * s)
    hy = 0.5 * (size[:, 0] * s + size[:, 1] * c)
    half = np.stack([hx, hy, 0.5 * size[:, 2]], 1)
    return centre - half, centre + half


def make_scene(keys: Sequence[str], kind, pos, size, yaw, mass, brick_id: Sequence[str] | None = None,
               friction: float = 0.0, source: str = "<memory>", fmt: str = "memory") -> Scene:
    """Build and validate a :class:`Scene` from plain arrays.

    Raises LayoutError naming ``source`` and the body on: no bodies,
    duplicate keys, a NaN or infinite number, a non-positive block size or
    mass, a block below the ground (bottom under z = 0 by more than
    OVERLAP_TOL_M), a brick with a non-integer or bad stud count or height,
    a negative bottom level or brick mass, a negative friction, and two
    bodies whose volumes overlap by more than OVERLAP_TOL_M (checked at the
    SPEC stud pitch and plate height: :func:`overlapping_pairs`).
    """
    keys = tuple(str(k) for k in keys)
    n = len(keys)
    if n == 0:
        raise LayoutError(source, "layout is empty (no bodies)")
    kind = np.asarray(kind, np.int8).reshape(-1)
    if kind.shape != (n,) or not np.isin(kind, (BRICK, BLOCK)).all():
        raise LayoutError(source, f"kind must hold BRICK or BLOCK for each of the {n} bodies")
    if len(set(keys)) != n:
        dup = next(k for k in keys if keys.count(k) > 1)
        raise LayoutError(source, "duplicate key", dup, what=body_word(kind[keys.index(dup)]))

    def arr(v, shape, what):
        try:
            a = np.asarray(v, np.float64)
        except (TypeError, ValueError) as exc:
            raise LayoutError(source, f"{what} are not numbers: {exc}") from None
        if a.size != int(np.prod(shape)):
            raise LayoutError(source, f"{what} must have shape {shape}, got {a.shape}")
        return a.reshape(shape)

    pos = arr(pos, (n, 3), "positions")
    size = arr(size, (n, 3), "sizes")
    yaw = arr(yaw, (n,), "yaws")
    mass = arr(mass, (n,), "masses")

    def fail(mask, message):
        if mask.any():
            i = int(np.argmax(mask))
            raise LayoutError(source, message(i), keys[i], what=body_word(kind[i]))

    blk, brk = kind == BLOCK, kind == BRICK
    fail(~np.isfinite(pos).all(1), lambda i: f"position {pos[i].tolist()} is not finite")
    fail(~np.isfinite(size).all(1), lambda i: f"size {size[i].tolist()} is not finite")
    fail(~np.isfinite(yaw), lambda i: f"yaw {yaw[i]} is not finite")
    fail(~np.isfinite(mass), lambda i: f"mass {mass[i]} is not finite")
    fail(blk & (size <= 0).any(1), lambda i: f"size {size[i].tolist()} must be positive")
    fail(blk & (mass <= 0), lambda i: f"mass {mass[i]:g} kg must be positive")
    fail(blk & (pos[:, 2] - size[:, 2] / 2 < -OVERLAP_TOL_M),
         lambda i: f"lies below the ground (bottom at z = {pos[i, 2] - size[i, 2] / 2:.6g} m)")
    fail(brk & (mass < 0), lambda i: f"mass must be >= 0, got {mass[i]:g}")
    with np.errstate(invalid="ignore"):
        fail(brk & ((size != np.round(size)).any(1) | (size < 1).any(1)),
             lambda i: f"stud counts and height {size[i].tolist()} must be positive integers")
        fail(brk & (size[:, :2] > MAX_SIZE).any(1), lambda i: f"size {size[i, :2].tolist()} too large "
                                                              f"(at most {MAX_SIZE} studs)")
        fail(brk & (pos[:, 2] < 0), lambda i: f"bottom level {pos[i, 2]:g} must be >= 0 (plate heights)")
        fail(brk & (np.abs(pos) > MAX_COORD).any(1), lambda i: f"position {pos[i].tolist()} too large "
                                                               f"(at most {MAX_COORD})")
    if not (isinstance(friction, (int, float)) and math.isfinite(friction) and friction >= 0):
        raise LayoutError(source, f"friction must be a finite number >= 0, got {friction!r}")
    if brick_id is None:
        brick_id = ("",) * n
    elif len(brick_id) != n:
        raise LayoutError(source, f"brick_id must hold one id per body ({n}), got {len(brick_id)}")
    scene = Scene(keys=keys, kind=kind, pos=pos, size=size, yaw=yaw, mass=mass,
                  brick_id=tuple(str(b) for b in brick_id), friction=float(friction), source=source, fmt=fmt)
    _check_overlap(scene)
    return scene


def overlapping_pairs(scene: Scene) -> np.ndarray:
    """(p, 2) index pairs i < j of bodies whose volumes overlap by more than
    OVERLAP_TOL_M (at the SPEC stud pitch and plate height), ordered by j."""
    centre, size, yaw = boxes(scene)
    lo, hi = footprint_bounds(centre, size, yaw)
    pairs = candidate_pairs(lo, hi, -OVERLAP_TOL_M)
    if not len(pairs):
        return pairs
    i, j = pairs[:, 0], pairs[:, 1]
    zlap = np.minimum(hi[i, 2], hi[j, 2]) - np.maximum(lo[i, 2], lo[j, 2])
    pa = rect_corners(centre[i, :2], size[i, :2], yaw[i])
    pb = rect_corners(centre[j, :2], size[j, :2], yaw[j])
    bad = pairs[(zlap > OVERLAP_TOL_M) & (separation(pa, pb) > OVERLAP_TOL_M)]
    return bad[np.lexsort((bad[:, 0], bad[:, 1]))]


def _check_overlap(scene: Scene) -> None:
    """LayoutError on the first two bodies whose volumes overlap."""
    bad = overlapping_pairs(scene)
    if len(bad):
        a, b = (int(v) for v in bad[0])
        raise LayoutError(scene.source, f"overlaps {body_word(scene.kind[a])} {scene.keys[a]!r}", scene.keys[b],
                          what=body_word(scene.kind[b]))


def scene_from_layout(layout: Layout) -> Scene:
    """The scene of a grid layout: every brick a BRICK at yaw 0 (same keys,
    masses and ids)."""
    pos = np.stack([layout.pos[:, 0] + layout.size[:, 0] / 2, layout.pos[:, 1] + layout.size[:, 1] / 2,
                    3.0 * layout.pos[:, 2]], 1)
    size = np.concatenate([layout.size.astype(np.float64), np.full((layout.n, 1), 3.0)], 1)
    return Scene(keys=layout.keys, kind=np.full(layout.n, BRICK, np.int8), pos=pos, size=size,
                 yaw=np.zeros(layout.n), mass=layout.mass.copy(), brick_id=layout.brick_id,
                 source=layout.source, fmt=layout.fmt)
