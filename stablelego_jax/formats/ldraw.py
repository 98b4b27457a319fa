"""LDraw (``.ldr``, ``.mpd``) export and import: bricks and plates on the stud grid.

LDraw is the file format of LeoCAD, LDView, LDCad and BrickLink Studio. A
part is a type-1 line ``1 colour X Y Z a b c d e f g h i part.dat``: the
part's origin (the centre of the top of its body) at (X, Y, Z) in LDraw
units (LDU) and a 3x3 rotation matrix, row by row. -Y is up. The native parts
lie with their long side along X.

Convention (the one of BrickGPT's ``.ldr`` files, see
``examples/brickgpt/guitar.ldr``): a stud is 20 LDU and a layer 24 LDU; the
brick with corner cell (x, y, z) and extent (sx, sy) has its origin at
``X = 20 (x + sx/2)``, ``Y = -24 z``, ``Z = 20 (y + sy/2)`` (layout y is LDraw
Z), rotated by ``-1 0 0 0 1 0 0 0 -1`` when it is longer along x (sx > sy)
and by ``0 0 1 0 1 0 -1 0 0`` otherwise (the long side turned onto Z).

Reading (:func:`parse_ldr`): multi-part documents (``0 FILE`` sections) and
sub-model references are flattened with their transforms
(:func:`flatten_ldr`); the parts are the bricks and plates of
:mod:`~stablelego_jax.formats.ldraw_parts` (a plate is one plate height, 8
LDU, a third of a brick; heights are counted in plate heights). A model of
the eight Table I bricks (PARTS: 3005 1x1, 3004 1x2, 3010 1x4, 3009 1x6,
3008 1x8, 3003 2x2, 3001 2x4, 2456 2x6) on one grid gives a grid Layout;
anything else a :class:`~stablelego_jax.scene.Scene` of bricks and plates.
A part that cannot be modelled is reported once per part number with its
count (:func:`unsupported_message`), or left out with ``skip_unsupported``.

Writing (:func:`layout_to_ldr`) takes a Layout or a Scene of bricks and
plates (yawed ones with their rotation matrices). What LDraw cannot say (a
brick's key, a mass other than the part's, e.g. the 200 g load block
written as a 2x2, a non-default library id or ori, a yaw the part's shape
cannot show) goes into a comment line ``0 // stablelego {json}`` just
before the part; the reader applies it, so export then import gives the
same layout. Other programs ignore those comments.
"""
from __future__ import annotations

import json
import math
import os
import re
from typing import NamedTuple

import numpy as np

from ..files import atomic_write_text, read_text
from ..layout import Layout, LayoutError, library_id_for, make_layout, table_i_bricks
from ..scene import BLOCK, BRICK, Scene, make_scene, overlapping_pairs
from .ldraw_parts import BRICK_H, LDRAW_PARTS, part_for, part_mass, part_number

__all__ = [
    "yaw_matrix",
    "first_stud",
    "flatten_ldr",
    "unsupported_message",
    "LDRAW_EXTS",
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
#: File name endings of LDraw models.
LDRAW_EXTS = (".ldr", ".mpd")
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
    layout: Layout | Scene,
    color: int | None = DEFAULT_COLOR,
    colors=None,
    step: str = "layer",
    header: bool = True,
    title: str | None = None,
    name: str | None = None,
    part_suffix: str = ".dat",
) -> str:
    """Layout or Scene -> LDraw text.

    Args:
      layout: the bricks (any Table I sizes, load blocks included), or a
        Scene of bricks and plates at any yaw (no plain blocks).
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
    has no LDraw part (:mod:`~stablelego_jax.formats.ldraw_parts`) and for
    a plain block.
    """
    if step not in ("layer", "brick", "none"):
        raise ValueError(f"step must be 'layer', 'brick' or 'none', got {step!r}")
    colors = _colors(layout.n, color, colors)
    if isinstance(layout, Scene):
        return _scene_to_ldr(layout, colors, step, header, title, name, part_suffix)
    n = layout.n
    order = np.argsort(layout.pos[:, 2], kind="stable")
    lines: list[str] = []
    if header:
        lines += _header(layout.source, title, name)
    for out_i, i in enumerate(order.tolist()):
        sx, sy = (int(v) for v in layout.size[i])
        x, y, z = (int(v) for v in layout.pos[i])
        key = layout.keys[i]
        dims = (min(sx, sy), max(sx, sy))
        part = PARTS.get(dims) or part_for(sx, sy, BRICK_H)
        if part is None:
            raise LayoutError(layout.source, f"{sx}x{sy} brick has no LDraw brick part (bricks: {_SUPPORTED}; "
                                             "others of formats.ldraw_parts)", key)
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


