"""The layered factorisation's floor: one block Cholesky of L layers of k rows.

    python benchmarks/block_cholesky.py [--layers 20] [--rows 600 672 768] [--repeat 3]

Times :func:`stablelego_jax.solvers.blocks.block_cholesky` (jitted, after
compile, best of ``--repeat``) on a random SPD block-tridiagonal matrix of
``--layers`` blocks of each ``--rows`` size, and its three pieces on one
block: the Cholesky factor, the triangular solve ``C^-1 E'`` (LAPACK's,
and :func:`~stablelego_jax.solvers.blocks.lower_solve`'s by pieces, which
``block_cholesky`` uses) and the product G'G, with their rates in GFLOP/s
(k^3/3, k^3 and 2 k^3 flops). A soft problem of
2000 placements over 20 layers of the bunny (issue 18) has blocks of
6 x 128 = 768 rows, and its loss + gradient takes about 13 factorisations.
Set ``OPENBLAS_NUM_THREADS`` and ``PJRT_NPROC`` to compare thread counts.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import jax  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_enable_x64", True)

import stablelego_jax  # noqa: E402,F401  (the package's thread settings)
from stablelego_jax.solvers.blocks import block_cholesky, lower_solve  # noqa: E402


def best(f, *args, repeat=3):
    jax.block_until_ready(f(*args))
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(f(*args))
        out.append(time.perf_counter() - t0)
    return min(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--layers", type=int, default=20)
    ap.add_argument("--rows", type=int, nargs="+", default=[600, 672, 768])
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    tri = jax.jit(lambda C, B: jax.scipy.linalg.solve_triangular(C, B, lower=True))
    for k in a.rows:
        X = rng.standard_normal((a.layers, k, k)) * 0.01
        D = np.einsum("lij,lkj->lik", X, X) + 5 * np.eye(k)
        E = rng.standard_normal((a.layers, k, k)) * 0.01
        t_all = best(jax.jit(block_cholesky), D, E, repeat=a.repeat)
        t_ch = best(jax.jit(jax.numpy.linalg.cholesky), D[0], repeat=a.repeat)
        C = jax.numpy.linalg.cholesky(D[0])
        t_tr = best(tri, C, E[0].T, repeat=a.repeat)
        t_ls = best(jax.jit(lower_solve), C, E[0].T, repeat=a.repeat)
        t_mm = best(jax.jit(lambda G: G.T @ G), E[0], repeat=a.repeat)
        print(f"k {k}: block_cholesky ({a.layers} layers) {t_all:.3f} s; one block: cholesky {t_ch * 1e3:.1f} ms "
              f"({k ** 3 / 3 / t_ch / 1e9:.1f} GFLOP/s), triangular solve {t_tr * 1e3:.1f} ms "
              f"({k ** 3 / t_tr / 1e9:.1f}), by pieces {t_ls * 1e3:.1f} ms ({k ** 3 / t_ls / 1e9:.1f}), "
              f"G'G {t_mm * 1e3:.1f} ms ({2 * k ** 3 / t_mm / 1e9:.1f})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
