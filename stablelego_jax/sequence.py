"""Build sequences: does every step of a build order stand, and under a robot's press?

A build order adds one brick a step; step ``k`` is the layout of the fixed
bricks plus the first ``k`` bricks of the order (a *prefix*). Every prefix is
an ordinary layout, so all of them are scored in one batched call
(:func:`~stablelego_jax.batch.analyze_many`).

The insertion press (``press`` newtons, as a robot pushes the new brick
down onto the knobs below it) is a load on the new brick: where the order
gives the press location (APEX-MR step files), a 1x2 load block of mass
``press / g`` on the brick's top at that spot, as APEX-MR's own stability
check models its press tool; otherwise an extra mass ``press / g`` at the
brick's centre (:attr:`Layout.mass`). Both are plain layouts: no change to
the force model. A :class:`~stablelego_jax.scene.Scene` (plates, turned
bricks, plain blocks) is sequenced the same way, its steps ordered by the
height of their bottoms and pressed at the body's centre. A press from below (a brick hung under the structure) is
not a load the model can carry and is left out at that step (reported).

A step that stands without the press but falls under it needs a support
under the pressed brick. Candidate supports are pillars of weightless 1x1
bricks filling the empty cells of one stud column under the pressed brick,
from the baseplate up (a second arm holding the structure from below, as
APEX-MR models it; grid layouts only: no pillar is tried in a scene); every candidate of every such step is scored in one
more batched call, and the best standing one (lowest highest score) is
reported as the top cell of its pillar.

:func:`plan_order` looks for an order in which every step stands.
"""
from __future__ import annotations

import dataclasses
import json
import time
from typing import Mapping, Sequence

import numpy as np

from .analysis import Analysis
from .batch import analyze_many
from .blas import one_blas_thread
from .files import read_text
from .layout import Layout, LayoutError, cells_of, make_layout
from .model import Params
from .scene import Scene, boxes

__all__ = ["BuildOrder", "Step", "SequenceResult", "layer_order", "read_order", "check_order", "prefix_layouts",
           "press_layout", "support_candidates", "bottoms", "analyze_sequence", "plan_order", "PRESS_KEY"]

#: Key of the press load block in a pressed step's layout.
PRESS_KEY = "press"
_SUPPORT_PREFIX = "support@"


@dataclasses.dataclass(frozen=True)
class BuildOrder:
    """An order in which to build a layout.

    keys: bricks in build order; fixed: bricks present before step 1
    (pillars, fixtures); press_at: {key: (x, y, layer, sx, sy)} cells of the
    press block on the new brick's top (absent: press at the brick's
    centre); no_press: steps whose press cannot be modelled (from below);
    support_ref: {key: (x, y, layer)} a reference planner's support pillar
    top (APEX-MR), for comparison only; name: where the order came from.
    """

    keys: tuple[str, ...]
    fixed: tuple[str, ...] = ()
    press_at: Mapping = dataclasses.field(default_factory=dict)
    no_press: frozenset = frozenset()
    support_ref: Mapping = dataclasses.field(default_factory=dict)
    name: str = "layers"


@dataclasses.dataclass
class Step:
    """One step of a scored sequence (scores: Eq. 10, N for forces).

    step: 1-based; key: the brick it adds; stable / weakest / score: the
    prefix without press; pressed_stable / pressed_weakest / pressed_score:
    under the press (None without ``press`` or where it cannot be modelled);
    needs_support: stands without the press, falls under it; support:
    (x, y, layer) top cell of the best standing support pillar found, None
    if none stands (or none needed); analysis / pressed: the Analyses.
    """

    step: int
    key: str
    n_bricks: int
    stable: bool
    weakest: str
    score: float
    analysis: Analysis
    pressed_stable: bool | None = None
    pressed_weakest: str | None = None
    pressed_score: float | None = None
    pressed: Analysis | None = None
    press_mode: str | None = None
    needs_support: bool = False
    support: tuple | None = None
    support_score: float | None = None
    support_tried: int = 0

    def to_json(self) -> dict:
        out = {"step": self.step, "brick": self.key, "n_bricks": self.n_bricks, "stable": self.stable,
               "weakest": self.weakest, "score": round(float(self.score), 6)}
        if self.press_mode is not None:
            out.update(press=self.press_mode, pressed_stable=self.pressed_stable,
                       pressed_weakest=self.pressed_weakest,
                       pressed_score=None if self.pressed_score is None else round(float(self.pressed_score), 6),
                       needs_support=self.needs_support,
                       support=None if self.support is None else list(self.support),
                       support_tried=self.support_tried)
        return out


