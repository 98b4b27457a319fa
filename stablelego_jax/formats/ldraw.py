"""LDraw (``.ldr``) export and import for the basic bricks.

LDraw is the file format of LeoCAD, LDView, LDCad and BrickLink Studio. A
brick is a type-1 line ``1 colour X Y Z a b c d e f g h i part.dat``: the
part's origin (the centre of the top of its body) at (X, Y, Z) in LDraw
units (LDU) and a 3x3 rotation matrix, row by row. -Y is up. The native parts
lie with their long side along X.

Convention (the one of BrickGPT's ``.ldr`` files, see
``examples/brickgpt/guitar.ldr``): a stud is 20 LDU and a layer 24 LDU; the
brick with corner cell (x, y, z) and extent (sx, sy) has its origin at
``X = 20 (x + sx/2)``, ``Y = -24 z``, ``Z = 20 (y + sy/2)`` (layout y is LDraw
Z), rotated by ``-1 0 0 0 1 0 0 0 -1`` when it is longer along x (sx > sy)
and by ``0 0 1 0 1 0 -1 0 0`` otherwise (the long side turned onto Z).

Parts: 3005 1x1, 3004 1x2, 3010 1x4, 3009 1x6, 3008 1x8, 3003 2x2, 3001 2x4,
2456 2x6. What LDraw cannot say (a brick's key, a mass other than Table I's,
e.g. the 200 g load block written as a 2x2, a non-default library id or
ori) goes into a comment line ``0 // stablelego {json}`` just before the
brick; the reader applies it, so export then import gives the same layout.
Other programs ignore those comments.
"""
from __future__ import annotations

import json
import math
import os
import re

import numpy as np

from ..files import atomic_write_text, read_text
from ..layout import TABLE_I_MASS_KG, Layout, LayoutError, library_id_for, make_layout, table_i_bricks
from ..scene import BLOCK, Scene

__all__ = [
    "yaw_matrix",
    "PARTS",
    "PART_SIZES",
    "LDU_STUD",
    "LDU_LAYER",
    "DEFAULT_COLOR",
    "layout_to_ldr",
    "write_ldr",
    "parse_ldr",
    "read_ldr",
]

#: LDraw part number of each basic brick, keyed by its (short, long) footprint.
PARTS: dict[tuple[int, int], str] = {
    (1, 1): "3005",
    (1, 2): "3004",
    (1, 4): "3010",
    (1, 6): "3009",
    (1, 8): "3008",
    (2, 2): "3003",
    (2, 4): "3001",
    (2, 6): "2456",
}
#: Inverse of PARTS: part number -> (short, long) footprint.
PART_SIZES: dict[str, tuple[int, int]] = {v: k for k, v in PARTS.items()}
LDU_STUD = 20
LDU_LAYER = 24
#: LDraw colour 115 (medium lime), the colour of BrickGPT's files.
DEFAULT_COLOR = 115

_ROT_X = "-1 0 0 0 1 0 0 0 -1"  # long side along x (LDraw X)
_ROT_Y = "0 0 1 0 1 0 -1 0 0"  # long side along y (LDraw Z)
_META = "0 // stablelego "
_TOL = 1e-3
_SUPPORTED = ", ".join(f"{p} ({a}x{b})" for (a, b), p in PARTS.items())


def _fmt(v: float) -> str:
    return repr(float(v))  # 110.0, 370.0, 12.5: as BrickGPT writes them


