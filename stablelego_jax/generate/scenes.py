"""Seeded scenes of plain blocks, pallets and rotated Lego bricks (paper Sec. IV.E).

Every function returns a validated :class:`~stablelego_jax.scene.Scene`
(keys "1".."n" unless stated). Blocks in metres and kilograms, yaw in
degrees; bricks in studs and plate heights with Table I masses.

* :func:`block_column`: one column of blocks, each offset from the one below;
* :func:`harmonic_stack`: the harmonic stack (block k from the top offset by
  ``frac * L / (2 k)`` from the one below it), the knife edge at ``frac = 1``;
* :func:`pallet`: a pallet with layers of boxes, optionally a top box;
* :func:`random_scene`: one random scene of a family (:data:`SCENE_FAMILIES`).
"""
from __future__ import annotations

import numpy as np

from ..layout import TABLE_I_MASS_KG
from ..scene import BLOCK, BRICK, Scene, make_scene

__all__ = ["block_column", "harmonic_stack", "pallet", "random_scene", "SCENE_FAMILIES"]

#: Families of :func:`random_scene`.
SCENE_FAMILIES = ("stack", "pile", "pallet", "lego", "mixed")


def block_column(offsets, size=(0.2, 0.1, 0.05), mass: float = 0.1, yaw=0.0, direction: float = 0.0,
                 friction: float = 0.0, source: str = "<memory>") -> Scene:
    """A column of ``len(offsets) + 1`` equal blocks on the ground, bottom
    first: block i + 1 sits on block i, its centre ``offsets[i]`` (m) from
    block i's along the direction ``direction`` (degrees from +x). ``yaw``:
    one yaw (degrees) for every block, or one per block."""
    off = np.asarray(offsets, np.float64).reshape(-1)
    n = len(off) + 1
    s = np.radians(direction)
    t = np.concatenate([[0.0], np.cumsum(off)])
    h = float(size[2])
    pos = np.stack([t * np.cos(s), t * np.sin(s), h / 2 + h * np.arange(n)], 1)
    yaws = np.broadcast_to(np.asarray(yaw, np.float64), (n,))
    return make_scene([str(i + 1) for i in range(n)], [BLOCK] * n, pos, [list(size)] * n, yaws, [mass] * n,
                      friction=friction, source=source, fmt="blocks")


def harmonic_stack(n: int, frac: float = 1.0, L: float = 0.2, W: float = 0.1, H: float = 0.05,
                   mass: float = 0.1, yaw: float = 0.0) -> Scene:
    """The harmonic stack of ``n`` blocks of length ``L`` (along their own
    x): block k from the top is offset ``frac * L / (2 k)`` beyond the block
    under it, so that at ``frac = 1`` every interface carries the centre of
    mass of the blocks above exactly over the edge. The whole stack is turned
    by ``yaw`` degrees (blocks and offsets)."""
    k = np.arange(n - 1, 0, -1)  # offset of block i + 1 over block i is that of block k = n - 1 - i from the top
    return block_column(frac * L / (2 * k), (L, W, H), mass, yaw, direction=yaw)


def pallet(cols: int = 3, rows: int = 2, layers: int = 2, box=(0.4, 0.4, 0.3), box_mass: float = 10.0,
           pallet_size=(1.2, 0.8, 0.15), pallet_mass: float = 25.0, gap: float = 0.0,
           top=None, friction: float = 0.0) -> Scene:
    """A pallet (key "pallet") on the ground with ``layers`` layers of
    ``cols x rows`` boxes (keys "box<layer>.<i>"), ``gap`` m between boxes,
    the grid centred on the pallet; ``top``: optional (x, y, yaw) of one more
    box ("top") on the last layer (x, y relative to the pallet centre)."""
    px, py, ph = pallet_size
    bx, by, bh = box
    keys, pos, size, mass, yaws = ["pallet"], [[0.0, 0.0, ph / 2]], [list(pallet_size)], [pallet_mass], [0.0]
    xs = (np.arange(cols) - (cols - 1) / 2) * (bx + gap)
    ys = (np.arange(rows) - (rows - 1) / 2) * (by + gap)
    for L in range(layers):
        z = ph + bh * (L + 0.5)
        for i, (x, y) in enumerate((x, y) for y in ys for x in xs):
            keys.append(f"box{L + 1}.{i + 1}")
            pos.append([float(x), float(y), z])
            size.append(list(box))
            mass.append(box_mass)
            yaws.append(0.0)
    if top is not None:
        keys.append("top")
        pos.append([float(top[0]), float(top[1]), ph + bh * (layers + 0.5)])
        size.append(list(box))
        mass.append(box_mass)
        yaws.append(float(top[2]))
    n = len(keys)
    return make_scene(keys, [BLOCK] * n, pos, size, yaws, mass, friction=friction, fmt="blocks")


