"""Seeded procedural layout families (stairs, levers, towers, bridges, ...).

Every function returns a validated :class:`~stablelego_jax.layout.Layout`
with keys "1".."n", Table I masses (kg) and StableLego library ids, so that
JSON export works. Positions are stud cells ``(x, y, z)``, sizes ``(sx, sy)``
studs along x and y, layer 0 on the baseplate. External loads are 2x2 "load
blocks" (library id "1") with the given mass in kg.
"""
from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from ..layout import TABLE_I_MASS_KG, Layout, brick_layout, make_layout, table_i_bricks

from .voxels import SHAPE_KINDS, merge_voxels, random_voxel_shape

__all__ = [
    "LOAD_BLOCK_KG",
    "FAMILIES",
    "stairs",
    "lever",
    "tower",
    "bridge",
    "wall",
    "cuboid",
    "pyramid",
    "pallet_of_boxes",
    "with_floating",
    "voxel_layout",
    "random_family_layout",
]

LOAD_BLOCK_KG = 0.2  # mass of the StableLego library's load block (id "1")

# Lengths (studs along the strip) of real bricks for a strip 1 or 2 studs wide.
_LENGTHS = {1: (8, 6, 4, 2, 1), 2: (6, 4, 2, 1)}


class _Builder:
    """Collects bricks; :meth:`build` validates them into a Layout."""

    def __init__(self):
        self.pos: list[tuple[int, int, int]] = []
        self.size: list[tuple[int, int]] = []
        self.mass: list[float] = []
        self.bid: list[str] = []
        self.ori: list[int] = []

    def brick(self, x, y, z, sx, sy):
        mass, bids, oris = table_i_bricks([(int(sx), int(sy))])
        self._add(x, y, z, sx, sy, mass[0], bids[0], oris[0])

    def load(self, x, y, z, mass_kg=LOAD_BLOCK_KG):
        if not np.isfinite(mass_kg) or mass_kg < 0:
            raise ValueError(f"load mass must be finite and >= 0, got {mass_kg}")
        self._add(x, y, z, 2, 2, float(mass_kg), "1", 0)

    def _add(self, x, y, z, sx, sy, m, bid, ori):
        self.pos.append((int(x), int(y), int(z)))
        self.size.append((int(sx), int(sy)))
        self.mass.append(float(m))
        self.bid.append(bid)
        self.ori.append(int(ori))

    def strip(self, x0, y0, z, length, width, along="x", offset=0, blen=None, avoid=()):
        """Bricks of one row ``width`` (1 or 2) studs wide covering ``length``
        studs along ``along`` from (x0, y0): first brick about ``offset``
        long (``blen`` if 0), then ``blen``-long ones, shortened where a joint
        would fall on a position in ``avoid`` (the joints of the row below,
        relative to the row start). Returns this row's joints."""
        lengths = _LENGTHS[width]
        blen = lengths[0] if blen is None else max(int(blen), 1)
        avoid = set(avoid)
        nominal = offset % blen or blen
        joints: set[int] = set()
        s = 0
        while s < length:
            cands = sorted((v for v in lengths if v <= length - s), key=lambda v: (abs(v - nominal), -v))
            L = next((v for v in cands if s + v == length or s + v not in avoid), cands[0])
            if along == "x":
                self.brick(x0 + s, y0, z, L, width)
            else:
                self.brick(x0, y0 + s, z, width, L)
            s += L
            if s < length:
                joints.add(s)
            nominal = blen
        return joints

    def rect(self, x0, y0, z, lx, ly, along="x", offset=0, blen=None, avoid=None):
        """Fill an lx-by-ly rectangle of layer z with strips along ``along``
        (2 studs wide, 1 for an odd remainder). ``avoid``: per-strip joints
        of the layer below (as returned by a previous call). Returns the
        per-strip joints."""
        across = ly if along == "x" else lx
        t, k, out = 0, 0, []
        while t < across:
            w = 2 if across - t >= 2 else 1
            bl = None if blen is None else min(int(blen), _LENGTHS[w][0])
            av = avoid[k] if avoid is not None and k < len(avoid) else ()
            if along == "x":
                out.append(self.strip(x0, y0 + t, z, lx, w, "x", offset, bl, av))
            else:
                out.append(self.strip(x0 + t, y0, z, ly, w, "y", offset, bl, av))
            t += w
            k += 1
        return out

    def build(self, source: str) -> Layout:
        n = len(self.pos)
        return make_layout(
            [str(i + 1) for i in range(n)],
            np.asarray(self.pos, np.int64).reshape(n, 3),
            np.asarray(self.size, np.int64).reshape(n, 2),
            np.asarray(self.mass, np.float64),
            brick_id=self.bid,
            ori=self.ori,
            source=source,
        )