def layout_to_ldr(
    layout: Layout,
    color: int | None = DEFAULT_COLOR,
    colors=None,
    step: str = "layer",
    header: bool = True,
    title: str | None = None,
    name: str | None = None,
    part_suffix: str = ".dat",
) -> str:
    """Layout -> LDraw text.

    Args:
      layout: the bricks (any Table I sizes, load blocks included).
      color: LDraw colour code of every brick (default 115).
      colors: optional per-brick colour codes (aligned with layout.keys);
        overrides ``color``.
      step: "layer" (a ``0 STEP`` after each layer: building instructions
        one layer at a time), "brick" (after each brick, as BrickGPT) or
        "none".
      header: write the ``0 title`` / ``0 Name:`` / ``0 Author:`` lines.
      title, name: header title and file name (defaults from layout.source).
      part_suffix: ".dat" (default) or ".DAT" (as BrickGPT writes it).

    Bricks are written bottom layer first (input order within a layer).
    Raises LayoutError (naming layout.source and the brick) for a size that
    has no basic LDraw part.
    """
    if step not in ("layer", "brick", "none"):
        raise ValueError(f"step must be 'layer', 'brick' or 'none', got {step!r}")
    if isinstance(layout, Scene):
        return _scene_to_ldr(layout, color, colors, step, header, title, name, part_suffix)
    n = layout.n
    if colors is not None:
        colors = [int(c) for c in colors]
        if len(colors) != n:
            raise ValueError(f"colors must hold one code per brick ({n}), got {len(colors)}")
    else:
        colors = [int(DEFAULT_COLOR if color is None else color)] * n
    order = np.argsort(layout.pos[:, 2], kind="stable")
    lines: list[str] = []
    if header:
        src = layout.source if layout.source and not layout.source.startswith("<") else ""
        stem = os.path.splitext(os.path.basename(os.path.normpath(src)))[0] if src else "layout"
        if stem == "task_graph":  # a dataset object: name it after its folder
            stem = os.path.basename(os.path.dirname(os.path.abspath(src))) or stem
        lines.append(f"0 {title if title is not None else stem}")
        lines.append(f"0 Name: {name if name is not None else stem + '.ldr'}")
        lines.append("0 Author: stablelego-jax")
    for out_i, i in enumerate(order.tolist()):
        sx, sy = (int(v) for v in layout.size[i])
        x, y, z = (int(v) for v in layout.pos[i])
        key = layout.keys[i]
        dims = (min(sx, sy), max(sx, sy))
        part = PARTS.get(dims)
        if part is None:
            raise LayoutError(layout.source, f"{sx}x{sy} brick has no basic LDraw part (supported: {_SUPPORTED})", key)
        meta = _meta_for(layout, i, out_i, dims)
        if meta:
            lines.append(_META + json.dumps(meta, separators=(",", ":")))
        rot = _ROT_X if sx > sy else _ROT_Y
        X = LDU_STUD * (x + sx / 2)
        Z = LDU_STUD * (y + sy / 2)
        Y = -LDU_LAYER * z
        lines.append(f"1 {colors[i]} {_fmt(X)} {Y} {_fmt(Z)} {rot} {part}{part_suffix}")
        last_in_layer = out_i == n - 1 or int(layout.pos[order[out_i + 1], 2]) != z
        if step == "brick" or (step == "layer" and last_in_layer):
            lines.append("0 STEP")
    return "\n".join(lines) + "\n"


def _header(source: str, title: str | None, name: str | None) -> list[str]:
    src = source if source and not source.startswith("<") else ""
    stem = os.path.splitext(os.path.basename(os.path.normpath(src)))[0] if src else "layout"
    if stem == "task_graph":  # a dataset object: name it after its folder
        stem = os.path.basename(os.path.dirname(os.path.abspath(src))) or stem
    return [f"0 {title if title is not None else stem}", f"0 Name: {name if name is not None else stem + '.ldr'}",
            "0 Author: stablelego-jax"]


def yaw_matrix(yaw_deg: float) -> np.ndarray:
    """The LDraw rotation (3x3, rows) of a part whose native x axis (its long
    side) points along layout angle ``yaw_deg`` (degrees from +x towards +y;
    layout x, y, z are LDraw X, Z, -Y)."""
    t = math.radians(yaw_deg)
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def _num(v: float) -> str:
    v = round(float(v), 9) + 0.0  # no -0.0, no 6.1e-17 for 0
    return repr(v) if v != int(v) else str(int(v)) if abs(v) < 1e15 else repr(v)


def _scene_to_ldr(scene: Scene, color, colors, step: str, header: bool, title, name, part_suffix: str) -> str:
    """A scene of (possibly rotated) bricks -> LDraw text: each brick's
    rotation matrix from its yaw (:func:`yaw_matrix`), its origin at its top
    centre with the module's convention (X = 20 cx, Z = 20 cy, Y = -24 z);
    plain blocks have no LDraw part (LayoutError naming the block)."""
    n = scene.n
    colors = [int(c) for c in colors] if colors is not None else [int(DEFAULT_COLOR if color is None else color)] * n
    if len(colors) != n:
        raise ValueError(f"colors must hold one code per brick ({n}), got {len(colors)}")
    order = np.argsort(scene.pos[:, 2], kind="stable")
    lines = _header(scene.source, title, name) if header else []
    for out_i, i in enumerate(order.tolist()):
        key = scene.keys[i]
        if scene.kind[i] == BLOCK:
            raise LayoutError(scene.source, "plain blocks have no LDraw part; export bricks only", key, what="block")
        sx, sy, thick = (int(v) for v in scene.size[i])
        dims = (min(sx, sy), max(sx, sy))
        part = PARTS.get(dims) if thick == 3 else None
        if part is None:
            raise LayoutError(scene.source, f"{sx}x{sy} part {thick} plate heights high has no basic LDraw part "
                                            f"(supported: {_SUPPORTED})", key)
        meta = {}
        if key != str(out_i + 1):
            meta["key"] = key
        m = float(scene.mass[i])
        if not math.isclose(m, TABLE_I_MASS_KG[dims], rel_tol=1e-12, abs_tol=0.0):
            meta["mass"] = m
        bid, _ = library_id_for(sx, sy)
        if scene.brick_id[i] != bid and not (scene.brick_id[i], bid) == ("", ""):
            meta["brick_id"] = scene.brick_id[i]
        yaw = float(scene.yaw[i])
        if yaw != 0:
            meta["yaw"] = yaw
        if meta:
            lines.append(_META + json.dumps(meta, separators=(",", ":")))
        rot = yaw_matrix(yaw if sx >= sy else yaw + 90.0)
        cx, cy, level = (float(v) for v in scene.pos[i])
        X, Z, Y = LDU_STUD * cx, LDU_STUD * cy, -LDU_LAYER * level / 3
        lines.append(f"1 {colors[i]} {_num(X)} {_num(Y)} {_num(Z)} {' '.join(_num(v) for v in rot.reshape(-1))} "
                     f"{part}{part_suffix}")
        last = out_i == n - 1 or scene.pos[order[out_i + 1], 2] != level
        if step == "brick" or (step == "layer" and last):
            lines.append("0 STEP")
    return "\n".join(lines) + "\n"


