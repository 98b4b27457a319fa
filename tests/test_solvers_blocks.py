"""Block-tridiagonal algebra: the block Cholesky against dense numpy solves."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stablelego_jax.solvers.blocks import (PIECE, block_cholesky, block_solve, cut_cholesky, lower_gram, lower_inverse,
                                          lower_solve)

pytestmark = pytest.mark.usefixtures("x64")


def _cut(M, L, k):
    for i in range(L):
        for j in range(L):
            if abs(i - j) > 1:
                M[i * k:(i + 1) * k, j * k:(j + 1) * k] = 0.0
    return M


def _blocks(M, L, k):
    blk = lambda i, j: M[i * k:(i + 1) * k, j * k:(j + 1) * k] if 0 <= j < L and i < L else np.zeros((k, k))  # noqa: E731
    D = np.stack([blk(l, l) for l in range(L)])
    E = np.stack([blk(l + 1, l) for l in range(L)])
    return D, E


@pytest.mark.parametrize("L,k", [(1, 5), (4, 3), (7, 6), (3, 300)])
def test_block_cholesky_solves_the_block_tridiagonal_system(L, k):
    rng = np.random.default_rng(0)
    N = L * k
    X = rng.normal(size=(N, N))
    M = _cut(X @ X.T, L, k) + N * np.eye(N)  # diagonally dominant after the cut: still SPD
    D, E = _blocks(M, L, k)
    C, G = block_cholesky(jnp.asarray(D), jnp.asarray(E))
    r = rng.normal(size=N)
    x = block_solve(C, G, jnp.asarray(r).reshape(L, k)).reshape(-1)
    np.testing.assert_allclose(np.asarray(x), np.linalg.solve(M, r), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("L,B,K", [(3, 4, 1), (4, 9, 3), (2, 50, 2)])
def test_block_cholesky_with_sparse_e_gives_the_same_factors(L, B, K):
    """``below=``: E[l] holds only each brick's blocks at its neighbours in
    the level below (at most K, some none); the factor, G and the solve are
    those of the dense step, to rounding, with pivot rows scaled over
    1e-3..1e3 (B = 50: 300-row blocks, the inverse split in blocks)."""
    rng = np.random.default_rng(2)
    k = 6 * B
    below = np.full((L, B, K), B)
    for l in range(L - 1):
        for i in range(B):
            q = rng.integers(1, K + 1)
            below[l, i, :q] = rng.choice(B, q, replace=False)
    mask = np.zeros((L * k, L * k), bool)
    for l in range(L):
        mask[l * k:(l + 1) * k, l * k:(l + 1) * k] = True
    for l in range(L - 1):
        for i in range(B):
            for j in below[l, i]:
                if j < B:
                    r, c = (l + 1) * k + 6 * i, l * k + 6 * j
                    mask[r:r + 6, c:c + 6] = mask[c:c + 6, r:r + 6] = True
    X = rng.normal(size=(L * k, L * k))
    S = 10.0 ** rng.uniform(-3, 3, size=L * k)
    M = np.where(mask, X @ X.T, 0.0)
    M = S[:, None] * (M + np.diag(np.abs(M).sum(1))) * S[None, :]  # SPD (diagonally dominant), rows scaled
    D, E = _blocks(M, L, k)
    C0, G0 = block_cholesky(jnp.asarray(D), jnp.asarray(E))
    C1, G1 = block_cholesky(jnp.asarray(D), jnp.asarray(E), below=jnp.asarray(below))
    for a, b in ((C0, C1), (G0, G1)):
        a, b = np.asarray(a), np.asarray(b)
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-9 * np.abs(a).max())
    r = rng.normal(size=L * k)
    x = block_solve(C1, G1, jnp.asarray(r).reshape(L, k)).reshape(-1)
    want = np.linalg.solve(M, r)
    np.testing.assert_allclose(np.asarray(x), want, rtol=1e-7, atol=1e-9 * np.abs(want).max())


@pytest.mark.parametrize("k", [5, PIECE, 2 * PIECE + 1, 300])
def test_lower_inverse_is_the_inverse(k):
    X = np.random.default_rng(3).normal(size=(k, k))
    C = np.linalg.cholesky(X @ X.T + k * np.eye(k))
    got = np.asarray(lower_inverse(jnp.asarray(C)))
    assert np.all(np.triu(got, 1) == 0.0)
    np.testing.assert_allclose(got @ C, np.eye(k), atol=1e-12)


@pytest.mark.parametrize("k", [100, 301, 390, 520])
def test_lower_gram_is_the_lower_triangle_of_the_gram_matrix(k):
    """One panel (k < 256), two uneven ones (301: 151 and 150 rows), three (390), four (520)."""
    G = np.random.default_rng(1).normal(size=(k, k))
    P = np.asarray(lower_gram(jnp.asarray(G)))
    np.testing.assert_allclose(np.tril(P), np.tril(G.T @ G), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("k", [100, 390])
def test_lower_gram_of_two_batched_factors_is_the_lower_triangle_of_their_product(k):
    """``lower_gram(G, H)`` over a batch dimension: tril of each ``G[i]' H[i]`` (G, H of 30 rows)."""
    rng = np.random.default_rng(2)
    G, H = rng.normal(size=(3, 30, k)), rng.normal(size=(3, 30, k))
    P = np.asarray(lower_gram(jnp.asarray(G), jnp.asarray(H)))
    assert P.shape == (3, k, k)
    for i in range(3):
        np.testing.assert_allclose(np.tril(P[i]), np.tril(G[i].T @ H[i]), rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("k,r", [(5, 3), (PIECE, 7), (192, 192), (PIECE * 3 + 10, 40)])
def test_lower_solve_is_the_triangular_solve(k, r):
    """lower_solve(C, R) = C^-1 R for the Cholesky factor C of an SPD
    matrix, whether k is below, at, a multiple of, or between multiples of
    its piece size; with rows scaled over 1e-6..1e6 (as an interior point's
    last Newton matrices) its componentwise backward error is at rounding
    level, as substitution's."""
    rng = np.random.default_rng(1)
    X = rng.normal(size=(k, k))
    S = 10.0 ** rng.uniform(-6, 6, size=k)
    C = np.linalg.cholesky(S[:, None] * (X @ X.T + k * np.eye(k)) * S[None, :])
    R = rng.normal(size=(k, r))
    got = np.asarray(lower_solve(jnp.asarray(C), jnp.asarray(R)))
    sub = np.asarray(jax.scipy.linalg.solve_triangular(jnp.asarray(C), jnp.asarray(R), lower=True))
    err = lambda Y: (np.abs(C @ Y - R) / (np.abs(C) @ np.abs(Y) + np.abs(R))).max()  # noqa: E731
    assert err(sub) < 1e-14 and err(got) < 1e-14


@pytest.mark.parametrize("live", [6, 150, 240, 300])
def test_cut_cholesky_factors_the_leading_rows_as_the_full_factor_does(live):
    """``D + P' P`` whose rows from ``live`` on are diagonal and decoupled
    (padding bricks): the factor of the smallest cut holding ``live`` rows,
    with the square root of the diagonal after it, is the full factor."""
    rng = np.random.default_rng(1)
    k, n = 300, 50
    X = rng.normal(size=(k, k))
    D = X @ X.T + k * np.eye(k)
    D[live:, :] = 0.0
    D[:, live:] = 0.0
    D[np.arange(live, k), np.arange(live, k)] = rng.uniform(1.0, 3.0, size=k - live)
    P = rng.normal(size=(n, k))
    P[-(-live // 6):, :] = 0.0  # the padding bricks' rows
    P[:, live:] = 0.0
    C, G = jax.jit(cut_cholesky, static_argnums=3)(jnp.asarray(D)[None], jnp.asarray(P), live, (120, 240, 300))
    np.testing.assert_allclose(np.asarray(C[0]), np.linalg.cholesky(D + P.T @ P), rtol=1e-10, atol=1e-10)
    assert C.shape == (1, k, k) and not np.asarray(G).any()


def test_block_cholesky_cut_per_layer_is_the_full_factor():
    """Layers whose slots from ``live[l]`` on are padding (decoupled,
    diagonal, no coupling to the next layers): each layer factored at the
    smallest cut holding its and its neighbours' live rows gives the full
    factor, and the system's solution."""
    rng = np.random.default_rng(3)
    L, k = 6, 96
    live = np.array([90, 30, 20, 12, 10, 40])  # cuts 96, 96, 48, 24, 48, 48
    N = L * k
    X = rng.normal(size=(N, N))
    M = _cut(X @ X.T, L, k) + N * np.eye(N)
    pad = np.concatenate([l * k + np.arange(live[l], k) for l in range(L)])
    diag = rng.uniform(1.0, 3.0, size=len(pad))
    M[pad, :] = 0.0
    M[:, pad] = 0.0
    M[pad, pad] = diag
    D, E = _blocks(M, L, k)
    full = jax.jit(block_cholesky)(jnp.asarray(D), jnp.asarray(E))
    fn = jax.jit(block_cholesky, static_argnums=3)
    C, G = fn(jnp.asarray(D), jnp.asarray(E), jnp.asarray(live, jnp.int32), (24, 48, 72, 96))
    np.testing.assert_allclose(np.asarray(C), np.asarray(full[0]), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.asarray(G), np.asarray(full[1]), rtol=1e-10, atol=1e-12)
    r = rng.normal(size=N)
    x = block_solve(C, G, jnp.asarray(r).reshape(L, k)).reshape(-1)
    np.testing.assert_allclose(np.asarray(x), np.linalg.solve(M, r), rtol=1e-10, atol=1e-12)
