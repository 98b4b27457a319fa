"""The reduced Newton matrix of both interior points, assembled by blocks.

Both interior points (the verdict LP of :mod:`.ipm`, the soft problems of
:mod:`.soft_ipm`) reduce each Newton system, in closed form per column and
per brick (its largest-drag variable eliminated), to one symmetric positive
definite matrix over the bricks' 6 equilibrium rows:

    M = A diag(e) A' + sum_b rho_b (A q_b)(A q_b)' + diag(dr)

with A the (scaled) equilibrium operator ((6 n, m): column p's wrench on
its two bricks), ``e`` (m,) the columns' weights, ``q_b`` the weights
``q`` (m,) restricted to brick b's NORMAL columns (those on its bottom,
whose drags its largest-drag variable bounds: ``A q_b`` touches b and the
bricks under it), ``rho`` (n,) and ``dr`` (6 n,) diagonal terms.
:func:`reduced_matrix` returns the function that assembles M's blocks for
:func:`~stablelego_jax.solvers.blocks.block_cholesky`: bricks numbered in
``L`` levels of ``B`` slots (``L = 1``: one dense block), every column
joining slots of one level or two adjacent ones. Three assemblies, by
where a brick's supports (the bricks under its NORMAL columns) lie:

* one block (``L = 1``) without ``supports``: the bricks' vectors
  ``A q_b`` as an (n, 6 n) matrix S, ``S' diag(rho) S`` (the soft
  problems; the verdict LP's dense problems carry supports,
  :func:`~stablelego_jax.solvers.problem.dense_supports`);
* layers (every support in the level just below its brick's): a brick's own
  part of ``A q_b`` is a 6 x 6 block on the diagonal, its product with the
  supports' part an outer product, so one product over each level (the
  supports' part with itself) is all the matrix work;
* slabs and dense problems (``supports`` given: a brick's supports may lie
  in any level next to its own): each brick's vector compacted to its own part and ``K``
  supports' parts, one ``(6 (K + 1))^2`` piece a brick, placed in the same
  scatter as the columns' pieces.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

from .blocks import lower_gram
from .problem import block_windows, gram_plan

__all__ = ["reduced_matrix"]


# a 6-entry window of an (n, 6 B) matrix at (row, column)
_ROW_WINDOWS = jax.lax.ScatterDimensionNumbers(
    update_window_dims=(1,), inserted_window_dims=(0,), scatter_dims_to_operand_dims=(0, 1))


def reduced_matrix(col_brick, coef, normal, n: int, L: int, chunks=None, supports=None, col_slot=None):
    """The assembly of M for one problem's static structure.

    col_brick (m, 2) int: each column's two brick slots (``0..n-1``; ``n``:
    none, e.g. the baseplate); slot 0 is the brick whose bottom a NORMAL
    column is on. coef (m, 2, 6): the columns' scaled wrenches on them.
    normal (m,) bool: the real NORMAL columns (the support in ``q_b``).
    ``n = L B`` slots, slot s in level ``s // B``; ``chunks`` (R, W): columns
    grouped by the pair of slots they join (``m``: none), or None.
    ``supports`` (n, K) and ``col_slot`` (m,): the slab assembly (each
    brick's distinct supports, ``n`` = none, and each NORMAL column's
    support's place among them, ``K``: none); otherwise ``L > 1`` requires
    every support in the level below its brick's (other terms are dropped).

    Returns ``assemble(e, q, rho, dr) -> (D, E)``, e and q (m,), rho (n,), dr
    (n * 6,): the (L, 6 B, 6 B) diagonal blocks and blocks below them of
    M (the layout of :mod:`.blocks`); layered without ``supports``, D is
    exact in its lower triangle (diagonal included), what the block
    Cholesky reads, and partial above it. One block with no ``supports``:
    ``assemble(..., split=True) -> (D, E, P)`` leaves the bricks' rank-one
    terms out of D as their factor P ((n, 6 n), ``M = D + P' P``), for
    :func:`~stablelego_jax.solvers.blocks.cut_cholesky`."""
    col_brick = jnp.minimum(jnp.asarray(col_brick), n)
    m = col_brick.shape[0]
    gram = gram_plan(col_brick, coef, n, L, chunks)
    B, k6 = gram.B, gram.k
    dtype = coef.dtype
    c12 = coef.reshape(m, 12)
    ob, lo = col_brick[:, 0], col_brick[:, 1]
    lay_o, lay_l = ob // B, lo // B
    ok_n = (jnp.asarray(normal) & (ob < n))[:, None]
    real = (lo < n)[:, None]
    own_idx = jnp.where(ok_n[:, 0], ob, n)

    def own_parts(q):
        """(n, 6) each brick's own part of its vector A q_b."""
        return jnp.zeros((n + 1, 6), dtype).at[own_idx].add(q[:, None] * c12[:, :6])[:n]

    def rows6(rows, cols, vals):
        """(n, 6 B): 6-entry windows ``vals`` (N, 6) added at (rows, cols),
        (N,) each; row ``n``: dropped."""
        return jax.lax.scatter_add(jnp.zeros((n, k6), dtype), jnp.stack([rows, cols], 1), vals, _ROW_WINDOWS,
                                   mode=jax.lax.GatherScatterMode.FILL_OR_DROP)

    def down(X):  # (L, ...) -> X[l + 1] at l, zeros at L - 1
        return jnp.concatenate([X[1:], jnp.zeros_like(X[:1])])

    def diag_blocks(dr):
        return jax.vmap(jnp.diag)(dr.reshape(L, k6))

    if supports is not None:
        supports = jnp.asarray(supports)
        K = supports.shape[1]
        # brick b's compact vector [own part; K supports' parts]: its (K + 1)^2 6 x 6 windows in [D; E]
        vb = jnp.concatenate([jnp.arange(n, dtype=supports.dtype)[:, None], supports], 1)  # (n, K + 1)
        sup_idx = block_windows(vb[:, :, None], vb[:, None, :], n, L)
        slot_idx = jnp.where(ok_n[:, 0] & real[:, 0] & (col_slot < K), ob * K + col_slot, n * K)

        def assemble(e, q, rho, dr):
            v = jnp.zeros((n * K + 1, 6), dtype).at[slot_idx].add(q[:, None] * c12[:, 6:])[: n * K]
            vec = jnp.concatenate([own_parts(q), v.reshape(n, 6 * K)], axis=1)  # (n, 6 (K + 1))
            piece = (rho[:, None] * vec)[:, :, None] * vec[:, None, :]
            piece = piece.reshape(n, K + 1, 6, K + 1, 6).transpose(0, 1, 3, 2, 4)
            D, E = gram.blocks(e, extra=(sup_idx, piece))
            return D + diag_blocks(dr), E

        return assemble

    if L > 1:
        below = ok_n & real & (lay_l == lay_o - 1)[:, None]
        w_row, w_col = jnp.where(below[:, 0], ob, n), 6 * (lo % B)
        slots = jnp.arange(n, dtype=col_brick.dtype)
        diag_idx = block_windows(slots, slots, n, L)

        def assemble(e, q, rho, dr):
            o = own_parts(q)
            ro = rho[:, None] * o
            # level l + 1's supports' parts (rows: its bricks, columns: level l's slots), moved
            # down a level before the products (not the (L, k, k) products after them)
            W = down(rows6(w_row, w_col, q[:, None] * c12[:, 6:]).reshape(L, B, k6))
            # their Gram W' diag(rho) W: its lower triangle only, the part the block Cholesky reads
            D0 = lower_gram(W * down(rho.reshape(L, B))[..., None], W)
            E0 = (down(ro.reshape(L, B, 6))[..., None] * W[:, :, None, :]).reshape(L, k6, k6)
            # each brick's 6 x 6 diagonal block rho o o' + diag(dr), with the Gram's windows
            P = ro[:, :, None] * o[:, None, :] + jax.vmap(jnp.diag)(dr.reshape(n, 6))
            return gram.blocks(e, extra=(diag_idx, P), base=(D0, E0))

        return assemble

    # brick b's vector A q_b as row b of S (n, 6 n): each NORMAL column's own part and its support's
    s_row = jnp.concatenate([own_idx, jnp.where(real[:, 0], own_idx, n)])
    s_col = jnp.concatenate([6 * ob, 6 * lo])

    def assemble(e, q, rho, dr, split=False):
        D, E = gram.blocks(e)
        qc = q[:, None] * c12
        S = rows6(s_row, s_col, jnp.concatenate([qc[:, :6], qc[:, 6:]]))
        if split:  # the rank-one terms left as a factor P (n, 6 n): M = D + P' P
            return D + diag_blocks(dr), E, jnp.sqrt(rho)[:, None] * S
        # S' diag(rho) S is symmetric: added as its transpose, which is the order the
        # Cholesky (column-major) reads D in, so no pass reads the product across
        SS = jnp.matmul(S.T * rho[None, :], S)
        return D + SS.T[None] + diag_blocks(dr), E

    return assemble