def _colors(n: int, color, colors) -> list[int]:
    """One LDraw colour code per part: ``colors`` if given, else ``color``."""
    if colors is None:
        return [int(DEFAULT_COLOR if color is None else color)] * n
    colors = [int(c) for c in colors]
    if len(colors) != n:
        raise ValueError(f"colors must hold one code per brick ({n}), got {len(colors)}")
    return colors


def _scene_to_ldr(scene: Scene, colors: list[int], step: str, header: bool, title, name, part_suffix: str) -> str:
    """A scene of (possibly rotated) bricks -> LDraw text: each brick's
    rotation matrix from its yaw (:func:`yaw_matrix`), its origin at its top
    centre with the module's convention (X = 20 cx, Z = 20 cy, Y = -24 z);
    plain blocks have no LDraw part (LayoutError naming the block)."""
    n = scene.n
    order = np.argsort(scene.pos[:, 2], kind="stable")
    lines = _header(scene.source, title, name) if header else []
    # the reader puts the studs of the first square part on the baseplate's lattice: where that part of this
    # file order is not on it, mark the scene's own anchor (its first square part) so that reading gives it back
    square = np.nonzero(_square(scene.yaw) & (scene.kind == BRICK))[0]
    sq = set(square.tolist())
    first_out = next((i for i in order.tolist() if i in sq), None)
    anchor = int(square[0]) if len(square) else None
    if anchor is None or first_out is None or _on_lattice(scene, first_out) or not _on_lattice(scene, anchor):
        anchor = None
    for out_i, i in enumerate(order.tolist()):
        key = scene.keys[i]
        if scene.kind[i] == BLOCK:
            raise LayoutError(scene.source, "plain blocks have no LDraw part; export bricks only", key, what="block")
        sx, sy, thick = (int(v) for v in scene.size[i])
        bid = scene.brick_id[i]
        part = bid if LDRAW_PARTS.get(bid) == (min(sx, sy), max(sx, sy), thick) else part_for(sx, sy, thick)
        if part is None:
            raise LayoutError(scene.source, f"{sx}x{sy} part {thick} plate heights high has no LDraw part "
                                            "(see formats.ldraw_parts)", key)
        meta = {}
        if key != str(out_i + 1):
            meta["key"] = key
        m = float(scene.mass[i])
        if not math.isclose(m, part_mass(sx, sy, thick), rel_tol=1e-12, abs_tol=0.0):
            meta["mass"] = m
        if bid != _default_id(sx, sy, thick, part):
            meta["brick_id"] = bid
        yaw = float(scene.yaw[i])
        if yaw % 90 != 0 or sx < sy:
            meta["yaw"] = yaw  # the reader would take the long side as the part's x
        if i == anchor:
            meta["anchor"] = True
        if meta:
            lines.append(_META + json.dumps(meta, separators=(",", ":")))
        rot = yaw_matrix(yaw if sx >= sy else yaw + 90.0)
        cx, cy, level = (float(v) for v in scene.pos[i])
        # the origin at the part's top; a brick on level 0 at Y = 0 (as the grid convention)
        X, Z, Y = LDU_STUD * cx, LDU_STUD * cy, -LDU_LAYER * (level + thick) / 3 + LDU_LAYER
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
    if not math.isclose(m, part_mass(dims[0], dims[1], BRICK_H), rel_tol=1e-12, abs_tol=0.0):
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


class _Part(NamedTuple):
    number: str
    M: np.ndarray  # (3, 3) rotation, LDraw frame
    t: np.ndarray  # (3,) origin, LDU
    where: str  # "line 12" or "sub.ldr line 3"
    meta: dict


def _split_mpd(lines: list[str]) -> tuple[str | None, dict]:
    """{sub-file name (lower case): [(line number, text)]} of a multi-part
    document and the name of its first (main) file; (None, {}) for a plain file."""
    docs: dict = {}
    main, cur = None, None
    for no, raw in enumerate(lines, start=1):
        s = raw.strip().lstrip("\ufeff")
        tok = s.split(maxsplit=2)
        if len(tok) >= 2 and tok[0] == "0" and tok[1].upper() == "FILE":
            cur = _ref_name(tok[2] if len(tok) > 2 else "")
            docs.setdefault(cur, [])
            main = main or cur
            continue
        if len(tok) >= 2 and tok[0] == "0" and tok[1].upper() == "NOFILE":
            cur = None
            continue
        if cur is not None:
            docs[cur].append((no, s))
    return main, docs


