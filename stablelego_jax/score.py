"""Per-brick scores (paper Eq. 10) from a force distribution.

The one implementation of each formula every solver, the loss and repair
use: :func:`equilibrium` and :func:`equilibrium_t` (the equilibrium
operator ``A f``, each column's force times its wrench on its two bricks,
and its transpose), :func:`largest_drag` and :func:`bottom_sum` (the
largest and the sum of a value over each brick's own bottom contacts),
:func:`residual_bad` (out of equilibrium beyond the tolerance),
:func:`floating_bricks` (no chain of contacts to the ground) and
:func:`verdict` (Eq. 10). Works on numpy arrays (no per-shape jit
compiles) or JAX arrays and tracers (so it jits and vmaps); one
(unbatched) model at a time, ``vmap`` it for batches.
"""
from __future__ import annotations

import numpy as np

from .model import NORMAL, Params

__all__ = ["equilibrium", "equilibrium_t", "residual", "largest_drag", "bottom_sum", "brick_drag", "residual_bad",
           "eq9_cost", "floating_bricks", "verdict", "brick_scores", "weakest_brick", "TIE"]

#: Scores (and drags / T) closer than this are a tie for the weakest brick.
TIE = 1e-6


def _xp(*arrays):
    """jax.numpy for JAX arrays and tracers, numpy otherwise (host arrays
    need no JAX, not even its import)."""
    if any(type(a).__module__.startswith(("jax", "jaxlib")) for a in arrays):
        import jax.numpy as jnp

        return jnp
    return np


def equilibrium(coef, col_brick, f, n):
    """The equilibrium operator ``A f``: the wrench of every column's force
    on its two bricks, summed per brick.

    coef: (m, 2, 6) wrench on each slot per unit force (any units: N and
    N m, or the solvers' scaled rows); col_brick: (m, 2) brick of each slot,
    ``n`` for none (the baseplate: dropped); f: (m,). Returns (n, 6) in
    coef's units times f's. numpy in, numpy out; JAX arrays and tracers
    give JAX arrays (jit- and vmap-friendly)."""
    xp = _xp(f, coef)
    if xp is np:
        out = np.zeros((n + 1, 6), np.result_type(f, coef))
        np.add.at(out, col_brick[:, 0], coef[:, 0, :] * f[:, None])
        np.add.at(out, col_brick[:, 1], coef[:, 1, :] * f[:, None])
        return out[:n]
    out = xp.zeros((n + 1, 6), f.dtype)
    out = out.at[col_brick[:, 0]].add(coef[:, 0, :] * f[:, None])
    out = out.at[col_brick[:, 1]].add(coef[:, 1, :] * f[:, None])
    return out[:n]


def equilibrium_t(coef, col_brick, y):
    """The transpose of :func:`equilibrium`: (n, 6) per-brick rows -> (m,)
    per column, ``(A' y)_p = sum over p's two slots of coef . y[brick]``."""
    xp = _xp(y, coef)
    yp = xp.concatenate([y, xp.zeros((1, 6), y.dtype)])
    # one gather of both slots (m, 2, 6): XLA's CPU code for two separate
    # gathers fused with their sums runs 6x slower (the same numbers); the 12
    # products summed as one chain of adds, not a reduction over the last axis,
    # which XLA's CPU compiler hands to YNNPACK: 2.7-3.1x slower at 1096-262400
    # columns (BENCHMARKS.md, issue 17, session 52)
    p = coef * yp[col_brick]
    s = p[:, 0, 0] + p[:, 1, 0]
    for k in range(1, 6):
        s = s + p[:, 0, k] + p[:, 1, k]
    return s


def residual(model, f):
    """Equilibrium residual ``A f + g`` per brick: (n_pad, 6) in N and N m."""
    return equilibrium(model.col_coef, model.col_brick, f, model.gravity.shape[0]) + model.gravity


def largest_drag(drag, group):
    """The largest of each brick's bottom-contact drags.

    drag: (m,) drag of each column (>= 0; 0 where a column has none);
    group: (n, P) the NORMAL columns on each brick's bottom (``m`` = empty
    slot). Returns (n,), 0 for a brick with no bottom contact.
    """
    xp = _xp(drag, group)
    d = xp.concatenate([drag, xp.zeros((1,), drag.dtype)])
    return d[group].max(axis=1)


def bottom_sum(v, group):
    """The sum of a per-column value over each brick's bottom NORMAL
    columns: v (m,), group (n, P) as in :func:`largest_drag`; returns (n,),
    0 for a brick with no bottom contact."""
    xp = _xp(v, group)
    return xp.concatenate([v, xp.zeros((1,), v.dtype)])[group].sum(axis=1)


