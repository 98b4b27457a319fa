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
from ..scene import Scene
from .blocks import is_scene_json, parse_scene_json, scene_to_json_dict
from .ldraw import LDRAW_EXTS, read_ldr
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


def load_layout(path: str, library: Library | str | None = None, skip_unsupported: bool = False,
                report: dict | None = None) -> Layout | Scene:
    """Read a layout file or dataset object folder, detecting the format.

    Args:
      path: ``.json`` StableLego layout or scene, ``.txt`` text layout,
        ``.ldr`` / ``.mpd`` LDraw model (:mod:`stablelego_jax.formats.ldraw`),
        or a folder holding ``task_graph.json``.
      library: a Library, a library JSON path, or None for the default.
      skip_unsupported, report: LDraw files only: leave out the parts that
        cannot be modelled instead of refusing the file, and tell which in
        ``report`` (see :func:`~stablelego_jax.formats.ldraw.parse_ldr`).

    A ``"blocks"`` document, or a StableLego layout with rotated bricks
    (``center`` / ``yaw``), gives a :class:`~stablelego_jax.scene.Scene`
    (:mod:`stablelego_jax.formats.blocks`); every other input a Layout.
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
    if ext in LDRAW_EXTS:
        return read_ldr(path, skip_unsupported=skip_unsupported, report=report)
    if ext == ".json":
        return _parse_json(read_json(path), lib, path)
    text = read_text(path)
    if ext == ".txt" or TEXT_LINE.match(text.strip().splitlines()[0] if text.strip() else ""):
        return parse_text_layout(text, source=path)
    if text.lstrip().startswith("{"):
        return _parse_json(read_json(path), lib, path)
    raise LayoutError(path, "unknown layout format (expected .json, .txt, .ldr, .mpd or a dataset folder)")


def _parse_json(raw, lib: Library, path: str) -> Layout | Scene:
    if is_scene_json(raw):
        return parse_scene_json(raw, lib, source=path)
    return parse_json_layout(raw, lib, source=path)


def write_layout(layout: Layout | Scene, path: str, fmt: str | None = None,
                 library: Library | str | None = None) -> None:
    """Write ``layout`` atomically as JSON (default) or text (``.txt`` or ``fmt="text"``).

    A Scene is written as JSON in the form it was read
    (:func:`~stablelego_jax.formats.blocks.scene_to_json_dict`); it has no
    text form. Raises LayoutError naming ``path`` and the brick when the
    format cannot represent a brick; nothing is written then.
    """
    fmt = fmt or ("text" if path.endswith(".txt") else "json")
    if fmt not in ("json", "text"):
        raise ValueError(f"unknown layout format {fmt!r} (expected 'json' or 'text')")
    if isinstance(layout, Scene):
        if fmt == "text":
            raise LayoutError(path, "blocks and rotated bricks have no text form; write JSON")
        atomic_write_text(path, json.dumps(scene_to_json_dict(layout, as_library(library)), indent=1) + "\n")
        return
    try:
        if fmt == "text":
            text = layout_to_text(layout)
        else:
            d = layout_to_json_dict(layout) if library is None else layout_to_json_dict(layout, library)
            text = json.dumps(d, indent=1) + "\n"
    except LayoutError as exc:
        if exc.source != layout.source:  # e.g. an unreadable library file
            raise
        raise LayoutError(path, exc.message, exc.key, what=exc.what) from None
    atomic_write_text(path, text)
