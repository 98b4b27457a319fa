"""Gradient-guided repair of unstable layouts (and the baselines it is compared with).

One repair step:

1. the exact solver (HiGHS, Eq. 9) analyses the current layout; stop if it
   stands;
2. :func:`propose` lists candidate units near the weakest bricks: supports
   under them (a brick in the layer below, carried down to the baseplate or
   to the first brick below as a pillar), bridging bricks across their
   joints with side neighbours (in the layer above or below), and, with
   ``allow_remove``, a longer brick replacing a weak one or the weak brick's
   row (it and its neighbours along its long axis, same cross-section, at
   most 16 studs) re-merged into bricks whose joints are bridged by the
   layers above and below;
3. :func:`rank` compiles the layout and all candidates into one soft layout
   (:mod:`stablelego_jax.soft`, candidates at weight 0) and takes the
   gradient of :func:`stablelego_jax.loss.stability_loss` with respect to
   their weights: one smooth solve and one adjoint solve for all of them;
4. ``verify`` candidates are checked with the exact solver: the best-ranked
   (most negative gradient per added brick), then the best-ranked of each
   unit size, smallest first; a stable one with the fewest bricks is taken,
   else the one that lowers the exact overload most per brick (if none of
   them lowers it, the next ``verify``, at most three rounds); when several
   clusters of bricks fail and no single unit makes the layout stand, the
   best-ranked unit of each cluster is checked together and taken if it
   stands or lowers the overload more; repeat until the layout stands, the
   brick budget (``max_add``, default max(4, n / 4)) is spent or ``time_s``
   runs out.

User bricks are never moved or deleted unless ``allow_remove`` (then only
by a replacement), candidates never overlap the layout, and every new cell
lies in the region: ``bbox`` (the layout's bounding box, extended down to
the baseplate), ``shape`` (cells above or below a cell of the layout in the
same column, up to its top layer) or ``any``.

Baselines (for ``benchmarks/repair.py``): :func:`greedy_repair` checks every
candidate with a full exact solve each step; :func:`rollback_repair` is the
rollback of LLM brick generators (remove the first unstable brick, in input
order, and every brick after it, until the layout stands).
"""
from __future__ import annotations

import dataclasses
import time
from typing import Sequence

import jax
import numpy as np

from ..analysis import Analysis, analyze_layout
from ..blas import one_blas_thread
from ..layout import TABLE_I_MASS_KG, Layout, cells_of
from ..loss import LossOptions, stability_loss
from ..model import Params
from ..score import floating_bricks, residual_bad
from ..soft import Candidate, SoftProblem, apply_candidates, candidate_brick, compile_soft, fresh_keys
from ..solvers.compiled import compiled
from ..solvers.problem import plan_soft

__all__ = [
    "RepairOptions",
    "RepairResult",
    "REGIONS",
    "propose",
    "rank",
    "repair",
    "greedy_repair",
    "rollback_repair",
    "exact_loss",
]

REGIONS = ("bbox", "shape", "any")
_PER_TARGET = 6  # support variants per supported brick (lowest pillars, widest contact first)

# support and bridge footprints (sx, sy): real bricks of paper Table I
_SUPPORT = ((1, 1), (1, 2), (2, 1), (2, 2), (1, 4), (4, 1), (2, 4), (4, 2))
_BRIDGE = ((1, 2), (2, 1), (2, 2), (1, 4), (4, 1), (2, 4), (4, 2), (1, 6), (6, 1), (2, 6), (6, 2), (1, 8), (8, 1))
_PER_CLUSTER = 24  # candidates per failing cluster when max_candidates is automatic


