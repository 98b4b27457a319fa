"""Block-tridiagonal linear algebra: the layered factorisation of both interior points.

Bricks numbered layer by layer (``L`` layers of ``B`` slots) make every
reduced Newton matrix of Eq. 9 block tridiagonal with ``(k, k)`` blocks,
``k = 6 B``: a force column joins bricks of one layer or of two adjacent
layers. Both interior points factorise it with a ``lax.scan`` over the
layers, ``O(L k^3)`` instead of ``O((L k)^3)``:

* :func:`block_cholesky` / :func:`block_solve`: symmetric positive definite
  matrices (the verdict LP of :mod:`.ipm`);
* :func:`block_lu` / :func:`block_lu_solve`: general matrices (the soft
  problems of :mod:`.soft_ipm`, whose Newton matrices are not symmetric
  when weights are below 1), block LU without pivoting between blocks and
  with partial pivoting inside each pivot block; solves with the matrix or
  its transpose from one factorisation.

Block layout: ``D`` (L, k, k) diagonal blocks, ``E`` (L, k, k) with
``E[l]`` = block (l+1, l) (below the diagonal; ``E[L-1]`` unused), ``F``
(L, k, k) with ``F[l]`` = block (l, l+1) (above; ``F[L-1]`` unused).
Right-hand sides are (L, k).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

__all__ = ["block_cholesky", "block_solve", "BlockLU", "block_lu", "block_lu_solve"]


def block_cholesky(D, E):
    """Factor a block-tridiagonal SPD matrix (``F = E^T``).
    Returns (C, G): C[l] lower Cholesky factor of the l-th pivot block,
    G[l] = C[l]^-1 E[l]'. One layer (``L = 1``, a dense matrix): one
    Cholesky factor and G = 0, with no triangular solve for it."""
    if D.shape[0] == 1:
        return jnp.linalg.cholesky(D), jnp.zeros_like(D)

    def body(Gprev, inp):
        Dl, El = inp
        C = jnp.linalg.cholesky(Dl - Gprev.T @ Gprev)
        G = jax.scipy.linalg.solve_triangular(C, El.T, lower=True)
        return G, (C, G)

    _, (C, G) = jax.lax.scan(body, jnp.zeros_like(D[0]), (D, E))
    return C, G


def block_solve(C, G, r):
    """Solve M y = r (r: (L, k)) with the factors of :func:`block_cholesky`."""
    tri = jax.scipy.linalg.solve_triangular
    if C.shape[0] == 1:  # dense: two triangular solves, nothing coupling layers
        y = tri(C[0], r[0], lower=True)
        return tri(C[0], y, lower=True, trans=1)[None]

    def fwd(yprev, inp):
        Cl, Gprev, rl = inp
        y = tri(Cl, rl - Gprev.T @ yprev, lower=True)
        return y, y

    Gshift = jnp.concatenate([jnp.zeros_like(G[:1]), G[:-1]])  # G[l-1] for layer l
    _, y = jax.lax.scan(fwd, jnp.zeros_like(r[0]), (C, Gshift, r))

    def bwd(xnext, inp):
        Cl, Gl, yl = inp
        x = tri(Cl, yl - Gl @ xnext, lower=True, trans=1)
        return x, x

    _, x = jax.lax.scan(bwd, jnp.zeros_like(r[0]), (C, G, y), reverse=True)
    return x


class BlockLU(NamedTuple):
    """Factors of :func:`block_lu`: ``M = Lo Up`` with ``Lo`` block lower
    bidiagonal (diagonal: the pivot blocks P[l], below: E[l]) and ``Up``
    unit block upper bidiagonal (above: X[l] = P[l]^-1 F[l])."""

    lu: jnp.ndarray  # (L, k, k) LU factors of the pivot blocks
    piv: jnp.ndarray  # (L, k) their row pivots
    X: jnp.ndarray  # (L, k, k)
    E: jnp.ndarray  # (L, k, k)


def block_lu(D, E, F) -> BlockLU:
    """Factor a general block-tridiagonal matrix:
    ``P[0] = D[0]``, ``P[l] = D[l] - E[l-1] X[l-1]``, ``X[l] = P[l]^-1 F[l]``."""

    def body(Xprev, inp):
        Dl, Eprev, Fl = inp
        lu, piv = jax.scipy.linalg.lu_factor(Dl - Eprev @ Xprev)
        X = jax.scipy.linalg.lu_solve((lu, piv), Fl)
        return X, (lu, piv, X)

    Eshift = jnp.concatenate([jnp.zeros_like(E[:1]), E[:-1]])  # E[l-1] for layer l
    _, (lu, piv, X) = jax.lax.scan(body, jnp.zeros_like(D[0]), (D, Eshift, F))
    return BlockLU(lu=lu, piv=piv, X=X, E=E)


def block_lu_solve(f: BlockLU, r, transpose: bool = False):
    """Solve ``M y = r`` (or ``M^T y = r``), r: (L, k), with :func:`block_lu`'s factors."""
    Eshift = jnp.concatenate([jnp.zeros_like(f.E[:1]), f.E[:-1]])
    Xshift = jnp.concatenate([jnp.zeros_like(f.X[:1]), f.X[:-1]])
    zero = jnp.zeros_like(r[0])
    if not transpose:
        # Lo c = r (forward), then Up y = c (backward)
        def fwd(cprev, inp):
            lu, piv, Ep, rl = inp
            c = jax.scipy.linalg.lu_solve((lu, piv), rl - Ep @ cprev)
            return c, c

        _, c = jax.lax.scan(fwd, zero, (f.lu, f.piv, Eshift, r))

        def bwd(ynext, inp):
            X, cl = inp
            y = cl - X @ ynext
            return y, y

        _, y = jax.lax.scan(bwd, zero, (f.X, c), reverse=True)
        return y

    # M^T = Up^T Lo^T: Up^T a = r (forward), then Lo^T y = a (backward)
    def fwd_t(aprev, inp):
        Xp, rl = inp
        a = rl - Xp.T @ aprev
        return a, a

    _, a = jax.lax.scan(fwd_t, zero, (Xshift, r))

    def bwd_t(ynext, inp):
        lu, piv, El, al = inp
        y = jax.scipy.linalg.lu_solve((lu, piv), al - El.T @ ynext, trans=1)
        return y, y

    _, y = jax.lax.scan(bwd_t, zero, (f.lu, f.piv, f.E, a), reverse=True)
    return y
