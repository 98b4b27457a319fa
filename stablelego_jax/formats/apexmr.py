"""APEX-MR build sequences (``config/lego_tasks/steps/<task>_seq.json``).

APEX-MR (Huang et al. 2025, the multi-robot Lego assembly planner of the
StableLego authors' lab) writes each task as a StableLego-style task graph
whose keys ``"1" .. "n"`` are the build order, one brick a step, with the
robot's press location (``press_x/y/z``, ``press_ori``: where its 1x2 press
tool pushes the new brick down) and, where its planner used a second arm to
hold the structure from below, that support's column and height
(``support_x/y/z``; ``support_x == -1``: no support). Its ``z`` counts from 1 on the plate;
layer = z - 1 here. The task's ``env_setup/env_setup_<task>.json`` places
every inventory brick (``b<id>_<k>``) on the plate before the build; bricks
that no step picks and that touch the structure through knobs are fixed
pillars the structure is built on (some tasks start on them).

:func:`read_apex_seq` returns the layout (steps and pillars, Table I
masses), the order and the per-step press and support locations, all in
this library's stud-grid cells.
"""
from __future__ import annotations

import dataclasses
import os
from typing import Mapping

from ..layout import Layout, LayoutError, brick_layout
from .stablelego import read_json

__all__ = ["APEX_SIZES", "PRESS_SIZE", "ApexTask", "is_apex_seq", "parse_apex_seq", "read_apex_seq",
           "env_setup_for"]

#: Brick ids of APEX-MR's ``config/lego_tasks/lego_library.json`` -> (height, width) in studs
#: (ori 0: height along x). Masses are taken from paper Table I by footprint.
APEX_SIZES: dict[int, tuple[int, int]] = {
    2: (2, 4), 3: (2, 6), 4: (1, 8), 5: (1, 4), 6: (1, 6), 7: (1, 4), 8: (1, 4),
    9: (1, 2), 10: (1, 1), 11: (1, 2), 12: (2, 2),
}
#: APEX-MR's press tool as its stability check models it: a 1x2 block (its library id 90).
PRESS_SIZE = (1, 2)
_STEP_FIELDS = ("x", "y", "z", "brick_id", "ori")


@dataclasses.dataclass(frozen=True)
class ApexTask:
    """One APEX-MR task in stud-grid cells (layer = APEX z - 1).

    layout: the step bricks (keys as in the file) and the fixed pillars
    (keys of env_setup); order: step keys in build order; fixed: pillar
    keys (present before step 1); press: {step key: (x, y, layer, sx, sy)}
    cells of the press block on top of the new brick; press_from_below:
    steps pressed from below (press layer under the brick: not a load this
    library can model); support: {step key: (x, y, layer)} for the steps
    where APEX-MR used a support: the stud column of its pillar and the
    highest layer it fills (its check puts support blocks in the empty cells
    of that column from the plate up to that layer, the one under the
    pressed brick).
    """

    layout: Layout
    order: tuple[str, ...]
    fixed: tuple[str, ...]
    press: dict
    press_from_below: frozenset
    support: dict


def is_apex_seq(raw) -> bool:
    """True when ``raw`` (parsed JSON) looks like an APEX-MR step file."""
    if not isinstance(raw, Mapping) or not raw:
        return False
    first = next(iter(raw.values()))
    return isinstance(first, Mapping) and "press_x" in first and "support_x" in first


def env_setup_for(seq_path: str) -> str | None:
    """``../env_setup/env_setup_<task>.json`` beside an APEX-MR step file, if it exists."""
    name = os.path.basename(seq_path)
    if not name.endswith("_seq.json"):
        return None
    task = name[: -len("_seq.json")]
    p = os.path.join(os.path.dirname(os.path.abspath(seq_path)), "..", "env_setup", f"env_setup_{task}.json")
    return os.path.normpath(p) if os.path.isfile(p) else None


def _size(bid, ori, source: str, key: str) -> tuple[int, int]:
    try:
        h, w = APEX_SIZES[int(bid)]
    except (KeyError, TypeError, ValueError):
        raise LayoutError(source, f"unknown APEX-MR brick_id {bid!r}", key) from None
    if ori not in (0, 1):
        raise LayoutError(source, f"ori must be 0 or 1, got {ori!r}", key)
    return (h, w) if ori == 0 else (w, h)


def _int(b: Mapping, f: str, source: str, key: str) -> int:
    v = b.get(f)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v != int(v):
        raise LayoutError(source, f"field {f}={v!r} is not an integer", key)
    return int(v)


