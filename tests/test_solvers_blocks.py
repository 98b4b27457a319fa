"""Block-tridiagonal algebra: the block Cholesky against dense numpy solves."""
import jax.numpy as jnp
import numpy as np
import pytest

from stablelego_jax.solvers.blocks import block_cholesky, block_solve, lower_gram

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


@pytest.mark.parametrize("k", [100, 301, 390, 520])
def test_lower_gram_is_the_lower_triangle_of_the_gram_matrix(k):
    """One panel (k < 256), two uneven ones (301: 151 and 150 rows), three (390), four (520)."""
    G = np.random.default_rng(1).normal(size=(k, k))
    P = np.asarray(lower_gram(jnp.asarray(G)))
    np.testing.assert_allclose(np.tril(P), np.tril(G.T @ G), rtol=1e-12, atol=1e-9)
