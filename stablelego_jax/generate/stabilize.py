"""A stable brick layout for a voxel shape: same cells, library bricks, stands by the exact solver.

:func:`stabilize` (``stablelego stabilize``) searches over exact covers of
one voxel shape (IoU 1, no overlaps, library bricks only):

1. the heuristic merge (:func:`~stablelego_jax.generate.voxels.merge_voxels`)
   with ``seeds`` tie-break seeds, those with no floating brick first; the
   first cover that stands by the exact solver is the answer;
2. rounds of re-merging around the failing bricks (the random rounds walk
   from the seed-0 merge, the gradient rounds from the best cover found by
   then, a seed's or a round's): the *region* (the cells
   of the bricks within ``reach`` studs of a failing brick, in its layer and
   the layers just below and above) is covered anew while every other brick
   stays, by

   * the **gradient move**: every placement of a library brick inside the
     region gets a probability ``p = sigmoid(theta)`` (warm start: the
     current bricks likely, the rest not); the bricks outside the region
     have weight 1, the region's placements their share of their most
     contested cell (:func:`~stablelego_jax.train.net.subset_shares`), and
     ``theta`` descends (Adam) shape fidelity ``sum_cells (coverage - 1)^2``
     + ``lam`` x the stability loss of the whole layout
     (:func:`~stablelego_jax.loss.stability_loss` on the layered soft
     interior point, on the size ladder); the probabilities are decoded to an
     exact cover of the region (most probable first, the rest filled with the
     largest bricks that fit);
   * **random moves**: randomised greedy covers of the region that prefer
     long bricks across the joints of the layers below and above;

   first up to ``rounds`` rounds of random moves (cheap: a few exact
   solves a round), then up to as many rounds that add the gradient move
   (a soft solve per Adam step, a compile per new problem shape) to the
   random ones, each started only while a quarter of the time budget
   remains; the region grows while the rounds find nothing better. Each
   candidate layout is verified by the exact solver and kept when it fails
   less (fewer failing bricks, then a smaller overload
   :func:`~stablelego_jax.design.repair.exact_loss`);

   a cover is first *screened* by its floating bricks (no chain of knob
   connections to the ground, :func:`~.voxels.floating_bricks`: a
   connectivity check, no solve). Each of them fails, so a cover with more
   of them than the cover it would have to beat fails with more bricks:
   it is set aside without an exact solve (the search decides as it would
   with the solve; only the solver calls and the time differ);
3. with ``allow_support``: if no cover stands within the budget, the fewest
   support bricks outside the shape (:func:`~stablelego_jax.design.repair.repair`).

Coordinates: cell (x, y, z) of the voxel grid is stud cell (x, y) of layer z.
"""
from __future__ import annotations

import dataclasses
import time
from typing import Callable, Sequence

import numpy as np

from ..analysis import Analysis, analyze_layout, make_analysis
from ..blas import one_blas_thread
from ..design.repair import RepairOptions, exact_loss, repair
from ..layout import Layout, brick_layout, cells_of, table_i_bricks
from ..model import Params, compile_layout
from ..runtime import x64
from ..solvers.exact import solve_lp_interior
from .voxels import DEFAULT_BRICKS, floating_bricks, merge_voxels, oriented, placements_in

__all__ = ["JUDGES", "StabilizeOptions", "StabilizeResult", "stabilize", "layout_voxels", "merit", "recover_region",
           "ungroundable_cells"]


#: How :func:`stabilize` solves candidate covers (``StabilizeOptions.judge``).
JUDGES = ("interior", "vertex", "canonical")


