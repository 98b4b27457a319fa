"""StableLego JSON and the text layouts of LLM brick generators.

StableLego JSON: ``{"key": {"x","y","z","brick_id","ori"}}`` with a brick
library (ids -> height, width, mass). Text: ``HxW (x,y,z)`` one brick a
line (H studs along x, W along y; keys are line numbers). Every parser
returns a validated :class:`~stablelego_jax.layout.Layout` or raises
:class:`~stablelego_jax.layout.LayoutError` naming the source and brick.
"""
from __future__ import annotations

import json
import math
import re
from typing import Mapping

from ..files import cut, read_bytes, read_text
from ..layout import (
    MAX_COORD,
    TABLE_I_MASS_KG,
    Layout,
    LayoutError,
    Library,
    brick_layout,
    default_library,
    library_id_for,
    make_layout,
)

__all__ = [
    "TEXT_LINE",
    "as_library",
    "read_json",
    "parse_json_layout",
    "parse_text_layout",
    "layout_to_json_dict",
    "layout_to_text",
]

#: One brick of a text layout: ``HxW (x,y,z)``.
TEXT_LINE = re.compile(r"^\s*(\d+)\s*x\s*(\d+)\s*\(\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*\)\s*$")
_FIELDS = ("x", "y", "z", "brick_id", "ori")


def parse_json_layout(raw, library: Library | None = None, source: str = "<memory>") -> Layout:
    """StableLego JSON object -> Layout (keys kept as given, order kept)."""
    lib = library or default_library()
    if not isinstance(raw, Mapping):
        raise LayoutError(source, "layout must be a JSON object of bricks")
    if not raw:
        raise LayoutError(source, "layout is empty (no bricks)")
    keys, pos, size, mass, bids, oris = [], [], [], [], [], []
    for key, b in raw.items():
        if not isinstance(b, Mapping):
            raise LayoutError(source, "brick entry is not an object", key)
        missing = [f for f in _FIELDS if f not in b]
        if missing:
            raise LayoutError(source, f"missing field(s) {', '.join(missing)}", key)
        xyz = []
        for f in ("x", "y", "z"):
            v = b[f]
            if not _is_json_number(v) or (isinstance(v, float) and (not math.isfinite(v) or v != int(v))):
                raise LayoutError(source, f"coordinate {f}={_short(v)} is not an integer", key)
            if v < 0:
                raise LayoutError(source, f"coordinate {f}={_short(v)} is negative", key)
            if v > MAX_COORD:
                raise LayoutError(source, f"coordinate {f}={_short(v)} is too large (at most {MAX_COORD})", key)
            xyz.append(int(v))
        bid = str(b["brick_id"])
        if bid not in lib.bricks:
            raise LayoutError(source, f"unknown brick_id {b['brick_id']!r} (not in {lib.source})", key)
        ori = b["ori"]
        if ori not in (0, 1) or isinstance(ori, bool):
            raise LayoutError(source, f"ori must be 0 or 1, got {ori!r}", key)
        h, w, m = lib.bricks[bid]
        extra = b.get("mass")  # optional per-brick override (external loads)
        if extra is not None:
            if not _is_json_number(extra) or not _finite(extra) or extra < 0:
                raise LayoutError(source, f"mass must be a finite number >= 0, got {_short(extra)}", key)
            m = float(extra)
        keys.append(str(key))
        pos.append(xyz)
        size.append((h, w) if ori == 0 else (w, h))
        mass.append(m)
        bids.append(bid)
        oris.append(int(ori))
    return make_layout(keys, pos, size, mass, bids, oris, source=source, fmt="json")