def _meta_for(layout: Layout, i: int, out_i: int, dims) -> dict:
    """The facts of brick i that the part line cannot carry (empty if none)."""
    meta = {}
    if layout.keys[i] != str(out_i + 1):
        meta["key"] = layout.keys[i]
    m = float(layout.mass[i])
    if not math.isclose(m, TABLE_I_MASS_KG[dims], rel_tol=1e-12, abs_tol=0.0):
        meta["mass"] = m
    sx, sy = (int(v) for v in layout.size[i])
    bid, ori = library_id_for(sx, sy)
    if layout.brick_id[i] != bid:
        meta["brick_id"] = layout.brick_id[i]
    if int(layout.ori[i]) != ori:
        meta["ori"] = int(layout.ori[i])
    return meta


def write_ldr(layout: Layout, path: str, **kwargs) -> None:
    """Write ``layout`` as an LDraw file, atomically (see :func:`layout_to_ldr`).

    Raises LayoutError naming ``path`` and the brick when a brick has no
    LDraw part; nothing is written then.
    """
    kwargs.setdefault("name", os.path.basename(path))
    try:
        text = layout_to_ldr(layout, **kwargs)
    except LayoutError as exc:
        raise LayoutError(path, exc.message, exc.key, what=exc.what) from None
    atomic_write_text(path, text)


def _rotation(vals, source: str, lineno: int, key: str) -> bool:
    """True if the brick's long side lies along LDraw X, False along Z.

    Accepts the rotations about the vertical axis by multiples of 90 degrees
    (and their mirror images); raises LayoutError for tilted or upside-down
    bricks.
    """
    M = np.asarray(vals, np.float64).reshape(3, 3)
    R = np.round(M)
    if not np.allclose(M, R, atol=_TOL) or not np.array_equal(np.abs(R[1]), [0, 1, 0]) \
            or not np.array_equal(np.abs(R[:, 1]), [0, 1, 0]):
        raise LayoutError(source, f"line {lineno}: brick is tilted (rotation {_short_mat(vals)}); "
                                  "only turns about the vertical axis are supported", key)
    if R[1, 1] != 1:
        raise LayoutError(source, f"line {lineno}: brick is upside down (rotation {_short_mat(vals)})", key)
    if abs(R[0, 0]) == 1 and abs(R[2, 2]) == 1 and R[0, 2] == 0 and R[2, 0] == 0:
        return True
    if abs(R[0, 2]) == 1 and abs(R[2, 0]) == 1 and R[0, 0] == 0 and R[2, 2] == 0:
        return False
    raise LayoutError(source, f"line {lineno}: rotation {_short_mat(vals)} is not a rotation matrix", key)


def _short_mat(vals) -> str:
    return " ".join(f"{float(v):g}" for v in vals)


def _on_grid(v: np.ndarray, what: str, source: str, lines, keys) -> np.ndarray:
    """Integers from ``v`` after removing one common fractional offset;
    LayoutError naming the first brick off the grid of the first one."""
    off = v[0] - np.round(v[0])
    w = v - off
    bad = np.abs(w - np.round(w)) > _TOL
    if bad.any():
        i = int(np.argmax(bad))
        raise LayoutError(source, f"line {lines[i]}: brick is not on the {what} grid of the first brick "
                                  f"(off by {float(w[i] - np.round(w[i])):+.3g} {what})", keys[i])
    return np.round(w).astype(np.int64)


