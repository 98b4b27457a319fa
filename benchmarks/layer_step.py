"""One layer's step of the layered factorisation, today's against a step through the pivot block's inverse (a probe).

    python benchmarks/layer_step.py [--slots 104 56 32 16] [--supports 1 2 4] [--repeat 3] [--json FILE]

The verdict LP's reduced matrix is block tridiagonal (:mod:`stablelego_jax.solvers.blocks`):
``k = 6 B`` rows a layer of ``B`` slots. The block below the diagonal, ``E``, couples a brick
with the bricks under it (its supports), so it holds at most ``K`` 6 x 6 blocks a row of
bricks: a unit cube has ``K = 1`` (every brick on one brick), walls of staggered bricks 2-4.
Two ways to form one layer's step, timed after compile (jitted, best of ``--repeat`` runs of
10 calls, one thread):

* ``today`` (``block_cholesky``): ``C = chol(D - G'G)`` with ``lower_gram``, then
  ``G = C^-1 E'`` with ``lower_solve`` (dense in E): about ``2.6 k^3`` flops;
* ``inverse`` (not in the library): ``C = chol(D - S)``, the triangular inverse ``Li = C^-1``
  (``blocks.lower_inverse``), ``Mi = Li' Li`` (panels that skip ``Li``'s zero rows), and the
  next Schur update ``S = E Mi E'`` from E's ``K`` blocks a brick (gathers of ``Mi`` at the
  supports): about ``1.3 k^3`` flops plus the gathers, which grow with ``K``.

Random SPD ``D`` and ``E`` with ``K`` supports a brick; the two steps' next Schur updates are
compared (relative difference). Prints one line per case (and ``--json``: the rows).

On these well-conditioned blocks both agree to rounding; in the interior point the ``E Mi E'``
update is not usable: forming ``Li' Li`` first loses the cancellation inside ``G = Li E'``, and
the unit cube's solve diverged (BENCHMARKS.md, issue 17, session 48). The library keeps the
Gram step's update and forms only ``G`` from the inverse (``block_cholesky(below=)``).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_enable_x64", True)

from stablelego_jax.solvers.blocks import below_product, lower_gram, lower_inverse, lower_solve  # noqa: E402


def tri_gram(Li, panels: int = 4):
    """Lower triangle of ``Li' Li`` for a lower triangular Li: a panel of columns
    ``[a, e)`` is zero above row a."""
    k = Li.shape[0]
    w = -(-k // panels)
    strips = [Li[a:, a:min(k, a + w)].T @ Li[a:, :min(k, a + w)] for a in range(0, k, w)]
    return jnp.concatenate([jnp.pad(s, ((0, 0), (0, k - s.shape[1]))) for s in strips])


def case(B: int, K: int, repeat: int, seed: int = 0) -> dict:
    k = 6 * B
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((k, 2 * k))
    D = A @ A.T / k + np.eye(k)
    sup = np.stack([(np.arange(B) + 7 * q) % B for q in range(K)], 1)  # K distinct supports a brick
    Ec = rng.standard_normal((B, K, 6, 6)) * 0.1
    E = np.zeros((B, 6, B, 6))
    for q in range(K):
        E[np.arange(B), :, sup[:, q], :] += Ec[:, q]
    E = E.reshape(k, k)
    G0 = np.linalg.solve(np.linalg.cholesky(D), E.T)

    def today(Gprev, Dl, El):
        C = jax.lax.linalg.cholesky(Dl - lower_gram(Gprev), symmetrize_input=False)
        return C, lower_solve(C, El.T)

    def inverse(Sprev, Dl, Ec, sup):
        C = jax.lax.linalg.cholesky(Dl - Sprev, symmetrize_input=False)
        Li = lower_inverse(C)
        Mi = tri_gram(Li)
        Mi = jnp.tril(Mi) + jnp.tril(Mi, -1).T
        U = below_product(Mi, Ec, sup).reshape(B, 6, k)  # Mi E', its rows by brick
        S = jnp.einsum("iqba,iqac->ibc", Ec, U[sup]).reshape(k, k)
        return C, Li, S

    f_today, f_inv = jax.jit(today), jax.jit(inverse)
    a_today = (jnp.asarray(G0), jnp.asarray(D), jnp.asarray(E))
    a_inv = (jnp.asarray(G0.T @ G0), jnp.asarray(D), jnp.asarray(Ec), jnp.asarray(sup))
    G1 = np.asarray(f_today(*a_today)[1])
    S1 = G1.T @ G1
    diff = float(np.abs(S1 - np.asarray(f_inv(*a_inv)[2])).max() / np.abs(S1).max())
    best = {}
    for _ in range(repeat):
        for name, f, a in (("today", f_today, a_today), ("inverse", f_inv, a_inv)):
            jax.block_until_ready(f(*a))
            t0 = time.perf_counter()
            for _ in range(10):
                r = f(*a)
            jax.block_until_ready(r)
            best[name] = min(best.get(name, np.inf), (time.perf_counter() - t0) / 10)
    return {"slots": B, "rows": k, "supports": K, "today_ms": 1e3 * best["today"],
            "inverse_ms": 1e3 * best["inverse"], "ratio": best["inverse"] / best["today"], "schur_rel_diff": diff}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--slots", type=int, nargs="+", default=[104, 56, 32, 16])
    ap.add_argument("--supports", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", help="write the rows here")
    a = ap.parse_args()
    rows = []
    for B in a.slots:
        for K in a.supports:
            r = case(B, K, a.repeat)
            rows.append(r)
            print(f"B={B:4d} k={r['rows']:4d} K={K}: today {r['today_ms']:7.2f} ms, inverse {r['inverse_ms']:7.2f} ms,"
                  f" ratio {r['ratio']:.2f}, Schur difference {r['schur_rel_diff']:.1e}", flush=True)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"rows": rows, "machine": platform.processor() or platform.machine(),
                       "date": time.strftime("%Y-%m-%d %H:%M"), "jax": jax.__version__}, fh, indent=1)


if __name__ == "__main__":
    main()