@dataclasses.dataclass(frozen=True)
class StabilizeOptions:
    """Budget and moves of :func:`stabilize`.

    seeds: heuristic tie-break seeds tried first; rounds: random re-merge
    rounds at most, then (``gradient``) as many again with the gradient move;
    time_s: wall-clock budget (s; checked between exact solves);
    max_solves: a budget in exact solves (None: none), checked where the
    clock is: the search stops before a candidate once it has made this
    many (a candidate the judge says stands is confirmed by a second,
    canonical solve, and the cover returned may get one). The search
    follows one path whatever its budget, so with a ``time_s`` it never
    reaches, the result is the same on any machine and under any load;
    reach: studs around a failing brick whose bricks are re-merged;
    random_moves: random covers tried per round; gradient: use the gradient
    move; steps / lr / lam: its Adam steps, step size and stability weight;
    max_placements: the most region placements it optimises (the region's
    current bricks and a random draw of the others; the decoding fills the
    rest);
    allow_support: add support bricks outside the shape when no cover
    stands; bricks: the library footprints (must hold 1x1); judge: how a
    candidate cover is solved during the search, one of :data:`JUDGES`:
    "interior" (default; Eq. 9's LP by Clarabel's interior point,
    :func:`~stablelego_jax.solvers.exact.solve_lp_interior`, about 8x
    faster than the canonical solve on large shapes) or "vertex" (HiGHS'
    interior point with crossover, about 2x) find an optimal force
    distribution without the canonical stage; a cover they say stands is
    solved canonically too and stands only if that agrees, and the cover
    returned is reported canonically; "canonical": every candidate by the
    canonical exact solve. Which bricks fail can differ between them on
    tied layouts, and so can the path of the search; sideways: after this
    many rounds in a row without a better cover, a random cover with no
    more failing bricks than the current one replaces it (a sideways step
    along a plateau of equally failing covers, whose failing bricks and
    region differ), without counting as progress; 0: only better covers."""

    seeds: int = 20
    rounds: int = 40
    time_s: float = 600.0
    max_solves: int | None = None
    reach: int = 2
    random_moves: int = 6
    gradient: bool = True
    steps: int = 12
    max_placements: int = 400
    lr: float = 0.5
    lam: float = 20.0
    allow_support: bool = False
    bricks: tuple = DEFAULT_BRICKS
    params: Params = Params()
    judge: str = "interior"
    sideways: int = 2

    def __post_init__(self):
        if self.judge not in JUDGES:
            raise ValueError(f"judge must be one of {', '.join(JUDGES)}, not {self.judge!r}")
        if self.max_solves is not None and self.max_solves < 1:
            raise ValueError(f"max_solves must be >= 1 or None, got {self.max_solves}")


@dataclasses.dataclass
class StabilizeResult:
    """layout: the best cover found (stands iff ``stable``); start: the
    heuristic merge with seed 0, or the cover given as ``start``; method:
    which step found it ("heuristic", "start" (the given cover stands),
    "seed", "gradient", "random", "support" or "none"); bricks_changed: bricks
    of ``layout`` not in ``start`` (same cell and size); exact_calls /
    soft_calls: solver calls; screened: covers set aside without an exact
    solve (more floating bricks than the cover to beat fails with);
    failing: failing bricks of ``layout``; reason: why it does not stand,
    when it does not."""

    layout: Layout
    start: Layout
    stable: bool
    method: str
    bricks_changed: int
    exact_calls: int
    soft_calls: int
    rounds: int
    failing: int
    support_bricks: int
    time_s: float
    reason: str = ""
    screened: int = 0

    def to_json(self) -> dict:
        return {"stable": self.stable, "method": self.method, "bricks": self.layout.n,
                "bricks_changed": self.bricks_changed, "support_bricks": self.support_bricks,
                "failing": self.failing, "exact_calls": self.exact_calls, "soft_calls": self.soft_calls,
                "screened": self.screened, "rounds": self.rounds, "time_s": round(self.time_s, 3),
                "reason": self.reason}


