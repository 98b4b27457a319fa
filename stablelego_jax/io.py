"""Readers and writers for layout files.

Formats: StableLego JSON (``{"key": {"x","y","z","brick_id","ori"}}`` plus a
brick library), StableLego dataset object folders (``task_graph.json``), and
the text format of LLM brick generators (``HxW (x,y,z)`` one brick a line).
Every reader returns a validated :class:`~stablelego_jax.layout.Layout` or
raises :class:`~stablelego_jax.layout.LayoutError` naming the file and brick.
"""
from __future__ import annotations

import json
import math
import os
import re
import tempfile
from typing import Mapping

from .layout import (
    TABLE_I_MASS_KG,
    Layout,
    LayoutError,
    Library,
    default_library,
    make_layout,
)

__all__ = [
    "load_layout",
    "parse_json_layout",
    "parse_text_layout",
    "layout_to_json_dict",
    "layout_to_text",
    "write_layout",
    "atomic_write_text",
]

_TEXT_LINE = re.compile(r"^\s*(\d+)\s*x\s*(\d+)\s*\(\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*,\s*(-?[\d.]+)\s*\)\s*$")
_FIELDS = ("x", "y", "z", "brick_id", "ori")


def load_layout(path: str, library: Library | str | None = None) -> Layout:
    """Read a layout file or dataset object folder, detecting the format.

    Args:
      path: ``.json`` StableLego layout, ``.txt`` text layout, or a folder
        holding ``task_graph.json``.
      library: a Library, a library JSON path, or None for the default.
    """
    lib = _as_library(library)
    if os.path.isdir(path):
        tg = os.path.join(path, "task_graph.json")
        if not os.path.isfile(tg):
            raise LayoutError(path, "folder is not a StableLego dataset object (no task_graph.json)")
        lay = parse_json_layout(_read_json(tg), lib, source=tg)
        return _with_fmt(lay, "dataset")
    if not os.path.exists(path):
        raise LayoutError(path, "no such file")
    ext = os.path.splitext(path)[1].lower()
    if ext == ".ldr":
        try:
            from .ldraw import read_ldr
        except ImportError:
            raise LayoutError(path, "LDraw (.ldr) import is not available in this version") from None
        return read_ldr(path)
    if ext == ".json":
        return parse_json_layout(_read_json(path), lib, source=path)
    text = _read_text(path)
    if ext == ".txt" or _TEXT_LINE.match(text.strip().splitlines()[0] if text.strip() else ""):
        return parse_text_layout(text, source=path)
    if text.lstrip().startswith("{"):
        return parse_json_layout(_read_json(path), lib, source=path)
    raise LayoutError(path, "unknown layout format (expected .json, .txt, .ldr or a dataset folder)")


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
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v != int(v):
                raise LayoutError(source, f"coordinate {f}={v!r} is not an integer", key)
            if v < 0:
                raise LayoutError(source, f"coordinate {f}={v!r} is negative", key)
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
            if isinstance(extra, bool) or not isinstance(extra, (int, float)) or not math.isfinite(extra) or extra < 0:
                raise LayoutError(source, f"mass must be a finite number >= 0, got {extra!r}", key)
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
    keys, pos, size, mass, bids, oris = [], [], [], [], [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        key = str(lineno)
        m = _TEXT_LINE.match(s)
        if not m:
            raise LayoutError(source, f"line {lineno}: cannot parse {s!r} (expected 'HxW (x,y,z)')", key)
        h, w = int(m.group(1)), int(m.group(2))
        coords = []
        for tok in m.group(3, 4, 5):
            v = float(tok)
            if v != int(v):
                raise LayoutError(source, f"line {lineno}: coordinate {tok} is not an integer", key)
            if v < 0:
                raise LayoutError(source, f"line {lineno}: coordinate {tok} is negative", key)
            coords.append(int(v))
        dims = (min(h, w), max(h, w))
        if dims not in TABLE_I_MASS_KG:
            raise LayoutError(source, f"line {lineno}: {h}x{w} is not a library brick", key)
        bid, ori = _library_id_for(h, w)
        keys.append(key)
        pos.append(coords)
        size.append((h, w))
        mass.append(TABLE_I_MASS_KG[dims])
        bids.append(bid)
        oris.append(ori)
    if not keys:
        raise LayoutError(source, "layout is empty (no bricks)")
    return make_layout(keys, pos, size, mass, bids, oris, source=source, fmt="text")


def _library_id_for(sx: int, sy: int) -> tuple[str, int]:
    """StableLego library id and ori of a real brick with extent (sx, sy)."""
    for bid, (h, w, _) in default_library().bricks.items():
        if bid == "1":  # the 200 g load block, not a real brick
            continue
        if (h, w) == (sx, sy):
            return bid, 0
        if (w, h) == (sx, sy):
            return bid, 1
    return "", 0


def layout_to_json_dict(layout: Layout) -> dict:
    """Layout -> StableLego JSON object (needs library ids)."""
    out = {}
    for i, k in enumerate(layout.keys):
        bid = layout.brick_id[i] or _library_id_for(*layout.size[i].tolist())[0]
        ori = int(layout.ori[i]) if layout.brick_id[i] else _library_id_for(*layout.size[i].tolist())[1]
        x, y, z = (int(v) for v in layout.pos[i])
        out[k] = {"x": x, "y": y, "z": z, "brick_id": int(bid) if bid.isdigit() else bid, "ori": ori}
    return out


def layout_to_text(layout: Layout) -> str:
    """Layout -> text format, one ``HxW (x,y,z)`` line per brick."""
    lines = [
        f"{int(s[0])}x{int(s[1])} ({int(p[0])},{int(p[1])},{int(p[2])})"
        for p, s in zip(layout.pos, layout.size)
    ]
    return "\n".join(lines) + "\n"


def write_layout(layout: Layout, path: str, fmt: str | None = None) -> None:
    """Write ``layout`` atomically as JSON (default for .json) or text."""
    fmt = fmt or ("text" if path.endswith(".txt") else "json")
    if fmt == "text":
        atomic_write_text(path, layout_to_text(layout))
    else:
        atomic_write_text(path, json.dumps(layout_to_json_dict(layout), indent=1) + "\n")


def atomic_write_text(path: str, text: str) -> None:
    """Write a file via a temporary sibling and rename: never half-written."""
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(dir=d, prefix=".tmp-", suffix=os.path.basename(path))
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _as_library(library) -> Library:
    if library is None:
        return default_library()
    if isinstance(library, Library):
        return library
    return Library.from_json(str(library))


def _with_fmt(layout: Layout, fmt: str) -> Layout:
    import dataclasses

    return dataclasses.replace(layout, fmt=fmt)


def _read_text(path: str) -> str:
    try:
        with open(path, encoding="utf-8") as fh:
            return fh.read()
    except UnicodeDecodeError:
        raise LayoutError(path, "file is not UTF-8 text") from None
    except OSError as exc:
        raise LayoutError(path, f"cannot read: {exc.strerror}") from None


def _read_json(path: str):
    text = _read_text(path)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise LayoutError(path, f"not valid JSON: {exc}") from None