def _lego(rng: np.random.Generator) -> tuple:
    """A base brick on the baseplate with rotated bricks joined to it (and to
    each other) by single knobs: (pos, size, yaw, mass) lists."""
    pos, size, yaw, mass = [[1.0, 2.0, 0.0]], [[2.0, 4.0, 3.0]], [0.0], [TABLE_I_MASS_KG[(2, 4)]]
    knobs = [(0.5, 0.5), (1.5, 3.5), (0.5, 3.5), (1.5, 0.5)]
    level = 3
    for _ in range(int(rng.integers(1, 4))):
        sx = int(rng.choice([1, 2]))
        sy = int(rng.choice([2, 4, 6] if sx == 2 else [2, 4, 6, 8]))
        kx, ky = knobs[int(rng.integers(len(knobs)))]
        th = float(rng.uniform(0, 360))
        c, s = np.cos(np.radians(th)), np.sin(np.radians(th))
        # the part's corner stud (cell 0, 0) on the knob: centre = knob - R (0.5 - sx/2, 0.5 - sy/2)
        ox, oy = 0.5 - sx / 2, 0.5 - sy / 2
        centre = (kx - (c * ox - s * oy), ky - (s * ox + c * oy))
        pos.append([centre[0], centre[1], float(level)])
        size.append([float(sx), float(sy), 3.0])
        yaw.append(th)
        m = TABLE_I_MASS_KG[(min(sx, sy), max(sx, sy))]
        mass.append(m * float(rng.choice([1.0, 1.0, 5.0, 20.0])))
        # the next part joins this one at its far corner stud
        fx, fy = sx - 0.5 - sx / 2, sy - 0.5 - sy / 2
        knobs = [(centre[0] + c * fx - s * fy, centre[1] + s * fx + c * fy)]
        level += 3
    return pos, size, yaw, mass


def random_scene(rng: np.random.Generator, family: str = "stack") -> Scene:
    """One random scene of ``family``: "stack" (a column of 2-12 blocks with
    random offsets and yaws), "pile" (a block or two bridging two or three
    supports), "pallet" (a pallet of boxes with gaps and a random top box),
    "lego" (bricks at random yaws joined to a base brick by single knobs),
    "mixed" (a stack with a random Coulomb friction). Some stand, some fall."""
    if family not in SCENE_FAMILIES:
        raise ValueError(f"unknown scene family {family!r} (expected one of {', '.join(SCENE_FAMILIES)})")
    if family in ("stack", "mixed"):
        n = int(rng.integers(2, 13))
        L = float(rng.uniform(0.1, 0.3))
        off = rng.uniform(-0.7, 0.7, n - 1) * L / 2
        yaw = rng.uniform(-20, 20, n) if rng.random() < 0.5 else 0.0
        mu = float(rng.choice([0.0, 0.2, 0.5])) if family == "mixed" else 0.0
        return block_column(off, (L, float(rng.uniform(0.05, 0.15)), float(rng.uniform(0.02, 0.08))),
                            float(rng.uniform(0.05, 2.0)), yaw, float(rng.uniform(0, 360)), friction=mu)
    if family == "pile":
        k = int(rng.integers(2, 4))
        gap = float(rng.uniform(0.0, 0.15))
        w = 0.1
        keys, pos, size, mass, yaw = [], [], [], [], []
        for i in range(k):
            keys.append(f"s{i + 1}")
            pos.append([i * (w + gap), 0.0, 0.05])
            size.append([w, w, 0.1])
            mass.append(1.0)
            yaw.append(0.0)
        span = (k - 1) * (w + gap)
        L = float(rng.uniform(0.5, 1.3)) * (span + w)
        keys.append("beam")
        S = span + w  # the supports' extent; the beam's centre anywhere from a quarter of it before to after
        pos.append([float(rng.uniform(-0.75, 0.75)) * S + span / 2, float(rng.uniform(-0.03, 0.03)), 0.125])
        size.append([L, 0.08, 0.05])
        mass.append(float(rng.uniform(0.2, 2.0)))
        yaw.append(float(rng.uniform(-10, 10)))
        if rng.random() < 0.5:
            keys.append("load")
            pos.append([pos[-1][0] + float(rng.uniform(-0.5, 0.5)) * L, pos[-1][1], 0.175])
            size.append([0.05, 0.05, 0.05])
            mass.append(float(rng.uniform(0.5, 5.0)))
            yaw.append(float(rng.uniform(0, 90)))
        n = len(keys)
        return make_scene(keys, [BLOCK] * n, pos, size, yaw, mass, fmt="blocks")
    if family == "pallet":
        cols, rows = int(rng.integers(1, 4)), int(rng.integers(1, 3))
        gap = float(rng.choice([0.0, 0.0, 0.02]))
        top = None
        if rng.random() < 0.8:
            top = (float(rng.uniform(-0.6, 0.6)), float(rng.uniform(-0.4, 0.4)), float(rng.uniform(0, 90)))
        return pallet(cols, rows, int(rng.integers(1, 3)), gap=gap, top=top,
                      friction=float(rng.choice([0.0, 0.0, 0.4])))
    pos, size, yaw, mass = _lego(rng)
    n = len(pos)
    return make_scene([str(i + 1) for i in range(n)], [BRICK] * n, pos, size, yaw, mass, fmt="json")