def _is_part(body) -> bool:
    """A sub-file that declares itself a part (``0 !LDRAW_ORG Part ...``,
    ``Unofficial_Part``, subparts, primitives): an inlined part definition,
    not a sub-model."""
    for _, s in body[:20]:
        tok = s.split()
        if len(tok) >= 3 and tok[0] == "0" and tok[1].upper() == "!LDRAW_ORG":
            kind = tok[2].lower()
            return any(w in kind for w in ("part", "primitive", "shortcut")) and "model" not in kind
    return False


def _ref_name(ref: str) -> str:
    return ref.strip().replace("\\", "/").lower()


def flatten_ldr(text: str, source: str = "<memory>", base_dir: str | None = None):
    """Every part placed by an LDraw file, sub-models flattened.

    A multi-part document (``0 FILE`` sections, ``.mpd``) starts at its first
    file; a type-1 reference to one of its sub-files (unless that declares
    itself a part: an inlined part definition), or to an ``.ldr`` / ``.mpd``
    file beside it in ``base_dir``, is expanded with its transform (rotation
    and offset composed). Any other ``.dat`` reference is a part, never
    expanded. Returns (parts, unsupported):
    parts a list of (number, rotation (3, 3), origin (3,) LDU, where, meta)
    for the parts of :data:`~stablelego_jax.formats.ldraw_parts.LDRAW_PARTS`
    (printed and mould variants included); unsupported {part number or
    what: [count, where first seen]} for everything else that adds geometry
    (other parts, missing sub-models, drawing primitives). Malformed lines,
    bad ``0 // stablelego`` comments and sub-models that include themselves
    raise LayoutError naming the file and line.
    """
    main, docs = _split_mpd(text.splitlines())
    if main is None:
        main, docs = "", {"": [(no, raw.strip().lstrip("\ufeff")) for no, raw in enumerate(text.splitlines(), 1)]}
    parts: list[_Part] = []
    unsupported: dict = {}
    loaded: dict = {}

    def miss(what: str, where: str):
        c = unsupported.setdefault(what, [0, where])
        c[0] += 1

    def lines_of(name: str, label: str):
        if name in docs:
            return docs[name], label
        if name in loaded:
            return loaded[name]
        path = os.path.join(base_dir, name) if base_dir is not None else None
        if path is None or not os.path.isfile(path):
            return None
        sub_main, sub_docs = _split_mpd(read_text(path).splitlines())
        if sub_main is None:
            body = [(no, raw.strip()) for no, raw in enumerate(read_text(path).splitlines(), 1)]
        else:
            docs.update({k: v for k, v in sub_docs.items() if k not in docs})
            body = sub_docs[sub_main]
        loaded[name] = (body, os.path.basename(path))
        return loaded[name]

    def expand(body, label: str, M: np.ndarray, t: np.ndarray, chain: tuple):
        pending, pending_where = None, ""
        for no, s in body:
            if not s:
                continue
            where = f"{label + ' ' if label else ''}line {no}"
            tok = s.split()
            kind = tok[0]
            if kind == "0":
                if s.startswith(_META.rstrip()) and len(s) > len(_META.rstrip()):
                    raw_meta = s[len(_META.rstrip()):].strip()
                    try:
                        pending = json.loads(raw_meta)
                    except json.JSONDecodeError:
                        raise LayoutError(source, f"{where}: bad stablelego comment {raw_meta[:60]!r}") from None
                    if not isinstance(pending, dict):
                        raise LayoutError(source, f"{where}: stablelego comment must be a JSON object")
                    pending_where = where
                continue
            if kind in ("2", "3", "4", "5"):
                miss(f"drawing primitives (line type {kind})", where)
                continue
            if kind != "1":
                raise LayoutError(source, f"{where}: unknown LDraw line type {kind[:20]!r}")
            meta, pending = pending or {}, None
            key = str(meta.get("key", len(parts) + 1))
            if len(tok) < 15:
                raise LayoutError(source, f"{where}: type-1 line needs 15 fields, got {len(tok)}", key)
            try:
                nums = np.array([float(v) for v in tok[2:14]])
            except ValueError:
                raise LayoutError(source, f"{where}: position or rotation is not a number", key) from None
            if not np.isfinite(nums).all():
                raise LayoutError(source, f"{where}: position or rotation is not finite", key)
            ref = " ".join(tok[14:])
            name = _ref_name(ref)
            Mc, tc = nums[3:].reshape(3, 3), nums[:3]
            Mw, tw = M @ Mc, M @ tc + t
            number = part_number(name)
            if number not in LDRAW_PARTS and (not name.endswith(".dat") or (name in docs and not _is_part(docs[name]))):
                sub = lines_of(name, name)
                if sub is None:
                    miss(f"{ref} (missing sub-model)", where)
                    continue
                if name in chain or len(chain) > 64:
                    raise LayoutError(source, f"{where}: sub-model {ref!r} includes itself")
                expand(sub[0], sub[1], Mw, tw, chain + (name,))
                continue
            if number not in LDRAW_PARTS:
                miss(number, where)
                continue
            parts.append(_Part(number, Mw, tw, where, meta))
        if pending is not None:
            raise LayoutError(source, f"{pending_where}: stablelego comment not followed by a brick")

    body = docs[main]
    expand(body, "", np.eye(3), np.zeros(3), (main,))
    return parts, unsupported


