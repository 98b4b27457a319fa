"""The LDraw parts that the stud-grid model covers: basic bricks and plates.

Every part here is a box with a full stud grid on top and the knob model of
SPEC underneath: a brick is three plate heights (24 LDU) high, a plate one
(8 LDU). LDraw names them "Brick a x b" / "Plate a x b" with a <= b; the
part lies with its b studs along its own X axis and its a studs along Z,
its origin at the centre of its top face. Part numbers and sizes as in the
LDraw library (LeoCAD's list of generated bricks and plates).

Masses: paper Table I for its eight bricks; other bricks by a least-squares
line through Table I in the stud count (1-wide bricks from the 1xN ones,
wider ones from the 2xN ones); plates a third of the brick of the same
footprint. The estimates are stated, not measured.
"""
from __future__ import annotations

import re

import numpy as np

from ..layout import TABLE_I_MASS_KG

__all__ = ["LDRAW_PARTS", "BRICK_H", "PLATE_H", "part_number", "part_size", "part_for", "part_mass"]

BRICK_H, PLATE_H = 3, 1  # heights in plate heights

#: part number -> (a, b, height in plate heights), a <= b
LDRAW_PARTS: dict[str, tuple[int, int, int]] = {
    # bricks
    "3005": (1, 1, 3), "3004": (1, 2, 3), "3622": (1, 3, 3), "3010": (1, 4, 3), "3009": (1, 6, 3),
    "3008": (1, 8, 3), "6111": (1, 10, 3), "6112": (1, 12, 3), "2465": (1, 16, 3),
    "3003": (2, 2, 3), "3002": (2, 3, 3), "3001": (2, 4, 3), "2456": (2, 6, 3), "3007": (2, 8, 3),
    "3006": (2, 10, 3), "2356": (4, 6, 3), "6212": (4, 10, 3), "4202": (4, 12, 3), "30400": (4, 18, 3),
    "4201": (8, 8, 3), "4204": (8, 16, 3), "733": (10, 10, 3),
    # plates
    "3024": (1, 1, 1), "3023": (1, 2, 1), "3623": (1, 3, 1), "3710": (1, 4, 1), "3666": (1, 6, 1),
    "3460": (1, 8, 1), "4477": (1, 10, 1), "60479": (1, 12, 1),
    "3022": (2, 2, 1), "3021": (2, 3, 1), "3020": (2, 4, 1), "3795": (2, 6, 1), "3034": (2, 8, 1),
    "3832": (2, 10, 1), "2445": (2, 12, 1), "91988": (2, 14, 1), "4282": (2, 16, 1),
    "3031": (4, 4, 1), "3032": (4, 6, 1), "3035": (4, 8, 1), "3030": (4, 10, 1), "3029": (4, 12, 1),
    "3958": (6, 6, 1), "3036": (6, 8, 1), "3033": (6, 10, 1), "3028": (6, 12, 1), "3456": (6, 14, 1),
    "3027": (6, 16, 1), "3026": (6, 24, 1), "41539": (8, 8, 1), "728": (8, 11, 1), "92438": (8, 16, 1),
}
_BY_SIZE = {v: k for k, v in LDRAW_PARTS.items()}
_NAME = re.compile(r"^(\d+)([a-z]?)(p[0-9a-z]+)?$")


def part_number(ref: str) -> str:
    """The part number of a type-1 reference: folders, ``.dat`` and case
    dropped (``parts\\3001.DAT`` -> ``3001``); a printed (``3001p11``) or
    mould variant (``3001a``) of a part of the table maps to the part."""
    name = re.split(r"[\\/]", ref.strip())[-1].lower()
    if name.endswith(".dat"):
        name = name[:-4]
    m = _NAME.match(name)
    if m and m.group(1) in LDRAW_PARTS and (m.group(2) or m.group(3)):
        return m.group(1)
    return name


def part_size(number: str):
    """(a, b, height) of a part of the table, or None."""
    return LDRAW_PARTS.get(number)


def part_for(sx: int, sy: int, height: int):
    """The part number of a part with these studs (either order) and height, or None."""
    return _BY_SIZE.get((min(sx, sy), max(sx, sy), height))


def _fit(points):
    x, y = np.array(points, np.float64).T
    return np.polyfit(x, y, 1)


_FIT_1 = _fit([(k, TABLE_I_MASS_KG[(1, k)]) for k in (1, 2, 4, 6, 8)])
_FIT_2 = _fit([(2 * k, TABLE_I_MASS_KG[(2, k)]) for k in (2, 4, 6)])


def part_mass(sx: int, sy: int, height: int) -> float:
    """Mass (kg) of a part with these studs and height (module doc)."""
    a, b = min(sx, sy), max(sx, sy)
    if (a, b) in TABLE_I_MASS_KG and height == BRICK_H:
        return TABLE_I_MASS_KG[(a, b)]
    if (a, b) in TABLE_I_MASS_KG:
        brick = TABLE_I_MASS_KG[(a, b)]
    else:
        fit = _FIT_1 if a == 1 else _FIT_2
        brick = float(np.polyval(fit, a * b))
    return brick * height / BRICK_H