@dataclasses.dataclass(frozen=True)
class RepairOptions:
    """Settings of a repair.

    region: "bbox" | "shape" | "any" (see the module docstring).
    max_add: most bricks to add; None (default): scales with the layout,
      max(4, ceil(n / 4)) for n bricks (:meth:`budget`).
    allow_remove: allow replacing user bricks.
    verify: candidates checked with the exact solver per step (gradient method).
    weak: how many of the weakest bricks get candidates around them (besides
      every failing brick).
    max_candidates: cap on candidates per step (weakest bricks first, in turn
      over the failing clusters); None (default): 48, or 24 per failing
      cluster when there are more, at most 480.
    combine: when several clusters of bricks fail (bricks joined by knob or
      side contacts), first try the best-ranked candidate of each cluster
      together (gradient method), one exact solve for all of them.
    time_s: wall-time budget in seconds (None: none); a repair that runs
      out returns what it has (not stable).
    temperature: loss temperature of the ranking.
    exact_method: HiGHS method of the exact solver.
    sizes: footprints (sx, sy) new bricks may have (None: every Table I brick);
      e.g. the sizes of a custom library.
    params: physical parameters.
    """

    region: str = "bbox"
    max_add: int | None = None
    allow_remove: bool = False
    verify: int = 3
    weak: int = 4
    max_candidates: int | None = None
    combine: bool = True
    time_s: float | None = None
    temperature: float = 0.02
    exact_method: str = "highs"
    sizes: tuple | None = None
    params: Params = Params()

    def allowed(self, sx: int, sy: int) -> bool:
        return self.sizes is None or (sx, sy) in self.sizes

    def __post_init__(self):
        if self.region not in REGIONS:
            raise ValueError(f"region must be one of {REGIONS}, got {self.region!r}")
        if self.max_add is not None and self.max_add < 0:
            raise ValueError(f"max_add must be >= 0 or None, got {self.max_add}")
        if self.verify < 1:
            raise ValueError(f"verify must be >= 1, got {self.verify}")
        if self.max_candidates is not None and self.max_candidates < 1:
            raise ValueError(f"max_candidates must be >= 1 or None, got {self.max_candidates}")
        if self.time_s is not None and not self.time_s > 0:
            raise ValueError(f"time_s must be > 0 or None, got {self.time_s}")

    def budget(self, n: int) -> int:
        """Most bricks a repair of an ``n``-brick layout may add."""
        return max(4, -(-n // 4)) if self.max_add is None else self.max_add

    def candidate_cap(self, clusters: int) -> int:
        """Most candidates per step when ``clusters`` clusters of bricks fail."""
        if self.max_candidates is not None:
            return self.max_candidates
        return min(max(48, _PER_CLUSTER * clusters), 480)


@dataclasses.dataclass
class Change:
    """One repair action: the candidate and the keys its bricks got."""

    candidate: Candidate
    keys: list
    removed: tuple = ()  # keys of the original bricks it replaced
    score: float = float("nan")  # gradient (per brick) that ranked it; NaN for greedy

    def describe(self) -> str:
        parts = []
        for k, (x, y, z), (sx, sy) in zip(self.keys, self.candidate.pos.tolist(), self.candidate.size.tolist()):
            parts.append(f"brick {k!r} {sx}x{sy} at ({x},{y},{z})")
        what = f"{self.candidate.kind}: " + ", ".join(parts)
        if self.removed:
            what += " replacing brick" + ("s " if len(self.removed) > 1 else " ") + ", ".join(map(repr, self.removed))
        if self.candidate.note:
            what += f" ({self.candidate.note})"
        return what


@dataclasses.dataclass
class RepairResult:
    """Outcome of a repair.

    layout: the final layout (original bricks first, unchanged, then new
    ones); changes: the actions in order; stable: exact verdict of the
    final layout; before/after: exact analyses; exact_calls / soft_calls:
    solver calls (soft = differentiable solve with gradient); time_s: wall
    time; kept: fraction of the original bricks still present.
    """

    method: str
    layout: Layout
    original: Layout
    changes: list
    stable: bool
    before: Analysis
    after: Analysis
    exact_calls: int
    soft_calls: int
    time_s: float
    emptied: bool = False  # rollback removed every brick (layout then holds the original)

    @property
    def added(self) -> int:
        return sum(len(c.keys) for c in self.changes)

    @property
    def removed(self) -> list:
        return [k for c in self.changes for k in c.removed]

    @property
    def kept(self) -> float:
        """Fraction of the original bricks in the final layout."""
        if self.emptied:
            return 0.0
        orig = set(self.original.keys)
        return len(orig & set(self.layout.keys)) / max(len(orig), 1)

    @property
    def solver_calls(self) -> int:
        return self.exact_calls + self.soft_calls


# --------------------------------------------------------------------------
# exact verdicts


def _exact(layout: Layout, opts: RepairOptions) -> Analysis:
    return analyze_layout(layout, solver="exact", params=opts.params, exact_method=opts.exact_method)


def exact_loss(a: Analysis) -> float:
    """Overload of an exact analysis, in units of T: the sum over bricks of
    drag beyond the capacity plus the unbalanced force of bricks out of
    equilibrium (the zero-temperature limit of the stability loss)."""
    T = a.model.params.T
    drag = np.array([a.max_drag[k] for k in a.layout.keys])
    over = np.maximum(drag / T - 1.0, 0.0).sum()
    res = np.abs(a.residual)
    p = a.model.params
    bad = residual_bad(res, p)
    unbalanced = (res[:, :3].sum(axis=1) + res[:, 3:].sum(axis=1) / p.stud)[bad].sum() / T
    return float(over + unbalanced)


def _failing_clusters(a: Analysis, failing: np.ndarray, rank: np.ndarray) -> list[list[int]]:
    """The ``failing`` bricks in clusters (bricks joined by knob or side
    contacts), each cluster weakest first by ``rank`` (n,) (floating
    clusters lowest first: a pillar under their lowest brick grounds them
    all), clusters by their weakest brick."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    layout = a.layout
    if not len(failing):
        return []
    ids = layout.occupancy()
    fail = np.zeros(layout.n + 1, bool)
    fail[failing] = True
    pairs = []
    for ax in range(3):
        lo = np.moveaxis(ids, ax, 0)[:-1]
        hi = np.moveaxis(ids, ax, 0)[1:]
        m = (lo >= 0) & (hi >= 0) & (lo != hi)
        m &= fail[lo] & fail[hi]
        pairs.append(np.stack([lo[m], hi[m]], axis=1))
    pr = np.concatenate(pairs)
    g = coo_matrix((np.ones(len(pr)), (pr[:, 0], pr[:, 1])), shape=(layout.n, layout.n))
    _, lab = connected_components(g, directed=False)
    floating = np.asarray(floating_bricks(a.model))[: layout.n]
    groups: dict = {}
    for i in failing.tolist():
        groups.setdefault(int(lab[i]), []).append(i)
    out = []
    for members in groups.values():
        if floating[members].all():
            members.sort(key=lambda i: (int(layout.pos[i, 2]), rank[i]))
        else:
            members.sort(key=lambda i: rank[i])
        out.append(members)
    out.sort(key=lambda m: min(rank[i] for i in m))
    return out


def _weak_order(a: Analysis, k: int) -> tuple[list[int], list[int]]:
    """(bricks, their cluster ids): the failing bricks, in turn over the
    failing clusters (ids 0, 1, ..., each cluster's weakest first), then the
    weakest standing bricks up to ``k`` in all (ids -1, -2, ...: each its own)."""
    keys = a.layout.keys
    score = np.array([a.scores[q] for q in keys])
    drag = np.array([a.max_drag[q] for q in keys])
    order = np.lexsort((-drag, -score))  # weakest first
    rank = np.empty(len(keys), np.int64)
    rank[order] = np.arange(len(keys))
    clusters = _failing_clusters(a, np.flatnonzero(score >= 1.0), rank)
    bricks, cid = [], []
    for r in range(max((len(m) for m in clusters), default=0)):
        for c, members in enumerate(clusters):
            if r < len(members):
                bricks.append(members[r])
                cid.append(c)
    rest = [int(i) for i in order if score[i] < 1.0][: max(k - len(bricks), 0)]
    return bricks + rest, cid + [-1 - j for j in range(len(rest))]


# --------------------------------------------------------------------------
# candidates


class _Space:
    """Occupancy and region tests for candidate placement."""

    def __init__(self, layout: Layout, region: str):
        cells, _ = cells_of(layout.pos, layout.size)
        self.occ = set(map(tuple, cells.tolist()))
        lo = layout.pos.min(axis=0)
        hi = (layout.pos + np.concatenate([layout.size, np.ones((layout.n, 1), np.int64)], axis=1)).max(axis=0)
        self.lo, self.hi = lo, hi  # hi exclusive
        self.columns = {(x, y) for x, y, _ in self.occ}
        self.region = region

    def free(self, x, y, z) -> bool:
        if x < 0 or y < 0 or z < 0 or (x, y, z) in self.occ:
            return False
        if self.region == "any":
            return True
        if z >= self.hi[2]:
            return False
        if self.region == "shape":
            return (x, y) in self.columns
        return self.lo[0] <= x < self.hi[0] and self.lo[1] <= y < self.hi[1]  # bbox, down to z = 0

    def rect_free(self, x0, y0, z, sx, sy) -> bool:
        return all(self.free(x0 + i, y0 + j, z) for i in range(sx) for j in range(sy))

    def rect_any_occ(self, x0, y0, z, sx, sy) -> bool:
        return z < 0 or any((x0 + i, y0 + j, z) in self.occ for i in range(sx) for j in range(sy))


def _footprint(layout: Layout, i: int):
    (x, y, z), (sx, sy) = layout.pos[i].tolist(), layout.size[i].tolist()
    return x, y, z, sx, sy


def _owner_grid(layout: Layout) -> dict:
    cells, owner = cells_of(layout.pos, layout.size)
    return dict(zip(map(tuple, cells.tolist()), owner.tolist()))


def _carried(layout: Layout, owner: dict, b: int) -> list[int]:
    """Overhanging bricks (a cell with nothing below) of b's structure: the
    bricks joined to b through knob connections, excluding those below b's
    layer; their weight reaches the ground through b's joints or next to
    them."""
    nbr: dict = {}
    for (x, y, z), q in owner.items():
        up = owner.get((x, y, z + 1))
        if up is not None and up != q:
            nbr.setdefault(q, set()).add(up)
            nbr.setdefault(up, set()).add(q)
    zb = int(layout.pos[b, 2])
    seen, stack = {b}, [b]
    while stack:
        q = stack.pop()
        for u in nbr.get(q, ()):
            if u not in seen and int(layout.pos[u, 2]) >= zb:
                seen.add(u)
                stack.append(u)
    out = []
    for q in seen - {b}:
        x, y, z, sx, sy = _footprint(layout, q)
        if z > 0 and any((x + i, y + j, z - 1) not in owner for i in range(sx) for j in range(sy)):
            out.append(q)
    return out


def propose(layout: Layout, analysis: Analysis, opts: RepairOptions, budget: int | None = None) -> list[Candidate]:
    """Candidate units around the weakest bricks of ``layout`` (see the module
    docstring), at most ``opts.candidate_cap(clusters)``, each of at most
    ``budget`` bricks (default ``opts.budget(layout.n)``); none overlaps the
    layout or leaves the region."""
    return _propose(layout, analysis, opts, budget)[0]


def _propose(layout: Layout, analysis: Analysis, opts: RepairOptions, budget: int | None = None):
    """(candidates, the failing cluster each was proposed for)."""
    budget = opts.budget(layout.n) if budget is None else budget
    if budget <= 0:
        return [], []
    space = _Space(layout, opts.region)
    seen: set = set()
    out: list[Candidate] = []
    target: list[int] = []
    weak, cid = _weak_order(analysis, opts.weak)
    n_clusters = max(len(set(cid)), 1)
    cap = opts.candidate_cap(n_clusters)
    per_cluster = max(cap // n_clusters, 1)
    count: dict = {}
    current = [0]  # the cluster being served

    def add(bricks, kind, note, replaces=()):
        key = (frozenset(bricks), tuple(sorted(replaces)))
        c = current[0]
        if key in seen or len(bricks) > budget or len(out) >= cap or count.get(c, 0) >= per_cluster:
            return
        seen.add(key)
        count[c] = count.get(c, 0) + 1
        out.append(candidate_brick(bricks, kind=kind, replaces=replaces, note=note))
        target.append(c)

    grid_occ = space.occ
    owner = _owner_grid(layout)

    def supports_under(b, key, note):
        """Supports under brick b: a brick in the layer below overlapping b,
        carried down as a pillar of the same footprint to the baseplate or to
        the first brick below."""
        x, y, z, sx, sy = _footprint(layout, b)
        if z == 0:
            return
        sups = []
        for fx, fy in _SUPPORT:
            if not opts.allowed(fx, fy):
                continue
            for x0 in range(x - fx + 1, x + sx):
                for y0 in range(y - fy + 1, y + sy):
                    if not space.rect_free(x0, y0, z - 1, fx, fy):
                        continue
                    under = sum(1 for i in range(fx) for j in range(fy)
                                if x <= x0 + i < x + sx and y <= y0 + j < y + sy)
                    bricks = [(x0, y0, z - 1, fx, fy)]
                    lev = z - 1
                    ok = True
                    while lev > 0 and not space.rect_any_occ(x0, y0, lev - 1, fx, fy):
                        if not space.rect_free(x0, y0, lev - 1, fx, fy):
                            ok = False
                            break
                        lev -= 1
                        bricks.append((x0, y0, lev, fx, fy))
                    if ok and len(bricks) <= budget:
                        sups.append((len(bricks), -under, fx * fy, bricks))
        for _, _, _, bricks in sorted(sups, key=lambda t: t[:3])[:_PER_TARGET]:
            add(bricks, "support", note)

    for b, c in zip(weak, cid):
        current[0] = c
        if len(out) >= cap:
            break
        if count.get(c, 0) >= per_cluster:
            continue
        x, y, z, sx, sy = _footprint(layout, b)
        key = layout.keys[b]
        # supports under b itself, then under the overhanging bricks whose
        # weight b carries (farthest first: they load b's joints the most)
        supports_under(b, key, f"under brick {key!r}")
        cx, cy = x + sx / 2.0, y + sy / 2.0
        carried = _carried(layout, owner, b)
        carried.sort(key=lambda q: -abs(layout.pos[q, 0] + layout.size[q, 0] / 2.0 - cx)
                     - abs(layout.pos[q, 1] + layout.size[q, 1] / 2.0 - cy))
        for q in carried[:4]:
            supports_under(q, layout.keys[q], f"under brick {layout.keys[q]!r}, carried by weak brick {key!r}")
        # bridges: a brick in the layer above or below spanning b and a side neighbour
        nbrs = set()
        for i in range(sx):
            for j in range(sy):
                for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                    c = (x + i + dx, y + j + dy, z)
                    if c in grid_occ and not (x <= c[0] < x + sx and y <= c[1] < y + sy):
                        nbrs.add(c)
        for zz in (z + 1, z - 1):
            if zz < 0:
                continue
            for fx, fy in _BRIDGE:
                if not opts.allowed(fx, fy):
                    continue
                for (cx, cy, _) in sorted(nbrs):
                    for x0 in range(min(x, cx) - fx + 1, max(x + sx, cx + 1)):
                        for y0 in range(min(y, cy) - fy + 1, max(y + sy, cy + 1)):
                            cov = {(x0 + i, y0 + j) for i in range(fx) for j in range(fy)}
                            on_b = any(x <= cx2 < x + sx and y <= cy2 < y + sy for cx2, cy2 in cov)
                            if not on_b or (cx, cy) not in cov or not space.rect_free(x0, y0, zz, fx, fy):
                                continue
                            add([(x0, y0, zz, fx, fy)], "bridge", f"across brick {key!r}'s side joint")
        # replacement by a longer brick (allow_remove only)
        if opts.allow_remove and budget >= 1:
            for along in (0, 1):
                length, width = (sx, sy) if along == 0 else (sy, sx)
                for ext in (2, 4):
                    new_len = length + ext
                    if (min(new_len, width), max(new_len, width)) not in TABLE_I_MASS_KG:
                        continue
                    if not opts.allowed(*((new_len, width) if along == 0 else (width, new_len))):
                        continue
                    for shift in range(0, ext + 1, max(ext // 2, 1)):
                        nx, ny = (x - shift, y) if along == 0 else (x, y - shift)
                        nsx, nsy = (new_len, sy) if along == 0 else (sx, new_len)
                        new_cells = [(nx + i, ny + j, z) for i in range(nsx) for j in range(nsy)
                                     if not (x <= nx + i < x + sx and y <= ny + j < y + sy)]
                        if all(space.free(*c) for c in new_cells):
                            add([(nx, ny, z, nsx, nsy)], "replace", f"longer brick for {key!r}", replaces=(b,))
            for bricks, row in _remerges(layout, owner, b, opts):
                add(bricks, "remerge", f"brick {key!r} and its row re-merged", replaces=row)
    return out, target


def _splits(length: int, parts: Sequence[int], most: int) -> list[tuple]:
    """Every ordered split of ``length`` into at most ``most`` pieces of ``parts``."""
    out, stack = [], [((), 0)]
    while stack:
        pre, tot = stack.pop()
        if tot == length:
            out.append(pre)
            continue
        if len(pre) < most:
            stack.extend((pre + (p,), tot + p) for p in parts if tot + p <= length)
    return out


def _remerges(layout: Layout, owner: dict, b: int, opts: RepairOptions, per_row: int = 4):
    """Re-merges of weak brick ``b`` (``allow_remove``): ``b`` and the bricks
    next to it along its long axis with the same cross-section (a row, at
    most 16 studs) re-split into Table I bricks whose joints lie under or
    over a brick of the layers above and below (bridged joints). Yields
    (bricks, replaced indices), at most ``per_row`` splits per row, fewest
    unbridged joints first, then fewest bricks."""
    x, y, z, sx, sy = _footprint(layout, b)
    along = 0 if sx >= sy else 1
    width = sy if along == 0 else sx
    if width > 2:
        return
    lo_w = y if along == 0 else x  # the cross-section: lo_w .. lo_w + width - 1

    def cell(a, w, zz):  # (along, across, layer) -> grid cell
        return (a, w, zz) if along == 0 else (w, a, zz)

    def same_section(q):
        qx, qy, qz, qsx, qsy = _footprint(layout, q)
        return qz == z and ((qy, qsy) == (y, sy) if along == 0 else (qx, qsx) == (x, sx))

    row = [b]
    start, end = (x, x + sx) if along == 0 else (y, y + sy)
    for step in (-1, 1):
        while end - start < 16:
            q = owner.get(cell(start - 1 if step < 0 else end, lo_w, z))
            if q is None or not same_section(q):
                break
            qlen = int(layout.size[q, along])
            if end - start + qlen > 16:
                break
            row.append(q)
            start, end = (start - qlen, end) if step < 0 else (start, end + qlen)
    if len(row) < 2:
        return
    parts = [n for n in range(1, 9)
             if (min(n, width), max(n, width)) in TABLE_I_MASS_KG
             and opts.allowed(*((n, width) if along == 0 else (width, n)))]
    cur = sorted(int(layout.pos[q, along]) for q in row)[1:]  # the row's joints now

    def bridged(cut):
        for zz in (z - 1, z + 1):
            for w in range(lo_w, lo_w + width):
                a, c = owner.get(cell(cut - 1, w, zz)), owner.get(cell(cut, w, zz))
                if a is not None and a == c:
                    return True
        return False

    ranked = []
    for split in _splits(end - start, parts, len(row) + 1):
        cuts = list(np.cumsum(split)[:-1] + start)
        if cuts == cur:
            continue
        ranked.append((sum(not bridged(c) for c in cuts), len(split), split))
    ranked.sort()
    for _, _, split in ranked[:per_row]:
        bricks, a = [], start
        for n in split:
            bricks.append((a, lo_w, z, n, width) if along == 0 else (lo_w, a, z, width, n))
            a += n
        yield bricks, tuple(row)


# --------------------------------------------------------------------------
# ranking by the gradient


def _grad_fn(opts: LossOptions, fields: tuple):
    """``fn(w, *soft problem arrays) -> (loss, d loss / d w)``; ``fields``: the
    names of the :class:`SoftProblem` fields the arrays are (those not None)."""
    vg = jax.value_and_grad(lambda w, p: stability_loss(w, None, p, opts=opts))

    def fn(w, *arrays):
        return vg(w, SoftProblem.from_flat(fields, arrays))

    return fn


def rank(layout: Layout, cands: Sequence[Candidate], opts: RepairOptions,
         loss_opts: LossOptions | None = None) -> tuple[np.ndarray, float]:
    """d loss / d weight of each candidate at weight 0 (one smooth solve and
    one adjoint solve for all), per candidate: the weight of its first brick;
    a replacement's is that minus the replaced brick's. Returns (scores, loss)."""
    lo = loss_opts or LossOptions(temperature=opts.temperature, params=opts.params)
    soft = compile_soft(layout, cands, opts.params)
    # on the ladder (similar layouts share one compiled gradient), layered when cheaper
    prob = plan_soft(soft.problem)
    w = np.zeros(prob.mass.shape[0])
    w[: soft.n] = soft.weights()
    fields, arrays = prob.flat()
    arrays = (w,) + arrays
    with one_blas_thread():
        val, g = jax.device_get(compiled("repair-grad", _grad_fn(lo, fields), (lo, fields), arrays)(*arrays))
        g = np.asarray(g)
    scores = g[soft.unit_index].copy()
    for k, c in enumerate(cands):
        if c.replaces:
            scores[k] -= g[list(c.replaces)].sum()
    return scores, float(val)


# --------------------------------------------------------------------------
# repair loops


def _verify_order(per_brick: np.ndarray, sizes) -> list[int]:
    """Order in which to verify candidates: those predicted to help (negative
    gradient) first: the best-ranked one overall, then round-robin over unit
    sizes, smallest first, each size's best-ranked first (the fewest bricks
    are wanted and the gradient says which of each size helps most); then
    the rest by gradient."""
    sizes = np.asarray(sizes)
    ranked = [int(i) for i in np.argsort(per_brick, kind="stable")]
    helps = [i for i in ranked if per_brick[i] < 0.0]
    groups = {k: [i for i in helps[1:] if sizes[i] == k] for k in sorted(set(sizes[helps[1:]].tolist()))}
    out = helps[:1]
    r = 0
    while len(out) < len(helps):
        for k in groups:
            if r < len(groups[k]):
                out.append(groups[k][r])
        r += 1
    return out + [i for i in ranked if per_brick[i] >= 0.0]


def _choose(trials):
    """(k, analysis) pairs -> the index to take: a stable one with the fewest
    bricks (then lowest loss), else the largest loss drop per brick."""
    stable = [t for t in trials if t[2].stable]
    if stable:
        return min(stable, key=lambda t: (t[1].k, exact_loss(t[2])))
    return min(trials, key=lambda t: t[3] / t[1].k)


def _finish(method, layout, original, changes, before, after, exact_calls, soft_calls, t0):
    return RepairResult(method=method, layout=layout, original=original, changes=changes,
                        stable=bool(after.stable), before=before, after=after,
                        exact_calls=exact_calls, soft_calls=soft_calls, time_s=time.perf_counter() - t0)


def _combined(cands, target, per_brick, room: int) -> list[int]:
    """The best-ranked helpful candidate (negative gradient per brick) of each
    failing cluster (``target`` >= 0), best first, skipping replacements and
    any that overlaps one already taken, at most ``room`` bricks in all."""
    best: dict = {}
    for i in np.argsort(per_brick, kind="stable").tolist():
        if per_brick[i] < 0.0 and not cands[i].replaces and target[i] >= 0:
            best.setdefault(target[i], []).append(i)
    picks, cells, used = [], set(), 0
    for c in sorted(best, key=lambda c: per_brick[best[c][0]]):
        for i in best[c]:
            ci = cands[i].cells()
            if used + cands[i].k <= room and not (ci & cells):
                picks.append(i)
                cells |= ci
                used += cands[i].k
                break
    return picks


def _search(layout: Layout, opts: RepairOptions, method: str) -> RepairResult:
    t0 = time.perf_counter()
    deadline = None if opts.time_s is None else t0 + opts.time_s
    original = layout
    current = _exact(layout, opts)
    before = current
    exact_calls, soft_calls = 1, 0
    changes: list[Change] = []
    used, budget = 0, opts.budget(layout.n)

    def out_of_time():
        return deadline is not None and time.perf_counter() > deadline

    while not current.stable and used < budget and not out_of_time():
        cands, target = _propose(layout, current, opts, budget=budget - used)
        if not cands:
            break
        base_loss = exact_loss(current)
        if method == "gradient":
            scores, _ = rank(layout, cands, opts)
            soft_calls += 1
            per_brick = scores / np.array([c.k for c in cands])
            order = _verify_order(per_brick, [c.k for c in cands])
            # verify the best-ranked; if none of them lowers the exact loss, the
            # next ones (at most three rounds)
            batches = [order[j:j + opts.verify] for j in range(0, min(len(order), 3 * opts.verify), opts.verify)]
        else:
            per_brick = np.full(len(cands), np.nan)
            batches = [list(range(len(cands)))]
        trials = []
        for picks in batches:
            for i in picks:
                if trials and out_of_time():
                    break
                a = _exact(apply_candidates(layout, [cands[i]], fresh_keys(layout.keys, cands[i].k)), opts)
                exact_calls += 1
                trials.append((i, cands[i], a, exact_loss(a) - base_loss))
            if any(t[2].stable or t[3] < 0.0 for t in trials) or out_of_time():
                break
        if method == "gradient" and opts.combine and not any(t[2].stable for t in trials) and not out_of_time():
            # several clusters fail and no single unit makes the layout stand:
            # the best of each cluster together, taken if it stands or gains more
            combo = _combined(cands, target, per_brick, budget - used)
            if len(combo) >= 2:
                picked = [cands[i] for i in combo]
                k = sum(c.k for c in picked)
                keys = fresh_keys(layout.keys, k)
                a = _exact(apply_candidates(layout, picked, keys), opts)
                exact_calls += 1
                if a.stable or exact_loss(a) - base_loss < min(t[3] for t in trials):
                    layout = a.layout  # the layout just analysed
                    for i in combo:
                        ck, keys = keys[:cands[i].k], keys[cands[i].k:]
                        changes.append(Change(candidate=cands[i], keys=ck, score=float(per_brick[i])))
                    used += k
                    current = a
                    continue
        i, cand, a, drop = _choose(trials)
        if not a.stable and drop >= 0.0:
            break  # nothing helps
        keys = fresh_keys(layout.keys, cand.k)
        removed = tuple(layout.keys[r] for r in cand.replaces)
        layout = apply_candidates(layout, [cand], keys)
        changes.append(Change(candidate=cand, keys=keys, removed=removed, score=float(per_brick[i])))
        used += cand.k
        current = a
    return _finish(method, layout, original, changes, before, current, exact_calls, soft_calls, t0)


def repair(layout: Layout, opts: RepairOptions = RepairOptions()) -> RepairResult:
    """Gradient-guided repair of ``layout`` (see the module docstring)."""
    return _search(layout, opts, "gradient")


def greedy_repair(layout: Layout, opts: RepairOptions = RepairOptions()) -> RepairResult:
    """Baseline: each step checks every candidate with a full exact solve."""
    return _search(layout, opts, "greedy")


def rollback_repair(layout: Layout, opts: RepairOptions = RepairOptions()) -> RepairResult:
    """Baseline: the rollback of LLM brick generators. While the layout does
    not stand, remove the first failing brick (in input order) and every brick
    after it."""
    t0 = time.perf_counter()
    original = layout
    a = _exact(layout, opts)
    before = a
    calls = 1
    while not a.stable:
        failing = [i for i, k in enumerate(layout.keys) if a.scores[k] >= 1.0]
        first = min(failing)
        if first == 0:  # the first brick fails: nothing of the design is left
            res = _finish("rollback", layout, original, [], before, a, calls, 0, t0)
            res.emptied = True
            return res
        layout = layout.subset(range(first))
        a = _exact(layout, opts)
        calls += 1
    return _finish("rollback", layout, original, [], before, a, calls, 0, t0)