def unsupported_message(unsupported: dict, limit: int = 12) -> str:
    """One line naming each unsupported part once, with its count and where
    it first appears, most frequent first."""
    items = sorted(unsupported.items(), key=lambda kv: (-kv[1][0], kv[0]))
    shown = [f"{k} x{c} ({w})" for k, (c, w) in items[:limit]]
    more = f", and {len(items) - limit} more" if len(items) > limit else ""
    total = sum(c for c, _ in unsupported.values())
    return f"{total} part{'s' * (total != 1)} cannot be modelled: {', '.join(shown)}{more}"


def _orient(M: np.ndarray):
    """(yaw of the part's X axis in degrees, or None; what is wrong): the
    part must stand upright, turned only about the vertical axis."""
    if not np.allclose(M.T @ M, np.eye(3), atol=_TOL):
        return None, "not a rotation"
    if abs(M[1, 1] - 1) <= _TOL and np.allclose(M[1, [0, 2]], 0, atol=_TOL) and np.allclose(M[[0, 2], 1], 0, atol=_TOL):
        return math.degrees(math.atan2(M[2, 0], M[0, 0])), ""
    if abs(M[1, 1] + 1) <= _TOL:
        return None, "upside down"
    return None, "tilted"


def parse_ldr(text: str, source: str = "<memory>", ground: bool = True, skip_unsupported: bool = False,
              base_dir: str | None = None, report: dict | None = None) -> Layout | Scene:
    """LDraw text (``.ldr`` or ``.mpd``) -> Layout or Scene.

    Sub-models are flattened (:func:`flatten_ldr`). Parts that cannot be
    modelled (anything but the bricks and plates of
    :data:`~stablelego_jax.formats.ldraw_parts.LDRAW_PARTS`, tilted or
    upside-down parts, drawing primitives, missing sub-models, and a part
    whose volume overlaps one placed before it, such as a duplicate) raise
    one LayoutError naming each once with its count
    (:func:`unsupported_message`); with ``skip_unsupported`` they are left
    out, and ``report`` (a dict, if given) receives them as {what: [count,
    where first seen]}. The colour is ignored.

    Only the basic bricks (PARTS) on one stud grid and one layer grid,
    turned by multiples of 90 degrees, give a grid Layout (as before: a
    common offset is removed, coordinates are shifted to be >= 0); anything
    else (plates, other sizes, other turns, half-stud offsets) gives a Scene
    whose bricks sit at their LDraw positions in studs and plate heights
    (one stud lattice: the first square part's studs at half-integer
    coordinates). With ``ground`` (default) the lowest bottom becomes the
    baseplate (layer or level 0).
    """
    parts, unsupported = flatten_ldr(text, source, base_dir)
    orient = [_orient(p.M) for p in parts]
    for p, (_, bad) in zip(parts, orient):
        if bad:
            c = unsupported.setdefault(f"{p.number} {bad}", [0, p.where])
            c[0] += 1
    if unsupported and not skip_unsupported:
        first = min((w for _, w in unsupported.values()), key=_line_order)
        raise LayoutError(source, f"{first}: {unsupported_message(unsupported)}; "
                                  "--skip-unsupported analyses the rest")
    keep = [i for i, (_, bad) in enumerate(orient) if not bad]
    parts = [parts[i] for i in keep]
    yaw = np.array([orient[i][0] for i in keep], np.float64)
    if not parts and unsupported:
        raise LayoutError(source, f"nothing left to analyse: {unsupported_message(unsupported)}")
    if not parts:
        raise LayoutError(source, "no brick parts (type-1 lines) in the file")
    scene = _scene_of(parts, yaw, source, ground)
    pairs = overlapping_pairs(scene)
    if len(pairs):
        if not skip_unsupported:
            i, j = (int(v) for v in pairs[0])
            raise LayoutError(source, f"{parts[j].where}: part {parts[j].number} overlaps part {parts[i].number} "
                                      f"({parts[i].where}); --skip-unsupported leaves it out", scene.keys[j])
        dropped: set = set()
        for i, j in pairs.tolist():  # ordered by j: keep the first of overlapping parts
            if i not in dropped and j not in dropped:
                dropped.add(j)
                c = unsupported.setdefault(f"{parts[j].number} overlapping another part", [0, parts[j].where])
                c[0] += 1
        kept = [k for k in range(len(parts)) if k not in dropped]
        parts, yaw = [parts[k] for k in kept], yaw[kept]
        scene = _scene_of(parts, yaw, source, ground)
    if report is not None:
        report.update(unsupported)
    grid = _grid_layout(parts, yaw, source, ground)
    if grid is not None:
        return grid
    return make_scene(scene.keys, scene.kind, scene.pos, scene.size, scene.yaw, scene.mass, scene.brick_id,
                      source=source, fmt="ldr")


