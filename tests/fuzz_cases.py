"""Random and malformed layout files for the fuzz suites (tests/test_fuzz.py,
benchmarks/fuzz.py): :func:`make_case` writes one, :func:`classify_error`
judges an error line. Seeded: the same seed writes the same files."""
from __future__ import annotations

import json
import os
import re

import numpy as np

#: The real bricks of the StableLego library: id -> (height, width).
SIZES = {2: (2, 4), 3: (2, 6), 4: (1, 8), 5: (1, 4), 6: (1, 6), 9: (1, 2), 10: (1, 1), 12: (2, 2)}
KINDS = ("valid_json", "valid_text", "valid_far", "truncated", "wrong_type", "bad_number", "overlap",
         "huge", "binary", "empty", "junk_text", "deep", "bad_mass", "ldr")

#: A Python exception class name in a message: the sign of an unexpected error.
EXC_NAME = re.compile(r"\b[A-Z][A-Za-z]*(Error|Exception)\b(?!\w)")


def random_bricks(rng, n_max: int = 10, span: int = 8) -> dict:
    """A random non-overlapping StableLego layout (dict), stacked from layer 0."""
    taken: set = set()
    out = {}
    for k in range(int(rng.integers(1, n_max + 1))):
        for _ in range(20):
            bid = int(rng.choice(list(SIZES)))
            ori = int(rng.integers(0, 2))
            h, w = SIZES[bid]
            sx, sy = (h, w) if ori == 0 else (w, h)
            x, y, z = int(rng.integers(0, span)), int(rng.integers(0, span)), int(rng.integers(0, 4))
            cells = {(x + i, y + j, z) for i in range(sx) for j in range(sy)}
            if not cells & taken:
                taken |= cells
                out[str(k + 1)] = {"x": x, "y": y, "z": z, "brick_id": bid, "ori": ori}
                break
    return out or {"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0}}


def _text(bricks: dict) -> str:
    lines = []
    for b in bricks.values():
        h, w = SIZES[b["brick_id"]]
        sx, sy = (h, w) if b["ori"] == 0 else (w, h)
        lines.append(f"{sx}x{sy} ({b['x']},{b['y']},{b['z']})")
    return "\n".join(lines) + "\n"


def make_case(rng, folder: str, i: int, kind: str | None = None) -> tuple[str, str]:
    """Write case ``i`` into ``folder``; returns (path, kind)."""
    kind = kind or str(rng.choice(KINDS))
    bricks = random_bricks(rng)
    ext, data = ".json", None
    if kind == "valid_json":
        data = json.dumps(bricks)
    elif kind == "valid_text":
        ext, data = ".txt", _text(bricks)
    elif kind == "valid_far":  # bricks far apart, within the documented limit
        k = next(iter(bricks))
        bricks[k]["x"] = bricks[k]["y"] = 2**16
        data = json.dumps(bricks)
    elif kind == "truncated":
        s = json.dumps(bricks)
        data = s[: int(rng.integers(0, len(s)))]
    elif kind == "wrong_type":
        b = bricks[str(rng.choice(list(bricks)))]
        f = str(rng.choice(["x", "y", "z", "brick_id", "ori"]))
        b[f] = [None, "1", [1], {"a": 1}, True, 1.5, "", -0.0][int(rng.integers(0, 8))]
        data = json.dumps(bricks) if rng.random() < 0.8 else json.dumps(list(bricks.values()))
    elif kind == "bad_number":
        b = bricks[str(rng.choice(list(bricks)))]
        b[str(rng.choice(["x", "y", "z"]))] = "@NUM@"
        num = ["NaN", "Infinity", "-Infinity", "1e308", "-1", "2.5", "1e400", "9" * 5000][int(rng.integers(0, 8))]
        data = json.dumps(bricks).replace('"@NUM@"', num)
    elif kind == "overlap":
        k = next(iter(bricks))
        bricks["dup"] = dict(bricks[k])
        data = json.dumps(bricks)
    elif kind == "huge":
        b = bricks[str(rng.choice(list(bricks)))]
        b[str(rng.choice(["x", "y", "z"]))] = int(10 ** int(rng.integers(5, 40)))
        data = json.dumps(bricks)
    elif kind == "binary":
        ext = str(rng.choice([".json", ".txt", ".ldr"]))
        raw = rng.integers(0, 256, int(rng.integers(1, 400)), dtype=np.uint8).tobytes()
        path = os.path.join(folder, f"case{i:05d}{ext}")
        with open(path, "wb") as fh:
            fh.write(raw)
        return path, kind
    elif kind == "empty":
        ext = str(rng.choice([".json", ".txt", ".ldr"]))
        data = ["", " ", "\n", "{}", "[]", "null", "0", '""'][int(rng.integers(0, 8))]
    elif kind == "junk_text":
        ext = ".txt"
        lines = _text(bricks).splitlines()
        j = int(rng.integers(0, len(lines)))
        lines[j] = ["2x4 (0,0)", "3x3 (0,0,0)", "2x4 (a,b,c)", "2x4 (1,1,1) extra", "0x0 (0,0,0)",
                    "2x4 (-1,0,0)", "2x4 (nan,0,0)", "99999999999x1 (0,0,0)", "\x00\x01"][int(rng.integers(0, 9))]
        data = "\n".join(lines) + "\n"
    elif kind == "deep":
        d = int(rng.integers(10, 200000))
        data = "[" * d + "]" * d if rng.random() < 0.5 else '{"a":' * d + "1" + "}" * d
    elif kind == "bad_mass":
        b = bricks[str(rng.choice(list(bricks)))]
        b["mass"] = "@M@"
        data = json.dumps(bricks).replace('"@M@"', ["-1", "NaN", '"heavy"', "1e300", "10.0", "0"][int(rng.integers(0, 6))])
    elif kind == "ldr":
        ext = ".ldr"
        parts = ["3001.dat", "3003.dat", "3005.dat", "9999.dat", "3001.DAT"]
        lines = ["0 fuzz"]
        for _ in range(int(rng.integers(0, 6))):
            xyz = rng.integers(-3, 4, 3) * np.array([20, 24, 20])
            lines.append(f"1 4 {xyz[0]} {xyz[1]} {xyz[2]} 1 0 0 0 1 0 0 0 1 {rng.choice(parts)}")
        if rng.random() < 0.3:
            lines.append(["1 4 x y z", "1 4 0 0 0 1 0 0 0 1 0 0 0 1", "1 4 nan 0 0 1 0 0 0 1 0 0 0 1 3001.dat"]
                         [int(rng.integers(0, 3))])
        data = "\n".join(lines) + "\n"
    else:
        raise ValueError(f"unknown kind {kind!r}")
    path = os.path.join(folder, f"case{i:05d}{ext}")
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(data)
    return path, kind


def classify_error(line: str, *paths: str) -> str:
    """"clear" for one error line naming one of ``paths`` (the input, or an
    output at fault) without a Python exception name; "unclear" otherwise."""
    if "\n" in line.strip() or "Traceback" in line or not any(p in line for p in paths) or EXC_NAME.search(line):
        return "unclear"
    return "clear"