@dataclasses.dataclass
class SequenceResult:
    """Every step of one build order. ``press``: N (None: no press);
    ``time_s``: wall time of the batched solves; ``n_solved``: layouts solved."""

    file: str
    layout: Layout | Scene
    order: BuildOrder
    steps: list
    press: float | None
    solver: str
    time_s: float
    n_solved: int

    @property
    def first_fall(self) -> int | None:
        """1-based step of the first prefix that does not stand (no press)."""
        return next((s.step for s in self.steps if not s.stable), None)

    @property
    def support_steps(self) -> list:
        """Steps that stand but fall under the press."""
        return [s.step for s in self.steps if s.needs_support]

    def to_json(self) -> dict:
        return {"file": self.file, "order": self.order.name, "n_steps": len(self.steps),
                "fixed": list(self.order.fixed), "stable": self.first_fall is None,
                "first_fall": self.first_fall, "press": self.press, "support_steps": self.support_steps,
                "solver": self.solver, "time_s": round(self.time_s, 3), "n_solved": self.n_solved,
                "steps": [s.to_json() for s in self.steps]}


# --------------------------------------------------------------------------
# orders


def bottoms(layout: Layout | Scene) -> np.ndarray:
    """(n,) height of every brick's bottom: its layer in a Layout, metres in a Scene."""
    if isinstance(layout, Scene):
        centre, size, _ = boxes(layout)
        return np.round(centre[:, 2] - size[:, 2] / 2, 9)
    return layout.pos[:, 2]


def layer_order(layout: Layout | Scene, fixed: Sequence[str] = ()) -> BuildOrder:
    """Bottom layer first, input order within a layer (``fixed`` left out);
    in a Scene, lowest bottom first."""
    fx = set(fixed)
    idx = [i for i in np.lexsort((np.arange(layout.n), bottoms(layout))) if layout.keys[i] not in fx]
    return BuildOrder(keys=tuple(layout.keys[i] for i in idx), fixed=tuple(fixed), name="layers")


def check_order(layout: Layout | Scene, order: BuildOrder, source: str | None = None) -> None:
    """LayoutError naming ``source`` unless fixed + keys name every brick of
    ``layout`` exactly once."""
    src = source or order.name
    seen: set = set()
    for k in tuple(order.fixed) + tuple(order.keys):
        if k not in layout.keys:
            raise LayoutError(src, f"brick {k!r} is not in {layout.source}")
        if k in seen:
            raise LayoutError(src, f"brick {k!r} appears twice in the order")
        seen.add(k)
    missing = [k for k in layout.keys if k not in seen]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise LayoutError(src, f"brick {missing[0]!r}{more} of {layout.source} is not in the order")


def read_order(path: str, layout: Layout | Scene) -> BuildOrder:
    """An order file: a JSON list of brick keys (or ``{"order": [...],
    "fixed": [...]}``), or text with one key a line (``#`` comments).
    Checked against ``layout`` (:func:`check_order`)."""
    text = read_text(path)
    fixed: list = []
    if text.lstrip().startswith(("[", "{")):
        try:
            raw = json.loads(text)
        except json.JSONDecodeError as exc:
            raise LayoutError(path, f"order is not valid JSON: {exc}") from None
        if isinstance(raw, dict):
            fixed, raw = raw.get("fixed", []), raw.get("order")
        if not isinstance(raw, list) or not isinstance(fixed, list):
            raise LayoutError(path, "order must be a JSON list of brick keys (or {\"order\": [...]})")
        keys = [str(k) for k in raw]
        fixed = [str(k) for k in fixed]
    else:
        keys = [ln.split("#")[0].strip() for ln in text.splitlines()]
        keys = [k for k in keys if k]
    order = BuildOrder(keys=tuple(keys), fixed=tuple(fixed), name=path)
    check_order(layout, order, path)
    return order


# --------------------------------------------------------------------------
# step layouts


def _add_bricks(layout: Layout, keys, pos, size, mass) -> Layout:
    """``layout`` plus bricks (no library id); LayoutError on overlap."""
    return make_layout(
        list(layout.keys) + list(keys), np.concatenate([layout.pos, np.reshape(pos, (-1, 3))]),
        np.concatenate([layout.size, np.reshape(size, (-1, 2))]), np.concatenate([layout.mass, mass]),
        list(layout.brick_id) + [""] * len(keys), np.concatenate([layout.ori, np.zeros(len(keys), np.int64)]),
        source=layout.source, fmt=layout.fmt)


def prefix_layouts(layout: Layout | Scene, order: BuildOrder) -> list:
    """Step layouts: fixed bricks plus the first k bricks of the order, k = 1..n."""
    index = {k: i for i, k in enumerate(layout.keys)}
    base = [index[k] for k in order.fixed]
    steps = [index[k] for k in order.keys]
    return [layout.subset(base + steps[: k + 1]) for k in range(len(steps))]


