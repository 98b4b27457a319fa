"""Per-brick scores (paper Eq. 10) from a force distribution.

Works on numpy or JAX arrays of one (unbatched) compiled model; ``vmap`` it
for batches.
"""
from __future__ import annotations

import jax.numpy as jnp

from .model import NORMAL

__all__ = ["residual", "brick_drag", "brick_scores"]


def residual(model, f):
    """Equilibrium residual ``A f + g`` per brick: (n_pad, 6) in N and N m."""
    cb, coef = model.col_brick, model.col_coef
    n_pad = model.gravity.shape[0]
    out = jnp.zeros((n_pad + 1, 6), f.dtype)
    out = out.at[cb[:, 0]].add(coef[:, 0, :] * f[:, None])
    out = out.at[cb[:, 1]].add(coef[:, 1, :] * f[:, None])
    return out[:n_pad] + model.gravity


def brick_drag(model, f):
    """Largest drag ``D = max(-n, 0)`` on each brick's bottom contacts: (n_pad,) N."""
    d = jnp.where(model.col_kind == NORMAL, jnp.maximum(-f, 0.0), 0.0)
    d = jnp.concatenate([d, jnp.zeros((1,), d.dtype)])
    return d[model.group].max(axis=1)


def brick_scores(model, f, params=None):
    """Eq. 10 score per brick (n_pad,), plus (residual_bad, max_drag).

    Score is 1 where the residual exceeds ``eq_tol`` (forces, N) or
    ``eq_tol * stud`` (torques, N m), or the largest drag reaches T; else
    largest drag / T. Padding bricks score 0.
    """
    p = params or model.params
    r = jnp.abs(residual(model, f))
    bad = (r[:, :3].max(axis=1) > p.eq_tol) | (r[:, 3:].max(axis=1) > p.eq_tol * p.stud)
    dmax = brick_drag(model, f)
    s = jnp.where(bad | (dmax >= p.T), 1.0, dmax / p.T)
    return jnp.where(model.brick_mask, s, 0.0), bad & model.brick_mask, dmax
