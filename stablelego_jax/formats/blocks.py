"""Scenes as JSON: plain blocks, boxes on pallets, rotated bricks (SPEC "Extensions").

The ``"blocks"`` format::

    {"units": "m", "friction": 0.0,
     "blocks": {"a": {"center": [x, y, z], "size": [sx, sy, sz], "yaw": 0.0, "mass": 0.5}, ...},
     "bricks": {"1": {"x": 0, "y": 0, "z": 0, "brick_id": 9, "ori": 0},
                "2": {"center": [2.0, 1.5], "yaw": 30.0, "z": 1, "brick_id": 9}, ...}}

Blocks: centre and extents (along the block's own axes before the yaw) in
metres, yaw in degrees about +z (default 0), mass in kg. Bricks: the
StableLego schema (``x``, ``y``, ``z``, ``brick_id``, ``ori``, optional
``mass``), or ``center`` ([cx, cy] in studs) and ``yaw`` in place of ``x``,
``y`` and ``ori`` (the library's height along the brick's own x). A plain
StableLego layout whose bricks give ``center`` / ``yaw`` is a scene too.

Extensions for parts outside the library (plates and other sizes, as LDraw
files bring them): ``"studs": [sx, sy]`` and ``"mass"`` in place of
``brick_id`` (``"part"``: an optional part number kept as the id),
``"thickness"``: the part's height in plate heights (3: a brick, the
default; 1: a plate), ``"level"``: its bottom in plate heights in place of
``z`` (a brick on layer z has level 3 z; LDraw models may place a part
between whole plate heights).

Keys are strings, one namespace for blocks and bricks, reported back as
given; errors name the file and the block or brick.
"""
from __future__ import annotations

import math
from typing import Mapping

from ..layout import MAX_COORD, LayoutError, Library, default_library
from ..scene import BLOCK, BRICK, Scene, make_scene

__all__ = ["is_scene_json", "parse_scene_json", "scene_to_json_dict", "UNITS"]

#: The units a scene file may name (metres, the SPEC's one).
UNITS = ("m",)
_BLOCK_FIELDS = {"center", "size", "yaw", "mass"}
_BRICK_FIELDS = {"x", "y", "z", "brick_id", "ori", "mass", "center", "yaw", "studs", "thickness", "level", "part"}


def is_scene_json(raw) -> bool:
    """True for a ``"blocks"`` document (a ``blocks`` or ``bricks`` object of
    objects beside the optional ``units`` / ``friction``), or a StableLego
    layout with a ``center`` or ``yaw`` brick."""
    if not isinstance(raw, Mapping):
        return False
    for sec in ("blocks", "bricks"):
        v = raw.get(sec)
        if isinstance(v, Mapping) and all(isinstance(b, Mapping) for b in v.values()) and \
                set(raw) <= {"blocks", "bricks", "units", "friction"}:
            return True
    return any(isinstance(b, Mapping) and ("center" in b or "yaw" in b) for b in raw.values())


def _num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and _finite(v)


def _finite(v) -> bool:
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


def _vec(b, field, n, source, key, what):
    v = b.get(field)
    if not isinstance(v, list) or len(v) != n or not all(_num(x) for x in v):
        raise LayoutError(source, f"{field} must be a list of {n} finite numbers, got {str(v)[:60]}", key, what=what)
    return [float(x) for x in v]


