"""Per-brick scores (paper Eq. 10) from a force distribution.

Works on numpy or JAX arrays of one (unbatched) compiled model; ``vmap`` it
for batches.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .layout import Layout, cells_of, layout_voxels
from .model import NORMAL


__all__ = ["residual", "brick_drag", "brick_scores", "score_grid"]


def _xp(*arrays):
    """numpy for host arrays (no per-shape jit compiles), jax.numpy otherwise
    (jax arrays and tracers, so the functions still jit and vmap)."""
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np


def residual(model, f):
    """Equilibrium residual ``A f + g`` per brick: (n_pad, 6) in N and N m."""
    cb, coef = model.col_brick, model.col_coef
    n_pad = model.gravity.shape[0]
    xp = _xp(f, coef)
    if xp is np:
        out = np.zeros((n_pad + 1, 6), np.result_type(f, coef))
        np.add.at(out, cb[:, 0], coef[:, 0, :] * f[:, None])
        np.add.at(out, cb[:, 1], coef[:, 1, :] * f[:, None])
        return out[:n_pad] + model.gravity
    out = jnp.zeros((n_pad + 1, 6), f.dtype)
    out = out.at[cb[:, 0]].add(coef[:, 0, :] * f[:, None])
    out = out.at[cb[:, 1]].add(coef[:, 1, :] * f[:, None])
    return out[:n_pad] + model.gravity


def brick_drag(model, f):
    """Largest drag ``D = max(-n, 0)`` on each brick's bottom contacts: (n_pad,) N."""
    xp = _xp(f)
    d = xp.where(model.col_kind == NORMAL, xp.maximum(-f, 0.0), 0.0)
    d = xp.concatenate([d, xp.zeros((1,), d.dtype)])
    return d[model.group].max(axis=1)


def brick_scores(model, f, params=None):
    """Eq. 10 score per brick (n_pad,), plus (residual_bad, max_drag).

    Score is 1 where the residual exceeds ``eq_tol`` (forces, N) or
    ``eq_tol * stud`` (torques, N m), or the largest drag reaches T (within
    ``drag_rtol * T``); else
    largest drag / T. Padding bricks score 0.
    """
    p = params or model.params
    xp = _xp(f)
    r = xp.abs(residual(model, f))
    bad = (r[:, :3].max(axis=1) > p.eq_tol) | (r[:, 3:].max(axis=1) > p.eq_tol * p.stud)
    dmax = brick_drag(model, f)
    s = xp.where(bad | (dmax >= p.T * (1.0 - p.drag_rtol)), 1.0, dmax / p.T)
    return xp.where(model.brick_mask, s, 0.0), bad & model.brick_mask, dmax


def score_grid(layout: Layout, scores, shape: Sequence[int] | None = None) -> np.ndarray:
    """(X, Y, Z) float64 grid: each brick's cells hold its score, empty cells 0.

    ``scores``: {key: score} or a sequence aligned with layout.keys.
    """
    if isinstance(scores, Mapping):
        s = np.array([float(scores[k]) for k in layout.keys])
    else:
        s = np.asarray(scores, np.float64).reshape(-1)
        if s.shape != (layout.n,):
            raise ValueError(f"scores must hold one value per brick ({layout.n}), got {s.shape}")
    shape = layout_voxels(layout, shape).shape
    grid = np.zeros(shape, np.float64)
    cells, owner = cells_of(layout.pos, layout.size)
    grid[cells[:, 0], cells[:, 1], cells[:, 2]] = s[owner]
    return grid
