"""The kernels of one layer's step of the layered factorisation, timed apart, and one LAPACK call that does a step's work (a probe; issue 18).

    python benchmarks/layer_kernels.py [--k 720 624 384] [--repeat 3] [--json FILE]

Run it under ``PJRT_NPROC=1`` and ``PJRT_NPROC=2`` (XLA's CPU pool threads;
LAPACK runs on one OpenBLAS thread either way, ``stablelego_jax.blas``).

``block_cholesky``'s step for a pivot block of ``k`` rows (the soft problem
at 2000 placements: ``k = 720``) is ``C = chol(D - G'G)`` (:func:`lower_gram`
and LAPACK's Cholesky) then ``G = C^-1 E'`` (:func:`lower_solve`: XLA
products), about ``2.2 k^3`` flops. Timed here, jitted, best of ``--repeat``
runs of 10 calls, on random well-conditioned blocks:

* ``step``: today's step; ``gram``, ``chol``, ``lower_solve``: its parts;
* ``trsm``: LAPACK's triangular solve for the same ``G`` (``lax.linalg.triangular_solve``);
* ``dot``: XLA's full product ``G'G`` (``2 k^3`` flops; its GFlop/s is printed);
* ``pair_potrf``: one LAPACK Cholesky of the ``2k`` block ``[[S, E'], [E, D]]``
  (``S = D - G'G`` formed first, as the step does): its blocks are the step's
  ``C``, its ``G'`` and the *next* pivot's factor ``chol(D - G'G)``, so it
  does a step and the next layer's Cholesky in one call (``8/3 k^3`` flops);
  the three blocks are compared with today's (largest relative difference).

Prints one line per ``k`` (and ``--json``: the rows). Not in the library: a
pair of layers per call changes the layer scan, its cuts and the adjoint's
factors; whether it pays depends on the CPU (BENCHMARKS.md, issue 18,
session 63).
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

from stablelego_jax.blas import one_blas_thread  # noqa: E402
from stablelego_jax.solvers.blocks import lower_gram, lower_solve  # noqa: E402


def _best_ms(f, *args, repeat: int) -> float:
    jax.block_until_ready(f(*args))
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(10):
            jax.block_until_ready(f(*args))
        best = min(best, (time.perf_counter() - t0) / 10)
    return 1e3 * best


def _chol(M):
    return jax.lax.linalg.cholesky(M, symmetrize_input=False)


@jax.jit
def step(Gprev, D, E):
    """Today's step (``block_cholesky``'s ``layer`` without cuts)."""
    C = _chol(D - lower_gram(Gprev))
    return C, lower_solve(C, E.T)


@jax.jit
def pair_potrf(Gprev, D, E, Dnext):
    """One Cholesky of the pair block: (C, G, the next pivot's factor)."""
    k = D.shape[0]
    S = D - Gprev.T @ Gprev
    F = _chol(jnp.block([[S, E.T], [E, Dnext]]))
    return F[:k, :k], F[k:, :k].T, F[k:, k:]


def case(k: int, repeat: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((k, 2 * k))
    D = jnp.asarray(A @ A.T / k + 4 * np.eye(k))
    E = jnp.asarray(rng.standard_normal((k, k)) / k)
    Gprev = jnp.asarray(rng.standard_normal((k, k)) / k)
    C, G = step(Gprev, D, E)
    Cn = _chol(D - lower_gram(G))  # the next pivot (the same D) as today's scan forms it
    pc, pg, pn = pair_potrf(Gprev, D, E, D)

    def rel(a, b):
        return float(jnp.max(jnp.abs(jnp.tril(a) - jnp.tril(b))) / jnp.max(jnp.abs(b)))

    gram = jax.jit(lower_gram)
    ls = jax.jit(lambda C, E: lower_solve(C, E.T))
    trsm = jax.jit(lambda C, E: jax.lax.linalg.triangular_solve(C, E.T, left_side=True, lower=True))
    dot = jax.jit(lambda G: G.T @ G)
    chol = jax.jit(_chol)
    t = {"step": _best_ms(step, Gprev, D, E, repeat=repeat),
         "gram": _best_ms(gram, Gprev, repeat=repeat),
         "chol": _best_ms(chol, D, repeat=repeat),
         "lower_solve": _best_ms(ls, C, E, repeat=repeat),
         "trsm": _best_ms(trsm, C, E, repeat=repeat),
         "dot": _best_ms(dot, Gprev, repeat=repeat),
         "pair_potrf": _best_ms(pair_potrf, Gprev, D, E, D, repeat=repeat)}
    return {"k": k, "ms": {n: round(v, 2) for n, v in t.items()},
            "dot_gflops": round(2 * k ** 3 / (t["dot"] * 1e6), 1),
            "pair_potrf_gflops": round(8 * k ** 3 / 3 / (t["pair_potrf"] * 1e6), 1),
            "step_plus_next_chol_ms": round(t["step"] + t["chol"], 2),
            "pair_rel_diff": {"C": rel(pc, C), "G": rel(pg, G), "next C": rel(pn, Cn)}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--k", type=int, nargs="+", default=[720, 624, 384])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    rows = []
    with one_blas_thread():
        for k in a.k:
            r = case(k, a.repeat)
            rows.append(r)
            ms = r["ms"]
            print(f"k={k} PJRT_NPROC={os.environ.get('PJRT_NPROC', '-')}: step {ms['step']} ms (gram {ms['gram']}, "
                  f"chol {ms['chol']}, lower_solve {ms['lower_solve']}); trsm {ms['trsm']}; dot {ms['dot']} "
                  f"({r['dot_gflops']} GFlop/s); pair_potrf {ms['pair_potrf']} ms ({r['pair_potrf_gflops']} GFlop/s) "
                  f"against step + next chol {r['step_plus_next_chol_ms']} ms; pair blocks vs today's: "
                  + ", ".join(f"{n} {v:.1e}" for n, v in r["pair_rel_diff"].items()), flush=True)
    if a.json:
        meta = {"command": "python benchmarks/layer_kernels.py " + " ".join(argv if argv is not None else sys.argv[1:]),
                "machine": f"{platform.machine()} {os.cpu_count()} cores", "pjrt_nproc": os.environ.get("PJRT_NPROC"),
                "date": time.strftime("%Y-%m-%d %H:%M"), "jax": jax.__version__}
        with open(a.json, "w") as fh:
            json.dump({"meta": meta, "rows": rows}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