def parse_scene_json(raw, library: Library | None = None, source: str = "<memory>") -> Scene:
    """A scene document (see the module doc) -> validated Scene."""
    lib = library or default_library()
    if not isinstance(raw, Mapping):
        raise LayoutError(source, "layout must be a JSON object")
    blocks_doc = any(k in raw for k in ("blocks", "bricks")) and set(raw) <= {"blocks", "bricks", "units", "friction"}
    friction, sections = 0.0, []
    if blocks_doc:
        units = raw.get("units", "m")
        if units not in UNITS:
            raise LayoutError(source, f"units must be {' or '.join(map(repr, UNITS))}, got {str(units)[:20]!r}")
        friction = raw.get("friction", 0.0)
        if not _num(friction) or friction < 0:
            raise LayoutError(source, f"friction must be a finite number >= 0, got {str(friction)[:20]}")
        for sec in raw:
            if sec in ("blocks", "bricks"):
                if not isinstance(raw[sec], Mapping):
                    raise LayoutError(source, f"{sec!r} must be an object of {sec}")
                sections.append((sec, raw[sec]))
        fmt = "blocks"
    else:
        sections.append(("bricks", raw))
        fmt = "json"
    keys, kind, pos, size, yaw, mass, bids = [], [], [], [], [], [], []
    for sec, entries in sections:
        for key, b in entries.items():
            key = str(key)
            what = "block" if sec == "blocks" else "brick"
            if not isinstance(b, Mapping):
                raise LayoutError(source, f"{what} entry is not an object", key, what=what)
            if sec == "blocks":
                extra = sorted(set(b) - _BLOCK_FIELDS)
                if extra:
                    raise LayoutError(source, f"unknown field(s) {', '.join(extra)}", key, what=what)
                missing = [f for f in ("center", "size", "mass") if f not in b]
                if missing:
                    raise LayoutError(source, f"missing field(s) {', '.join(missing)}", key, what=what)
                c = _vec(b, "center", 3, source, key, what)
                s = _vec(b, "size", 3, source, key, what)
                y = b.get("yaw", 0.0)
                if not _num(y):
                    raise LayoutError(source, f"yaw must be a finite number (degrees), got {str(y)[:20]}", key,
                                      what=what)
                m = b["mass"]
                if not _num(m):
                    raise LayoutError(source, f"mass must be a finite number (kg), got {str(m)[:20]}", key, what=what)
                keys.append(key), kind.append(BLOCK), pos.append(c), size.append(s), yaw.append(float(y))
                mass.append(float(m)), bids.append("")
            else:
                p, s, y, m, bid = _brick(b, lib, source, key)
                keys.append(key), kind.append(BRICK), pos.append(p), size.append(s), yaw.append(y)
                mass.append(m), bids.append(bid)
    if not keys:
        raise LayoutError(source, "layout is empty (no blocks or bricks)")
    return make_scene(keys, kind, pos, size, yaw, mass, bids, friction=float(friction), source=source, fmt=fmt)


def _brick(b: Mapping, lib: Library, source: str, key: str):
    """(pos, size, yaw, mass, id) of one brick entry (see the module doc)."""
    extra = sorted(set(b) - _BRICK_FIELDS)
    if extra:
        raise LayoutError(source, f"unknown field(s) {', '.join(extra)}", key)
    rotated = "center" in b or "yaw" in b
    if rotated and any(f in b for f in ("x", "y", "ori")):
        raise LayoutError(source, "give either center and yaw or x, y and ori, not both", key)
    if ("z" in b) == ("level" in b):
        raise LayoutError(source, "give exactly one of z (layer) and level (plate heights)", key)
    # size and mass: library id, or explicit studs and mass
    if "studs" in b:
        st = b["studs"]
        if not isinstance(st, list) or len(st) != 2 or not all(_num(v) and v == int(v) and v >= 1 for v in st):
            raise LayoutError(source, f"studs must be two integers >= 1, got {str(st)[:40]}", key)
        if "mass" not in b:
            raise LayoutError(source, "a brick given by studs needs a mass (kg)", key)
        h, w, m = int(st[0]), int(st[1]), None
        bid = str(b.get("part", b.get("brick_id", "")))
    else:
        if "brick_id" not in b:
            raise LayoutError(source, "missing field brick_id (or studs and mass)", key)
        bid = str(b["brick_id"])
        if bid not in lib.bricks:
            raise LayoutError(source, f"unknown brick_id {b['brick_id']!r} (not in {lib.source})", key)
        h, w, m = lib.bricks[bid]
    if "mass" in b:
        m = b["mass"]
        if not _num(m) or m < 0:
            raise LayoutError(source, f"mass must be a finite number >= 0, got {str(m)[:20]}", key)
    thick = b.get("thickness", 3)
    if not (_num(thick) and thick == int(thick) and thick >= 1):
        raise LayoutError(source, f"thickness must be an integer >= 1 (plate heights), got {str(thick)[:20]}", key)
    if "z" in b:
        z = b["z"]
        if not (_num(z) and z == int(z) and 0 <= z <= MAX_COORD):
            raise LayoutError(source, f"z must be an integer layer in 0..{MAX_COORD}, got {str(z)[:20]}", key)
        level = 3 * int(z)
    else:
        level = b["level"]
        if not (_num(level) and 0 <= level <= 3 * MAX_COORD):
            raise LayoutError(source, f"level must be a number >= 0 (plate heights), got {str(level)[:20]}", key)
    if rotated:
        if "center" not in b:
            raise LayoutError(source, "a brick with a yaw needs a center [cx, cy] (studs)", key)
        cx, cy = _vec(b, "center", 2, source, key, "brick")
        y = b.get("yaw", 0.0)
        if not _num(y):
            raise LayoutError(source, f"yaw must be a finite number (degrees), got {str(y)[:20]}", key)
        sx, sy, yaw = h, w, float(y)
    else:
        missing = [f for f in ("x", "y") if f not in b]
        if missing:
            raise LayoutError(source, f"missing field(s) {', '.join(missing)}", key)
        for f in ("x", "y"):
            v = b[f]
            if not (_num(v) and v == int(v) and 0 <= v <= MAX_COORD):
                raise LayoutError(source, f"coordinate {f}={str(v)[:20]} must be an integer in 0..{MAX_COORD}", key)
        ori = b.get("ori", 0)
        if ori not in (0, 1) or isinstance(ori, bool):
            raise LayoutError(source, f"ori must be 0 or 1, got {ori!r}", key)
        sx, sy = (h, w) if ori == 0 else (w, h)
        cx, cy, yaw = b["x"] + sx / 2, b["y"] + sy / 2, 0.0
    return [float(cx), float(cy), float(level)], [float(sx), float(sy), float(thick)], yaw, float(m), bid


