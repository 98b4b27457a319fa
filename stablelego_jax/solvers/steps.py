"""The step rules both interior points share (:mod:`.ipm`, the verdict LP;
:mod:`.soft_ipm`, the soft problems): how far a Newton direction may go
before a slack or a dual leaves the positive orthant, and Mehrotra's
centring parameter. Pure functions of JAX arrays (jit- and vmap-friendly).
"""
from __future__ import annotations

import jax.numpy as jnp

__all__ = ["boundary_step", "centring"]


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
