"""What every JAX solver shares: the problem and solution pytrees, the one
size ladder, padding and solve plans, and the scaled equilibrium operators.

Units inside the solvers: forces in units of the friction capacity T,
torque rows in T x stud pitch (so force and torque rows have one size).
"""
from __future__ import annotations

import dataclasses
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ..model import KNOB, NORMAL, SIDE, ForceModel, Params
from ..score import equilibrium, equilibrium_t
from ..soft import ScenePositions, SoftProblem
from .blocks import layer_cuts, layer_picks

__all__ = [
    "merge_plans",
    "plan_seconds",
    "DENSE_COMPILE_S",
    "LAYERED_COMPILE_S",
    "compile_seconds",
    "LOAD_S",
    "Problem",
    "Solution",
    "to_problem",
    "stack_problems",
    "rung",
    "ladder",
    "batch_rung",
    "FULL_BATCH",
    "bucket_shape",
    "pad_to_bucket",
    "pad_soft",
    "pad_positions",
    "stack_soft",
    "layer_soft",
    "cut_layers",
    "cut_saving",
    "CUT_BRANCH_S",
    "soft_levels",
    "soft_layer_plan",
    "soft_plan",
    "plan_soft",
    "soft_bucket",
    "SOFT_COLUMNS_PER_BRICK",
    "SOFT_SLOTS",
    "SOFT_BRICKS_PER_SLOT",
    "SOFT_COLUMNS_PER_SLOT",
    "SOFT_CHUNKS_PER_SLOT",
    "pair_chunks",
    "CHUNK",
    "layer_levels",
    "layer_plan",
    "layer_bucket",
    "factor_flops",
    "slab_levels",
    "levels_ok",
    "support_count",
    "support_table",
    "support_rung",
    "SUPPORTS_RATIO",
    "to_layered",
    "layered_problem",
    "chunk_rows",
    "solve_plan",
    "fit_plan",
    "plan_problem",
    "dense_supports",
    "DENSE_SUPPORTS",
    "row_scale",
    "scaled_wrenches",
    "operators",
    "LayerGram",
    "gram_plan",
    "block_windows",
    "make_solution",
]


class Problem(NamedTuple):
    """Array-only pytree of one compiled model (see ForceModel for shapes)."""

    col_brick: jnp.ndarray  # (m, 2) int32, n = sink
    col_coef: jnp.ndarray  # (m, 2, 6) float
    col_kind: jnp.ndarray  # (m,) int8
    col_mask: jnp.ndarray  # (m,) bool
    group: jnp.ndarray  # (n, P) int32, m = empty
    gravity: jnp.ndarray  # (n, 6)
    brick_mask: jnp.ndarray  # (n,) bool
    member: jnp.ndarray  # (n,) int32 layout of a pack each brick is in (ForceModel.member; 0: one layout)
    layers: jnp.ndarray | None = None  # (L,): bricks numbered layer by layer (None: one layer, dense)
    chunks: jnp.ndarray | None = None  # (C, W) int32: columns grouped by brick pair, m = none (pair_chunks)
    # bricks numbered by slabs (slab_levels) and dense problems (dense_supports; None: by layers):
    # each brick's supports, the bricks under its NORMAL columns, in any level next to its own
    # (support_table)
    supports: jnp.ndarray | None = None  # (n, K) int32 brick of each support slot, n = none
    col_slot: jnp.ndarray | None = None  # (m,) int32 support slot of each column's lower brick, K = none


class Solution(NamedTuple):
    """Solver output for one layout (add a batch axis under vmap).

    f: (m,) forces in N; iters; converged (bool); primal_res, dual_res
    (scaled, inf-norm); objective (Eq. 9 value, N-based units); dual_bound;
    gap: (objective - dual_bound) / max(1e-12, |objective|) scaled-unit
    relative gap.
    """

    f: jnp.ndarray
    iters: jnp.ndarray
    converged: jnp.ndarray
    primal_res: jnp.ndarray
    dual_res: jnp.ndarray
    objective: jnp.ndarray
    dual_bound: jnp.ndarray
    gap: jnp.ndarray


def to_problem(model: ForceModel) -> Problem:
    """The arrays of a compiled (and padded) model as a :class:`Problem`."""
    return Problem(
        col_brick=np.asarray(model.col_brick, np.int32),
        col_coef=np.asarray(model.col_coef, np.float64),
        col_kind=np.asarray(model.col_kind, np.int8),
        col_mask=np.asarray(model.col_mask, bool),
        group=np.asarray(model.group, np.int32),
        gravity=np.asarray(model.gravity, np.float64),
        brick_mask=np.asarray(model.brick_mask, bool),
        member=np.zeros(model.n_pad, np.int32) if model.member is None else np.asarray(model.member, np.int32),
    )


def stack_problems(problems) -> Problem:
    """Stack equally padded problems along a new leading batch axis."""
    return Problem(*[None if a[0] is None else np.stack(a) for a in zip(*problems)])


# ------------------------------------------------------------ the size ladder
#
# Every padded dimension is chosen here: bricks, columns and contact slots per
# brick (dense problems, soft problems), and layers and slots per layer
# (layered problems), so that similar layouts share one compiled solver.


def rung(k: int, base: int = 8, growth: float = 1.25) -> int:
    """The padded size of ``k`` bricks, columns or contact slots: the
    smallest value >= k of the ladder ``base``, then x ``growth`` rounded up
    to a multiple of 8 (8, 16, 24, 32, 40, 56, 72, 96, 120, 152, ... from
    base 8; 64, 80, 104, 136, 176, 224, ... from base 64)."""
    b = int(base)
    while b < k:
        b = int(np.ceil(b * growth / 8.0) * 8)
    return b


def ladder(k: int, base: int = 8) -> list[int]:
    """The rungs of :func:`rung` from ``base`` below ``k``, then ``k``."""
    out = []
    b = rung(1, base)
    while b < k:
        out.append(b)
        b = rung(b + 1, base)
    return out + [int(k)]


#: Smallest padded sizes (ladder bases) of bricks, columns and contact slots per brick.
MIN_BRICKS, MIN_COLUMNS, MIN_SLOTS = 8, 64, 4
#: ... and of column chunks (rows of :func:`pair_chunks`).
MIN_CHUNKS = 8

#: Padded layers and slots per layer of layered problems: finer than :func:`rung`
#: at small sizes, where a layered factorisation costs ~ layers x slots^3.
LAYER_RUNGS = (2, 4, 6, 8, 12, 16, 20, 24, 32, 40, 48, 64)
SLOT_RUNGS = (1, 2, 4, 6, 8, 12, 16, 20, 24, 32, 40, 48, 56, 64, 80, 96, 128)


def batch_rung(k: int, n_dev: int = 1, cap: int | None = None) -> int:
    """Padded batch of ``k`` problems: ``n_dev`` times a power of two (so few
    batch shapes compile and every device gets an equal share), at most
    ``cap``. A ``cap`` of at most :data:`FULL_BATCH` pads every batch to
    ``cap``: a few padded solves cost less than another compiled size."""
    if cap is not None and cap <= FULL_BATCH:
        return int(cap)
    size = max(int(n_dev), 1)
    while size < k:
        size *= 2
    return size if cap is None else min(size, cap)


#: Batches of at most this many problems are always padded to full (:func:`batch_rung`).
FULL_BATCH = 8


def bucket_shape(n: int, m: int, p: int) -> tuple[int, int, int]:
    """Padded (bricks, columns, contact slots per brick) on the ladder."""
    return rung(n, MIN_BRICKS), rung(m, MIN_COLUMNS), rung(p, MIN_SLOTS)


def pad_to_bucket(model: ForceModel) -> ForceModel:
    """Pad a model to the ladder so similar sizes share one compile."""
    return model.pad(*bucket_shape(model.n, model.m, model.group.shape[1]))


# ------------------------------------------------------------- soft problems