def press_layout(prefix: Layout | Scene, key: str, newtons: float, order: BuildOrder,
                 params: Params = Params()) -> tuple[Layout | None, str]:
    """``prefix`` with brick ``key`` pressed down by ``newtons`` N, and how:
    "block" (a load block of mass N / g at ``order.press_at[key]``), "brick"
    (N / g added to the brick's own mass, acting at its centre; also where
    the press block would overlap a brick) or "none" (press from below:
    layout None)."""
    if key in order.no_press:
        return None, "none"
    extra = float(newtons) / params.g
    at = order.press_at.get(key)
    if at is not None:
        x, y, z, sx, sy = at
        try:
            return _add_bricks(prefix, [PRESS_KEY], [x, y, z], [sx, sy], [extra]), "block"
        except LayoutError:
            pass  # the spot is taken: press the brick itself
    mass = prefix.mass.copy()
    mass[prefix.keys.index(key)] += extra
    return dataclasses.replace(prefix, mass=mass), "brick"


def support_candidates(layout: Layout | Scene, key: str) -> list:
    """Support pillars under brick ``key`` of ``layout``: for each stud
    column of its footprint, weightless 1x1 bricks in every empty cell of
    that column below it. Returns [((x, y, top layer), layout with pillar)],
    columns without an empty cell left out; [] for a Scene."""
    if isinstance(layout, Scene):
        return []
    i = layout.keys.index(key)
    x0, y0, z0 = (int(v) for v in layout.pos[i])
    cells, _ = cells_of(layout.pos, layout.size)
    taken = {tuple(c) for c in cells.tolist()}
    out = []
    for x in range(x0, x0 + int(layout.size[i, 0])):
        for y in range(y0, y0 + int(layout.size[i, 1])):
            free = [z for z in range(z0) if (x, y, z) not in taken]
            if not free:
                continue
            lay = _add_bricks(layout, [f"{_SUPPORT_PREFIX}{x},{y},{z}" for z in free],
                              [(x, y, z) for z in free], [(1, 1)] * len(free), np.zeros(len(free)))
            out.append(((x, y, max(free)), lay))
    return out


def _score(a: Analysis) -> float:
    return float(a.scores[a.weakest])


def _solve(layouts: list, solver: str, params: Params, jobs: int = 1) -> list:
    """One Analysis per layout (``jobs``: worker processes of the exact
    solver, :func:`~stablelego_jax.batch.iter_analyses`; the JAX solver's
    batched calls run in this process)."""
    with one_blas_thread():  # JAX's CPU LAPACK goes through OpenBLAS (see blas.py)
        res = analyze_many(layouts, solver, params=params, jobs=jobs, jax_jobs=1)
    for r in res:
        if isinstance(r, Exception):
            raise r
    return res


def analyze_sequence(layout: Layout | Scene, order: BuildOrder | None = None, press: float | None = None,
                     solver: str = "jax", params: Params = Params(), find_support: bool = True,
                     jobs: int = 1) -> SequenceResult:
    """Score every step of ``order`` (default: :func:`layer_order`).

    One batched call scores every prefix (and, with ``press`` N, every
    pressed prefix); with ``find_support``, one more call scores every
    support candidate (:func:`support_candidates`) of the steps that stand
    but fall under the press. ``jobs`` > 1 (the exact solver, from
    ``batch.POOL_MIN`` layouts a call): that many spawned worker processes,
    the same answers as one; a script that passes it must keep its own work
    under ``if __name__ == "__main__":`` (spawned workers import it)."""
    order = order or layer_order(layout)
    check_order(layout, order)
    t0 = time.perf_counter()
    prefixes = prefix_layouts(layout, order)
    todo, pressed = list(prefixes), []
    if press is not None:
        for lay, k in zip(prefixes, order.keys):
            p, mode = press_layout(lay, k, press, order, params)
            pressed.append((len(todo) if p is not None else None, mode))
            if p is not None:
                todo.append(p)
    res = _solve(todo, solver, params, jobs)
    n_solved = len(todo)
    steps = []
    for s, (lay, k) in enumerate(zip(prefixes, order.keys)):
        a = res[s]
        st = Step(step=s + 1, key=k, n_bricks=lay.n, stable=a.stable, weakest=a.weakest, score=_score(a),
                  analysis=a)
        if press is not None:
            j, st.press_mode = pressed[s]
            if j is not None:
                pa = res[j]
                st.pressed, st.pressed_stable, st.pressed_weakest = pa, pa.stable, pa.weakest
                st.pressed_score = _score(pa)
                st.needs_support = st.stable and not pa.stable
        steps.append(st)
    if find_support and press is not None:
        cands = []
        for st in steps:
            if st.needs_support:
                for cell, lay in support_candidates(st.pressed.layout, st.key):
                    cands.append((st, cell, lay))
        if cands:
            sres = _solve([c[2] for c in cands], solver, params, jobs)
            n_solved += len(cands)
            for (st, cell, _), a in zip(cands, sres):
                st.support_tried += 1
                if a.stable and (st.support_score is None or _score(a) < st.support_score):
                    st.support, st.support_score = cell, _score(a)
    return SequenceResult(file=layout.source, layout=layout, order=order, steps=steps, press=press,
                          solver=solver, time_s=time.perf_counter() - t0, n_solved=n_solved)


