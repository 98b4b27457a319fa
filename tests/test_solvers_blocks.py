"""Block-tridiagonal algebra: Cholesky and LU against dense numpy solves."""
import jax.numpy as jnp
import numpy as np
import pytest

from stablelego_jax.solvers.blocks import block_cholesky, block_lu, block_lu_solve, block_solve

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
    F = np.stack([blk(l, l + 1) for l in range(L)])
    return D, E, F


@pytest.mark.parametrize("L,k", [(1, 5), (4, 3), (7, 6)])
def test_block_cholesky_solves_the_block_tridiagonal_system(L, k):
    rng = np.random.default_rng(0)
    N = L * k
    X = rng.normal(size=(N, N))
    M = _cut(X @ X.T, L, k) + N * np.eye(N)  # diagonally dominant after the cut: still SPD
    D, E, _ = _blocks(M, L, k)
    C, G = block_cholesky(jnp.asarray(D), jnp.asarray(E))
    r = rng.normal(size=N)
    x = block_solve(C, G, jnp.asarray(r).reshape(L, k)).reshape(-1)
    np.testing.assert_allclose(np.asarray(x), np.linalg.solve(M, r), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("L,k", [(1, 4), (5, 3), (6, 7)])
@pytest.mark.parametrize("transpose", [False, True])
def test_block_lu_solves_a_nonsymmetric_system_and_its_transpose(L, k, transpose):
    rng = np.random.default_rng(L * k)
    N = L * k
    M = _cut(rng.normal(size=(N, N)), L, k) + 2 * np.sqrt(N) * np.eye(N)
    # a pivot block that needs row exchanges inside it
    M[:2, :2] = [[0.0, 1.0], [1.0, 0.0]] if k >= 2 else M[:2, :2]
    D, E, F = _blocks(M, L, k)
    f = block_lu(jnp.asarray(D), jnp.asarray(E), jnp.asarray(F))
    r = rng.normal(size=N)
    x = block_lu_solve(f, jnp.asarray(r).reshape(L, k), transpose=transpose).reshape(-1)
    ref = np.linalg.solve(M.T if transpose else M, r)
    np.testing.assert_allclose(np.asarray(x), ref, rtol=1e-9, atol=1e-10)
