"""Voxel shapes and their merge into library bricks (StableLego dataset style).

A voxel grid is an ``(X, Y, Z)`` bool array: cell ``(x, y, z)`` is one stud
cell of layer ``z`` (layer 0 stands on the baseplate). :func:`merge_voxels`
covers the occupied cells exactly with real bricks; the shape makers return
varied grids resting on ``z = 0``.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import ndimage

from ..layout import TABLE_I_MASS_KG, Layout, brick_layout

__all__ = [
    "BRICK_SETS",
    "DEFAULT_BRICKS",
    "parse_bricks",
    "SHAPE_KINDS",
    "merge_voxels",
    "random_blob",
    "random_voxel_shape",
    "ground",
    "floating_bricks",
    "oriented",
    "placements_in",
]

# (short, long) footprints, largest first (2-wide before 1-wide on equal area).
DEFAULT_BRICKS: tuple[tuple[int, int], ...] = (
    (2, 6), (2, 4), (1, 8), (1, 6), (2, 2), (1, 4), (1, 2), (1, 1),
)

#: Named brick sets for :func:`merge_voxels` (``--bricks`` of the CLI). Each
#: holds 1x1 so that every voxel can be covered.
BRICK_SETS: dict[str, tuple[tuple[int, int], ...]] = {
    # all eight bricks of paper Table I (= the StableLego library, ids 2-12)
    "all": DEFAULT_BRICKS,
    # 1-wide bricks only (walls, thin shells)
    "1xn": ((1, 8), (1, 6), (1, 4), (1, 2), (1, 1)),
    # 2-wide bricks, 1x2 and 1x1 only as fillers
    "2xn": ((2, 6), (2, 4), (2, 2), (1, 2), (1, 1)),
    # the classic small set
    "basic": ((2, 4), (2, 2), (1, 4), (1, 2), (1, 1)),
    # unit bricks (every voxel its own 1x1)
    "unit": ((1, 1),),
}

SHAPE_KINDS: tuple[str, ...] = ("blob", "boxes", "spheres", "arch", "overhang", "floating")


# --------------------------------------------------------------------------
# merge


def parse_bricks(spec) -> tuple[tuple[int, int], ...]:
    """A brick set from a name of BRICK_SETS ("all", "1xn", "2xn", "basic",
    "unit") or a comma-separated list of footprints ("2x4,2x2,1x2,1x1"), or a
    sequence of (a, b) pairs. Returns (short, long) footprints, largest
    first. Raises ValueError for a size outside paper Table I or a set
    without 1x1."""
    if isinstance(spec, str):
        name = spec.strip().lower()
        if name in BRICK_SETS:
            return BRICK_SETS[name]
        pairs = []
        for tok in name.replace(" ", "").split(","):
            if not tok:
                continue
            parts = tok.split("x")
            if len(parts) != 2 or not all(p.isdigit() for p in parts):
                raise ValueError(f"bad brick {tok!r} in {spec!r}: expected a set name "
                                 f"({', '.join(BRICK_SETS)}) or sizes like 2x4,1x2,1x1")
            pairs.append((int(parts[0]), int(parts[1])))
    else:
        pairs = [(int(a), int(b)) for a, b in spec]
    out = []
    for a, b in pairs:
        t = (min(a, b), max(a, b))
        if t not in TABLE_I_MASS_KG:
            raise ValueError(f"{a}x{b} is not a library brick (Table I sizes: "
                             f"{', '.join(f'{p}x{q}' for p, q in TABLE_I_MASS_KG)})")
        if t not in out:
            out.append(t)
    if (1, 1) not in out:
        raise ValueError("a brick set must contain 1x1 so that every voxel can be covered")
    return tuple(sorted(out, key=lambda t: (-t[0] * t[1], -t[0])))


def _wsum(a: np.ndarray, sx: int, sy: int) -> np.ndarray:
    """Sums of ``a`` (X, Y) over all sx-by-sy windows -> (X-sx+1, Y-sy+1)."""
    X, Y = a.shape
    if sx > X or sy > Y or sx < 1 or sy < 1:
        return np.zeros((max(X - sx + 1, 0), max(Y - sy + 1, 0)), np.int64)
    c = np.zeros((X + 1, Y + 1), np.int64)
    c[1:, 1:] = a.astype(np.int64).cumsum(0).cumsum(1)
    return c[sx:, sy:] - c[:-sx, sy:] - c[sx:, :-sy] + c[:-sx, :-sy]


def oriented(bricks: Sequence[tuple[int, int]] = DEFAULT_BRICKS) -> tuple[tuple[int, int], ...]:
    """Footprints (sx, sy) of ``bricks`` in both orientations, largest first."""
    out = []
    for a, b in parse_bricks(bricks):
        for t in ((a, b), (b, a)):
            if t not in out:
                out.append(t)
    return tuple(out)


def placements_in(mask: np.ndarray, types: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """Every placement of an oriented footprint of ``types`` whose cells all
    lie in ``mask`` (X, Y, Z) bool: (pos (k, 3) corner cells, size (k, 2)),
    grouped by type in the order given, then by layer, x, y."""
    mask = np.asarray(mask, bool)
    pos, size = [], []
    for sx, sy in types:
        for z in np.nonzero(mask.any(axis=(0, 1)))[0]:
            ok = np.argwhere(_wsum(mask[:, :, z], sx, sy) == sx * sy)
            if len(ok):
                pos.append(np.column_stack([ok, np.full(len(ok), z)]))
                size.append(np.tile([sx, sy], (len(ok), 1)))
    if not pos:
        return np.zeros((0, 3), np.int64), np.zeros((0, 2), np.int64)
    return np.concatenate(pos).astype(np.int64), np.concatenate(size).astype(np.int64)


def _joint_count(below: np.ndarray, sx: int, sy: int, shape) -> np.ndarray:
    """Per window: number of brick-to-brick joints of the layer below it spans."""
    out = np.zeros(shape, np.int64)
    if sx > 1:
        jx = (below[1:] >= 0) & (below[:-1] >= 0) & (below[1:] != below[:-1])
        out += _wsum(jx, sx - 1, sy)
    if sy > 1:
        jy = (below[:, 1:] >= 0) & (below[:, :-1] >= 0) & (below[:, 1:] != below[:, :-1])
        out += _wsum(jy, sx, sy - 1)
    return out


def merge_voxels(
    vox: np.ndarray,
    seed: int = 0,
    bricks: Sequence[tuple[int, int]] = DEFAULT_BRICKS,
    source: str = "<voxels>",
    repair: bool = True,
) -> Layout:
    """Cover the occupied cells of ``vox`` (X, Y, Z) bool exactly with bricks.

    Greedy, layer by layer from the bottom, brick types largest first
    (``bricks``: footprints or a set name, see :func:`parse_bricks`; must
    contain 1x1 and be Table I sizes). Within a type, windows are taken by priority:
    anchored windows (at least one cell with support below) that cover the
    most unsupported cells first (each weighted by its distance to the
    nearest supported cell), then the layer's preferred orientation
    (even layers: long axis along x, odd: along y), then windows that span a
    joint of the layer below, then scan order. Windows with no support at all
    come last. ``seed`` only flips the scan direction per layer (tie-break).
    With ``repair`` (default) a second pass re-merges the same-layer
    neighbourhood of every brick the greedy pass left floating (no chain of
    knob connections to the ground) so that it reaches a cell held by a
    grounded brick, when that lowers the number of floating bricks. Bricks
    that remain floating have no such cell within reach (e.g. a one-layer
    lid over a wide cavity).
    Returns a Layout with keys "1".."n", Table I masses and library ids.
    """
    vox = np.asarray(vox).astype(bool)
    if vox.ndim != 3:
        raise ValueError(f"vox must be a 3-D (X, Y, Z) array, got shape {vox.shape}")
    if not vox.any():
        raise ValueError("vox has no occupied cell")
    types = list(parse_bricks(bricks))
    X, Y, Z = vox.shape
    R = X * Y + 1  # rank range: scan order tie-break below any structural step
    rng = np.random.default_rng(seed)
    ids = -np.ones((X, Y, Z), np.int32)
    out_pos: list[tuple[int, int, int]] = []
    out_size: list[tuple[int, int]] = []

    for z in range(Z):
        free = vox[:, :, z].copy()
        if not free.any():
            continue
        sup = vox[:, :, z - 1] if z > 0 else np.ones((X, Y), bool)
        unsup = free & ~sup
        # weight of an unsupported cell: taxicab distance to the nearest
        # supported cell of the layer (far cells are the hard ones to hold)
        held = free & sup
        if held.any() and unsup.any():
            far = ndimage.distance_transform_cdt(~held, metric="taxicab")
            far = np.where(unsup, far, 0)
        else:
            far = unsup.astype(np.int64)
        below = ids[:, :, z - 1] if z > 0 else -np.ones((X, Y), np.int32)
        flip_x, flip_y = rng.integers(0, 2, size=2).astype(bool)
        long_x = z % 2 == 0
        for a, b in types:
            orients = [(b, a), (a, b)] if long_x else [(a, b), (b, a)]
            if a == b:
                orients = orients[:1]
            cand = []  # per orientation: (sx, sy, key array)
            for k, (sx, sy) in enumerate(orients):
                if sx > X or sy > Y:
                    continue
                valid = _wsum(free, sx, sy) == sx * sy
                if not valid.any():
                    continue
                n_sup = _wsum(free & sup, sx, sy)
                n_uns = _wsum(far, sx, sy)
                jn = _joint_count(below, sx, sy, valid.shape) > 0
                pref = 1 if k == 0 else 0
                struct = np.where(n_sup > 0, 1 + 4 * n_uns + 2 * pref + jn, 0)
                gx = np.arange(valid.shape[0])
                gy = np.arange(valid.shape[1])
                if flip_x:
                    gx = gx[::-1]
                if flip_y:
                    gy = gy[::-1]
                # rows along the brick's long axis
                if sx >= sy:
                    rank = gy[None, :] * valid.shape[0] + gx[:, None]
                else:
                    rank = gx[:, None] * valid.shape[1] + gy[None, :]
                key = struct.astype(np.int64) * R + (R - 1 - rank)
                key[~valid] = -1
                cand.append([sx, sy, key])
            if not cand:
                continue
            while True:
                best, bk, bi = -1, None, None
                for c in cand:
                    i = int(np.argmax(c[2]))
                    v = int(c[2].flat[i])
                    if v > best:
                        best, bk, bi = v, c, i
                if best < 0:
                    break
                sx, sy = bk[0], bk[1]
                px, py = np.unravel_index(bi, bk[2].shape)
                px, py = int(px), int(py)
                ids[px:px + sx, py:py + sy, z] = len(out_pos)
                free[px:px + sx, py:py + sy] = False
                out_pos.append((px, py, z))
                out_size.append((sx, sy))
                for c in cand:  # windows overlapping the new brick become invalid
                    csx, csy, key = c
                    x0, y0 = max(px - csx + 1, 0), max(py - csy + 1, 0)
                    key[x0:px + sx, y0:py + sy] = -1
        if free.any():  # cannot happen with (1, 1) in bricks
            raise AssertionError("merge_voxels left cells uncovered")
    if repair:
        out_pos, out_size = _repair_floating(vox, ids, out_pos, out_size, types)
    return brick_layout(out_pos, out_size, source=source)


# --------------------------------------------------------------------------
# repair: re-merge around bricks that the greedy pass left floating


def _floating(ids: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: bricks with no chain of knob connections to layer 0.
    ``ids``: (X, Y, Z) brick index per cell, -1 empty."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    lo, hi = ids[:, :, :-1], ids[:, :, 1:]
    m = (lo >= 0) & (hi >= 0) & (lo != hi)
    ground = n  # an extra node for the baseplate
    base = np.unique(ids[:, :, 0][ids[:, :, 0] >= 0])
    a = np.concatenate([lo[m], base])
    b = np.concatenate([hi[m], np.full(len(base), ground)])
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(n + 1, n + 1))
    _, lab = connected_components(g, directed=False)
    return lab[:n] != lab[ground]


def floating_bricks(layout: Layout) -> np.ndarray:
    """(n,) bool: bricks of ``layout`` with no chain of knob connections
    down to the baseplate (they cannot be balanced)."""
    return _floating(layout.occupancy(), layout.n)


def _cover_region(region: np.ndarray, must: np.ndarray, anchor: np.ndarray, types,
                  budget: int = 4000) -> list | None:
    """Bricks (x, y, sx, sy) covering the cells of the 2-D ``region`` exactly,
    every ``must`` cell in a brick that also covers an ``anchor`` cell.

    A depth-first search: the first uncovered ``must`` cell (scan order) is
    covered by a window (any type and orientation, inside the free region)
    that holds it and at least one free ``anchor`` cell, tried in the order
    most ``must`` cells, then largest; on a dead end the next window
    (backtracking, at most ``budget`` windows tried). Once every ``must``
    cell is covered, the rest is filled largest first. None if no cover
    was found."""
    X, Y = region.shape
    shapes = []
    for a, b in types:
        for sx, sy in ((a, b), (b, a)) if a != b else ((a, b),):
            if sx <= X and sy <= Y:
                shapes.append((sx, sy))
    tried = [0]

    def fill_rest(free, out):
        for sx, sy in shapes:
            while True:
                ok = _wsum(free, sx, sy) == sx * sy
                if not ok.any():
                    break
                x, y = (int(v) for v in np.unravel_index(int(np.argmax(ok)), ok.shape))
                free[x:x + sx, y:y + sy] = False
                out.append((x, y, sx, sy))
        return out if not free.any() else None

    def search(free, out):
        left = must & free
        if not left.any():
            return fill_rest(free, out)  # both are this call's own (copied by the caller)
        cx, cy = (int(v) for v in np.argwhere(left)[0])
        options = []
        for sx, sy in shapes:
            for x in range(max(cx - sx + 1, 0), min(cx, X - sx) + 1):
                for y in range(max(cy - sy + 1, 0), min(cy, Y - sy) + 1):
                    win = (slice(x, x + sx), slice(y, y + sy))
                    if free[win].all() and anchor[win].any():
                        options.append((-int(left[win].sum()), -sx * sy, x, y, sx, sy))
        for _, _, x, y, sx, sy in sorted(options):
            tried[0] += 1
            if tried[0] > budget:
                return None
            nxt = free.copy()
            nxt[x:x + sx, y:y + sy] = False
            got = search(nxt, out + [(x, y, sx, sy)])
            if got is not None:
                return got
        return None

    return search(region.copy(), [])


def _repair_floating(vox, ids, pos, size, types, max_rounds: int = 4):
    """Re-merge the neighbourhood of every floating brick so that it reaches
    a cell held by a grounded brick (the cell under or over it belongs to
    one). The floating brick and its same-layer neighbours are re-covered
    (:func:`_cover_region`: the floating cells anchored; failing that, every
    cell that holds nothing itself anchored too); a change is kept only if
    the number of floating bricks drops. Deterministic."""
    pos, size = list(pos), list(size)
    ids = ids.copy()
    X, Y, Z = vox.shape
    cross = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], bool)

    def n_floating(grid, alive):
        return int((_floating(grid, len(alive)) & alive).sum())

    for _ in range(max_rounds):
        alive = np.array([p is not None for p in pos])
        fl = _floating(ids, len(pos)) & alive
        if not fl.any():
            break
        improved = False
        for i in np.nonzero(fl)[0].tolist():
            if pos[i] is None:
                continue
            alive = np.array([p is not None for p in pos])
            cur = _floating(ids, len(pos)) & alive
            if not cur[i]:
                continue  # an earlier repair of this round anchored it already
            z = pos[i][2]
            layer = ids[:, :, z]
            grow = ndimage.binary_dilation(layer == i, structure=cross)
            group = sorted(set(layer[grow & (layer >= 0)].tolist()))
            if len(group) < 2:
                continue  # nothing beside it to merge with
            region = np.isin(layer, group)
            held = np.zeros((X, Y), bool)
            if z == 0:
                held[:] = True
            for dz in (-1, 1):
                if 0 <= z + dz < Z:
                    nb = ids[:, :, z + dz]
                    held |= (nb >= 0) & ~cur[np.maximum(nb, 0)]
            # first the floating bricks' cells must reach a held cell; if that
            # plan leaves as many floating (a new brick on no held cell), every
            # cell of the region that holds nothing itself must
            flo = region & np.isin(layer, [g for g in group if cur[g]])
            wider = flo | (region & ~held)
            found = None
            for must in (flo, wider) if (wider != flo).any() else (flo,):
                plan = _cover_region(region, must, region & held, types)
                if plan is None:
                    continue
                slots = list(group) + list(range(len(pos), len(pos) + max(len(plan) - len(group), 0)))
                trial = ids.copy()
                tl = trial[:, :, z]
                tl[region] = -1
                t_alive = np.concatenate([alive, np.ones(len(slots) - len(group), bool)])
                for k in group[len(plan):]:
                    t_alive[k] = False
                for (bx, by, sx, sy), k in zip(plan, slots):
                    tl[bx:bx + sx, by:by + sy] = k
                if n_floating(trial, t_alive) < int(cur.sum()):
                    found = plan, slots, trial
                    break
            if found is None:
                continue
            plan, slots, trial = found
            pos.extend([None] * (len(slots) - len(group)))
            size.extend([None] * (len(slots) - len(group)))
            for k in group:
                pos[k] = size[k] = None
            for (bx, by, sx, sy), k in zip(plan, slots):
                pos[k], size[k] = (bx, by, z), (sx, sy)
            ids = trial
            improved = True
        if not improved:
            break
    keep = sorted((k for k in range(len(pos)) if pos[k] is not None), key=lambda k: (pos[k][2], k))
    return [pos[k] for k in keep], [size[k] for k in keep]


# --------------------------------------------------------------------------
# shapes


def ground(vox: np.ndarray, keep: str = "grounded") -> np.ndarray:
    """Drop a (X, Y, Z) bool shape onto z = 0 and filter its parts.

    ``keep="grounded"`` keeps only face-connected parts that touch layer 0;
    ``"all"`` keeps everything (floating parts stay where they are).
    """
    vox = np.asarray(vox, bool)
    if not vox.any():
        return vox.copy()
    zs = np.nonzero(vox.any(axis=(0, 1)))[0]
    out = np.zeros_like(vox)
    out[:, :, : vox.shape[2] - zs[0]] = vox[:, :, zs[0]:]
    if keep == "grounded":
        lab, _ = ndimage.label(out)
        touching = np.unique(lab[:, :, 0])
        out = np.isin(lab, touching[touching > 0])
    return out


def random_blob(grid: int = 20, seed: int = 0, fill: float = 0.25, smooth: float | None = None) -> np.ndarray:
    """Smoothed-noise blob, (grid, grid, grid) bool, resting on z = 0.

    ``fill`` is the fraction of cells above the noise threshold; only the
    largest face-connected part is kept and dropped onto the ground, so the
    blob holds at most that fraction. ``smooth``: noise correlation length in
    cells (default grid / 6).
    """
    rng = np.random.default_rng(seed)
    smooth = grid / 6.0 if smooth is None else smooth
    f = ndimage.gaussian_filter(rng.standard_normal((grid, grid, grid)), smooth, mode="constant")
    c = (np.arange(grid) - (grid - 1) / 2.0) / (grid / 2.0)
    r2 = c[:, None, None] ** 2 + c[None, :, None] ** 2 + c[None, None, :] ** 2
    f = f / (f.std() + 1e-12) - 0.8 * r2  # fade out towards the box faces
    thr = np.quantile(f, 1.0 - fill)
    lab, n = ndimage.label(f > thr)
    if n == 0:
        return np.zeros((grid,) * 3, bool)
    largest = 1 + int(np.argmax(np.bincount(lab.ravel())[1:]))
    return ground(lab == largest)


def _box(v, x0, y0, z0, x1, y1, z1):
    v[max(x0, 0):x1, max(y0, 0):y1, max(z0, 0):z1] = True


def random_voxel_shape(seed: int = 0, grid: int = 20, kind: str | None = None) -> np.ndarray:
    """Random (grid, grid, grid) bool shape of a given ``kind`` (see SHAPE_KINDS).

    ``kind=None`` draws one. "boxes": stacked random boxes (overhangs where a
    box sticks out); "spheres": union of balls; "arch": block with an arched
    opening; "overhang": stem with a wide cap or a side arm; "floating": a
    grounded shape plus a part hovering above an empty layer; "blob": smooth
    noise. All but "floating" keep only parts touching z = 0.
    """
    rng = np.random.default_rng(seed)
    if kind is None:
        kind = SHAPE_KINDS[int(rng.integers(len(SHAPE_KINDS)))]
    g = int(grid)
    if g < 6:
        raise ValueError("grid must be at least 6")
    v = np.zeros((g, g, g), bool)
    ri = lambda lo, hi: int(rng.integers(lo, max(hi, lo + 1)))  # noqa: E731

    if kind == "blob":
        return random_blob(g, int(rng.integers(2**31)), fill=float(rng.uniform(0.12, 0.3)))
    if kind == "boxes":
        hmap = np.zeros((g, g), np.int64)
        for _ in range(ri(2, 6)):
            sx, sy, sz = ri(2, g // 2 + 1), ri(2, g // 2 + 1), ri(1, g // 3 + 1)
            x0, y0 = ri(0, g - sx + 1), ri(0, g - sy + 1)
            z0 = int(hmap[x0:x0 + sx, y0:y0 + sy].max())
            if z0 + sz > g:
                continue
            _box(v, x0, y0, z0, x0 + sx, y0 + sy, z0 + sz)
            hmap[x0:x0 + sx, y0:y0 + sy] = z0 + sz
        return ground(v)
    if kind == "spheres":
        x, y, z = np.meshgrid(*(np.arange(g),) * 3, indexing="ij")
        for _ in range(ri(1, 5)):
            r = rng.uniform(1.5, g / 3.0)
            c = rng.uniform(r, g - r, size=3)
            c[2] = rng.uniform(r * 0.5, min(g - r, 2.5 * r))
            v |= (x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2 <= r * r
        return ground(v)
    if kind == "arch":
        w, d, h = ri(6, g + 1), ri(1, min(g, 6) + 1), ri(4, g + 1)
        x0, y0 = ri(0, g - w + 1), ri(0, g - d + 1)
        _box(v, x0, y0, 0, x0 + w, y0 + d, h)
        half = rng.uniform(1.5, (w - 2) / 2.0)  # half width of the opening
        top = rng.uniform(1.0, h - 1.0)  # opening height at its middle
        xc = x0 + w / 2.0 - 0.5
        xs = np.arange(g)[:, None]
        zs = np.arange(g)[None, :]
        hole = ((xs - xc) / half) ** 2 + (zs / top) ** 2 <= 1.0
        v[:, y0:y0 + d, :] &= ~hole[:, None, :]
        return ground(v)
    if kind == "overhang":
        sx, sy, sz = ri(1, 4), ri(1, 4), ri(1, g // 2)
        x0, y0 = ri(0, g - sx + 1), ri(0, g - sy + 1)
        _box(v, x0, y0, 0, x0 + sx, y0 + sy, sz)
        cz = ri(1, 3)
        if rng.random() < 0.5:  # mushroom cap centred-ish on the stem
            cx, cy = ri(sx, g + 1), ri(sy, g + 1)
            ax = int(np.clip(x0 - ri(0, cx - sx + 1), 0, g - cx))
            ay = int(np.clip(y0 - ri(0, cy - sy + 1), 0, g - cy))
            _box(v, ax, ay, sz, ax + cx, ay + cy, min(sz + cz, g))
        else:  # side arm (cantilever) along x
            length = ri(3, g)
            if x0 + length <= g:
                _box(v, x0, y0, sz, x0 + length, y0 + sy, min(sz + cz, g))
            else:
                _box(v, max(x0 + sx - length, 0), y0, sz, x0 + sx, y0 + sy, min(sz + cz, g))
        return ground(v)
    if kind == "floating":
        base = random_voxel_shape(int(rng.integers(2**31)), g, "boxes")
        zs = np.nonzero(base.any(axis=(0, 1)))[0]
        top = int(zs[-1]) + 1 if zs.size else 0
        z0 = min(top + 1, g - 1)  # at least one empty layer in between
        if z0 <= top:  # base reaches the top: shrink it to make room
            base[:, :, g - 2:] = False
            base = ground(base)
            z0 = g - 1
        sx, sy, sz = ri(1, g // 3 + 1), ri(1, g // 3 + 1), ri(1, max(g - z0, 1) + 1)
        x0, y0 = ri(0, g - sx + 1), ri(0, g - sy + 1)
        v = base.copy()
        _box(v, x0, y0, z0, x0 + sx, y0 + sy, min(z0 + sz, g))
        return v
    raise ValueError(f"unknown shape kind {kind!r}; expected one of {SHAPE_KINDS}")
