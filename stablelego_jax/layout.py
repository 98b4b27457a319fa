"""Brick layouts: the validated, format-independent input of the analysis.

A :class:`Layout` holds ``n`` bricks as flat numpy arrays. Brick ``i`` occupies
cells ``[x, x+sx) x [y, y+sy) x {z}`` of the stud grid (``sx`` studs along x,
``sy`` along y, one layer high); layer 0 stands on the baseplate. Keys are the
brick names exactly as the input gave them (strings).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
from typing import Mapping, Sequence

import numpy as np

__all__ = [
    "LayoutError",
    "Library",
    "Layout",
    "default_library",
    "TABLE_I_MASS_KG",
    "make_layout",
    "MAX_COORD",
    "MAX_SIZE",
    "MAX_GRID_CELLS",
    "layout_voxels",
    "cells_of",
    "cell_owner",
    "library_id_for",
    "table_i_bricks",
    "brick_layout",
    "cut",
]

# Paper Table I, in kg, keyed by the sorted (short, long) footprint.
TABLE_I_MASS_KG: dict[tuple[int, int], float] = {
    (1, 1): 0.43e-3,
    (1, 2): 0.81e-3,
    (1, 4): 1.57e-3,
    (1, 6): 2.28e-3,
    (1, 8): 3.03e-3,
    (2, 2): 1.15e-3,
    (2, 4): 2.16e-3,
    (2, 6): 3.23e-3,
}

# Input bounds: a cell coordinate may be at most MAX_COORD and a brick at most
# MAX_SIZE studs long; the dense occupancy grid may have at most MAX_GRID_CELLS
# cells (1 GiB of int32). They keep a typo or a hostile file from asking for a
# giant allocation.
MAX_COORD = 2**16
MAX_SIZE = 64
MAX_GRID_CELLS = 2**28

_DEFAULT_LIBRARY_PATH = os.path.join(os.path.dirname(__file__), "lego_library.json")


class LayoutError(ValueError):
    """Bad input. The message names the source (file) and the brick (or the
    body ``what`` names: "block", ...) at fault."""

    def __init__(self, source: str, message: str, key: str | None = None, what: str = "brick"):
        self.source = source
        self.key = key
        self.message = message
        self.what = what
        where = f"{source}: {what} {key!r}: " if key is not None else f"{source}: "
        super().__init__(where + message)


@dataclasses.dataclass(frozen=True)
class Library:
    """Brick library: id -> (height, width, mass in kg).

    ``height`` is the extent along x and ``width`` along y when ``ori == 0``;
    ``ori == 1`` swaps them (StableLego convention).
    """

    bricks: Mapping[str, tuple[int, int, float]]
    source: str = "<library>"

    @classmethod
    def from_json(cls, path: str) -> "Library":
        """The library of a JSON file (the bundled default; user files are
        read through :func:`~stablelego_jax.formats.stablelego.as_library`,
        which refuses non-regular files)."""
        try:
            with open(path, "rb") as fh:
                data = fh.read()
        except OSError as exc:
            raise LayoutError(path, f"cannot read brick library: {exc.strerror}") from None
        return cls.from_text(data, source=path)

    @classmethod
    def from_text(cls, data, source: str = "<library>") -> "Library":
        """The library of JSON text (str or bytes); LayoutError naming ``source``."""
        try:
            text = data.decode("utf-8") if isinstance(data, bytes) else data
            raw = json.loads(text)
        except UnicodeDecodeError:
            raise LayoutError(source, "brick library is not UTF-8 text") from None
        except json.JSONDecodeError as exc:
            raise LayoutError(source, f"brick library is not valid JSON: {exc}") from None
        except (ValueError, RecursionError) as exc:
            raise LayoutError(source, f"brick library is not valid JSON: {str(exc)[:80]}") from None
        return cls.from_dict(raw, source=source)

    @classmethod
    def from_dict(cls, raw: Mapping, source: str = "<library>") -> "Library":
        if not isinstance(raw, Mapping) or not raw:
            raise LayoutError(source, "brick library must be a non-empty JSON object")
        bricks: dict[str, tuple[int, int, float]] = {}
        for bid, entry in raw.items():
            if not isinstance(entry, Mapping):
                raise LayoutError(source, f"library entry {bid!r} is not an object")
            missing = [f for f in ("height", "width", "mass") if f not in entry]
            if missing:
                raise LayoutError(source, f"library entry {bid!r} lacks {', '.join(missing)}")
            h, w, m = entry["height"], entry["width"], entry["mass"]
            if not (_is_int(h) and _is_int(w) and h >= 1 and w >= 1):
                raise LayoutError(source, f"library entry {bid!r} has a bad size {cut(str(h))}x{cut(str(w))}")
            if h > MAX_SIZE or w > MAX_SIZE:
                raise LayoutError(source, f"library entry {bid!r}: size {h}x{w} too large "
                                          f"(at most {MAX_SIZE} studs)")
            if not _is_number(m) or not math.isfinite(m) or m < 0:
                raise LayoutError(source, f"library entry {bid!r} has a bad mass {cut(repr(m))}")
            bricks[str(bid)] = (int(h), int(w), float(m))
        return cls(bricks=bricks, source=source)


_DEFAULT_LIBRARY: Library | None = None


def default_library() -> Library:
    """The StableLego library (ids 2-12 real bricks, id 1 a 200 g load block)."""
    global _DEFAULT_LIBRARY
    if _DEFAULT_LIBRARY is None:
        _DEFAULT_LIBRARY = Library.from_json(_DEFAULT_LIBRARY_PATH)
    return _DEFAULT_LIBRARY


def library_id_for(sx: int, sy: int) -> tuple[str, int]:
    """StableLego library id and ori of the real brick with extent (sx, sy)
    in the default library; ("", 0) when it has none."""
    for bid, (h, w, _) in default_library().bricks.items():
        if bid == "1":  # the 200 g load block, not a real brick
            continue
        if (h, w) == (sx, sy):
            return bid, 0
        if (w, h) == (sx, sy):
            return bid, 1
    return "", 0


def table_i_bricks(size) -> tuple[np.ndarray, tuple[str, ...], np.ndarray]:
    """Masses (kg), library ids and ori of real bricks of extents ``size``
    ((k, 2) studs along x and y), from paper Table I and the default
    library. Raises ValueError naming a footprint that is not a Table I brick."""
    size = np.asarray(size, np.int64).reshape(-1, 2)
    mass, bids, oris = [], [], []
    for sx, sy in size.tolist():
        key = (min(sx, sy), max(sx, sy))
        if key not in TABLE_I_MASS_KG:
            raise ValueError(f"{sx}x{sy} is not a Table I brick")
        bid, ori = library_id_for(sx, sy)
        mass.append(TABLE_I_MASS_KG[key])
        bids.append(bid)
        oris.append(ori)
    return np.asarray(mass, np.float64), tuple(bids), np.asarray(oris, np.int64)


def brick_layout(pos, size, keys: Sequence[str] | None = None, source: str = "<memory>",
                 fmt: str = "memory") -> "Layout":
    """The one builder of layouts of real bricks from positions and sizes:
    ``pos`` (k, 3) corner cells, ``size`` (k, 2) extents; masses, library ids
    and ori from Table I and the default library; keys "1".."k" unless given.
    LayoutError (naming ``source``) on a footprint that is not a Table I
    brick, or any :func:`make_layout` check."""
    pos = np.asarray(pos, np.int64).reshape(-1, 3)
    size = np.asarray(size, np.int64).reshape(-1, 2)
    try:
        mass, bids, oris = table_i_bricks(size)
    except ValueError as exc:
        raise LayoutError(source, str(exc)) from None
    keys = [str(i + 1) for i in range(len(pos))] if keys is None else list(keys)
    return make_layout(keys, pos, size, mass, bids, oris, source=source, fmt=fmt)


@dataclasses.dataclass(frozen=True, eq=False)
class Layout:
    """A validated brick layout.

    Attributes:
      keys: (n,) brick names as given by the input, in input order.
      pos: (n, 3) int64 corner cell (x, y, z) with the smallest coordinates.
      size: (n, 2) int64 extent (sx along x, sy along y) in studs.
      mass: (n,) float64 brick mass in kg (extra loads included).
      brick_id: (n,) library ids as strings ("" when the input had none).
      ori: (n,) int64 StableLego orientation (0: height along x, 1: along y).
      source: file the layout came from ("<memory>" otherwise).
      fmt: input format ("json", "text", "dataset", "ldr", "memory").
    """

    keys: tuple[str, ...]
    pos: np.ndarray
    size: np.ndarray
    mass: np.ndarray
    brick_id: tuple[str, ...]
    ori: np.ndarray
    source: str = "<memory>"
    fmt: str = "memory"

    @property
    def n(self) -> int:
        return len(self.keys)

    def occupancy(self) -> np.ndarray:
        """(X, Y, Z) int32 grid: index of the brick in each cell, -1 where empty."""
        return _occupancy(self.pos, self.size, self.source, self.keys)

    def subset(self, idx: Sequence[int]) -> "Layout":
        idx = np.asarray(idx, dtype=np.int64)
        return dataclasses.replace(
            self,
            keys=tuple(self.keys[i] for i in idx),
            pos=self.pos[idx],
            size=self.size[idx],
            mass=self.mass[idx],
            brick_id=tuple(self.brick_id[i] for i in idx),
            ori=self.ori[idx],
        )


def make_layout(
    keys: Sequence[str],
    pos,
    size,
    mass,
    brick_id: Sequence[str] | None = None,
    ori=None,
    source: str = "<memory>",
    fmt: str = "memory",
) -> Layout:
    """Build and validate a :class:`Layout` from plain arrays.

    Raises LayoutError (naming ``source`` and the brick) on empty layouts,
    duplicate keys, arrays of the wrong shape, non-integer, negative or too
    large (> MAX_COORD) cells, bad or too large (> MAX_SIZE) sizes, NaN or
    negative masses, ori values other than 0/1, and overlapping bricks.
    """
    keys = tuple(str(k) for k in keys)
    n = len(keys)
    if n == 0:
        raise LayoutError(source, "layout is empty (no bricks)")
    if len(set(keys)) != n:
        dup = next(k for k in keys if keys.count(k) > 1)
        raise LayoutError(source, "duplicate brick key", dup)
    pos_f = _as_float_array(pos, (n, 3), "coordinates", source)
    size_f = _as_float_array(size, (n, 2), "sizes", source)
    mass = _as_float_array(mass, (n,), "masses", source)
    for arr, what in ((pos_f, "coordinates"), (size_f, "size")):
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(arr).all(axis=1) | (arr != np.round(arr)).any(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise LayoutError(source, f"non-integer {what} {arr[i].tolist()}", keys[i])
    bad = (pos_f < 0).any(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise LayoutError(source, f"negative coordinates {pos_f[i].astype(int).tolist()}", keys[i])
    bad = (pos_f > MAX_COORD).any(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise LayoutError(
            source, f"coordinates {[int(v) for v in pos_f[i]]} too large (at most {MAX_COORD})", keys[i]
        )
    bad = (size_f < 1).any(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise LayoutError(source, f"bad brick size {size_f[i].astype(int).tolist()}", keys[i])
    bad = (size_f > MAX_SIZE).any(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise LayoutError(
            source, f"brick size {[int(v) for v in size_f[i]]} too large (at most {MAX_SIZE} studs)", keys[i]
        )
    bad = ~np.isfinite(mass) | (mass < 0)
    if bad.any():
        i = int(np.argmax(bad))
        raise LayoutError(source, f"mass must be a finite number >= 0, got {mass[i]}", keys[i])
    if brick_id is None:
        brick_id = ("",) * n
    elif isinstance(brick_id, str) or len(brick_id) != n:
        got = "a string" if isinstance(brick_id, str) else f"{len(brick_id)} ids"
        raise LayoutError(source, f"brick_id must hold one id per brick ({n}), got {got}")
    if ori is None:
        ori_arr = np.zeros(n, np.int64)
    else:
        ori_f = _as_float_array(ori, (n,), "ori values", source)
        bad = (ori_f != 0) & (ori_f != 1)
        if bad.any():
            i = int(np.argmax(bad))
            raise LayoutError(source, f"ori must be 0 or 1, got {ori_f[i]:g}", keys[i])
        ori_arr = ori_f.astype(np.int64)
    pos_i = pos_f.astype(np.int64)
    size_i = size_f.astype(np.int64)
    _check_overlap(pos_i, size_i, source, keys)
    return Layout(
        keys=keys,
        pos=pos_i,
        size=size_i,
        mass=mass,
        brick_id=tuple(str(b) for b in brick_id),
        ori=ori_arr,
        source=source,
        fmt=fmt,
    )


def _as_float_array(values, shape: tuple[int, ...], what: str, source: str) -> np.ndarray:
    """``values`` as a float64 array of ``shape``; LayoutError on junk or a wrong shape."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise LayoutError(source, f"{what} are not numbers: {exc}") from None
    if arr.size != int(np.prod(shape)):
        raise LayoutError(source, f"{what} must have shape {shape}, got {arr.shape}")
    return arr.reshape(shape)


