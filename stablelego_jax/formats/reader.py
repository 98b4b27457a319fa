"""Reading and writing layout files of any supported format, by path.

:func:`load_layout` detects the format (StableLego JSON, text, LDraw, a
dataset object folder); :func:`write_layout` writes JSON or text
atomically.
"""
from __future__ import annotations

import dataclasses
import json
import os

from ..files import atomic_write_text, read_text
from ..layout import Layout, LayoutError, Library
from .ldraw import read_ldr
from .stablelego import (
    TEXT_LINE,
    as_library,
    layout_to_json_dict,
    layout_to_text,
    parse_json_layout,
    parse_text_layout,
    read_json,
)

__all__ = ["load_layout", "write_layout"]


def load_layout(path: str, library: Library | str | None = None) -> Layout:
    """Read a layout file or dataset object folder, detecting the format.

    Args:
      path: ``.json`` StableLego layout, ``.txt`` text layout, ``.ldr``
        LDraw file of basic bricks (:mod:`stablelego_jax.formats.ldraw`), or a
        folder holding ``task_graph.json``.
      library: a Library, a library JSON path, or None for the default.
    """
    path = os.fspath(path)
    lib = as_library(library)
    if os.path.isdir(path):
        tg = os.path.join(path, "task_graph.json")
        try:
            os.listdir(path)
        except OSError as exc:
            raise LayoutError(path, f"cannot read folder: {exc.strerror}") from None
        if not os.path.isfile(tg):
            raise LayoutError(path, "folder is not a StableLego dataset object (no task_graph.json)")
        lay = parse_json_layout(read_json(tg), lib, source=tg)
        return dataclasses.replace(lay, fmt="dataset")
    if not os.path.exists(path):
        raise LayoutError(path, "no such file")
    ext = os.path.splitext(path)[1].lower()
    if ext == ".ldr":
        return read_ldr(path)
    if ext == ".json":
        return parse_json_layout(read_json(path), lib, source=path)
    text = read_text(path)
    if ext == ".txt" or TEXT_LINE.match(text.strip().splitlines()[0] if text.strip() else ""):
        return parse_text_layout(text, source=path)
    if text.lstrip().startswith("{"):
        return parse_json_layout(read_json(path), lib, source=path)
    raise LayoutError(path, "unknown layout format (expected .json, .txt, .ldr or a dataset folder)")


def write_layout(layout: Layout, path: str, fmt: str | None = None, library: Library | str | None = None) -> None:
    """Write ``layout`` atomically as JSON (default) or text (``.txt`` or ``fmt="text"``).

    Raises LayoutError naming ``path`` and the brick when the format cannot
    represent a brick; nothing is written then.
    """
    fmt = fmt or ("text" if path.endswith(".txt") else "json")
    if fmt not in ("json", "text"):
        raise ValueError(f"unknown layout format {fmt!r} (expected 'json' or 'text')")
    try:
        if fmt == "text":
            text = layout_to_text(layout)
        else:
            d = layout_to_json_dict(layout) if library is None else layout_to_json_dict(layout, library)
            text = json.dumps(d, indent=1) + "\n"
    except LayoutError as exc:
        if exc.source != layout.source:  # e.g. an unreadable library file
            raise
        raise LayoutError(path, exc.message, exc.key) from None
    atomic_write_text(path, text)