def layout_voxels(layout: Layout, which: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(vox (X, Y, Z) bool of the cells a grid layout covers, offset (3,)
    of cell [0, 0, 0] in the layout's coordinates); ``which`` (n,) bool:
    only the cells of those bricks, in the grid of the whole layout."""
    cells, owner = cells_of(layout.pos, layout.size)
    lo = cells.min(axis=0)
    ext = cells.max(axis=0) - lo + 1
    vox = np.zeros(tuple(ext.tolist()), bool)
    sel = cells if which is None else cells[which[owner]]
    vox[tuple((sel - lo).T)] = True
    return vox, lo


def ungroundable_cells(vox: np.ndarray, bricks: Sequence = DEFAULT_BRICKS) -> np.ndarray:
    """(X, Y, Z) bool: cells that no cover with ``bricks`` can join to the
    ground: no chain of library-brick placements inside the shape, each
    resting on or carrying the one before (a cell of one directly above a
    cell of the other), leads from them to layer 0. Bricks on them float in
    every cover. (Side contacts carry no weight: a cell held only from the
    side, farther out than the longest brick that fits reaches, is lost too.)

    A fixed point over every placement of :func:`~.voxels.placements_in`:
    a placement is grounded when it lies in layer 0 or one of its cells sits
    on or under a cell of a grounded placement."""
    vox = np.asarray(vox, bool)
    pos, size = placements_in(vox, oriented(bricks))
    cells, owner = cells_of(pos, size)
    shape = np.array(vox.shape)
    flat = np.ravel_multi_index(cells.T, vox.shape)
    nbr = []
    for dz in (-1, 1):
        z = cells[:, 2] + dz
        ok = (z >= 0) & (z < shape[2])
        nbr.append(np.where(ok, flat + dz, -1))  # z is the last axis: its stride is 1
    grounded = np.zeros(vox.size + 1, bool)  # the last slot: "no neighbour"
    grounded[np.ravel_multi_index(np.argwhere(vox[:, :, :1]).T, vox.shape)] = True
    base = cells[:, 2] == 0
    count = -1
    while count != int(grounded.sum()):
        count = int(grounded.sum())
        touch = base | grounded[nbr[0]] | grounded[nbr[1]]
        held = np.bincount(owner, weights=touch, minlength=len(pos)) > 0
        grounded[flat[held[owner]]] = True
    return vox & ~grounded[:-1].reshape(vox.shape)


def _failing(a: Analysis) -> np.ndarray:
    """Indices of the bricks that fail (score >= 1)."""
    return np.array([i for i, k in enumerate(a.layout.keys) if a.scores[k] >= 1.0], np.int64)


def merit(a: Analysis) -> tuple[int, float]:
    """(failing bricks, exact overload in T): lower is better; (0, 0) stands."""
    return len(_failing(a)), exact_loss(a)


def _region(layout: Layout, failing: np.ndarray, reach: int) -> np.ndarray:
    """(n,) bool: bricks to re-merge: those within ``reach`` studs (x, y) of
    a failing brick's footprint in its layer and the layers just above and
    below."""
    pos, size = layout.pos, layout.size
    lo, hi = pos[:, :2], pos[:, :2] + size
    take = np.zeros(layout.n, bool)
    for f in failing:
        near = ((lo[:, 0] < hi[f, 0] + reach) & (hi[:, 0] > lo[f, 0] - reach)
                & (lo[:, 1] < hi[f, 1] + reach) & (hi[:, 1] > lo[f, 1] - reach)
                & (np.abs(pos[:, 2] - pos[f, 2]) <= 1))
        take |= near
    return take


def _exact_cover(mask: np.ndarray, pos: np.ndarray, size: np.ndarray, order: np.ndarray,
                 types: Sequence[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """Placements taken greedily in ``order`` where all their cells of
    ``mask`` are still free, then the cells left filled with the largest
    footprints of ``types`` that fit (1x1 last): an exact cover of ``mask``."""
    free = np.asarray(mask, bool).copy()
    out_p, out_s = [], []

    def take(p, s):
        (x, y, z), (sx, sy) = p, s
        win = free[x:x + sx, y:y + sy, z]
        if win.shape == (sx, sy) and win.all():
            free[x:x + sx, y:y + sy, z] = False
            out_p.append((x, y, z))
            out_s.append((sx, sy))

    for i in order:
        take(pos[i].tolist(), size[i].tolist())
    if free.any():
        fp, fs = placements_in(free, types)  # grouped by type, largest first
        for p, s in zip(fp.tolist(), fs.tolist()):
            take(p, s)
    assert not free.any(), "1x1 must be in the brick set"
    return np.asarray(out_p, np.int64).reshape(-1, 3), np.asarray(out_s, np.int64).reshape(-1, 2)


def recover_region(layout: Layout, region: np.ndarray, rank: np.ndarray, pos: np.ndarray, size: np.ndarray,
                   types) -> Layout:
    """``layout`` with the bricks of ``region`` (n,) bool replaced by an exact
    cover of their cells from placements (pos, size) taken in ``rank``
    order (see :func:`_exact_cover`)."""
    mask, lo = layout_voxels(layout, region)
    p, s = _exact_cover(mask, pos - lo, size, rank, types)
    keep = ~region
    return brick_layout(np.concatenate([layout.pos[keep], p + lo]), np.concatenate([layout.size[keep], s]),
                        source=layout.source)


def _region_placements(layout: Layout, region: np.ndarray, types):
    """(pos, size) of every placement of ``types`` inside the region's cells."""
    mask, lo = layout_voxels(layout, region)
    pos, size = placements_in(mask, types)
    return pos + lo, size


def _random_rank(layout: Layout, region: np.ndarray, pos: np.ndarray, size: np.ndarray,
                 rng: np.random.Generator) -> np.ndarray:
    """A random priority over the region's placements: area times a random
    factor, doubled for placements that span a joint of the fixed layer
    below or above (a long brick across two bricks ties them together)."""
    keep = ~region
    owner = {}
    c, o = cells_of(layout.pos[keep], layout.size[keep])
    for cell, b in zip(map(tuple, c.tolist()), o.tolist()):
        owner[cell] = b
    area = size[:, 0] * size[:, 1]
    bonus = np.ones(len(pos))
    for i, ((x, y, z), (sx, sy)) in enumerate(zip(pos.tolist(), size.tolist())):
        for dz in (-1, 1):
            below = {owner.get((x + a, y + b, z + dz)) for a in range(sx) for b in range(sy)} - {None}
            if len(below) >= 2:
                bonus[i] *= 2.0
    key = area * bonus * rng.random(len(pos)) ** 0.5
    return np.argsort(-key, kind="stable")


def _bricks(pos: np.ndarray, size: np.ndarray) -> list[tuple]:
    """(corner, size) tuples of bricks or placements, to compare as sets."""
    return list(zip(map(tuple, pos.tolist()), map(tuple, size.tolist())))


def _same_bricks(a: Layout, b: Layout) -> int:
    """Bricks of ``a`` that are not in ``b`` (same corner and size)."""
    sb = set(_bricks(b.pos, b.size))
    return sum(1 for t in _bricks(a.pos, a.size) if t not in sb)


class _Gradient:
    """The gradient move's optimiser: one jitted Adam step (optax) on
    fidelity + lam x stability over the padded soft problem, compiled once
    per ladder shape."""

    def __init__(self, opts: StabilizeOptions):
        import jax
        import jax.numpy as jnp
        import optax

        from ..loss import LossOptions, stability_loss
        from ..soft import SoftProblem
        from ..train.net import subset_shares

        lo = LossOptions(params=opts.params)
        self.opts = opts
        self.adam = adam = optax.adam(opts.lr)
        self.fns = {}
        self.steps_done = 0  # soft solves (each a loss and its gradient)

        def make(fields):
            def f(theta, fixed, inc, lam, *arrays):
                prob = SoftProblem.from_flat(fields, arrays)
                p = jax.nn.sigmoid(theta)
                ps = jnp.where(fixed | (inc.sum(0) == 0), 0.0, p)
                share = subset_shares(ps[None], inc[None])[0]
                w = jnp.where(fixed, 1.0, share)
                cov = inc @ ps
                real = inc.sum(1) > 0
                fid = jnp.where(real, (cov - 1.0) ** 2, 0.0).sum()
                return fid + lam * stability_loss(w, None, prob, opts=lo)

            def step(theta, state, fixed, inc, lam, *arrays):
                g = jnp.nan_to_num(jax.grad(f)(theta, fixed, inc, lam, *arrays))
                upd, state = adam.update(g, state)
                return optax.apply_updates(theta, upd), state

            return jax.jit(step)

        self.make = make

    def run(self, layout: Layout, region: np.ndarray, pos: np.ndarray, size: np.ndarray,
            rng: np.random.Generator, deadline: float) -> np.ndarray:
        """Probabilities (k,) of the region's placements after ``steps`` Adam
        steps (fewer past ``deadline``, a perf_counter time); placements
        beyond ``max_placements`` are not optimised (probability 0)."""
        k_all = len(pos)
        cur = set(_bricks(layout.pos[region], layout.size[region]))
        is_cur = np.array([t in cur for t in _bricks(pos, size)], bool)
        keep = np.nonzero(is_cur)[0]
        others = np.nonzero(~is_cur)[0]
        room = max(self.opts.max_placements - len(keep), 0)
        pick = np.sort(np.concatenate([keep, rng.choice(others, size=min(room, len(others)), replace=False)]))
        p_all = np.zeros(k_all)
        p_all[pick] = self._run(layout, region, pos[pick], size[pick], is_cur[pick], deadline)
        return p_all

    def _run(self, layout: Layout, region: np.ndarray, pos: np.ndarray, size: np.ndarray, is_cur: np.ndarray,
             deadline: float):
        import jax

        from ..soft import compile_placements
        from ..solvers.problem import plan_soft

        keep = ~region
        fpos, fsize = layout.pos[keep], layout.size[keep]
        allpos = np.concatenate([fpos, pos])
        allsize = np.concatenate([fsize, size])
        mass = table_i_bricks(allsize)[0]
        # solved once a step: a padding fitted to the region when the steps pay for its compile
        prob = plan_soft(compile_placements(allpos, allsize, mass, self.opts.params), calls=self.opts.steps)
        n_pad = prob.mass.shape[0]
        nf, k = len(fpos), len(pos)
        cells, owner = cells_of(pos, size)
        ucells, cid = np.unique(cells, axis=0, return_inverse=True)
        c_pad = -(-len(ucells) // 64) * 64
        inc = np.zeros((c_pad, n_pad))
        inc[np.ravel(cid), nf + owner] = 1.0
        fixed = np.zeros(n_pad, bool)
        fixed[:nf] = True
        theta = np.full(n_pad, -3.0)  # warm start: the region's current bricks likely, the rest not
        theta[nf:nf + k][is_cur] = 2.0
        fields, arrays = prob.flat()
        key = (fields, n_pad, c_pad) + tuple(np.shape(a) for a in arrays)
        if key not in self.fns:
            self.fns[key] = self.make(fields)
        fn = self.fns[key]
        state = self.adam.init(jax.numpy.asarray(theta))
        with one_blas_thread():
            for t in range(1, self.opts.steps + 1):
                if t > 1 and time.perf_counter() > deadline:
                    break
                self.steps_done += 1
                # each step waits for its solve, so the deadline sees the time spent
                theta, state = jax.block_until_ready(fn(theta, state, fixed, inc, np.float64(self.opts.lam), *arrays))
        theta = np.asarray(theta)
        return 1.0 / (1.0 + np.exp(-theta[nf:nf + k]))


@x64
def stabilize(vox: np.ndarray, opts: StabilizeOptions = StabilizeOptions(), source: str = "<voxels>",
              progress: Callable[[str], None] | None = None, start: Layout | None = None) -> StabilizeResult:
    """A stable exact cover of ``vox`` (X, Y, Z) bool (see the module
    docstring); brick coordinates are the grid's indices. ``start``: an
    exact cover of ``vox`` to begin from instead of the heuristic merge with
    seed 0 (a generator's decoding to refine; the seeds are still tried
    after it, ``seeds=1`` for none; it is solved by ``opts.judge`` first, the
    merge canonically first); ValueError if it covers other cells."""
    t0 = time.perf_counter()
    say = progress or (lambda s: None)
    types = oriented(opts.bricks)
    calls = {"exact": 0, "soft": 0, "screened": 0}

    lp_only = dataclasses.replace(opts.params, ridge=0.0)  # no canonical stage

    def check(layout: Layout, canonical: bool = False) -> Analysis:
        """A candidate's analysis by ``opts.judge`` (or canonically): a cover
        the judge says stands is solved canonically too, and stands only if
        that agrees (a tied layout's verdict can differ)."""
        calls["exact"] += 1
        if canonical or opts.judge == "canonical":
            return analyze_layout(layout, solver="exact", params=opts.params)
        if opts.judge == "vertex":
            a = analyze_layout(layout, solver="exact", params=lp_only, exact_method="highs-ipm")
        else:
            t = time.perf_counter()
            model = compile_layout(layout, lp_only)
            r = solve_lp_interior(model)
            a = make_analysis(layout, model, r.f, "exact", r.success, t, objective=r.objective)
        return check(layout, canonical=True) if a.stable else a

    def spent() -> bool:
        """Whether the budget is spent: the time, or the exact solves."""
        return time.perf_counter() - t0 > opts.time_s or (
            opts.max_solves is not None and calls["exact"] >= opts.max_solves)

    def final(layout: Layout, a: Analysis) -> Analysis:
        """The canonical analysis of the cover returned (``a`` when it is one already)."""
        return a if a.model.params == opts.params else check(layout, canonical=True)

    def floating(layout: Layout) -> int:
        return int(floating_bricks(layout).sum())

    def beaten(n_floating: int, *rivals: Analysis) -> bool:
        """Whether a cover with ``n_floating`` floating bricks fails with
        more bricks than each rival does (then it cannot beat any of them:
        every floating brick fails); counted as screened."""
        out = all(n_floating > merit(r)[0] for r in rivals)
        calls["screened"] += out
        return out

    def out(layout, a, method, rounds, support=0, reason=""):
        calls["soft"] += grad.steps_done if grad is not None else 0
        if method != "support":
            a = final(layout, a)
            if not a.stable and not reason:
                reason = _reason(a)
        return StabilizeResult(layout=layout, start=start, stable=bool(a.stable), method=method,
                               bricks_changed=_same_bricks(layout, start), exact_calls=calls["exact"],
                               soft_calls=calls["soft"], rounds=rounds, failing=merit(a)[0],
                               support_bricks=support, time_s=time.perf_counter() - t0, reason=reason,
                               screened=calls["screened"])

    grad = None
    given = start is not None
    if given:  # a Layout has no overlaps: it covers vox exactly when its cells are vox's
        v, lo = layout_voxels(start)
        hi = lo + np.asarray(v.shape)
        if (lo < 0).any() or (hi > np.asarray(vox.shape)).any() or int(v.sum()) != int(vox.sum()) or \
                not np.array_equal(vox[tuple(slice(a, b) for a, b in zip(lo, hi))], v):
            raise ValueError(f"{source}: the start layout does not cover exactly the shape's cells")
    else:
        start = merge_voxels(vox, seed=0, bricks=opts.bricks, source=source)
    # the heuristic merge, the likeliest answer, is solved as it is reported; a given start (a
    # generator's decoding, often failing and large: a canonical solve can take a minute) by the judge
    start_a = check(start) if given else check(start, canonical=True)
    best, best_a, how = start, start_a, "start" if given else "heuristic"
    say(f"{'start cover' if given else 'heuristic merge'}: {start.n} bricks, {merit(start_a)[0]} failing")
    if start_a.stable:
        return out(start, start_a, how, 0)
    lost = ungroundable_cells(vox, opts.bricks)
    if lost.any():
        say(f"{int(lost.sum())} cells have no chain of bricks to the ground in any cover: no cover can stand")
    # the seeds' covers with no floating brick first (only they can stand), each group in seed order;
    # none when some cells cannot be grounded (no cover stands: the search is skipped)
    covers = []
    for seed in range(1, 1 if lost.any() else opts.seeds):
        if spent():
            break
        lay = merge_voxels(vox, seed=seed, bricks=opts.bricks, source=source)
        covers.append((floating(lay), seed, lay))
    for n_fl, seed, lay in sorted(covers, key=lambda c: (c[0] > 0, c[1])):
        if spent():
            break
        if beaten(n_fl, best_a):
            continue
        a = check(lay)
        if merit(a) < merit(best_a):
            best, best_a, how = lay, a, "seed"
            say(f"seed {seed}: {merit(a)[0]} failing")
        if a.stable:
            return out(lay, a, "seed", 0)

    rng = np.random.default_rng(0)
    grad = _Gradient(opts) if opts.gradient else None
    rounds = 0
    stuck = 0
    max_rounds = opts.rounds * (2 if grad is not None else 1)
    # the random rounds walk from the heuristic merge (the fewest failing
    # bricks of a seed is a poor guide to what a re-merge can fix); the
    # gradient rounds from the best cover found by then
    cur, cur_a = start, start_a
    while rounds < max_rounds and not spent() and not best_a.stable and not lost.any():
        rounds += 1
        if rounds == opts.rounds + 1:
            cur, cur_a, stuck = best, best_a, 0
        base = cur  # every move of this round re-covers the region of the round's start
        failing = _failing(cur_a)
        # grow the region when the last rounds found nothing
        region = _region(base, failing, opts.reach + stuck)
        pos, size = _region_placements(base, region, types)
        improved = False

        def attempt(name, order):
            nonlocal best, best_a, how, cur, cur_a
            lay = recover_region(base, region, order, pos, size, types)
            if beaten(floating(lay), cur_a, best_a):
                return False
            a = check(lay)
            if merit(a) < merit(best_a):
                best, best_a, how = lay, a, name
            if merit(a) < merit(cur_a):
                cur, cur_a = lay, a
                return True
            if opts.sideways and stuck >= opts.sideways and merit(a)[0] <= merit(cur_a)[0]:
                cur, cur_a = lay, a  # a sideways step: as few failing bricks, another cover to walk from
            return False

        # cheap random covers; after the random rounds, the gradient move
        # (a soft solve per step) when they find nothing better, begun only
        # while a quarter of the budget remains (its compile cannot stop)
        for _ in range(opts.random_moves):
            if spent() or best_a.stable:
                break
            improved |= attempt("random", _random_rank(base, region, pos, size, rng))
        if (rounds > opts.rounds and not improved and not best_a.stable and grad is not None
                and time.perf_counter() - t0 < 0.75 * opts.time_s):
            try:
                p = grad.run(base, region, pos, size, rng, t0 + opts.time_s)
                improved = attempt("gradient", np.argsort(-p, kind="stable"))
            except Exception as exc:  # noqa: BLE001 - the random moves go on
                say(f"gradient move failed ({type(exc).__name__}: {exc}); random moves only")
                grad = None
        stuck = 0 if improved else min(stuck + 1, 4)
        say(f"round {rounds}: region {int(region.sum())} bricks, {merit(cur_a)[0]} failing"
            f" (best {merit(best_a)[0]}, {how}), {calls['exact']} exact solves, {calls['screened']} covers screened")
    if best_a.stable:
        return out(best, best_a, how, rounds)
    reason = (f"{int(lost.sum())} cells of the shape have no chain of bricks to the ground in any cover (no "
              "brick that fits there rests on or carries one that leads to the ground)") if lost.any() \
        else ""  # out() says why from the canonical analysis
    if opts.allow_support:
        say("no stable cover found; adding support bricks outside the shape")
        r = repair(best, RepairOptions(params=opts.params))
        calls["exact"] += r.exact_calls
        calls["soft"] += r.soft_calls
        if r.stable:
            return out(r.layout, r.after, "support", rounds, support=r.layout.n - best.n)
    return out(best, best_a, "none", rounds, reason=reason)


def _reason(a: Analysis) -> str:
    """Why the best cover fails, in words."""
    from ..score import floating_bricks

    fl = int(np.asarray(floating_bricks(a.model))[: a.layout.n].sum())
    n_fail = merit(a)[0]
    if fl:
        return (f"{fl} of {n_fail} failing bricks have no chain of knob connections to the ground in the "
                "best cover found")
    return f"{n_fail} bricks exceed the knob capacity or cannot balance in the best cover found"