def pad_soft(prob: SoftProblem, n_pad: int | None = None, m_pad: int | None = None,
             p_pad: int | None = None, c_pad: int | None = None) -> SoftProblem:
    """Pad to (n_pad bricks, m_pad columns, p_pad points per group); default
    the ladder (:func:`bucket_shape`), so similar sizes share a compiled
    solver. Padding bricks have no columns and no mass; padding
    columns are inert (zero wrench, masked). A layered problem
    (:func:`layer_soft`) stays layered, its padding bricks in no slot, its
    column chunks padded to ``c_pad`` rows (default: the ladder)."""
    n, m = prob.mass.shape[0], prob.col_kind.shape[0]
    P = prob.group.shape[1]
    nb, mb, pb = bucket_shape(n, m, P)
    n_pad = nb if n_pad is None else n_pad
    m_pad = mb if m_pad is None else m_pad
    p_pad = pb if p_pad is None else p_pad
    if n_pad < n or m_pad < m or p_pad < P:
        raise ValueError(f"cannot pad (n={n}, m={m}, P={P}) to ({n_pad}, {m_pad}, {p_pad})")
    dm, dn = m_pad - m, n_pad - n
    cb = np.where(np.asarray(prob.col_brick) >= n, n_pad, prob.col_brick)
    cb = np.concatenate([cb, np.full((dm, 2), n_pad)]).astype(np.int32)
    grp = np.full((n_pad, p_pad), m_pad, np.int32)
    g = np.asarray(prob.group)
    grp[:n, :P] = np.where(g >= m, m_pad, g)
    slot = chunk = None
    if prob.slot is not None:
        slot = np.concatenate([prob.slot, np.full(dn, prob.layers.size)]).astype(np.int32)
    if prob.chunk is not None:
        chunk = _pad_chunks(np.where(prob.chunk >= m, m_pad, prob.chunk), c_pad, m_pad)
    return SoftProblem(
        col_brick=cb,
        col_coef=np.concatenate([prob.col_coef, np.zeros((dm, 2, 6))]),
        col_kind=np.concatenate([prob.col_kind, np.full(dm, KNOB, np.int8)]),
        col_mask=np.concatenate([prob.col_mask, np.zeros(dm, bool)]),
        group=grp,
        mass=np.concatenate([prob.mass, np.zeros(dn)]),
        brick_mask=np.concatenate([prob.brick_mask, np.zeros(dn, bool)]),
        unit=np.concatenate([prob.unit, np.arange(n, n_pad)]).astype(np.int32),
        level=np.concatenate([prob.level, np.full(dn, -1)]).astype(np.int32),
        slot=slot,
        layers=prob.layers,
        chunk=chunk,
        cut=prob.cut,
    )


def pad_positions(geo: ScenePositions, n_pad: int, m_pad: int) -> ScenePositions:
    """A scene's :class:`~stablelego_jax.soft.ScenePositions` padded as its
    soft problem is (:func:`pad_soft` to ``n_pad`` bodies, ``m_pad``
    columns), so that :func:`~stablelego_jax.loss.position_loss` of scenes
    of one padded shape shares a compile. Padding bodies sit at the origin
    and never move; padding columns have no force (zero wrench) and act on
    body 0 against the ground; the ground is body ``n_pad``."""
    n, m = len(geo.centre), len(geo.pair)
    if n_pad < n or m_pad < m:
        raise ValueError(f"cannot pad (n={n}, m={m}) positions to ({n_pad}, {m_pad})")
    dm, dn = m_pad - m, n_pad - n
    pair = np.where(np.asarray(geo.pair) >= n, n_pad, geo.pair)
    pair = np.concatenate([pair, np.tile(np.array([[0, n_pad]]), (dm, 1))]).astype(np.int32)
    return ScenePositions(
        pair=pair,
        force=np.concatenate([geo.force, np.zeros((dm, 3))]),
        point=np.concatenate([geo.point, np.zeros((dm, 3))]),
        jac=np.concatenate([geo.jac, np.zeros((dm,) + geo.jac.shape[1:])]),
        smooth=np.concatenate([geo.smooth, np.ones(dm, bool)]),
        centre=np.concatenate([geo.centre, np.zeros((dn, 3))]),
        movable=np.concatenate([geo.movable, np.zeros(dn, bool)]),
    )


def stack_soft(problems: Sequence[SoftProblem]) -> SoftProblem:
    """Stack equally padded (and equally layered) problems along a new
    leading (batch) axis, without their ``cut`` (under ``vmap`` every
    branch of a cut factor would run)."""
    problems = [p._replace(cut=None) for p in problems]
    return SoftProblem(*[None if a[0] is None else np.stack(a) for a in zip(*problems)])


def soft_levels(prob: SoftProblem) -> np.ndarray:
    """(n,) layer of each brick slot for the layered factorisation (padding:
    0): ``prob.level`` where every column spans one layer or two adjacent
    ones and every brick's supports lie in the layer below its own (the
    rule of :func:`layer_levels`, :func:`levels_ok` "below"), else 0 for all
    (one layer; a scene's contact levels can put a hanging brick above the
    one it hangs from)."""
    real = np.asarray(prob.brick_mask)
    z = np.where(real, np.asarray(prob.level, np.int64), 0)
    if real.any():
        z = np.where(real, z - z[real].min(), 0)
    ok = _spans_ok(prob.col_brick, prob.col_mask, prob.group, z, supports="below")
    return z if ok else np.zeros(len(z), np.int64)


def soft_layer_plan(prob: SoftProblem) -> tuple[int, int]:
    """(layers, largest bricks per layer) of a soft problem's real bricks
    (:func:`soft_levels`)."""
    z = soft_levels(prob)[np.asarray(prob.brick_mask)]
    if z.size == 0:
        return 1, 1
    counts = np.bincount(z)
    return int(len(counts)), int(counts.max())


def layer_soft(prob: SoftProblem, L: int | None = None, B: int | None = None) -> SoftProblem:
    """The problem with its real bricks placed layer by layer (``slot``,
    ``layers``) for the block-tridiagonal factorisation of
    :mod:`.soft_ipm`: brick b goes to layer ``level[b] - min level``, slots
    in brick order. Default (L, B): the ladder (:func:`layer_bucket`).
    Brick and column indices do not change (weights, loads and results
    keep their meaning)."""
    L0, B0 = soft_layer_plan(prob)
    Lb, Bb = layer_bucket(L0, B0)
    L = Lb if L is None else L
    B = Bb if B is None else B
    if L0 > L or B0 > B:
        raise ValueError(f"problem needs {L0} x {B0} layer slots, got {L} x {B}")
    real = np.asarray(prob.brick_mask)
    z = soft_levels(prob)
    idx = np.nonzero(real)[0]
    zr = z[idx]
    order = np.argsort(zr, kind="stable")
    counts = np.bincount(zr, minlength=1)
    rank = np.empty(len(idx), np.int64)
    rank[order] = np.arange(len(idx)) - np.repeat(np.cumsum(counts) - counts, counts)
    slot = np.full(len(z), L * B, np.int32)
    slot[idx] = zr * B + rank
    return prob._replace(slot=slot, layers=np.zeros((L, B), np.int8), chunk=pair_chunks(prob), cut=None)