def brick_drag(model, f):
    """Largest drag ``D = max(-n, 0)`` on each brick's bottom contacts: (n_pad,) N."""
    xp = _xp(f)
    d = xp.where(model.col_kind == NORMAL, xp.maximum(-f, 0.0), 0.0)
    return largest_drag(d, model.group)


def eq9_cost(model, f, params: Params | None = None) -> float:
    """Paper Eq. 9's cost of forces ``f`` ((m_pad,) N) on ``model`` (a
    ForceModel, or a solver's Problem with ``params``): the L1 norm of the
    equilibrium residual (N and N m, every row weighted 1: the solvers'
    scaled rows and weights multiply out to that), plus ``alpha`` times the
    sum of each brick's largest drag, plus ``beta`` times the sum of the
    drags (N). The solvers report it as ``objective``."""
    xp = _xp(f)
    p = params or model.params
    r = residual(model, f) * model.brick_mask[:, None]
    d = xp.where(model.col_kind == NORMAL, xp.maximum(-f, 0.0), 0.0)
    return xp.abs(r).sum() + p.alpha * largest_drag(d, model.group).sum() + p.beta * d.sum()


def residual_bad(r, params: Params):
    """(n,) bool: the brick is out of equilibrium, its residual ``r`` ((n, 6),
    N and N m) beyond ``eq_tol`` (forces) or ``eq_tol * stud`` (torques)."""
    xp = _xp(r)
    r = xp.abs(r)
    return (r[:, :3].max(axis=1) > params.eq_tol) | (r[:, 3:].max(axis=1) > params.eq_tol * params.stud)


def floating_bricks(model) -> np.ndarray:
    """(n_pad,) bool: the real bricks with no chain of contacts that can
    carry vertical force (knob connections, supports and frictions of plain
    blocks; not side presses) to the ground.

    A group of bricks joined to each other but not to the ground cannot
    hold its weight, but Eq. 9 may put the whole group's residual on any one
    of them; these bricks fail whatever the solver returns (host-side,
    numpy and scipy; ``model`` a :class:`~stablelego_jax.model.ForceModel`
    of numpy arrays)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n_pad = model.gravity.shape[0]
    cb = np.asarray(model.col_brick)
    vert = np.asarray(model.col_mask) & (np.abs(np.asarray(model.col_coef)[:, 0, 2]) > 0)
    a, b = cb[vert, 0], cb[vert, 1]
    # node n_pad is the ground (the sink of baseplate columns)
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(n_pad + 1, n_pad + 1))
    _, comp = connected_components(g, directed=False)
    return np.asarray(model.brick_mask, bool) & (comp[:n_pad] != comp[n_pad])


def verdict(dmax, bad, params: Params):
    """Paper Eq. 10: the score of each brick from its largest drag ``dmax``
    (N) and whether it is out of equilibrium (``bad``): 1 where ``bad`` or
    the drag reaches T (within ``drag_rtol * T``), else drag / T."""
    xp = _xp(dmax)
    return xp.where(bad | (dmax >= params.T * (1.0 - params.drag_rtol)), 1.0, dmax / params.T)


def brick_scores(model, f, params=None, floating=None):
    """Eq. 10 score per brick (n_pad,), plus (residual_bad, max_drag).

    See :func:`verdict`; padding bricks score 0. ``floating``: (n_pad,)
    bool bricks that fail whatever their residual (:func:`floating_bricks`;
    they count as out of equilibrium), or None.
    """
    p = params or model.params
    xp = _xp(f)
    bad = residual_bad(residual(model, f), p)
    if floating is not None:
        bad = bad | floating
    dmax = brick_drag(model, f)
    s = verdict(dmax, bad, p)
    return xp.where(model.brick_mask, s, 0.0), bad & model.brick_mask, dmax


def weakest_brick(scores, dmax, T: float) -> int:
    """Index of the weakest brick: the highest score; among scores within
    :data:`TIE` of it, the largest drag (within ``TIE * T``); then the first
    in input order. Exact ties (symmetric bricks, several floating bricks)
    so get one answer whatever the solver's last digits. scores, dmax: (n,)
    numpy, n >= 1; T: N."""
    s, d = np.asarray(scores, float), np.asarray(dmax, float)
    top = s >= s.max() - TIE
    d = np.where(top, d, -np.inf)
    return int(np.argmax(top & (d >= d.max() - TIE * T)))