def scene_to_json_dict(scene: Scene, library: Library | None = None) -> dict:
    """Scene -> JSON object, in the form it was read in: a ``"blocks"``
    document, or (``fmt == "json"``, bricks only) a StableLego layout with
    ``center`` / ``yaw`` bricks. Bricks at yaw 0 on the grid are written as
    ``x``, ``y``, ``ori``; bricks whose size is not their library id's
    (or that have none) with ``studs`` and ``mass``; a mass other than the
    library's is written as ``mass``. Reading the result gives the same scene."""
    lib = library or default_library()
    bricks, blocks = {}, {}
    for i, k in enumerate(scene.keys):
        if scene.kind[i] == BLOCK:
            blocks[k] = {"center": scene.pos[i].tolist(), "size": scene.size[i].tolist(),
                         "yaw": float(scene.yaw[i]), "mass": float(scene.mass[i])}
        else:
            bricks[k] = _brick_entry(scene, i, lib)
    if scene.fmt == "json" and not blocks and scene.friction == 0:
        return bricks
    out: dict = {"units": "m", "friction": scene.friction}
    sections = [("bricks", bricks), ("blocks", blocks)]
    if scene.kind[0] == BLOCK:  # the kind of the first body first
        sections.reverse()
    out.update((name, sec) for name, sec in sections if sec)
    return out


def _brick_entry(scene: Scene, i: int, lib: Library) -> dict:
    (cx, cy, level), (sx, sy, thick) = scene.pos[i].tolist(), scene.size[i].tolist()
    sx, sy, thick = int(sx), int(sy), int(thick)
    level = int(level) if level == int(level) else level
    bid, m, yaw = scene.brick_id[i], float(scene.mass[i]), float(scene.yaw[i])
    d: dict = {}
    entry = lib.bricks.get(bid)
    ori = None
    if entry is not None:
        h, w, lib_m = entry
        if (sx, sy) == (h, w):
            ori = 0
        elif (sx, sy) == (w, h) and yaw == 0:
            ori = 1
    x0, y0 = cx - sx / 2, cy - sy / 2
    if yaw == 0 and ori is not None and x0 == int(x0) and y0 == int(y0) and x0 >= 0 and y0 >= 0:
        d.update(x=int(x0), y=int(y0))
    else:
        d.update(center=[cx, cy], yaw=yaw)
    if isinstance(level, int) and level % 3 == 0:
        d["z"] = level // 3
    else:
        d["level"] = level
    if ori is not None:
        d["brick_id"] = int(bid) if bid.isdigit() else bid
        if "x" in d:
            d["ori"] = ori
        if not math.isclose(m, entry[2], rel_tol=1e-12, abs_tol=0.0):
            d["mass"] = m
    else:
        d["studs"] = [sx, sy]
        d["mass"] = m
        if bid:
            d["part"] = bid
    if thick != 3:
        d["thickness"] = thick
    return d