def _grid_dims(pos: np.ndarray, size: np.ndarray) -> list[int]:
    return [int(v) for v in (pos[:, :2] + size).max(axis=0)] + [int(pos[:, 2].max()) + 1]


def _check_overlap(pos: np.ndarray, size: np.ndarray, source: str, keys) -> tuple:
    """Raise LayoutError on the first overlap, without a dense grid.

    Returns (dims, flat cell index, owner) for :func:`_occupancy`.
    """
    cells, owner = cells_of(pos, size)
    dims = _grid_dims(pos, size)
    flat = np.ravel_multi_index(cells.T, dims)
    order = np.argsort(flat, kind="stable")
    sf = flat[order]
    dup = np.nonzero(sf[1:] == sf[:-1])[0]
    if dup.size:
        a, b = owner[order[dup[0]]], owner[order[dup[0] + 1]]
        c = np.unravel_index(sf[dup[0]], dims)
        raise LayoutError(
            source,
            f"overlaps brick {keys[a]!r} at cell {tuple(int(v) for v in c)}",
            keys[b],
        )
    return dims, flat, owner


def cell_owner(layout: "Layout"):
    """Sparse occupancy of ``layout``: ``lookup(cells)`` ((k, 3) int cells,
    any coordinates) gives the index of the brick in each cell, -1 where
    empty. Memory grows with the bricks' cells, not with the bounding box,
    so bricks far apart (coordinates up to MAX_COORD) cost nothing extra."""
    pos, size = layout.pos, layout.size
    dims, flat, owner = _check_overlap(pos, size, layout.source, layout.keys)
    order = np.argsort(flat, kind="stable")
    keys, own = flat[order], owner[order]
    hi = np.asarray(dims)

    def lookup(cells) -> np.ndarray:
        q = np.asarray(cells, np.int64).reshape(-1, 3)
        out = np.full(len(q), -1, np.int64)
        inside = (q >= 0).all(axis=1) & (q < hi).all(axis=1)
        f = np.ravel_multi_index(q[inside].T, dims)
        j = np.minimum(np.searchsorted(keys, f), len(keys) - 1)
        out[inside] = np.where(keys[j] == f, own[j], -1)
        return out

    return lookup


