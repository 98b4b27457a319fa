"""Repair by moving blocks: slide a plain block along the gradient of the loss
with respect to its position until the scene stands (paper Sec. IV.E: an
8-level stack made unstable by moving one block stands again when the top
block is moved).

One round: the gradient of :func:`~stablelego_jax.loss.position_loss` with
respect to every plain block's horizontal translation (one differentiable
solve and its adjoint); the blocks with the largest gradient are tried in
turn. For a block, its line ``-gradient`` is searched with the exact solver
on a ladder of distances (``first``, ``first * growth``, ... up to
``reach``, default the block's longer side); where a stretch of the line
stands, its two ends are found by bisection and the block is put in the
middle of it (the largest margin both ways along the line). A position
where the block would overlap another body is skipped. If no tried block
stands anywhere on its line, the move that leaves the fewest failing bodies
(then the smallest equilibrium residual) is taken when it improves on the
current scene, and the next round starts from there. Lego parts never move
(their knobs hold only where studs coincide).
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..analysis import Analysis, analyze_layout
from ..layout import LayoutError
from ..model import Params, shifted
from ..scene import Scene, make_scene

__all__ = ["MoveOptions", "Move", "MoveResult", "move_repair"]


@dataclasses.dataclass(frozen=True)
class MoveOptions:
    """Settings of :func:`move_repair` (lengths in metres).

    max_blocks: most distinct blocks moved; rounds: gradient rounds; tries:
    blocks searched per round (largest gradient first); first, growth,
    reach: the line search's ladder of distances (reach None: the block's
    longer side); refine: bisection steps at each end of a standing stretch;
    time_s: wall budget (checked between solves; None: none); min_grad:
    the least gradient (loss per metre) that gives a block a direction to
    search (below it the gradient is the loss's rounding: on a scene whose
    loss does not depend on any block's place it is ~1e-14, and its
    direction noise)."""

    max_blocks: int = 1
    rounds: int = 3
    tries: int = 3
    first: float = 5e-4
    growth: float = 2 ** 0.5
    reach: float | None = None
    refine: int = 8
    time_s: float | None = None
    min_grad: float = 1e-9
    params: Params = Params()


@dataclasses.dataclass(frozen=True)
class Move:
    """Block ``key`` moved by ``shift`` (dx, dy) metres; ``grad`` the loss
    gradient (per metre) that chose it."""

    key: str
    shift: tuple[float, float]
    grad: tuple[float, float]

    def describe(self) -> str:
        dx, dy = (v * 1e3 for v in self.shift)
        return f"moved block {self.key!r} by ({dx:+.1f}, {dy:+.1f}) mm ({np.hypot(dx, dy):.1f} mm)"


@dataclasses.dataclass
class MoveResult:
    """What :func:`move_repair` did: the scene before and after, their exact
    analyses, the moves, solver calls and wall time."""

    original: Scene
    layout: Scene
    before: Analysis
    after: Analysis
    moves: list
    exact_calls: int
    soft_calls: int
    time_s: float

    @property
    def stable(self) -> bool:
        return bool(self.after.stable)


def _badness(a: Analysis) -> tuple:
    """(failing bodies, total |equilibrium residual|): smaller is better."""
    return (sum(v >= 1.0 for v in a.scores.values()), float(np.abs(a.residual).sum()))


def _moved(scene: Scene, b: int, d: np.ndarray, params: Params) -> Scene | None:
    """``scene`` with body ``b`` moved by ``d`` (2,) m, validated; None where it overlaps."""
    shift = np.zeros((scene.n, 2))
    shift[b] = d
    s = shifted(scene, shift, params)
    try:
        return make_scene(s.keys, s.kind, s.pos, s.size, s.yaw, s.mass, s.brick_id, friction=s.friction,
                          source=s.source, fmt=s.fmt)
    except LayoutError:
        return None


def _gradient(scene: Scene, params: Params) -> np.ndarray:
    """(n, 2) d loss / d translation (per m) of every body (zero for Lego parts)."""
    import jax

    from ..loss import LossOptions, position_loss
    from ..soft import scene_positions, soft_problem
    from ..solvers.problem import pad_positions, plan_soft

    # padded as repair's problems are (plan_soft): scenes of one rung share a compiled gradient
    prob = plan_soft(soft_problem(scene, params))
    n_pad, n = prob.mass.shape[0], scene.n
    geo = pad_positions(scene_positions(scene, params), n_pad, prob.col_kind.shape[0])
    w = np.zeros(n_pad)
    w[:n] = 1.0
    opts = LossOptions(params=params)
    g = jax.grad(lambda d: position_loss(d, w, None, prob, geo, opts=opts))(np.zeros((n_pad, 2)))
    return np.where(geo.movable[:n, None], np.asarray(g, np.float64)[:n], 0.0)


def move_repair(scene: Scene, opts: MoveOptions = MoveOptions()) -> MoveResult:
    """Move plain blocks of ``scene`` until the exact solver says it stands
    (see the module doc). The moved scene keeps every key, size and mass."""
    t0 = time.perf_counter()
    p = opts.params
    calls = {"exact": 0, "soft": 0}

    def exact(s: Scene) -> Analysis:
        calls["exact"] += 1
        return analyze_layout(s, solver="exact", params=p)

    def out_of_time() -> bool:
        return opts.time_s is not None and time.perf_counter() - t0 > opts.time_s

    before = exact(scene)
    cur, cur_a, moves = scene, before, []
    for _ in range(opts.rounds if not before.stable else 0):
        if out_of_time():
            break
        g = _gradient(cur, p)
        calls["soft"] += 1
        mag = np.hypot(g[:, 0], g[:, 1])
        moved = {m.key for m in moves}
        if len(moved) >= opts.max_blocks:
            mag = np.where([k in moved for k in cur.keys], mag, 0.0)
        order = [int(b) for b in np.argsort(-mag, kind="stable")[: opts.tries] if mag[b] > opts.min_grad]
        best = None  # (badness, scene, analysis, move)
        for b in order:
            u = -g[b] / mag[b]
            reach = opts.reach if opts.reach is not None else float(np.max(cur.size[b, :2]))
            if reach <= 0:
                continue
            ladder = [opts.first * opts.growth ** k for k in
                      range(int(np.floor(np.log(max(reach / opts.first, 1.0)) / np.log(opts.growth))) + 1)]
            tried = []  # (t, stands)
            for t in ladder:
                if out_of_time():
                    break
                s = _moved(cur, b, t * u, p)
                if s is None:
                    continue
                a = exact(s)
                tried.append((t, a.stable))
                if a.stable:
                    continue
                if any(st for _, st in tried[:-1]):
                    break  # past the standing stretch
                key = _badness(a)
                if best is None or key < best[0]:
                    best = (key, s, a, Move(cur.keys[b], tuple(t * u), tuple(g[b])))
            stands = [t for t, st in tried if st]
            if not stands:
                continue
            lo_t, hi_t = min(stands), max(stands)
            below = max([t for t, st in tried if not st and t < lo_t], default=0.0)
            above = min([t for t, st in tried if not st and t > hi_t], default=None)

            def edge(ok_t, bad_t):  # bisection towards the last standing distance
                for _ in range(opts.refine):
                    mid = 0.5 * (ok_t + bad_t)
                    s = _moved(cur, b, mid * u, p)
                    if s is not None and exact(s).stable:
                        ok_t = mid
                    else:
                        bad_t = mid
                return ok_t

            lo_t = edge(lo_t, below)
            if above is not None:
                hi_t = edge(hi_t, above)
            for t in (0.5 * (lo_t + hi_t), lo_t, hi_t):
                s = _moved(cur, b, t * u, p)
                a = exact(s) if s is not None else None
                if a is not None and a.stable:
                    best = ((0, 0.0), s, a, Move(cur.keys[b], tuple(t * u), tuple(g[b])))
                    break
            if best is not None and best[2].stable:
                break
        if best is None or best[0] >= _badness(cur_a):
            break
        _, cur, cur_a, mv = best
        moves.append(mv)
        if cur_a.stable:
            break
    return MoveResult(original=scene, layout=cur, before=before, after=cur_a, moves=moves,
                      exact_calls=calls["exact"], soft_calls=calls["soft"], time_s=time.perf_counter() - t0)