def _cells(pos, size):
    x, y, z = pos
    return {(x + i, y + j, z) for i in range(size[0]) for j in range(size[1])}


def parse_apex_seq(raw, env: Mapping | None = None, source: str = "<memory>",
                   env_source: str = "<env_setup>") -> ApexTask:
    """APEX-MR step file (parsed JSON) and optional env_setup -> :class:`ApexTask`.

    LayoutError naming ``source`` (or ``env_source``) and the key on a
    missing field, an unknown brick id, a brick below the plate or
    overlapping bricks."""
    if not is_apex_seq(raw):
        raise LayoutError(source, "not an APEX-MR step file (entries need press_x and support_x)")
    keys, pos, size = [], [], []
    press, below, support, picked = {}, set(), {}, set()
    for key, b in raw.items():
        key = str(key)
        if not isinstance(b, Mapping):
            raise LayoutError(source, "step entry is not an object", key)
        for f in _STEP_FIELDS:
            if f not in b:
                raise LayoutError(source, f"missing field {f}", key)
        x, y, z = (_int(b, f, source, key) for f in ("x", "y", "z"))
        if z < 1:
            raise LayoutError(source, f"z={z} is below the plate (APEX-MR layers start at 1)", key)
        sz = _size(b["brick_id"], b["ori"], source, key)
        keys.append(key)
        pos.append((x, y, z - 1))
        size.append(sz)
        if "brick_seq" in b:
            picked.add(f"b{b['brick_id']}_{b['brick_seq']}")
        pz = _int(b, "press_z", source, key) - 1
        if pz == z:  # one layer above the brick (its top): a downward press
            po = _int(b, "press_ori", source, key)
            p = PRESS_SIZE if po % 2 == 0 else PRESS_SIZE[::-1]
            press[key] = (_int(b, "press_x", source, key), _int(b, "press_y", source, key), pz, p[0], p[1])
        else:
            below.add(key)
        if _int(b, "support_x", source, key) != -1:
            support[key] = (_int(b, "support_x", source, key), _int(b, "support_y", source, key),
                            _int(b, "support_z", source, key))
    fixed = []
    if env:
        fixed = _pillars(env, picked, [_cells(p, s) for p, s in zip(pos, size)], env_source)
    fk = [k for k, _, _ in fixed]
    if set(fk) & set(keys):
        raise LayoutError(env_source, "env_setup key is also a step key", sorted(set(fk) & set(keys))[0])
    layout = brick_layout([p for _, p, _ in fixed] + pos, [s for _, _, s in fixed] + size, fk + keys,
                          source=source, fmt="json")
    return ApexTask(layout=layout, order=tuple(keys), fixed=tuple(fk), press=press,
                    press_from_below=frozenset(below), support=support)


def _pillars(env: Mapping, picked: set, step_cells: list, source: str) -> list:
    """(key, pos, size) of the env_setup bricks that no step picks and that
    are knob-connected (directly or through each other) to a step brick."""
    cand = []
    for name, b in env.items():
        if name in picked:
            continue
        if not isinstance(b, Mapping):
            raise LayoutError(source, "entry is not an object", name)
        try:
            bid = int(str(name)[1:].split("_")[0])
        except ValueError:
            raise LayoutError(source, "name is not b<id>_<k>", name) from None
        x, y, z = (_int(b, f, source, name) for f in ("x", "y", "z"))
        if z < 1:
            raise LayoutError(source, f"z={z} is below the plate", name)
        sz = _size(bid, b.get("ori", 0), source, name)
        cand.append((str(name), (x, y, z - 1), sz))
    reach = set().union(*step_cells) if step_cells else set()
    out, todo = [], list(cand)
    grew = True
    while grew:
        grew = False
        for c in list(todo):
            cells = _cells(c[1], c[2])
            if any((x, y, z + 1) in reach or (x, y, z - 1) in reach for x, y, z in cells):
                out.append(c)
                reach |= cells
                todo.remove(c)
                grew = True
    return sorted(out, key=lambda c: (c[1][2], c[0]))


def read_apex_seq(path: str, env_setup: str | None = "auto") -> ApexTask:
    """Read an APEX-MR step file; ``env_setup``: its env_setup JSON,
    "auto" (the task's file beside it in the APEX-MR tree, when there) or
    None (no pillars)."""
    raw = read_json(path)
    env_path = env_setup_for(path) if env_setup == "auto" else env_setup
    env = read_json(env_path) if env_path else None
    if env is not None and not isinstance(env, Mapping):
        raise LayoutError(env_path, "env_setup must be a JSON object of bricks")
    return parse_apex_seq(raw, env, source=path, env_source=env_path or "<env_setup>")
