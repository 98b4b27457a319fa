"""The primal-dual interior-point iteration both interior points share.

:mod:`.ipm` (the verdict LP of Eq. 9) and :mod:`.soft_ipm` (the central
path of the soft problems) are each a ``step`` over their own state (their
own variables, Newton reduction and stopping test); this module holds what
they have in common: :func:`iterate`, the one guarded loop that runs a
step until it says stop, and the two step rules of a Mehrotra
predictor-corrector method, :func:`boundary_step` (how far a direction may
go before a slack or a dual leaves the positive orthant) and
:func:`centring` (Mehrotra's centring parameter). Pure functions of JAX
arrays and pytrees (jit- and vmap-friendly).
"""
from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

__all__ = ["iterate", "boundary_step", "centring"]


def iterate(step: Callable, state, max_iter: int):
    """Run ``step`` from ``state`` until it stops: at most ``max_iter`` times.

    ``step(state) -> (new, stop, keep)``: ``stop`` (bool scalar): ``new`` is
    the answer; ``keep`` (bool scalar): the step broke down (non-finite
    numbers, a polish that lost convergence, ...), so the previous state is
    kept and the loop stops. A ``lax.while_loop``: under ``vmap`` every
    problem of a batch runs until all have stopped, a stopped one left
    unchanged. Returns ``(state, iterations)`` (iterations: int32 scalar,
    the kept step counted)."""

    def body(c):
        old, _, it = c
        new, stop, keep = step(old)
        out = jax.tree_util.tree_map(lambda a, b: jnp.where(keep, a, b), old, new)
        return out, stop | keep, it + 1

    state, _, it = jax.lax.while_loop(lambda c: (~c[1]) & (c[2] < max_iter), body,
                                      (state, jnp.asarray(False), jnp.asarray(0)))
    return state, it


def boundary_step(v, dv, on):
    """The largest step ``t`` keeping ``v + t dv >= 0`` on the entries
    ``on`` (where ``v > 0``): the least ``-v / dv`` over ``on`` and
    ``dv < 0``; ``inf`` if no entry limits it. v, dv, on: same shape."""
    lim = jnp.where(on & (dv < 0), -v / jnp.where(dv < 0, dv, -1.0), jnp.inf)
    return lim.min()


def centring(mu_aff, mu):
    """Mehrotra's centring parameter ``sigma = (mu_aff / mu)^3`` in [0, 1]:
    mu, the mean complementarity product at the iterate; mu_aff, at the end
    of the affine-scaling (predictor) step."""
    return jnp.clip((mu_aff / mu) ** 3, 0.0, 1.0)