def _line_order(where: str):
    m = re.search(r"line (\d+)$", where)
    return (" " in where.rsplit("line", 1)[0].strip(), int(m.group(1)) if m else 0)


def _keys(parts) -> list[str]:
    return [str(p.meta.get("key", i + 1)) for i, p in enumerate(parts)]


def _grid_layout(parts, yaw, source: str, ground: bool) -> Layout | None:
    """The grid Layout of ``parts`` if every one is a basic brick (PARTS)
    turned by a multiple of 90 degrees, all on one stud and layer grid, and
    no comment gives a yaw; else None."""
    quarter = yaw / 90.0
    if any(p.number not in PART_SIZES or "yaw" in p.meta for p in parts) or \
            (np.abs(quarter - np.round(quarter)) * 90.0 > 0.06).any():
        return None
    dims = np.array([PART_SIZES[p.number] for p in parts], np.int64)
    long_x = np.round(quarter).astype(np.int64) % 2 == 0  # the part's X (its long side) along layout x
    size = np.where(long_x[:, None], dims[:, ::-1], dims)  # (sx, sy)
    P = np.array([p.t for p in parts])
    coords = []
    for v in (P[:, 0] / LDU_STUD - size[:, 0] / 2, P[:, 2] / LDU_STUD - size[:, 1] / 2, -P[:, 1] / LDU_LAYER):
        w = v - (v[0] - np.round(v[0]))
        if (np.abs(w - np.round(w)) > _TOL).any():
            return None
        coords.append(np.round(w).astype(np.int64))
    x, y, z = coords
    x -= min(int(x.min()), 0)
    y -= min(int(y.min()), 0)
    z -= int(z.min()) if ground else min(int(z.min()), 0)
    keys = _keys(parts)
    table_mass, table_bids, table_oris = table_i_bricks(size)
    mass, bids, oris = [], [], []
    for i, p in enumerate(parts):
        m = p.meta.get("mass", float(table_mass[i]))
        if isinstance(m, bool) or not isinstance(m, (int, float)):
            raise LayoutError(source, f"{p.where}: mass {m!r} is not a number", keys[i])
        mass.append(float(m))
        bids.append(str(p.meta.get("brick_id", table_bids[i])))
        oris.append(p.meta.get("ori", int(table_oris[i])))
    return make_layout(keys, np.stack([x, y, z], axis=1), size, mass, bids, oris, source=source, fmt="ldr")


def _default_id(sx: int, sy: int, height: int, number: str) -> str:
    """The id a part gets when read: the StableLego library id of a Table I
    brick, else its LDraw part number."""
    bid, _ = library_id_for(sx, sy) if height == BRICK_H else ("", 0)
    return bid or number