# --------------------------------------------------------------------------
# planning


def _resting_pairs(layout: Layout | Scene) -> list | None:
    """[(upper, lower)] bodies of a Scene's Lego and bottom contacts (lower
    ``n``: the ground); None for a Layout."""
    if not isinstance(layout, Scene):
        return None
    from .contacts import scene_contacts

    c = scene_contacts(layout)
    return np.concatenate([c.lego_pair, c.push_pair[c.push_bottom.astype(bool)]]).tolist()


def _connected(layout: Layout | Scene, placed: set, remaining: Sequence[str], pairs: list | None) -> list:
    """Bricks of ``remaining`` on the baseplate or with a knob on or under a
    placed brick (in a Scene: resting on the ground, or on or under a placed
    body, by its ``pairs``, :func:`_resting_pairs`)."""
    index = {k: i for i, k in enumerate(layout.keys)}
    if isinstance(layout, Scene):
        base = {layout.n} | {index[k] for k in placed}
        near = {a for a, b in pairs if b in base} | {b for a, b in pairs if a in base}
        return [k for k in remaining if index[k] in near]
    cells, owner = cells_of(layout.pos, layout.size)
    occupied = {tuple(c) for c, o in zip(cells.tolist(), owner.tolist()) if layout.keys[o] in placed}
    out = []
    for k in remaining:
        i = index[k]
        x0, y0, z = (int(v) for v in layout.pos[i])
        if z == 0 or any((x, y, z + d) in occupied for x in range(x0, x0 + int(layout.size[i, 0]))
                         for y in range(y0, y0 + int(layout.size[i, 1])) for d in (-1, 1)):
            out.append(k)
    return out


def plan_order(layout: Layout | Scene, press: float | None = None, fixed: Sequence[str] = (), solver: str = "jax",
               params: Params = Params(), window: int = 64, max_candidates: int = 64,
               base: BuildOrder | None = None) -> tuple[BuildOrder, bool]:
    """Look for an order in which every step stands (under ``press`` N when
    given). Returns (order, found): found False when some step could not be
    made to stand (that step then adds the least-failing brick).

    Greedy, in batched calls: the remaining bricks in layer order are scored
    as prefixes (up to ``window`` at a time) and the standing run is
    accepted; where the next brick would fall, every connected remaining
    brick (up to ``max_candidates``, lowest layers first) is tried as the
    next step in one call, and the standing one of lowest layer and score
    is taken."""
    base = base or BuildOrder(keys=(), fixed=tuple(fixed))
    check = layer_order(layout, base.fixed)
    remaining = list(check.keys)
    placed: list = []
    found = True
    index = {k: i for i, k in enumerate(layout.keys)}
    level = bottoms(layout)
    resting = _resting_pairs(layout)  # the geometry does not change while planning

    def stands(k_list, lays):
        jobs = []
        for lay, k in zip(lays, k_list):
            if press is not None:
                lay = press_layout(lay, k, press, base, params)[0] or lay
            jobs.append(lay)
        return _solve(jobs, solver, params)

    def prefix(keys):
        return layout.subset([index[k] for k in list(base.fixed) + keys])

    while remaining:
        run = remaining[:window]
        res = stands(run, [prefix(placed + run[: j + 1]) for j in range(len(run))])
        k = next((j for j, a in enumerate(res) if not a.stable), len(run))
        placed += run[:k]
        remaining = remaining[k:]
        if not remaining or k:
            continue
        cands = _connected(layout, set(base.fixed) | set(placed), remaining, resting)
        cands = sorted(cands, key=lambda c: (level[index[c]], remaining.index(c)))[:max_candidates]
        cands = cands or remaining[:1]
        res = stands(cands, [prefix(placed + [c]) for c in cands])
        ranked = sorted(range(len(cands)), key=lambda j: (not res[j].stable, level[index[cands[j]]],
                                                          _score(res[j]), j))
        best = cands[ranked[0]]
        found = found and res[ranked[0]].stable
        placed.append(best)
        remaining.remove(best)
    return dataclasses.replace(base, keys=tuple(placed), name="plan"), found
