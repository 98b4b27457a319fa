"""Block-tridiagonal linear algebra: the layered factorisation of both interior points.

Bricks numbered layer by layer (``L`` layers of ``B`` slots) make every
reduced Newton matrix of Eq. 9 block tridiagonal with ``(k, k)`` blocks,
``k = 6 B``: a force column joins bricks of one layer or of two adjacent
layers. Both interior points factorise it with a ``lax.scan`` over the
layers, ``O(L k^3)`` instead of ``O((L k)^3)``:

:func:`block_cholesky` / :func:`block_solve`, for the symmetric positive
definite reduced matrices of :mod:`.newton` (the verdict LP of :mod:`.ipm`
and, scaled by the bricks' weights, the soft problems of :mod:`.soft_ipm`).

Block layout: ``D`` (L, k, k) diagonal blocks, ``E`` (L, k, k) with
``E[l]`` = block (l+1, l) (below the diagonal; ``E[L-1]`` unused); the
blocks above are ``E[l]'``.
Right-hand sides are (L, k).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["block_cholesky", "block_solve", "cut_cholesky", "layer_cuts", "layer_picks", "lower_gram", "lower_solve",
           "lower_inverse", "below_blocks", "below_product"]

#: rows of the diagonal pieces :func:`lower_solve` inverts (every block size
#: ``6 B``, B a multiple of 8, is a multiple of it)
PIECE = 48


#: Slots between the sizes :func:`layer_cuts` offers.
CUT_STEP = 8


def layer_cuts(B: int) -> tuple:
    """The sizes (rows, 6 per slot) :func:`block_cholesky` may cut a layer
    of ``B`` slots to: every multiple of :data:`CUT_STEP` slots below B,
    then B (one compiled branch each)."""
    return tuple(6 * b for b in range(CUT_STEP, B, CUT_STEP)) + (6 * B,)


def layer_picks(live, cuts, xp=jnp):
    """(L,) index into ``cuts`` of the size :func:`block_cholesky` forms
    each layer's step at: the smallest cut that holds the live rows of the
    layer and of both its neighbours (the Schur product reads the previous
    layer's rows, ``G`` the next one's). live (L,) int; xp: jax.numpy
    (traced) or numpy (a planner's estimate)."""
    zero = xp.zeros((1,), live.dtype)
    need = xp.maximum(live, xp.maximum(xp.concatenate([zero, live[:-1]]), xp.concatenate([live[1:], zero])))
    return xp.minimum(xp.searchsorted(xp.asarray(cuts), need), len(cuts) - 1)


def lower_gram(G, H=None):
    """``G' H`` ((..., k, k); H default G) where a Cholesky reads it: its
    lower triangle, diagonal included (above it: zeros, or the full product
    for one panel), one product per panel of rows, ``G[..., panel]'
    H[..., :end]``, about ``(1 + 1 / p) k^3`` flops for ``p`` panels instead
    of the full product's ``2 k^3`` (G (k, k)); ``p = min(4, k // 128)``
    (one panel below 256 rows, where smaller products run slower). Leading
    dimensions of G and H (equal) are batch dimensions."""
    H = G if H is None else H
    k = G.shape[-1]
    p = max(1, min(4, k // 128))
    if p == 1:
        return jnp.swapaxes(G, -1, -2) @ H
    w = -(-k // p)
    strips = [jnp.swapaxes(G[..., a:min(k, a + w)], -1, -2) @ H[..., :min(k, a + w)] for a in range(0, k, w)]
    pad = [(0, 0)] * (G.ndim - 2)
    return jnp.concatenate([jnp.pad(s, pad + [(0, 0), (0, k - s.shape[-1])]) for s in strips], axis=-2)


def lower_inverse(C, leaf: int = 2 * PIECE):
    """``C^-1`` of a lower triangular C ((k, k)), lower triangular, by
    2 x 2 blocks split at a multiple of :data:`PIECE` rows:
    ``[[A, 0], [B, D]]^-1 = [[A^-1, 0], [-D^-1 B A^-1, D^-1]]``, down to
    blocks of at most ``leaf`` rows (a triangular solve with the identity).
    About ``2 k^3 / 3`` flops in products; 5.4-6.5 ms at k = 624 on one
    core, where LAPACK's solve against the identity took 5.7-7.1 ms and
    :func:`lower_solve` of 624 columns 10.9 ms (BENCHMARKS.md, issue 17,
    sessions 47-48)."""
    n = C.shape[0]
    if n <= leaf:
        return jax.scipy.linalg.solve_triangular(C, jnp.eye(n, dtype=C.dtype), lower=True)
    h = -(-(n // 2) // PIECE) * PIECE
    Ai, Di = lower_inverse(C[:h, :h], leaf), lower_inverse(C[h:, h:], leaf)
    return jnp.concatenate([jnp.concatenate([Ai, jnp.zeros((h, n - h), C.dtype)], 1),
                            jnp.concatenate([-(Di @ (C[h:, :h] @ Ai)), Di], 1)])


def below_blocks(El, below):
    """(B, K, 6, 6) the blocks of ``El`` ((6 B, 6 B): block (l + 1, l),
    rows the bricks of level l + 1) at each brick's neighbours in level l,
    ``below`` ((B, K) slots of level l, ``B`` = none: a zero block)."""
    B = below.shape[0]
    E4 = El.reshape(B, 6, B, 6).transpose(0, 2, 1, 3)
    return E4.at[jnp.arange(B)[:, None], below].get(mode="fill", fill_value=0.0)


def below_product(X, Ec, below):
    """``X E'`` ((k, 6 B)) for X (k, 6 B) and E given by its blocks ``Ec``
    ((B, K, 6, 6), :func:`below_blocks`) at ``below`` ((B, K)): column
    ``6 j + d`` sums X's 6 columns of each of brick j's neighbours times
    their block's row d. ``O(36 K k B)`` flops, not E's dense ``2 (6 B)^3``."""
    k, B = X.shape[0], below.shape[0]
    Xc = X.reshape(k, B, 6).at[:, below].get(mode="fill", fill_value=0.0)  # (k, B, K, 6)
    return jnp.einsum("rjqc,jqdc->rjd", Xc, Ec).reshape(k, 6 * B)


def lower_solve(C, R):
    """``C^-1 R`` for a lower triangular C ((k, k)) and R ((k, r)), by
    pieces of :data:`PIECE` rows, top down: a piece's rows of R less C's
    rows left of the piece times the result so far, times the inverse of
    its diagonal piece (a triangular solve with the identity). Products
    instead of one LAPACK triangular solve: 1.4-2x faster for k = 96-720
    on one CPU core (BENCHMARKS.md, session 31)."""
    k = C.shape[0]
    X = []
    for a in range(0, k, PIECE):
        b = min(k, a + PIECE)
        r = R[a:b] if a == 0 else R[a:b] - C[a:b, :a] @ jnp.concatenate(X)
        inv = jax.scipy.linalg.solve_triangular(C[a:b, a:b], jnp.eye(b - a, dtype=C.dtype), lower=True)
        X.append(inv @ r)
    return jnp.concatenate(X)


def block_cholesky(D, E, live=None, cuts=(), below=None):
    """Factor a block-tridiagonal SPD matrix (``F = E^T``).
    Returns (C, G): C[l] lower Cholesky factor of the l-th pivot block,
    G[l] = C[l]^-1 E[l]'. One layer (``L = 1``, a dense matrix): one
    Cholesky factor and G = 0, with no triangular solve for it. Each pivot
    block's Cholesky reads its lower triangle only (:func:`lower_gram`
    forms no more of the Schur update).

    below ((L, B, K) int, ``k = 6 B``, or None): the only nonzero 6 x 6
    blocks of E[l] are each brick of level l + 1's at ``below[l]``, its
    neighbours in level l (``B``: none). Then ``G = C^-1 E'`` is formed
    from the pivot block's inverse (:func:`lower_inverse`) and E's blocks
    (:func:`below_product`): about ``2 k^3 / 3`` flops instead of
    :func:`lower_solve`'s ``k^3`` against a dense E. The unit cube's
    solve took 0.84-0.99x the time (BENCHMARKS.md, issue 17, session 48).
    The same numbers to rounding. Not with ``live``.

    live ((L,) int, traced) and cuts (static sizes, ascending, the last
    ``k``): the rows of layer l from ``live[l]`` on are decoupled and
    diagonal in D[l] and empty in E (padding slots after the real ones).
    Each layer's step (Schur update, Cholesky, ``G``) is then formed, by
    ``lax.switch``, at the smallest cut that holds the live rows of the
    layer and of both its neighbours (:func:`layer_picks`), and the rest of its factor is the
    square root of D's diagonal: the numbers of the full factor, with
    about ``sum_l cut_l^3 / (L k^3)`` of its flops (one branch per cut
    compiled). For an unbatched solve only: under ``vmap`` every branch
    runs."""
    if D.shape[0] == 1:
        # the lower triangle as assembled (symmetric): symmetrising it was one more
        # transposing pass over the matrix
        return jax.lax.linalg.cholesky(D, symmetrize_input=False), jnp.zeros_like(D)

    def layer(Gprev, Dl, El, bl=None):
        C = jax.lax.linalg.cholesky(Dl - lower_gram(Gprev), symmetrize_input=False)
        if bl is None:
            return C, lower_solve(C, El.T)
        # E's blocks with the inverse, not the inverse's Gram Ci' Ci sandwiched between
        # them as the Schur update: that product lost the cancellation inside G, and an
        # interior point of unit bricks diverged (its factors 5e-8 to 3e-7 of their largest
        # entry off by the third and fourth layers; BENCHMARKS.md, session 48)
        return C, below_product(lower_inverse(C), below_blocks(El, bl), bl)

    if below is not None and live is not None:
        raise ValueError("block_cholesky: below= does not cut layers (live=)")

    if live is None or len(cuts) < 2:
        def body(Gprev, inp):
            C, G = layer(Gprev, *inp)
            return G, (C, G)

        _, (C, G) = jax.lax.scan(body, jnp.zeros_like(D[0]), (D, E) if below is None else (D, E, jnp.asarray(below)))
        return C, G

    k = D.shape[-1]

    def branch(c):
        def f(Gprev, Dl, El):
            # Gprev is zero outside its previous and this layer's live rows, El outside
            # this and the next layer's: every product stays inside the leading c rows
            Cc, Gc = layer(Gprev[:c, :c], Dl[:c, :c], El[:c, :c])
            rest = jnp.where(jnp.arange(k) < c, 0.0, jnp.sqrt(jnp.diagonal(Dl)))
            return jnp.diag(rest).at[:c, :c].set(Cc), jnp.zeros_like(Dl).at[:c, :c].set(Gc)
        return f if c < k else layer

    pick = layer_picks(live, cuts)
    branches = [branch(c) for c in cuts]

    def cut_body(Gprev, inp):
        Dl, El, i = inp
        C, G = jax.lax.switch(i, branches, Gprev, Dl, El)
        return G, (C, G)

    _, (C, G) = jax.lax.scan(cut_body, jnp.zeros_like(D[0]), (D, E, pick))
    return C, G


def cut_cholesky(D, P, live, cuts):
    """:func:`block_cholesky` of one dense block ``M = D[0] + P' P`` (D (1,
    k, k), P (n, k), or None: ``M = D[0]``) whose rows from ``live`` on (a
    traced count) are decoupled and diagonal in D and empty in P (padding
    bricks after the real ones): the product and the factor are formed for the smallest cut
    of ``cuts`` (static sizes, ascending, the last ``k``) that holds
    ``live`` rows, by ``lax.switch``, and the rest of the factor is the
    square root of D's diagonal. A 57-brick layout padded to 120 bricks
    factors 342 rows, not 720 ((120 / 57)^3 = 9x fewer flops). For an
    unbatched solve only: under ``vmap`` every branch runs."""
    k = D.shape[-1]
    rest = jnp.sqrt(jnp.diagonal(D[0]))

    def branch(c):
        def f(D, P, rest):
            if P is None:  # the rank-one terms are in D already
                Cc = jax.lax.linalg.cholesky(D[0, :c, :c], symmetrize_input=False)
            else:
                Pc = P[: c // 6, :c]
                Cc = jax.lax.linalg.cholesky(D[0, :c, :c] + (Pc.T @ Pc).T, symmetrize_input=False)
            C = jnp.diag(jnp.where(jnp.arange(k) < c, 0.0, rest))
            return C.at[:c, :c].set(Cc)
        return f

    i = jnp.searchsorted(jnp.asarray(cuts), live)
    C = jax.lax.switch(jnp.minimum(i, len(cuts) - 1), [branch(c) for c in cuts], D, P, rest)
    return C[None], jnp.zeros_like(D)


def _tri(C, r, trans):
    """``C^-1 r`` (``trans``: ``C'^-1 r``) for a lower triangular C (k, k)
    stored row-major: LAPACK is handed ``C'`` (upper, the same buffer read
    column-major) with the other transpose flag, so that XLA copies no
    block into column-major order for one right-hand side (a 720-row
    block solve 19 ms instead of 29; the same numbers)."""
    return jax.scipy.linalg.solve_triangular(C.T, r, lower=False, trans=1 - trans)


def block_solve(C, G, r):
    """Solve M y = r (r: (L, k)) with the factors of :func:`block_cholesky`."""
    if C.shape[0] == 1:  # dense: two triangular solves, nothing coupling layers
        return _tri(C[0], _tri(C[0], r[0], 0), 1)[None]

    def fwd(t, inp):  # t = G[l-1]' y[l-1], carried: no shifted copy of G
        Cl, Gl, rl = inp
        y = _tri(Cl, rl - t, 0)
        # y' G, not G' y: XLA's CPU code transposed the (k, k) block into a copy for
        # G' y on every layer of every solve (768 rows: 1.47 ms a product against 0.40)
        return y @ Gl, y

    _, y = jax.lax.scan(fwd, jnp.zeros_like(r[0]), (C, G, r))

    def bwd(xnext, inp):
        Cl, Gl, yl = inp
        x = _tri(Cl, yl - Gl @ xnext, 1)
        return x, x

    _, x = jax.lax.scan(bwd, jnp.zeros_like(r[0]), (C, G, y), reverse=True)
    return x
