"""LAPACK calls side by side for XLA's CPU pool (stablelego_jax.blas), the
one program of tests/test_blas.py and benchmarks/pool_deadlock.py:
:func:`command` runs it in a fresh interpreter; it prints "done" when every
call has returned. A call: four independent triangular solves (and, with
``factorise``, four Cholesky factorisations) of ``n x n`` matrices, batched
``batch`` at a time (0: unbatched), in one jitted program, waited on."""
from __future__ import annotations

import sys

PROGRAM = """
import sys
package, B, n, calls, factorise = (int(a) for a in sys.argv[1:6])
if package:
    import stablelego_jax  # noqa: F401  (the guard runs on import)
import jax, jax.numpy as jnp
from jax.scipy.linalg import solve_triangular
jax.config.update("jax_enable_x64", True)
shape = (B, n, n) if B else (n, n)
T = (lambda a: a.transpose(0, 2, 1)) if B else (lambda a: a.T)
A = [jax.random.normal(k, shape) for k in jax.random.split(jax.random.key(0), 4)]
L = [jnp.linalg.cholesky(a @ T(a) + n * jnp.eye(n)) for a in A]


def term(i, Ai, Li, x):
    t = solve_triangular(Li, x * (i + 1), lower=True).sum()
    return t + jnp.linalg.cholesky(Ai @ T(Ai) + n * jnp.eye(n)).sum() if factorise else t


f = jax.jit(lambda A, L, x: sum(term(i, Ai, Li, x) for i, (Ai, Li) in enumerate(zip(A, L))))
x = jnp.ones(shape)
for i in range(calls):
    float(f(A, L, x + i))
print("done")
"""


def command(batch: int, n: int, calls: int, factorise: bool = True, package: bool = True) -> list:
    """The argv that runs :data:`PROGRAM` (``package``: import stablelego_jax
    first, so that its pool guard runs)."""
    return [sys.executable, "-c", PROGRAM, str(int(package)), str(batch), str(n), str(calls), str(int(factorise))]