def parse_text_layout(text: str, source: str = "<memory>") -> Layout:
    """Text layout (``HxW (x,y,z)`` per line) -> Layout; keys are line numbers."""
    keys, pos, size = [], [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        key = str(lineno)
        m = TEXT_LINE.match(s)
        if not m:
            raise LayoutError(source, f"line {lineno}: cannot parse {_short(s, 80)} (expected 'HxW (x,y,z)')", key)
        if max(len(g.lstrip("0")) for g in m.group(1, 2)) > 4:  # no library brick is that long
            raise LayoutError(source, f"line {lineno}: {cut(m.group(1))}x{cut(m.group(2))} "
                                      "is not a library brick", key)
        h, w = int(m.group(1)), int(m.group(2))
        coords = []
        for tok in m.group(3, 4, 5):
            try:
                v = float(tok)
            except ValueError:
                raise LayoutError(source, f"line {lineno}: coordinate {_short(tok)} is not a number", key) from None
            if not math.isfinite(v) or v != int(v):
                raise LayoutError(source, f"line {lineno}: coordinate {cut(tok)} is not an integer", key)
            if v < 0:
                raise LayoutError(source, f"line {lineno}: coordinate {cut(tok)} is negative", key)
            if v > MAX_COORD:
                raise LayoutError(source, f"line {lineno}: coordinate {cut(tok)} is too large "
                                          f"(at most {MAX_COORD})", key)
            coords.append(int(v))
        if (min(h, w), max(h, w)) not in TABLE_I_MASS_KG:
            raise LayoutError(source, f"line {lineno}: {h}x{w} is not a library brick", key)
        keys.append(key)
        pos.append(coords)
        size.append((h, w))
    if not keys:
        raise LayoutError(source, "layout is empty (no bricks)")
    return brick_layout(pos, size, keys, source=source, fmt="text")


def layout_to_json_dict(layout: Layout, library: Library | str | None = None) -> dict:
    """Layout -> StableLego JSON object.

    Bricks keep their library id and ori; bricks without one get the id of
    the real brick of their size. A brick whose mass differs from its
    library mass (an external load) gets a ``"mass"`` field, which the reader
    accepts, so masses round-trip.

    Raises LayoutError (naming ``layout.source`` and the brick) for a brick
    with no library id (e.g. 3x3) or whose size does not match its id.
    """
    lib = as_library(library)
    src = layout.source
    out = {}
    for i, k in enumerate(layout.keys):
        sx, sy = (int(v) for v in layout.size[i])
        m = float(layout.mass[i])
        bid = layout.brick_id[i]
        if bid:
            ori = int(layout.ori[i])
        else:
            bid, ori = library_id_for(sx, sy)
            if not bid:
                raise LayoutError(
                    src, f"{sx}x{sy} brick has no StableLego library id, so it cannot be written as JSON", k
                )
        entry = lib.bricks.get(bid)
        write_mass = entry is None  # an id of another library: keep the mass explicit
        if entry is not None:
            h, w, lib_m = entry
            if (sx, sy) != ((h, w) if ori == 0 else (w, h)):
                raise LayoutError(
                    src,
                    f"size {sx}x{sy} does not match brick_id {bid!r} ({h}x{w}) with ori {ori}; cannot write it",
                    k,
                )
            write_mass = not math.isclose(m, lib_m, rel_tol=1e-12, abs_tol=0.0)
        x, y, z = (int(v) for v in layout.pos[i])
        d = {"x": x, "y": y, "z": z, "brick_id": int(bid) if bid.isdigit() else bid, "ori": ori}
        if write_mass:
            d["mass"] = m
        out[k] = d
    return out


def layout_to_text(layout: Layout) -> str:
    """Layout -> text format, one ``HxW (x,y,z)`` line per brick.

    The text format knows only the real bricks of paper Table I with their
    Table I masses: the 200 g load block (id "1"), other sizes and other
    masses raise LayoutError (naming ``layout.source`` and the brick) instead
    of being silently lost.
    """
    src = layout.source
    lines = []
    for i, k in enumerate(layout.keys):
        sx, sy = (int(v) for v in layout.size[i])
        x, y, z = (int(v) for v in layout.pos[i])
        if layout.brick_id[i] == "1":
            raise LayoutError(src, "the 200 g load block (brick_id 1) cannot be written as text; use JSON", k)
        dims = (min(sx, sy), max(sx, sy))
        if dims not in TABLE_I_MASS_KG:
            raise LayoutError(src, f"{sx}x{sy} is not a library brick; cannot write it as text", k)
        m = float(layout.mass[i])
        if not math.isclose(m, TABLE_I_MASS_KG[dims], rel_tol=1e-9, abs_tol=0.0):
            raise LayoutError(
                src,
                f"mass {m:g} kg differs from the {sx}x{sy} brick's {TABLE_I_MASS_KG[dims]:g} kg; "
                "the text format cannot express it (use JSON)",
                k,
            )
        lines.append(f"{sx}x{sy} ({x},{y},{z})")
    return "\n".join(lines) + "\n"


def as_library(library) -> Library:
    """A Library from a Library, a library JSON path, or None (the default)."""
    if library is None:
        return default_library()
    if isinstance(library, Library):
        return library
    path = str(library)
    return Library.from_text(read_bytes(path, "brick library"), source=path)


def read_json(path: str):
    """Parse a layout JSON file; duplicate brick keys (or duplicate fields of
    a brick), which json.loads would silently merge, raise LayoutError."""
    text = read_text(path)
    dups: list[tuple[dict, str]] = []

    def pairs_hook(pairs):
        obj = dict(pairs)
        if len(obj) != len(pairs):
            seen = set()
            for k, _ in pairs:
                if k in seen:
                    dups.append((obj, k))
                    break
                seen.add(k)
        return obj

    try:
        raw = json.loads(text, object_pairs_hook=pairs_hook)
    except json.JSONDecodeError as exc:
        raise LayoutError(path, f"not valid JSON: {exc}") from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits
        raise LayoutError(path, f"not valid JSON: {cut(str(exc), 120)}") from None
    except RecursionError:
        raise LayoutError(path, "not valid JSON: nested too deeply") from None
    if dups:
        for obj, k in dups:
            if obj is raw:
                raise LayoutError(path, "duplicate brick key", k)
        if isinstance(raw, dict):
            for key, b in raw.items():
                for obj, f in dups:
                    if obj is b:
                        raise LayoutError(path, f"duplicate field {f!r}", key)
    return raw


def _is_json_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _finite(v) -> bool:
    """math.isfinite that also takes integers too large for a float."""
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


def _short(v, limit: int = 40) -> str:
    """repr of a value, cut to ``limit`` characters (keeps error messages readable)."""
    return cut(repr(v), limit)