def parse_ldr(text: str, source: str = "<memory>", ground: bool = True) -> Layout:
    """LDraw text -> Layout (see the module doc for the convention).

    Only the basic bricks (PARTS) may appear; any other part, a submodel
    reference or a drawing primitive (line types 2-5) raises LayoutError
    naming the line and the part. The colour is ignored. Bricks must lie on
    one stud grid and one layer grid (a common offset is removed) and turn
    only about the vertical axis. Coordinates are shifted so that none is
    negative; with ``ground`` (default) the lowest layer becomes layer 0,
    the baseplate (a model built on the ground plane of LeoCAD or Studio has
    its bottom bricks one layer above BrickGPT's layer 0).
    """
    keys, lines_of, dims_l, long_x, xyz, metas = [], [], [], [], [], []
    pending: dict | None = None
    pending_line = 0
    for lineno, raw in enumerate(text.splitlines(), start=1):
        s = raw.strip().lstrip("\ufeff")
        if not s:
            continue
        tok = s.split()
        kind = tok[0]
        if kind == "0":
            if s.startswith(_META.rstrip()) and len(s) > len(_META.rstrip()):
                body = s[len(_META.rstrip()):].strip()
                try:
                    pending = json.loads(body)
                except json.JSONDecodeError:
                    raise LayoutError(source, f"line {lineno}: bad stablelego comment {body[:60]!r}") from None
                if not isinstance(pending, dict):
                    raise LayoutError(source, f"line {lineno}: stablelego comment must be a JSON object")
                pending_line = lineno
            continue
        if kind in ("2", "3", "4", "5"):
            raise LayoutError(source, f"line {lineno}: drawing primitive (line type {kind}); "
                                      "only brick parts (line type 1) are supported")
        if kind != "1":
            raise LayoutError(source, f"line {lineno}: unknown LDraw line type {kind[:20]!r}")
        meta = pending or {}
        pending = None
        key = str(meta.get("key", len(keys) + 1))
        if len(tok) < 15:
            raise LayoutError(source, f"line {lineno}: type-1 line needs 15 fields, got {len(tok)}", key)
        ref = " ".join(tok[14:])
        part = re.split(r"[\\/]", ref)[-1].lower()
        if part.endswith(".dat"):
            part = part[:-4]
        if part not in PART_SIZES:
            raise LayoutError(source, f"line {lineno}: part {ref!r} is not a supported brick "
                                      f"(supported: {_SUPPORTED})", key)
        try:
            nums = [float(t) for t in tok[2:14]]
        except ValueError:
            raise LayoutError(source, f"line {lineno}: position or rotation is not a number", key) from None
        if not all(math.isfinite(v) for v in nums):
            raise LayoutError(source, f"line {lineno}: position or rotation is not finite", key)
        long_x.append(_rotation(nums[3:], source, lineno, key))
        keys.append(key)
        lines_of.append(lineno)
        dims_l.append(PART_SIZES[part])
        xyz.append(nums[:3])
        metas.append(meta)
    if pending is not None:
        raise LayoutError(source, f"line {pending_line}: stablelego comment not followed by a brick")
    if not keys:
        raise LayoutError(source, "no brick parts (type-1 lines) in the file")
    n = len(keys)
    dims = np.asarray(dims_l, np.int64)
    lx = np.asarray(long_x)
    size = np.where(lx[:, None], dims[:, ::-1], dims)  # (sx, sy)
    P = np.asarray(xyz, np.float64)
    fx = P[:, 0] / LDU_STUD - size[:, 0] / 2
    fy = P[:, 2] / LDU_STUD - size[:, 1] / 2
    fz = -P[:, 1] / LDU_LAYER
    x = _on_grid(fx, "stud", source, lines_of, keys)
    y = _on_grid(fy, "stud", source, lines_of, keys)
    z = _on_grid(fz, "layer", source, lines_of, keys)
    x -= min(int(x.min()), 0)
    y -= min(int(y.min()), 0)
    z -= int(z.min()) if ground else min(int(z.min()), 0)
    table_mass, table_bids, table_oris = table_i_bricks(size)
    mass, bids, oris = [], [], []
    for i in range(n):
        bid, ori = table_bids[i], int(table_oris[i])
        meta = metas[i]
        m = meta.get("mass", float(table_mass[i]))
        if isinstance(m, bool) or not isinstance(m, (int, float)):
            raise LayoutError(source, f"line {lines_of[i]}: mass {m!r} is not a number", keys[i])
        mass.append(float(m))
        bids.append(str(meta.get("brick_id", bid)))
        oris.append(meta.get("ori", ori))
    return make_layout(keys, np.stack([x, y, z], axis=1), size, mass, bids, oris, source=source, fmt="ldr")


def read_ldr(path: str, ground: bool = True) -> Layout:
    """Read an LDraw file (see :func:`parse_ldr`); errors name ``path``."""
    return parse_ldr(read_text(path), source=path, ground=ground)