def _half(blen: int, width: int) -> int:
    """Joint stagger for running bond: the longest real length <= blen / 2."""
    return next(v for v in _LENGTHS[width] if v <= max(int(blen) // 2, 1))


def _check_pos(**kw):
    for k, v in kw.items():
        if int(v) < 1:
            raise ValueError(f"{k} must be >= 1, got {v}")


# --------------------------------------------------------------------------
# families


def stairs(
    n_levels: int,
    step: int = 2,
    brick: tuple[int, int] = (4, 2),
    origin: tuple[int, int] = (0, 0),
    load_kg: float | None = None,
    load_offset: int = 1,
) -> Layout:
    """Cantilever staircase (paper Fig. 1): one ``brick`` (sx, sy) per level,
    level i at x = i * step. ``stairs(20, origin=(0, 21))`` is the paper's
    stair_20. With ``load_kg`` a 2x2 load block of that mass sits on the top
    brick at x offset ``load_offset`` (``stairs(4, load_kg=0.2)`` is
    external_weight_fail)."""
    _check_pos(n_levels=n_levels)
    b = _Builder()
    x0, y0 = origin
    for i in range(n_levels):
        b.brick(x0 + i * step, y0, i, *brick)
    if load_kg is not None:
        b.load(x0 + (n_levels - 1) * step + load_offset, y0, n_levels, load_kg)
    return b.build(f"<stairs n={n_levels} step={step}>")


def lever(
    beam_len: int = 36,
    base_len: int = 8,
    base_height: int = 2,
    loads: Sequence[float] = (LOAD_BLOCK_KG,),
    load_x: Sequence[int] | None = None,
    width: int = 1,
    blen: int = 6,
    origin: tuple[int, int] = (0, 0),
) -> Layout:
    """Cantilevered beam over a base (like StableLego's stick_heavy).

    Base: ``base_height`` running-bond layers covering x in [0, base_len).
    Beam: two layers above it covering x in [0, base_len + beam_len) with
    ``blen``-long bricks, joints staggered by about blen / 2. Loads: one 2x2 load
    block per entry of ``loads`` (kg) on top of the beam at ``load_x``
    (default: at the tip, then every 3 studs back). ``width``: 1 or 2 studs.
    """
    _check_pos(beam_len=beam_len, base_len=base_len, base_height=base_height)
    if width not in (1, 2):
        raise ValueError("width must be 1 or 2")
    x0, y0 = origin
    total = base_len + beam_len
    b = _Builder()
    half = _half(blen, width)
    joints: set[int] = set()
    for z in range(base_height):
        joints = b.strip(x0, y0, z, base_len, width, "x", half * (z % 2), blen, joints)
    for k in range(2):
        joints = b.strip(x0, y0, base_height + k, total, width, "x", half * k, blen, joints)
    if load_x is None:
        load_x = [total - 2 - 3 * i for i in range(len(loads))]
    if len(load_x) != len(loads):
        raise ValueError("load_x and loads must have the same length")
    for m, lx in zip(loads, load_x):
        b.load(x0 + int(lx), y0, base_height + 2, m)
    return b.build(f"<lever beam={beam_len} loads={len(loads)}>")


def tower(
    height: int,
    footprint: tuple[int, int] = (2, 2),
    lean: int = 0,
    origin: tuple[int, int] = (0, 0),
    seed: int = 0,
) -> Layout:
    """Column of ``height`` layers, each covering ``footprint`` (fx, fy).
    ``lean`` >= 0 shifts each layer by that many studs along x (a leaning
    tower; no overlap between layers once lean >= fx; with lean > 0 every
    brick is connected to the ground only when fx is a brick length, 2, 4
    or 6, so that one brick spans each row). The prism is merged
    into bricks with :func:`~stablelego_jax.generate.voxels.merge_voxels` (long axes
    alternating x/y, overhangs held by bricks that reach back; ``seed`` its
    tie-break)."""
    _check_pos(height=height, fx=footprint[0], fy=footprint[1])
    if lean < 0:
        raise ValueError("lean must be >= 0")
    fx, fy = footprint
    vox = np.zeros((fx + lean * (height - 1), fy, height), bool)
    for z in range(height):
        vox[lean * z:lean * z + fx, :, z] = True
    lay = merge_voxels(vox, seed=seed, source=f"<tower h={height} {fx}x{fy} lean={lean}>")
    return dataclasses.replace(lay, pos=lay.pos + np.array([origin[0], origin[1], 0], np.int64))


def bridge(
    span: int = 8,
    height: int = 4,
    width: int = 2,
    pillar_len: int = 2,
    deck_layers: int = 2,
    blen: int = 6,
    origin: tuple[int, int] = (0, 0),
) -> Layout:
    """Two pillars (pillar_len x width, ``height`` layers) ``span`` studs
    apart under a deck of ``deck_layers`` running-bond layers (joints
    staggered by about blen / 2 between deck layers; one layer leaves joints over
    the gap unbridged)."""
    _check_pos(span=span, height=height, width=width, pillar_len=pillar_len, deck_layers=deck_layers)
    x0, y0 = origin
    b = _Builder()
    for z in range(height):
        along = "x" if z % 2 == 0 else "y"
        for px in (x0, x0 + pillar_len + span):
            b.rect(px, y0, z, pillar_len, width, along)
    total = 2 * pillar_len + span
    half = _half(blen, min(width, 2))
    joints = None
    for k in range(deck_layers):
        joints = b.rect(x0, y0, height + k, total, width, "x", half * (k % 2), blen, joints)
    return b.build(f"<bridge span={span} h={height}>")


def wall(
    length: int = 16,
    height: int = 6,
    width: int = 1,
    blen: int = 4,
    origin: tuple[int, int] = (0, 0),
) -> Layout:
    """Running-bond wall along x: ``height`` layers of ``blen``-long bricks,
    ``width`` (1 or 2) studs thick, joints shifted by about blen / 2 every
    other layer."""
    _check_pos(length=length, height=height, width=width)
    if width not in (1, 2):
        raise ValueError("width must be 1 or 2")
    b = _Builder()
    joints: set[int] = set()
    for z in range(height):
        joints = b.strip(origin[0], origin[1], z, length, width, "x", _half(blen, width) * (z % 2), blen, joints)
    return b.build(f"<wall {length}x{height}>")


def cuboid(nx: int, ny: int, nz: int) -> Layout:
    """nx * ny * nz unit 1x1 bricks filling a box (for scaling curves)."""
    _check_pos(nx=nx, ny=ny, nz=nz)
    z, x, y = np.meshgrid(np.arange(nz), np.arange(nx), np.arange(ny), indexing="ij")
    pos = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    return brick_layout(pos, np.ones((len(pos), 2), np.int64), source=f"<cuboid {nx}x{ny}x{nz}>")


def pyramid(levels: int, lean: tuple[int, int] = (1, 1)) -> Layout:
    """A stepped pyramid of 2x2 bricks (as LDraw's generated ``pyramidN``
    models): level ``z`` (from 0) is a square of ``levels - z`` x ``levels - z``
    bricks, shifted by ``lean`` studs (x, y) per level against the one
    below, so each brick sits on up to four (2870 bricks at 20 levels). A
    wide, low layout: its bottom layer holds ``levels^2`` bricks, a vertical
    slab about half as many."""
    _check_pos(levels=levels)
    if not all(0 <= v <= 1 for v in lean):
        raise ValueError(f"lean must be 0 or 1 stud per level along x and y, got {lean}")
    pos = [(2 * i + lean[0] * z, 2 * j + lean[1] * z, z)
           for z in range(levels) for i in range(levels - z) for j in range(levels - z)]
    return brick_layout(pos, np.full((len(pos), 2), 2, np.int64), source=f"<pyramid {levels}>")


def pallet_of_boxes(
    n_boxes: int = 6,
    seed: int = 0,
    pallet: tuple[int, int] = (16, 12),
    max_box: int = 6,
    max_box_height: int = 4,
) -> Layout:
    """A two-layer brick pallet with ``n_boxes`` random brick boxes stacked
    on it (each box rests on the highest layer under its footprint, so boxes
    may overhang lower neighbours; its bricks come from merge_voxels, which
    makes them reach back to the cells it rests on where it can). Footprints
    2..max_box studs, heights 1..max_box_height layers."""
    _check_pos(n_boxes=n_boxes, px=pallet[0], py=pallet[1])
    rng = np.random.default_rng(seed)
    px, py = pallet
    b = _Builder()
    b.rect(0, 0, 0, px, py, "x")
    b.rect(0, 0, 1, px, py, "y")
    hmap = np.full((px, py), 2, np.int64)
    for _ in range(n_boxes):
        fx = int(rng.integers(2, min(max_box, px) + 1))
        fy = int(rng.integers(2, min(max_box, py) + 1))
        h = int(rng.integers(1, max_box_height + 1))
        x0 = int(rng.integers(0, px - fx + 1))
        y0 = int(rng.integers(0, py - fy + 1))
        under = hmap[x0:x0 + fx, y0:y0 + fy]
        z0 = int(under.max())
        sub = np.ones((fx, fy, h + 1), bool)
        sub[:, :, 0] = under == z0  # the cells it rests on
        box = merge_voxels(sub, seed=int(rng.integers(2**31)))
        for p, sz in zip(box.pos.tolist(), box.size.tolist()):
            if p[2] >= 1:
                b.brick(x0 + p[0], y0 + p[1], z0 - 1 + p[2], *sz)
        hmap[x0:x0 + fx, y0:y0 + fy] = z0 + h
    return b.build(f"<pallet boxes={n_boxes} seed={seed}>")


def with_floating(layout: Layout, seed: int = 0, n: int = 1, gap: int = 1) -> Layout:
    """``layout`` plus ``n`` random bricks connected to nothing: each hovers
    over the structure with at least ``gap`` >= 1 empty layers below it, or
    beside it (one free column in between) on a layer >= 1. Existing keys are
    kept; new keys are the next unused integers."""
    _check_pos(n=n, gap=gap)
    rng = np.random.default_rng(seed)
    occ = layout.occupancy() >= 0
    X, Y, Z = occ.shape
    sizes = sorted(TABLE_I_MASS_KG)
    pos, size = [], []
    ztop = Z - 1 + gap + 1  # first layer with `gap` empty layers under it
    for i in range(n):
        s = sizes[int(rng.integers(len(sizes)))]
        sx, sy = (s[1], s[0]) if rng.random() < 0.5 else s
        if rng.random() < 0.5 or Z < 2:  # above the structure
            x = int(rng.integers(0, max(X - sx, 0) + 1))
            y = int(rng.integers(0, max(Y - sy, 0) + 1))
            z = ztop
            ztop += gap + 1
        else:  # beside it, off the ground, clear of everything
            x = X + 1 + 9 * i  # successive side bricks never touch
            y = int(rng.integers(0, max(Y - sy, 0) + 1))
            z = int(rng.integers(1, Z))
        pos.append((x, y, z))
        size.append((sx, sy))
    used = set(layout.keys)
    keys, k = [], layout.n + 1
    while len(keys) < n:
        if str(k) not in used:
            keys.append(str(k))
        k += 1
    mass, bids, oris = table_i_bricks(size)
    return make_layout(
        list(layout.keys) + keys,
        np.concatenate([layout.pos, np.asarray(pos, np.int64)]),
        np.concatenate([layout.size, np.asarray(size, np.int64)]),
        np.concatenate([layout.mass, mass]),
        brick_id=list(layout.brick_id) + list(bids),
        ori=np.concatenate([layout.ori, oris]),
        source=layout.source + "+floating",
        fmt=layout.fmt,
    )


def voxel_layout(seed: int = 0, grid: int = 16, kind: str | None = None) -> Layout:
    """A random voxel shape (see stablelego_jax.generate.voxels) merged into bricks."""
    vox = random_voxel_shape(seed, grid, kind)
    if not vox.any():  # degenerate draw: fall back to a small block
        vox[:2, :2, :2] = True
    return merge_voxels(vox, seed=seed, source=f"<voxels {kind} seed={seed}>")


FAMILIES: tuple[str, ...] = (
    "stairs",
    "stairs_load",
    "lever",
    "tower",
    "bridge",
    "wall",
    "cuboid",
    "pallet",
    "voxels",
    "floating",
)


def random_family_layout(seed: int, family: str | None = None) -> tuple[str, Layout]:
    """Draw a family (uniformly from FAMILIES unless given) and random
    parameters; returns (name, Layout). Names are the family, with the shape
    kind for voxel layouts ("voxels/arch") and the base family for floating
    ones ("floating/wall"). Sizes run from a handful to a few hundred bricks;
    parameters cover likely-stable and likely-unstable cases (long
    cantilevers, heavy loads, overhangs, floating bricks)."""
    rng = np.random.default_rng(seed)
    fam = family if family is not None else FAMILIES[int(rng.integers(len(FAMILIES)))]
    ri = lambda lo, hi: int(rng.integers(lo, hi + 1))  # noqa: E731  inclusive
    sub = int(rng.integers(2**31))
    if fam == "stairs":
        sx = int(rng.choice([2, 4, 6]))
        step = ri(1, sx - 1) if sx > 1 else 1
        return fam, stairs(ri(2, 26), step=step, brick=(sx, int(rng.choice([1, 2]))))
    if fam == "stairs_load":
        n = ri(2, 8)
        m = float(rng.choice([0.02, 0.05, 0.1, 0.2, 0.3]))
        return fam, stairs(n, load_kg=m, load_offset=ri(0, 2))
    if fam == "lever":
        n_loads = ri(0, 3)
        beam, base_len = ri(4, 44), ri(4, 8)
        loads = [float(rng.choice([0.005, 0.02, 0.05, 0.1, 0.2])) for _ in range(n_loads)]
        lx = rng.choice(np.arange(0, base_len + beam - 1, 2), size=n_loads, replace=False)
        return fam, lever(beam, base_len=base_len, base_height=ri(1, 4), loads=loads,
                          load_x=sorted(lx.tolist()), width=ri(1, 2), blen=int(rng.choice([4, 6])))
    if fam == "tower":
        if rng.random() < 0.5:  # straight
            return fam, tower(ri(2, 20), (ri(1, 6), ri(1, 6)), seed=sub)
        fx = int(rng.choice([2, 4, 6]))  # leaning: rows of one brick stay connected
        return fam, tower(ri(2, 16), (fx, ri(1, 4)), lean=ri(1, fx - 1), seed=sub)
    if fam == "bridge":
        return fam, bridge(span=ri(1, 20), height=ri(1, 8), width=ri(1, 4), pillar_len=ri(1, 4),
                           deck_layers=ri(1, 3), blen=int(rng.choice([4, 6])))
    if fam == "wall":
        return fam, wall(ri(4, 40), ri(2, 16), width=ri(1, 2), blen=int(rng.choice([2, 4, 6])))
    if fam == "cuboid":
        return fam, cuboid(ri(1, 6), ri(1, 6), ri(1, 8))
    if fam == "pallet":
        return fam, pallet_of_boxes(ri(1, 10), seed=sub, pallet=(ri(6, 20), ri(6, 16)))
    if fam == "voxels":
        kind = SHAPE_KINDS[int(rng.integers(len(SHAPE_KINDS)))]
        return f"voxels/{kind}", voxel_layout(sub, grid=ri(8, 20), kind=kind)
    if fam == "floating":
        base_fam, base = random_family_layout(sub, FAMILIES[int(rng.integers(len(FAMILIES) - 1))])
        return f"floating/{base_fam}", with_floating(base, seed=sub, n=ri(1, 3), gap=ri(1, 2))
    raise ValueError(f"unknown family {family!r}; expected one of {FAMILIES}")