def cut_layers(prob: SoftProblem) -> SoftProblem:
    """The layered problem (:func:`layer_soft`) with ``cut`` set: each
    layer's used slots, so that a solve factors each layer at its own size
    (:class:`~stablelego_jax.soft.SoftProblem`)."""
    if prob.slot is None:
        raise ValueError("only a layered problem (layer_soft) can be cut by layers")
    L, B = prob.layers.shape
    slot = np.asarray(prob.slot)
    slot = slot[slot < L * B]
    cut = np.zeros(L, np.int32)
    np.maximum.at(cut, slot // B, slot % B + 1)
    return prob._replace(cut=cut)


def cut_saving(prob: SoftProblem, solves: float | None = None) -> float:
    """Rough seconds that ``cut`` (:func:`cut_layers`) saves a layered soft
    problem over ``solves`` factorisations (default :data:`SOFT_SOLVES`, a
    loss and its gradient): half the factor flops the cuts leave out, at
    :func:`plan_seconds`' price of a layer's factor. Half: the branches
    copy their blocks in and out (the 2000-placement bunny, 20 x 120
    slots: 0.79 of the flops, 7-11% of the solve; session 42). ``prob``:
    with ``cut`` set, or without (then worked out here)."""
    L, B = prob.layers.shape
    sizes = np.asarray(layer_cuts(B))
    cut = cut_layers(prob).cut if prob.cut is None else prob.cut
    c = sizes[layer_picks(6 * cut, sizes, np)].astype(float)
    solves = SOFT_SOLVES if solves is None else solves
    return float(0.5 * solves * LAYER_K3_S * ((6.0 * B) ** 3 * L - (c ** 3).sum()))


#: Compile seconds of each size a cut factor may take (:func:`~stablelego_jax.solvers.blocks.layer_cuts`):
#: 10-19 s more for the 15 sizes of 120 slots (the loss and its gradient, which factors twice; session 42).
CUT_BRANCH_S = 1.0


#: Columns per row of :func:`pair_chunks`.
CHUNK = 8


def pair_chunks(prob, width: int = CHUNK) -> np.ndarray:
    """(C, width) int32: the real columns of ``prob`` (a :class:`SoftProblem`,
    :class:`Problem` or ForceModel: its ``col_brick``, ``col_mask``) grouped
    by the pair of bricks they join, ``width`` per row at most (a pair with
    more columns takes several rows), ``m`` where a row has fewer."""
    m = prob.col_kind.shape[0]
    cols = np.nonzero(np.asarray(prob.col_mask))[0]
    if len(cols) == 0:
        return np.full((1, width), m, np.int32)
    cb = np.asarray(prob.col_brick, np.int64)[cols]
    order = np.lexsort((cb[:, 1], cb[:, 0]))
    cols, cb = cols[order], cb[order]
    new_pair = np.concatenate([[True], (cb[1:] != cb[:-1]).any(axis=1)])
    pair = np.cumsum(new_pair) - 1
    start = np.nonzero(new_pair)[0]
    k = np.arange(len(cols)) - start[pair]  # rank of the column inside its pair
    per = np.bincount(pair)
    rows_per = -(-per // width)
    row0 = np.concatenate([[0], np.cumsum(rows_per)[:-1]])
    row = row0[pair] + k // width
    out = np.full((int(rows_per.sum()), width), m, np.int32)
    out[row, k % width] = cols
    return out


def soft_plan(prob: SoftProblem) -> tuple:
    """("dense",) or ("layered", L, B) for a soft problem; at most
    ``DENSE_MAX`` bricks stay dense. Layered where it factorises more
    cheaply by :func:`solve_plan`'s flop count (``L B^3 < n^3 / 9``, B and
    L on the ladder, n the real bricks), and also where the time model of
    an iteration (:func:`plan_seconds`: the dense rung of its bricks against
    the ladder's layers and slots, uncut) says a solve of
    ``SOFT_SOLVES`` factorisations saves more than ``SOFT_SHARE`` of a
    compile: the flop count alone kept wide problems dense (the slots
    rounded up to the ladder), and a 640-placement training subset of 16
    levels of at most 99 bricks took 63.4 s for its loss and gradient dense
    against 11.1 s layered and cut, the same loss to 10 digits; smaller
    problems keep the dense rungs, which fewer shapes share (BENCHMARKS.md,
    issue 19, session 58)."""
    n = int(np.asarray(prob.brick_mask).sum())
    Lp, Bp = layer_bucket(*soft_layer_plan(prob))
    if n <= DENSE_MAX or Lp <= 1:
        return ("dense",)
    saving = SOFT_SOLVES * (plan_seconds(("dense", rung(n, MIN_BRICKS)), 0, 1) - plan_seconds(("layered", Lp, Bp), 0, 1))
    if factor_flops(("layered", Lp, Bp)) < factor_flops(("dense", n)) or saving > SOFT_SHARE * SOFT_COMPILE_S:
        return ("layered", Lp, Bp)
    return ("dense",)


def soft_bucket(n: int, m: int, p: int, layers: tuple | None = None, chunks: int = 0) -> tuple:
    """The padded (bricks, columns, contact slots per brick, column chunks)
    that every soft problem of one rung shares where :func:`plan_soft`
    allows it: at least :data:`SOFT_SLOTS` contact slots, and

    * dense (``layers`` None; the fourth entry None: no column chunks): the
      brick rung, at least :data:`SOFT_COLUMNS_PER_BRICK` columns per
      padded brick;
    * layered (``layers`` = (L, B), the ladder's layers and slots per
      layer): per layer slot at least :data:`SOFT_BRICKS_PER_SLOT` bricks,
      :data:`SOFT_COLUMNS_PER_SLOT` columns and
      :data:`SOFT_CHUNKS_PER_SLOT` column chunks (``chunks``: the
      problem's own).

    The ladder's rung of the problem's own size where that is larger. On the
    ladder alone a rung splits into a shape for every (columns, slots,
    chunks) rung: the first solves of ``repair``'s 100-layout benchmark fell
    into 46 shapes over 10 brick rungs, those of 40 mesh layouts of its large
    set into 31 layered shapes over 14 (L, B) rungs, each a compile of
    3.3-5.3 s, while the padding costs a solve 2-70 ms dense and 7-26%
    layered (BENCHMARKS.md, session 35)."""
    if layers is None:
        nb = rung(n, MIN_BRICKS)
        return (nb, max(rung(m, MIN_COLUMNS), rung(SOFT_COLUMNS_PER_BRICK * nb, MIN_COLUMNS)),
                max(rung(p, MIN_SLOTS), SOFT_SLOTS), None)
    slots = int(layers[0]) * int(layers[1])
    return (max(rung(n, MIN_BRICKS), rung(int(np.ceil(SOFT_BRICKS_PER_SLOT * slots)), MIN_BRICKS)),
            max(rung(m, MIN_COLUMNS), rung(SOFT_COLUMNS_PER_SLOT * slots, MIN_COLUMNS)),
            max(rung(p, MIN_SLOTS), SOFT_SLOTS),
            max(rung(chunks, MIN_CHUNKS), rung(SOFT_CHUNKS_PER_SLOT * slots, MIN_CHUNKS)))


def plan_soft(prob: SoftProblem, calls: int = 1, shared: bool = False) -> SoftProblem:
    """The problem padded to the ladder (:func:`pad_soft`), layered
    (:func:`layer_soft`) when :func:`soft_plan` says that is cheaper; padded
    further, to the one shape its rung shares (:func:`soft_bucket`: the
    bricks' rung dense, the layers and slots per layer layered), where the
    extra columns cost the caller's ``calls`` solves at most
    :data:`SOFT_SHARE` of a compile (problems solved a few times:
    ``repair``'s ranking).

    ``calls``: how many solves (loss + gradient) the caller makes of this
    problem, e.g. the steps of an optimisation. The padding is fitted to
    the problem alone (its own layer count; slots per layer and bricks
    rounded up to 8, columns and column chunks to 64 and 8, each where
    that is below the ladder's rung; its own contact slots) when the time
    that saves over ``calls`` solves (:func:`plan_seconds` at
    ``SOFT_SOLVES`` factorisations a solve) exceeds one compile
    (``SOFT_COMPILE_S``): a fitted shape is shared with no other problem.
    The 2000-placement bunny of ``benchmarks/loss_scale.py``: 20 layers of
    120 slots and 262400 columns instead of 128 and 293752, loss +
    gradient 1.17x faster (BENCHMARKS.md, session 30).

    A layered problem is also cut (:func:`cut_layers`: each layer factored
    at its own size) when the time that saves over ``calls`` solves
    (:func:`cut_saving`) exceeds the compile of its sizes
    (:data:`CUT_BRANCH_S` each). The same bunny, fitted: 9.6-10.5 s
    against 10.6-11.5 s (session 42).

    ``shared`` (``calls`` then unused): always the shape its rung shares,
    never a fitted one, and a layered problem always cut, so that one
    executable serves every problem of the rung: for a caller whose shapes
    recur over many problems, each solved once (training's stability
    subsets: a cut solve took 0.65x the time of an uncut one there, for
    5.5 s more compile a shape; BENCHMARKS.md, issue 19, session 55)."""

    def up(k, q):
        return -(-k // q) * q

    n, m, P = prob.mass.shape[0], prob.col_kind.shape[0], prob.group.shape[1]
    key, shape = soft_plan(prob), bucket_shape(n, m, P)
    fshape = tuple(min(a, b) for a, b in zip(shape, (up(n, 8), up(m, 64), P)))
    if key[0] == "layered":
        L, B = soft_layer_plan(prob)
        ladder, fit = key, ("layered", L, min(key[2], up(B, 8)))
    else:
        ladder, fit = ("dense", shape[0]), ("dense", fshape[0])
    saving = calls * (plan_seconds(ladder, shape[1], SOFT_SOLVES) - plan_seconds(fit, fshape[1], SOFT_SOLVES))
    fitted = saving > SOFT_COMPILE_S and not shared
    if fit[0] == "layered":
        prob = layer_soft(prob, *(fit if fitted else ladder)[1:])
    # chunks: the ladder's rungs are multiples of 8, so 8 never pads more
    c_pad = up(len(prob.chunk), 8) if fitted and prob.chunk is not None else None
    if not fitted:
        c_own = 0 if prob.chunk is None else len(prob.chunk)
        bucket = soft_bucket(n, m, P, None if prob.layers is None else prob.layers.shape, c_own)
        # priced as columns: the padded columns, and a padded column chunk as one column
        # (with the padded bricks and contact slots, that matched three layered problems'
        # measured extra time within 20%: BENCHMARKS.md, session 35)
        dc = 0 if bucket[3] is None else bucket[3] - rung(c_own, MIN_CHUNKS)
        extra = calls * (plan_seconds(ladder, bucket[1] + dc, SOFT_SOLVES)
                         - plan_seconds(ladder, shape[1], SOFT_SOLVES))
        if extra <= SOFT_SHARE * SOFT_COMPILE_S or shared:
            shape, c_pad = bucket[:3], bucket[3]
    prob = pad_soft(prob, *(fshape if fitted else shape), c_pad=c_pad)
    if prob.layers is not None:
        cut = cut_layers(prob)
        if shared or calls * cut_saving(cut) > CUT_BRANCH_S * len(layer_cuts(prob.layers.shape[1])):
            return cut
    return prob


#: Factorisations of one soft solve with its gradient (15-17 interior-point
#: iterations and the adjoint's one on the 500-2000-placement problems of
#: ``benchmarks/loss_scale.py``), and seconds of one compile of it there
#: (6.7-9.5 s, session 30).
SOFT_SOLVES = 18
SOFT_COMPILE_S = 7.0
#: The least padding of a soft problem's shared shape (:func:`soft_bucket`):
#: columns per padded brick (dense), contact slots per brick, and bricks,
#: columns and column chunks per layer slot (layered). The most that the
#: first solves of ``repair``'s benchmarks needed: 48.0 columns per padded
#: brick and 426 contact slots (100 small layouts, dense); 0.73 bricks,
#: 24.4 columns and 5.55 chunks per slot and 420 contact slots (40 mesh
#: layouts of the large set, 31 of them layered).
SOFT_COLUMNS_PER_BRICK = 48
SOFT_SLOTS = 480
SOFT_BRICKS_PER_SLOT = 0.75
SOFT_COLUMNS_PER_SLOT = 25
SOFT_CHUNKS_PER_SLOT = 6
#: The share of one compile that :func:`plan_soft` lets the shared shape of
#: :func:`soft_bucket` cost the caller's solves.
SOFT_SHARE = 0.1


# ---------------------------------------------------------------- layering


#: The layer count :func:`layer_plan` gives a model with no layered
#: numbering: no layered bucket fits it.
NOT_LAYERED = 1 << 30


def layer_levels(model: ForceModel) -> np.ndarray | None:
    """(n,) layer of each real brick for the layered numbering: the model's
    ``layer`` where :func:`levels_ok` accepts it with every support in the
    layer below its brick's; None otherwise (a scene's contact levels can
    put a hanging brick above the one it hangs from, or a support beside
    its brick) and for models built by hand (no layers)."""
    n = model.n
    if model.layer is None:
        return None
    z = np.asarray(model.layer[:n], np.int64)
    z = z - (z.min() if n else 0)
    return z if levels_ok(model, z, supports="below") else None


def layer_plan(model: ForceModel) -> tuple[int, int]:
    """(layers, largest bricks per layer) of a compiled model's real bricks
    (:func:`layer_levels`); (``NOT_LAYERED``, n) without a layered numbering."""
    z = layer_levels(model)
    if z is None:
        return NOT_LAYERED, max(model.n, 1)
    if z.size == 0:
        return 1, 1
    counts = np.bincount(z)
    return int(len(counts)), int(counts.max())


def layer_bucket(L: int, B: int) -> tuple[int, int]:
    """Padded (layers, slots per layer): the next of :data:`LAYER_RUNGS` and
    :data:`SLOT_RUNGS`; beyond them, the next multiple of 16."""

    def up(k, rungs):
        return next((r for r in rungs if r >= k), -(-k // 16) * 16)

    return up(L, LAYER_RUNGS), up(B, SLOT_RUNGS)


def factor_flops(key: tuple) -> float:
    """Flops of one factorisation of bucket ``key`` over 648: ("dense", n)
    n^3 / 9 (a Cholesky of 6 n rows, (6 n)^3 / 3 flops), ("layered", L, B)
    or ("slabs", L, B, ...) L B^3 (block tridiagonal, ~3 L (6 B)^3): the
    count by which :func:`solve_plan`, :func:`soft_plan` and
    :func:`slab_levels` compare the forms."""
    if key[0] == "dense":
        return key[1] ** 3 / 9
    return key[1] * key[2] ** 3


def levels_ok(model: ForceModel, levels: np.ndarray, supports: str = "adjacent") -> bool:
    """Whether ``levels`` ((n,) int, one per real brick) can number the
    bricks of a block-tridiagonal factorisation: every column joins bricks
    of one level or of two adjacent ones, and so does every brick with its
    supports, the bricks under its NORMAL columns (its largest drag couples
    them all). ``supports``: where a brick's supports may lie, "adjacent"
    (its own level or either next one: slabs) or "below" (the one below:
    what the layered assembly of :mod:`.newton` needs)."""
    n, m = model.n, model.m
    return _spans_ok(model.col_brick[:m], np.ones(m, bool), model.group[:n], levels, supports)


def _spans_ok(col_brick, col_mask, group, levels, supports: str) -> bool:
    """:func:`levels_ok` on arrays: ``levels`` (n,) of bricks ``0..n-1``
    (``group`` (n, P)); bricks >= n in ``col_brick`` are none, columns
    outside ``col_mask`` ignored."""
    n, m = len(levels), len(col_mask)
    lv = np.append(np.asarray(levels, np.int64), 0)  # the sink: level of nothing
    cb = np.minimum(np.asarray(col_brick), n)
    cb = np.where(np.asarray(col_mask)[:, None], cb, n)
    real = (cb < n).all(1)
    if real.any() and np.abs(lv[cb[real, 0]] - lv[cb[real, 1]]).max() > 1:
        return False
    g = np.asarray(group)
    low = np.append(cb[:, 1], n)[np.minimum(g, m)]  # (n, P) brick under each NORMAL column, n = none
    own = lv[:n, None]
    hi = np.where(low < n, lv[low], own).max(1)
    lo_ = np.where(low < n, lv[low], own).min(1)
    if supports not in ("adjacent", "below"):
        raise ValueError(f"unknown supports rule {supports!r}")
    if supports == "below" and (np.where(low < n, lv[low], -1) >= np.where(low < n, own, 0)).any():
        return False
    return bool((np.maximum(hi, own[:, 0]) - np.minimum(lo_, own[:, 0]) <= 1).all())


#: Slab widths tried by :func:`slab_levels`, in stud pitches.
SLAB_WIDTHS = (1, 2, 3, 4, 6, 8, 12, 16)


def slab_levels(model: ForceModel) -> np.ndarray | None:
    """Bricks numbered by vertical slabs instead of layers: (n,) int32 level
    of each real brick, the slab (along x or y, of the narrowest width of
    :data:`SLAB_WIDTHS` that :func:`levels_ok` accepts) its centre lies in,
    empty slabs dropped; of the two axes the one whose block-tridiagonal
    factorisation is cheaper (padded, :func:`layer_bucket`). A wide, low
    layout (a pyramid: 20 layers of up to 400 bricks) has far fewer bricks
    per slab than per layer (210). None without centres or when no width
    works."""
    if model.centre is None or model.n == 0:
        return None
    c = np.asarray(model.centre[: model.n])
    best, best_cost = None, np.inf
    for axis in (0, 1):
        x = (c[:, axis] - c[:, axis].min()) / model.params.stud
        for w in SLAB_WIDTHS:
            lv = np.unique(np.floor(x / w + 1e-9).astype(np.int64), return_inverse=True)[1].ravel()
            if levels_ok(model, lv):
                cost = factor_flops(("layered",) + layer_bucket(len(np.unique(lv)), int(np.bincount(lv).max())))
                if cost < best_cost:
                    best, best_cost = lv.astype(np.int32), cost
                break
    return best


def to_layered(model: ForceModel, L: int, B: int, levels: np.ndarray | None = None) -> ForceModel:
    """The model with bricks renumbered layer by layer: brick ``l B + s`` is
    slot ``s`` of layer ``l`` (``n_pad = L B``; empty slots are padding
    bricks). Columns keep their order, so forces solved on the result are
    forces of ``model`` (same ``m_pad``). ``levels`` ((n,) int, default
    :func:`layer_levels`): number by these levels instead
    (:func:`slab_levels`); the result's ``layer`` holds them."""
    n = model.n
    src = layer_levels(model) if levels is None else np.asarray(levels)[:n]
    if src is None:
        raise ValueError("layout has no layer-by-layer numbering (layer_levels); number it by slab_levels")
    z = np.asarray(src, np.int64) - (src.min() if n else 0)
    counts = np.bincount(z, minlength=1)
    if len(counts) > L or counts.max(initial=0) > B:
        raise ValueError(f"layout needs {len(counts)} x {counts.max()} layer slots, got {L} x {B}")
    order = np.argsort(z, kind="stable")
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n) - np.repeat(np.cumsum(counts) - counts, counts)
    new = z * B + rank  # new index of old brick i
    n_new = L * B
    remap = np.full(model.n_pad + 1, n_new, np.int64)  # padding bricks / sink -> sink
    remap[:n] = new
    cb = remap[np.minimum(model.col_brick, model.n_pad)]
    group = np.full((n_new, model.group.shape[1]), model.m_pad, np.int32)
    group[new] = model.group[:n]
    lay = np.full(n_new, -1, np.int32)
    lay[new] = z
    return dataclasses.replace(model.bricks_moved(n_new, new), col_brick=cb.astype(np.int32), group=group, layer=lay)


def _pad_chunks(c: np.ndarray, c_pad: int | None, m: int) -> np.ndarray:
    """Column chunks ``c`` ((C, W), ``m`` = no column) padded with empty rows
    to ``c_pad`` rows (None: the ladder)."""
    c_pad = rung(len(c), MIN_CHUNKS) if c_pad is None else c_pad
    if c_pad < len(c):
        raise ValueError(f"cannot pad {len(c)} column chunks to {c_pad}")
    return np.concatenate([c, np.full((c_pad - len(c), c.shape[1]), m)]).astype(np.int32)


def chunk_rows(model) -> int:
    """Rows of :func:`pair_chunks` of a model or problem (its real columns
    grouped by brick pair, ``CHUNK`` per row)."""
    return len(pair_chunks(model))


def _support_pairs(model: ForceModel):
    """(cols, pairs, inv, rank): the NORMAL columns between two real bricks,
    their distinct (brick, support) pairs sorted by brick, each column's
    pair, and each pair's rank among its brick's supports."""
    N = model.n_pad
    cb = np.minimum(np.asarray(model.col_brick), N)
    normal = (np.asarray(model.col_kind) == NORMAL) & np.asarray(model.col_mask) & (cb[:, 1] < N) & (cb[:, 0] < N)
    cols = np.nonzero(normal)[0]
    pairs, inv = np.unique(cb[cols].reshape(-1, 2), axis=0, return_inverse=True)
    first = np.concatenate([[True], pairs[1:, 0] != pairs[:-1, 0]])
    rank = np.arange(len(pairs)) - np.maximum.accumulate(np.where(first, np.arange(len(pairs)), 0))
    return cols, pairs, inv.ravel(), rank


def support_count(model: ForceModel) -> int:
    """Most distinct real bricks under one brick's NORMAL columns (at least 1)."""
    rank = _support_pairs(model)[3]
    return int(rank.max()) + 1 if len(rank) else 1


def support_table(model: ForceModel, K: int) -> tuple[np.ndarray, np.ndarray]:
    """(supports (n_pad, K) int32: the distinct real bricks under each
    brick's NORMAL columns, ``n_pad`` = none; col_slot (m_pad,) int32: the
    slot of each NORMAL column's lower brick in its owner's row, ``K`` for
    other columns and for the baseplate). ValueError if a brick has more
    than ``K``."""
    N, M = model.n_pad, model.m_pad
    cols, pairs, inv, rank = _support_pairs(model)
    owner = pairs[:, 0]
    if len(pairs) and rank.max() >= K:
        raise ValueError(f"a brick has {rank.max() + 1} supports, more than {K} slots")
    supports = np.full((N, K), N, np.int32)
    supports[owner, rank] = pairs[:, 1]
    col_slot = np.full(M, K, np.int32)
    col_slot[cols] = rank[inv]
    return supports, col_slot


def layered_problem(model: ForceModel, L: int, c_pad: int | None = None, supports: int | None = None) -> Problem:
    """Problem arrays of an (already layered, ``n_pad = L B``) model; the
    ``layers`` field (shape (L,)) carries the layer count through jit, and
    ``chunks`` its columns grouped by brick pair (:func:`pair_chunks`),
    padded to ``c_pad`` rows (default: the ladder) for the weighted Gram
    (:func:`gram_plan`). ``supports`` = K: numbered by slabs, with each
    brick's supports in K slots (:func:`support_table`), which the interior
    point assembles brick by brick."""
    prob = to_problem(model)
    chunks = _pad_chunks(pair_chunks(prob), c_pad, prob.col_kind.shape[0])
    prob = prob._replace(layers=np.zeros(L, np.int8), chunks=chunks)
    if supports is None:
        return prob
    sup, slot = support_table(model, supports)
    return prob._replace(supports=sup, col_slot=slot)


#: Support slots per brick of slab problems: padded to these rungs.
SUPPORT_RUNGS = (4, 8, 16, 32, 64)


def support_rung(k: int) -> int:
    """Support slots for a layout whose bricks have at most ``k`` supports:
    the next of :data:`SUPPORT_RUNGS`, then multiples of 16."""
    return next((r for r in SUPPORT_RUNGS if r >= k), -(-k // 16) * 16)


#: A layered layout solved alone assembles each brick's largest-drag term
#: from its supports' pieces (``(6 (K + 1))^2`` entries a brick, in the
#: Gram's scatter: the slabs' assembly) instead of one product per level
#: (``2 (6 B)^2`` flops a brick) when ``2 B^2 / (K + 1)^2`` is at least
#: this. One core, solve after compile: the 10^3 unit cube (B = 104, K =
#: 4 slots; ratio 865) 2.81-3.08 s against 3.02-3.13 s, the 8^3 one (328)
#: 0.69-0.72 s against 0.72 s, a solid 20^3 shape (B = 40) the same
#: (BENCHMARKS.md, issue 17, session 43).
SUPPORTS_RATIO = 500


def _supports_pay(B: int, K: int) -> bool:
    """Whether a layer of ``B`` slots assembles its bricks' rank-one terms
    more cheaply from ``K`` support slots a brick than as the product:
    ``2 B^2 / (K + 1)^2 >= SUPPORTS_RATIO``."""
    return 2 * B ** 2 >= SUPPORTS_RATIO * (K + 1) ** 2


#: Layouts of at most this many (padded) bricks are always solved dense.
DENSE_MAX = 48


#: Slabs replace layers only when their factorisation costs at most this
#: fraction of the layers' (their per-brick assembly scatters K^2 pieces).
SLAB_GAIN = 0.5


def solve_plan(model: ForceModel) -> tuple:
    """Bucket key of ``model``: ("dense", n_pad), ("layered", L_pad, B_pad)
    or ("slabs", L_pad, B_pad, K_pad) (numbered by :func:`slab_levels`,
    K_pad support slots per brick: :data:`SUPPORT_RUNGS`),
    whichever factorises more cheaply (the block-tridiagonal form costs
    ~3 L (6 B)^3 flops, the dense one (6 n)^3 / 3; slabs must save
    ``SLAB_GAIN`` on layers); layouts of up to ``DENSE_MAX`` bricks stay
    dense (one small factor beats a scan over layers). Layers as
    :func:`layer_levels` gives them (a scene whose contact levels do not
    number a block-tridiagonal form has one)."""
    n_b = rung(model.n, MIN_BRICKS)
    if n_b <= DENSE_MAX:
        return ("dense", n_b)
    L, B = layer_plan(model)
    layers = 1 < L < NOT_LAYERED
    Lp, Bp = layer_bucket(L, B) if layers else (1, B)
    best = ("dense", n_b)
    if layers and factor_flops(("layered", Lp, Bp)) < factor_flops(best):
        best = ("layered", Lp, Bp)
    if Bp > SLOT_RUNGS[-1] // 2 or not layers:  # slab_levels is host work: only for large layers
        lv = slab_levels(model)
        if lv is not None:
            Ls, Bs = layer_bucket(len(np.unique(lv)), int(np.bincount(lv).max()))
            gain = SLAB_GAIN if best[0] == "layered" else 1.0
            if Ls > 1 and factor_flops(("slabs", Ls, Bs)) <= gain * factor_flops(best):
                k = support_count(model)
                best = ("slabs", Ls, Bs, support_rung(k))
    return best


def fit_plan(model: ForceModel, key: tuple, m_pad: int | None = None) -> tuple:
    """``key`` (:func:`solve_plan`) fitted to ``model`` alone, for a solve of
    one layout: its own level count and slots (or bricks) rounded up to a
    multiple of 8 instead of the ladder's rungs, when the estimated time
    that saves (:func:`plan_seconds`) exceeds one compile of a single
    solver (``SINGLE_COMPILE_S``: a shape of its own is not shared with
    other layouts). A 10^3 unit cube is solved in 10 layers of 104 slots
    instead of 12 of 128. A fitted layered key gets a fourth entry, its
    support slots (:func:`support_rung`), where the supports' pieces are
    the cheaper assembly (:data:`SUPPORTS_RATIO`): ("layered", 10, 104, 4)
    for that cube."""
    if key[0] == "dense":
        fit = ("dense", -(-model.n // 8) * 8)
    else:
        z = slab_levels(model) if key[0] == "slabs" else layer_levels(model)
        fit = (key[0], len(np.unique(z)), -(-int(np.bincount(z).max()) // 8) * 8) + key[3:]
        # the supports can only pay from the fewest slots on: count them only then
        if fit[0] == "layered" and _supports_pay(fit[2], SUPPORT_RUNGS[0]):
            K = support_rung(support_count(model))
            if _supports_pay(fit[2], K):
                fit += (K,)
    if plan_seconds(key, m_pad) - plan_seconds(fit, m_pad) > SINGLE_COMPILE_S:
        return fit
    return key


#: Seconds one compile of the (unbatched) interior point takes for a large
#: layout: 1.5-2.5 s for layered and slab shapes of 343-1240 bricks on this
#: 2-core CPU (session 34, ``benchmarks/large_layouts.py --case cube7 cube8
#: cube9 cube10 solid20 pyramid12 pyramid15 --solvers jax``, an empty cache;
#: 3.7-5.3 s in session 25, before the flat interior-point vectors and the
#: CPU compiler options of :mod:`stablelego_jax.runtime`).
SINGLE_COMPILE_S = 2.0


#: Seconds one compile of a batched interior-point solver takes on a CPU core,
#: tracing and export included, by kind (the layered program's scans over
#: layers compile to more kernels): in ``score``'s pool on this 2-core CPU,
#: session 39, 1.4-1.8 s a dense shape and 2.6-2.8 s a layered one (2.4-2.9
#: s either in session 33; 3.5-8.9 s before the flat interior-point vectors
#: and the CPU compiler options of :mod:`stablelego_jax.runtime`); and one
#: load of a compiled solver from the disk cache (0.10-0.14 s a shape in
#: the same runs; 0.34-0.37 s in session 21).
DENSE_COMPILE_S = 1.7
LAYERED_COMPILE_S = 2.7
LOAD_S = 0.15


def compile_seconds(key: tuple) -> float:
    """Seconds one compile of bucket ``key``'s batched solver takes on a CPU
    core (:data:`DENSE_COMPILE_S` or, layered and slabs, :data:`LAYERED_COMPILE_S`)."""
    return DENSE_COMPILE_S if key[0] == "dense" else LAYERED_COMPILE_S

#: Columns per padded brick of a typical layout (dense buckets of the small set: 28-54).
COLUMNS_PER_BRICK = 36


#: :func:`plan_seconds`' seconds per cubed row of a layer's factor (a Cholesky, a
#: triangular solve and the Schur product).
LAYER_K3_S = 6.88e-11


def plan_seconds(key: tuple, m_pad: int | None = None, iters: float | None = None) -> float:
    """Rough seconds one layout of bucket ``key`` with ``m_pad`` columns
    (default ``COLUMNS_PER_BRICK`` per padded brick) takes in the
    interior-point solve as batched on a CPU (:func:`~stablelego_jax.batch.batch_sizes`),
    over ``iters`` iterations (default: 4.8 + 3.83 ln(padded bricks), the
    mean count). Per iteration: 0.187 us per column (the weighted Gram and
    the operators), and for ``k = 6 B`` rows of a factor block 30 us +
    3.18 ns k^2 + 12.4 ps k^3 dense (``B`` = the padded bricks), 60 us and
    per layer 9.5 us + 6.11 ns k^2 + 68.8 ps k^3 layered (a Cholesky, a
    triangular solve and products per layer; the constants: an iteration's
    ~170 small kernels). Fitted to warm solves of 50 buckets (the 500 small
    layouts unmerged and merged, and 143 of the 1000-layout shard,
    unmerged, batched as ``score`` batches them, one CPU core; session 39,
    ``benchmarks/bucket_times.py``): per iteration within 15% on all 50
    (0.80-1.15x, median 1.01); the iteration count within 0.89-1.42x
    (session 32's model of the count, refitted to the same buckets). The
    soft interior point's 2000-placement layered problem (20 x 120 slots,
    262400 columns) is priced at 0.63 s an iteration, as measured (about
    0.62 s). Session 32's fit (0.45 us a column; 7.3 ns k^2 + 11 ps k^3
    dense, 14 ns k^2 + 208 ps k^3 a layer) priced today's solves 1.2-2.9x
    too high, the small dense ones most."""
    if key[0] == "dense":
        k, n_b = 6 * key[1], key[1]
        per_k = 30.2e-6 + 3.18e-9 * k * k + 1.24e-11 * k ** 3
    else:
        L, k, n_b = key[1], 6 * key[2], key[1] * key[2]
        per_k = 60.0e-6 + L * (9.5e-6 + 6.11e-9 * k * k + LAYER_K3_S * k ** 3)
    if m_pad is None:
        m_pad = COLUMNS_PER_BRICK * n_b
    if iters is None:
        iters = 4.8 + 3.83 * np.log(max(n_b, 1))
    return float(iters * (0.187e-6 * m_pad + per_k))


def _fits(key: tuple, size: tuple) -> bool:
    """Whether a layout of (padded bricks, layers, slots per layer) ``size``
    can be solved in bucket ``key``."""
    n_b, L, B = size
    if key[0] == "slabs":  # sizes count layers; slab buckets take no other layouts
        return False
    return n_b <= key[1] if key[0] == "dense" else (L <= key[1] and B <= key[2])


def merge_plans(sizes: dict, compile_s: float | None = None, ready=frozenset(), m_pads=None,
                load_s: float = LOAD_S, pieces=None) -> dict:
    """Fewer compiled shapes for one run: ``sizes`` maps each bucket key
    (:func:`solve_plan`) to the (padded bricks, layers, slots per layer) of
    its layouts; returns {key: key to solve it in} (a joined key, below,
    maps to itself). A bucket moves into a
    larger bucket of the same run (one its layouts fit in) when that lowers
    the run's estimated time: the padded layouts' solve time
    (:func:`plan_seconds`, with the buckets' padded columns ``m_pads``
    {key: m_pad} when given) plus ``compile_s`` per distinct batch size
    compiled (None: :func:`compile_seconds` of each bucket's kind). ``pieces(key, m_pad, count) -> [padded batch size of each
    piece]`` says how a bucket of ``count`` layouts is cut into batches
    (default: one unpadded batch), so that a merge which pads a batch to
    the next power of two, or adds a batch size, pays for it. The dense
    buckets are cut into runs of consecutive sizes, each solved in its
    largest bucket, at the least estimated time (dynamic programming over
    the chain); then the other buckets move, the smallest first, each to
    the cheapest target; then pairs of buckets that no bucket of the run
    takes together join in the smallest bucket of the ladder that takes
    both (a key not in ``sizes``: one compile instead of two), the pair
    that saves the most first. A bucket in ``ready``
    (its solvers compiled already: in this process or on disk) costs only
    ``load_s`` per batch size it had. With ``compile_s`` = 0 and no
    bucket ready nothing moves."""
    sizes = {k: list(v) for k, v in sizes.items()}
    m_pads = dict(m_pads) if m_pads else {k: None for k in sizes}
    target = {k: k for k in sizes}
    count = {k: len(v) for k, v in sizes.items()}

    def cut(k, m, c):
        return [c] if pieces is None else list(pieces(k, m, c))

    have = {k: set(cut(k, m_pads[k], count[k])) if k in ready else set() for k in sizes}

    def cost(k, m, c):
        """Estimated seconds of bucket ``k`` with ``c`` layouts padded to ``m`` columns."""
        p = cut(k, m, c)
        new = compile_seconds(k) if compile_s is None else compile_s
        done = have[k] if k in have else set(p) if k in ready else ()  # a joined key may be ready too
        return sum(p) * plan_seconds(k, m) + sum(load_s if s in done else new for s in set(p))

    def move(k, t):
        for j in target:
            if target[j] == k:
                target[j] = t
        count[t] += count[k]
        sizes[t] += sizes[k]
        if m_pads[t] is not None:
            m_pads[t] = max(m_pads[t], m_pads[k] or 0)

    # the dense buckets are a chain (a layout fits every larger one): its cheapest cut into
    # runs, each solved in its largest bucket, by dynamic programming (moves one at a time
    # cascade up the chain, or jump into a far larger bucket that is compiled anyway)
    dense = sorted((k for k in sizes if k[0] == "dense"), key=lambda k: k[1])
    total, start = [0.0], []
    for j, t in enumerate(dense):
        def run(i):
            m = None if m_pads[t] is None else max(m_pads[g] or 0 for g in dense[i: j + 1])
            return total[i] + cost(t, m, sum(count[g] for g in dense[i: j + 1]))
        v, i = min((run(i), -i) for i in range(j + 1))  # ties: the shorter run
        total.append(v)
        start.append(-i)
    j = len(dense) - 1
    while j >= 0:
        for g in dense[start[j]: j]:
            move(g, dense[j])
        j = start[j] - 1

    # the rest, smallest first, each into the cheapest bucket that takes it
    for k in sorted(sizes, key=lambda k: (count[k], plan_seconds(k, m_pads[k]))):
        if target[k] != k:
            continue
        best, best_extra = None, 0.0
        alone = cost(k, m_pads[k], count[k])
        for t in sizes:
            if t == k or target[t] != t or not all(_fits(t, sz) for sz in sizes[k]):
                continue
            m_t = None if m_pads[t] is None else max(m_pads[t], m_pads[k] or 0)
            extra = cost(t, m_t, count[t] + count[k]) - cost(t, m_pads[t], count[t]) - alone
            if extra < best_extra:
                best, best_extra = t, extra
        if best is not None:
            move(k, best)

    # then pairs that no bucket of the run takes together: both into the smallest bucket of the
    # ladder that takes the layouts of both (:func:`_join_keys`; one compile instead of two: on the
    # small set, layered 6 x 24, 12 x 20 and 16 x 16 of one layout each and the dense 56 and 96
    # buckets end in dense 152; a bucket of that key joins them), the join that saves the most
    # first, until none saves
    while compile_s is None or compile_s > 0:
        live = sorted((k for k in sizes if target[k] == k and k[0] != "slabs"), key=str)
        best, best_extra = None, 0.0
        for a, k in enumerate(live):
            for t in live[a + 1:]:
                for j in _join_keys(sizes[k] + sizes[t]):
                    if j in sizes and target[j] != j:  # merged into another already
                        continue
                    group = list(dict.fromkeys([k, t] + ([j] if j in sizes else [])))
                    m_j = max(m_pads[g] or 0 for g in group) or None
                    c_j = sum(count[g] for g in group)
                    extra = cost(j, m_j, c_j) - sum(cost(g, m_pads[g], count[g]) for g in group)
                    # paid for by the compiles it saves: each bucket's layouts are padded, none
                    # estimated faster there than where :func:`solve_plan` put them
                    padded = all(plan_seconds(j, m_j) >= plan_seconds(g, m_pads[g]) for g in group)
                    if padded and extra < best_extra:
                        best, best_extra = (group, j, m_j), extra
        if best is None:
            break
        group, j, m_j = best
        if j not in sizes:  # its cost reads ``ready`` itself
            sizes[j], count[j], target[j] = [], 0, j
        m_pads[j] = m_j
        for g in group:
            if g != j:
                move(g, j)
    return target


def _join_keys(sizes: list) -> list:
    """The smallest dense bucket and, where every layout has a layered
    numbering, the smallest layered bucket of the ladder that take every
    layout of ``sizes`` ((padded bricks, layers, slots per layer) each, as
    :func:`merge_plans` gets them)."""
    out = [("dense", max(s[0] for s in sizes))]
    L, B = max(s[1] for s in sizes), max(s[2] for s in sizes)
    if L < NOT_LAYERED:
        out.append(("layered", *layer_bucket(L, B)))
    return out


def plan_problem(model: ForceModel, key: tuple, m_pad: int, p_pad: int,
                 c_pad: int | None = None) -> tuple[ForceModel, Problem]:
    """(model to score the forces on, Problem to solve) for bucket ``key`` with
    ``m_pad`` columns, ``p_pad`` contact slots and ``c_pad`` column chunks
    (default: the ladder of its own, :func:`chunk_rows`): the scoring model
    keeps the input brick order; the Problem is numbered layer by layer when
    layered."""
    if key[0] in ("layered", "slabs"):
        fm = model.pad(model.n, m_pad, p_pad)
        if key[0] == "slabs":
            lv = slab_levels(fm)
            return fm, layered_problem(to_layered(fm, key[1], key[2], lv), key[1], c_pad, supports=key[3])
        # ("layered", L, B, K): a fitted key whose supports' pieces are the cheaper assembly
        return fm, layered_problem(to_layered(fm, key[1], key[2]), key[1], c_pad,
                                   supports=key[3] if len(key) > 3 else None)
    fm = model.pad(key[1], m_pad, p_pad)
    return fm, layered_problem(fm, 1, c_pad, supports=dense_supports(fm))


#: Support slots per brick of a dense problem (:func:`dense_supports`).
DENSE_SUPPORTS = 8


def dense_supports(model: ForceModel) -> int:
    """Support slots per brick of a dense problem: :data:`DENSE_SUPPORTS`,
    or the next of :data:`SUPPORT_RUNGS` for a layout with more. Dense
    problems assemble each brick's rank-one term (its largest drag) from
    its supports, one (6 (K + 1))^2 piece a brick, instead of the product
    of an (n, 6 n) matrix with itself, when solved alone
    (:attr:`~stablelego_jax.solvers.ipm.IPMOptions.cut`; a batch keeps the
    product, measured nowhere else): one core, the small set's layouts
    solved alone, 0.73-0.82x the time an iteration where the factor is cut
    (41-120 bricks), 0.94x at 25-40, the same at 9-24, 1.08x at 1-8; every
    shape compiled 0.2-0.4 s faster (BENCHMARKS.md, issue 17, session 42)."""
    k = support_count(model)
    return DENSE_SUPPORTS if k <= DENSE_SUPPORTS else support_rung(k)


# --------------------------------------------------------------- operators


def row_scale(params: Params):
    """Row scaling: forces / T, torques / (T * stud); weights of the scaled L1."""
    s = jnp.array([1.0, 1.0, 1.0, 1.0 / params.stud, 1.0 / params.stud, 1.0 / params.stud])
    w = jnp.array([1.0, 1.0, 1.0, params.stud, params.stud, params.stud])
    return s / params.T, w


def scaled_wrenches(col_coef, params: Params):
    """(m, 2, 6) wrench per unit force in the solvers' scaled rows (forces in
    T, torques in T stud; :func:`row_scale`), from ``col_coef`` in N and N m
    per N: the columns of the verdict LP (:func:`operators`) and of the soft
    problems (:mod:`.soft_ipm`)."""
    return col_coef * row_scale(params)[0].astype(col_coef.dtype) * params.T


def operators(prob: Problem, params: Params):
    """The equilibrium operator in scaled units: (A, A', coef, g, w).

    A: (m,) forces in T -> (n, 6) scaled wrench per brick; A': its
    transpose; coef: (m, 2, 6) scaled wrench per unit force; g: (n, 6)
    scaled gravity; w: (n, 6) weights of the scaled L1 residual (0 on
    padding bricks). ``A f`` is :func:`~stablelego_jax.score.equilibrium`
    on the scaled wrenches.
    """
    s6, w6 = (a.astype(prob.col_coef.dtype) for a in row_scale(params))
    coef = scaled_wrenches(prob.col_coef, params)  # unit force in units of T
    cb = prob.col_brick
    n = prob.gravity.shape[0]

    def A(x):
        return equilibrium(coef, cb, x, n)

    def At(y):
        return equilibrium_t(coef, cb, y)

    g = prob.gravity * s6
    w = jnp.where(prob.brick_mask[:, None], w6, 0.0) * jnp.ones_like(g)
    return A, At, coef, g, w


class LayerGram(NamedTuple):
    """Scatter plan of ``A diag(e) A'`` (the scaled equilibrium operator's
    weighted Gram matrix, (6 n, 6 n)) as block-tridiagonal blocks over the
    ``L`` layers of ``B`` brick slots of a problem (``L = 1``: one dense
    block). Rows of a layer's block: ``6 * slot + component``; the blocks
    are :mod:`.blocks`' layout. Built once per solve (static indices);
    :meth:`blocks` assembles for any column weights: per chunk of columns
    joining one pair of bricks (``rows``, the problem's ``chunks``) a
    (W, 12) x (W, 12) product, then the 12 x 12 piece's four 6 x 6 brick
    blocks placed as windows (one index each, not one per entry); without
    chunks one piece per column."""

    L: int
    B: int
    k: int  # 6 B, the block size
    idx: jnp.ndarray  # (R, 4, 3) each piece's brick blocks: (block of [D; E], row, column) of the 6 x 6 window
    coef: jnp.ndarray  # (R, W, 12) coefficients of each piece's columns (W = 1 without chunks)
    rows: jnp.ndarray | None  # (R, W) the piece's columns, m = none (None: piece r = column r)

    def blocks(self, e, extra=None, base=None):
        """(D, E), each (L, k, k): the diagonal blocks and the blocks below
        them (``E[l]`` = block (l + 1, l)) of ``A diag(e) A'``; ``e``: (m,).
        ``extra`` (idx (N, 3), values (N, 6, 6)): more 6 x 6 windows added
        in the same scatter (:func:`block_windows`' indices). ``base`` (D0,
        E0), each (L, k, k): blocks the Gram is added to, each by a scatter
        of its own windows in place (no zeroed (2 L, k, k) buffer, and no
        pass adding its halves to them)."""
        L, k = self.L, self.k
        R, W = self.coef.shape[:2]
        ew = e[:, None] if self.rows is None else jnp.concatenate([e, jnp.zeros((1,), e.dtype)])[self.rows]
        # each piece's four 6 x 6 brick blocks, summed column by column in the
        # windows' layout: one fused loop (a batched (12, W) x (W, 12) product
        # and the transpose into windows took 1.4x as long: 2000 placements,
        # BENCHMARKS.md issue 18, session 43)
        win = 0.0
        for w in range(W):
            c = self.coef[:, w]
            win = win + (c * ew[:, w, None]).reshape(R, 2, 1, 6, 1) * c.reshape(R, 1, 2, 1, 6)
        win = win.reshape(4 * R, 6, 6)
        idx = self.idx.reshape(4 * R, 3)
        if extra is not None:
            idx = jnp.concatenate([idx, extra[0].reshape(-1, 3)])
            win = jnp.concatenate([win, extra[1].reshape(-1, 6, 6)])
        if base is not None:
            drop = jax.lax.GatherScatterMode.FILL_OR_DROP
            shift = jnp.asarray([L, 0, 0], idx.dtype)  # E's windows are blocks L..2L-1; D's fall below 0
            return (jax.lax.scatter_add(base[0], idx, win, _WINDOWS, mode=drop),
                    jax.lax.scatter_add(base[1], idx - shift, win, _WINDOWS, mode=drop))
        # one layer: no block below the diagonal, so no buffer for E (its windows
        # fall past the end and are dropped): a dense 720-row problem's buffer is
        # 4 MB, and zeroing the unused half took a third of its Gram's time
        depth = 2 * L if L > 1 else 1
        buf = jax.lax.scatter_add(
            jnp.zeros((depth, k, k), e.dtype), idx, win, _WINDOWS,
            mode=jax.lax.GatherScatterMode.FILL_OR_DROP)
        return (buf[:L], buf[L:]) if L > 1 else (buf, jnp.zeros_like(buf))


# a (6, 6) window of a (2 L, k, k) buffer at (block, row, column)
_WINDOWS = jax.lax.ScatterDimensionNumbers(
    update_window_dims=(1, 2), inserted_window_dims=(0,), scatter_dims_to_operand_dims=(0, 1, 2))


def block_windows(bi, bj, n: int, L: int):
    """Where brick block (bi, bj) of a block-tridiagonal matrix over ``n =
    L B`` slots lies in :class:`LayerGram`'s buffer [D; E] ((2 L, 6 B, 6 B)):
    (..., 3) int (block, row, column) of its 6 x 6 window, block ``2 L``
    (past the end: dropped) where it is above the diagonal blocks, joins
    layers further apart, or a slot is ``n`` or more (none); ``bi``, ``bj``
    int arrays that broadcast together."""
    bi, bj = jnp.broadcast_arrays(bi, bj)
    B = n // L
    li, lj = bi // B, bj // B
    ok = (bi < n) & (bj < n)
    blk = jnp.where(ok & (li == lj), li, jnp.where(ok & (li == lj + 1), L + lj, 2 * L))
    return jnp.stack([blk, 6 * (bi % B), 6 * (bj % B)], axis=-1)


def gram_plan(col_brick, coef, n: int, L: int, chunks=None) -> LayerGram:
    """The :class:`LayerGram` of columns joining brick slots ``col_brick``
    ((m, 2) int, ``0..n-1``; ``n`` or more: none, e.g. the baseplate or
    padding) with coefficients ``coef`` (m, 2, 6); ``n = L B`` slots, slot s
    in layer ``s // B``. Every column joins slots of one layer or of two
    adjacent layers; coefficients of no slot are dropped. ``chunks`` (R, W):
    columns grouped by the pair of slots they join (``m``: none), or None."""
    m = col_brick.shape[0]
    B = n // L
    k = 6 * B
    c12 = coef.reshape(m, 12)
    if chunks is None:
        rows, pb, rcoef = None, col_brick, c12[:, None, :]
    else:
        rows = jnp.asarray(chunks)
        # a chunk's columns join one pair of bricks: those of its first column (none: the sink)
        pb = jnp.concatenate([col_brick, jnp.full((1, 2), n, col_brick.dtype)])[rows[:, 0]]
        rcoef = jnp.concatenate([c12, jnp.zeros((1, 12), c12.dtype)])[rows]  # (R, W, 12)
    b1, b2 = pb[:, 0], pb[:, 1]
    idx = block_windows(jnp.stack([b1, b1, b2, b2], 1), jnp.stack([b1, b2, b1, b2], 1), n, L)
    return LayerGram(L, B, k, idx, rcoef, rows)


def make_solution(prob: Problem, params: Params, x, iters, converged, pr, dr, obj, dual, gap) -> Solution:
    """A Solution from scaled forces ``x`` (in T) and scaled diagnostics:
    side presses clipped to >= 0, padding columns zeroed, forces and
    objective back in N."""
    x = jnp.where(prob.col_kind == SIDE, jnp.maximum(x, 0.0), x)
    x = jnp.where(prob.col_mask, x, 0.0)
    T = params.T
    return Solution(
        f=(x * T).astype(jnp.float64), iters=iters, converged=converged, primal_res=pr, dual_res=dr,
        objective=obj * T, dual_bound=dual * T, gap=gap,
    )