def _occupancy(pos: np.ndarray, size: np.ndarray, source: str, keys) -> np.ndarray:
    """Dense (X, Y, Z) grid of brick indices; raises LayoutError on overlap or a huge grid."""
    dims = _grid_dims(pos, size)
    cells = int(np.prod(dims, dtype=np.float64))
    if cells > MAX_GRID_CELLS:
        raise LayoutError(
            source,
            f"layout spans a {dims[0]}x{dims[1]}x{dims[2]} grid ({cells} cells, at most {MAX_GRID_CELLS})",
        )
    dims, flat, owner = _check_overlap(pos, size, source, keys)
    grid = -np.ones(dims, dtype=np.int32)
    grid.reshape(-1)[flat] = owner
    return grid


def cells_of(pos: np.ndarray, size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All stud cells of all bricks, vectorised.

    Returns (cells (c, 3) int64, owner (c,) int64 brick index).
    """
    area = size[:, 0] * size[:, 1]
    owner = np.repeat(np.arange(len(pos)), area)
    start = np.cumsum(area) - area
    local = np.arange(int(area.sum())) - np.repeat(start, area)
    sy = size[owner, 1]
    dx, dy = local // sy, local % sy
    cells = np.stack([pos[owner, 0] + dx, pos[owner, 1] + dy, pos[owner, 2]], axis=1)
    return cells, owner


def cut(s: str, limit: int = 40) -> str:
    """``s`` cut to ``limit`` characters (keeps error messages readable)."""
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def layout_voxels(layout: Layout, shape: Sequence[int] | None = None) -> np.ndarray:
    """(X, Y, Z) bool occupancy of ``layout``; ``shape`` at least its extent
    (default exactly its extent). Raises LayoutError if a brick lies outside
    ``shape``."""
    occ = layout.occupancy() >= 0
    if shape is None:
        return occ
    shape = tuple(int(s) for s in shape)
    if len(shape) != 3 or any(o > s for o, s in zip(occ.shape, shape)):
        raise LayoutError(layout.source, f"bricks span a {'x'.join(map(str, occ.shape))} grid, "
                                         f"larger than the voxel grid {'x'.join(map(str, shape))}")
    out = np.zeros(shape, bool)
    out[: occ.shape[0], : occ.shape[1], : occ.shape[2]] = occ
    return out