def _square(yaw):
    """Turned by a multiple of 90 degrees (to 1e-9 of a quarter turn)?"""
    return np.abs(np.asarray(yaw) / 90.0 - np.round(np.asarray(yaw) / 90.0)) < 1e-9


def first_stud(centre, studs, yaw_deg: float) -> np.ndarray:
    """(2,) centre of the stud in the local (-x, -y) corner of a part with
    ``studs`` (2,) along its own axes, centred at ``centre`` (2,) and turned
    by ``yaw_deg``; all in studs."""
    t = math.radians(float(yaw_deg))
    o = 0.5 - np.asarray(studs, np.float64) / 2
    return np.asarray(centre, np.float64) + [o[0] * math.cos(t) - o[1] * math.sin(t),
                                              o[0] * math.sin(t) + o[1] * math.cos(t)]


def _on_lattice(scene: Scene, i: int) -> bool:
    """Do part ``i``'s studs sit at half-integer stud coordinates (the baseplate's lattice)?"""
    st = first_stud(scene.pos[i, :2], scene.size[i, :2], scene.yaw[i]) - 0.5
    return bool(np.allclose(st, np.round(st), atol=_TOL))


def _scene_of(parts, yaw, source: str, ground: bool) -> Scene:
    """The Scene of ``parts`` (see :func:`parse_ldr`), not yet checked for overlaps."""
    n = len(parts)
    dims = np.array([LDRAW_PARTS[p.number] for p in parts], np.int64)  # (a, b, height)
    studs = dims[:, [1, 0]].copy()  # the part's X holds its b studs
    yaw = np.round(yaw, 9)
    for i, p in enumerate(parts):  # a written yaw (this module's comment) says which way the part was turned
        if "yaw" in p.meta:
            want = float(p.meta["yaw"])
            d = (yaw[i] - want) % 180.0
            if min(abs(d - 90.0), 180.0 - abs(d - 90.0)) < 1e-3:
                studs[i] = dims[i, :2]
            yaw[i] = want
    P = np.array([p.t for p in parts])
    xy = P[:, [0, 2]] / LDU_STUD
    level = -(P[:, 1] / (LDU_LAYER / 3) + dims[:, 2])
    # one stud lattice: the studs of the first part turned by a multiple of 90 degrees at half-integers
    # (or of the part an export marked as its anchor), and that part's plate grid
    marked = [i for i, p in enumerate(parts) if p.meta.get("anchor")]
    square = np.nonzero(_square(yaw))[0]
    anchor = marked[0] if marked else int(square[0]) if len(square) else None
    if anchor is not None and _square(yaw[anchor]):
        stud = first_stud(xy[anchor], studs[anchor], yaw[anchor])
        xy = xy - ((stud - 0.5) - np.round(stud - 0.5))
    xy = np.round(xy, 9) + 0.0
    z0 = level[marked[0] if marked else 0]
    level = level - (z0 - np.round(z0))  # that part's (else the first part's) plate grid
    level = np.where(np.abs(level - np.round(level)) <= _TOL, np.round(level), np.round(level, 9))
    level -= level.min() if ground else min(level.min(), 0.0)
    keys = _keys(parts)
    mass, bids = [], []
    for i, p in enumerate(parts):
        sx, sy, h = int(studs[i, 0]), int(studs[i, 1]), int(dims[i, 2])
        m = p.meta.get("mass", part_mass(sx, sy, h))
        if isinstance(m, bool) or not isinstance(m, (int, float)):
            raise LayoutError(source, f"{p.where}: mass {m!r} is not a number", keys[i])
        mass.append(float(m))
        bids.append(str(p.meta.get("brick_id", _default_id(sx, sy, h, p.number))))
    pos = np.column_stack([xy, level])
    size = np.column_stack([studs, dims[:, 2]]).astype(np.float64)
    return Scene(keys=tuple(keys), kind=np.full(n, BRICK, np.int8), pos=pos, size=size, yaw=yaw,
                 mass=np.array(mass), brick_id=tuple(bids), source=source, fmt="ldr")


def read_ldr(path: str, ground: bool = True, skip_unsupported: bool = False,
             report: dict | None = None) -> Layout | Scene:
    """Read an LDraw file (``.ldr`` or ``.mpd``; see :func:`parse_ldr`), sub-models
    in other files resolved beside it; errors name ``path``."""
    return parse_ldr(read_text(path), source=path, ground=ground, skip_unsupported=skip_unsupported,
                     base_dir=os.path.dirname(os.path.abspath(path)), report=report)
