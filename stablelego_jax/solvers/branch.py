"""A branch that a batch takes only when one of its members needs it.

``lax.cond`` with a predicate that differs across a ``vmap``-ed batch is
batched by JAX as a select: both branches run for every member, every
time. The soft interior point branches on something rarely true (it
refines its centring steps' directions, the last few of its iterations),
so a batch paid for the rare branch on every iteration. (The ADMM's
refactorisation when a step size moves was tried with it and not kept:
2% less solve time, 12% more compile on a CPU; BENCHMARKS.md, issue 18,
session 50.) :func:`cond_any` is
``lax.cond`` unbatched; batched, it runs the rare branch (for the whole
batch) only in the iterations where at least one member takes it, and each
member keeps its own branch's value. Pure JAX; jit- and vmap-friendly
(nested ``vmap`` included).
"""
from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

__all__ = ["cond_any"]


def cond_any(pred, rare: Callable, usual: Callable, *operands):
    """``lax.cond(pred, rare, usual, *operands)``; under ``vmap`` with a
    batched ``pred``: ``rare`` runs (batched) only when some member's pred
    holds, and each member gets ``rare``'s value where its pred holds,
    ``usual``'s elsewhere (JAX's own batching of a cond runs both branches
    always). ``rare`` and ``usual`` take ``operands`` (pytrees of arrays;
    nothing batched may be closed over) and return pytrees of one
    structure, shapes and dtypes. pred: bool scalar."""

    @jax.custom_batching.custom_vmap
    def run(p, *ops):
        return jax.lax.cond(p, rare, usual, *ops)

    @run.def_vmap
    def _batched(axis_size, in_batched, p, *ops):
        p_batched, *ops_batched = in_batched
        axes = tuple(jax.tree_util.tree_map(lambda b: 0 if b else None, ob) for ob in ops_batched)

        def each(fn):
            return jax.vmap(fn, in_axes=axes, out_axes=0, axis_size=axis_size)

        if not p_batched:  # one predicate for the whole batch: an ordinary branch
            out = jax.lax.cond(p, each(rare), each(usual), *ops)
        else:
            def mixed(*o):
                a, b = each(rare)(*o), each(usual)(*o)
                return jax.tree_util.tree_map(
                    lambda u, v: jnp.where(p.reshape(p.shape + (1,) * (u.ndim - 1)), u, v), a, b)

            out = jax.lax.cond(jnp.any(p), mixed, each(usual), *ops)
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return run(pred, *operands)
