"""Where one interior-point iteration's time goes, for one bucket of layouts
(issue 17, item 3: a profile of the batched solve).

Usage:
  python benchmarks/iteration_parts.py --key layered,16,12 [--inputs DIR ...] [--batch 32] [--repeat 5]
  python benchmarks/iteration_parts.py --file LAYOUT.json

The layouts of ``--inputs`` (default: ``benchmarks/results/shard1000``,
made by ``benchmarks/make_shard.py``) whose bucket (``solve_plan``) is
``--key`` are padded to one shape as ``score`` pads a bucket (common
columns, contact slots and column chunks; the batch filled up to
``--batch`` with copies of the last), or ``--file`` alone. Timed, jitted
and ``vmap``-ed over the batch, best of ``--repeat``: the whole solve (ms
per iteration of the batch: the solve over its largest iteration count),
the assembly of the reduced Newton matrix (:mod:`stablelego_jax.solvers.newton`)
for fixed weights, of which the weighted Gram's column pieces and their
scatter (``LayerGram.blocks``), the assembly and the block Cholesky, and
those plus two block solves (a predictor and a corrector). One OpenBLAS
thread; pin it to a core (``taskset -c 0``) and run nothing else: the parts
are tens of milliseconds and this machine's noise is 10-30% on one run.
"""
from __future__ import annotations

import argparse
import glob
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", nargs="+", default=[os.path.join(HERE, "results", "shard1000")])
    ap.add_argument("--key", help="bucket, e.g. layered,16,12 or dense,72")
    ap.add_argument("--file", help="one layout instead of a bucket")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--repeat", type=int, default=5)
    a = ap.parse_args()
    if (a.key is None) == (a.file is None):
        ap.error("give --key or --file")
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.model import NORMAL, Params, compile_layout
    from stablelego_jax.solvers import ipm
    from stablelego_jax.solvers.blocks import block_cholesky, block_solve
    from stablelego_jax.solvers.newton import reduced_matrix
    from stablelego_jax.solvers.problem import gram_plan, operators, plan_problem, solve_plan, stack_problems

    if a.file:
        models = [compile_layout(load_layout(a.file))]
        key = solve_plan(models[0])
        size = 1
    else:
        key = tuple(int(x) if x.isdigit() else x for x in a.key.split(","))
        files = sorted(f for d in a.inputs for f in (glob.glob(os.path.join(d, "*.json")) if os.path.isdir(d) else [d]))
        models = [m for m in (compile_layout(load_layout(f)) for f in files) if solve_plan(m) == key]
        if not models:
            raise SystemExit(f"no layout of {' '.join(a.inputs)} is in bucket {key}")
        models = models[: a.batch]
        size = a.batch
    m_pad = max(m.m_pad for m in models)
    p_pad = max(m.group.shape[1] for m in models)
    c_pad = max(plan_problem(m, key, m_pad, p_pad)[1].chunks.shape[0] for m in models)
    probs = [plan_problem(m, key, m_pad, p_pad, c_pad)[1] for m in models]
    probs += [probs[-1]] * (size - len(probs))
    P = stack_problems(probs)

    def best(fn, *args):
        return timed(jax.jit(jax.vmap(fn)), *args)

    def timed(f, *args):  # best of --repeat of a jitted f after its compile, ms
        jax.block_until_ready(f(*args))
        t = []
        for _ in range(a.repeat):
            s = time.perf_counter()
            jax.block_until_ready(f(*args))
            t.append(time.perf_counter() - s)
        return min(t) * 1e3

    def weights(p):
        mm = p.col_kind.shape[0]
        return jnp.ones(mm) + 0.1 * jnp.arange(mm) / mm

    def assemble(p):
        _, _, coef, g, _ = operators(p, Params())
        n = g.shape[0]
        L = 1 if p.layers is None else p.layers.shape[0]
        asm = reduced_matrix(p.col_brick, coef, (p.col_kind == NORMAL) & p.col_mask, n, L, p.chunks,
                             p.supports, p.col_slot)
        e = weights(p)
        return asm(e, e, jnp.ones(n), jnp.ones(6 * n))

    def gram(p):
        _, _, coef, g, _ = operators(p, Params())
        L = 1 if p.layers is None else p.layers.shape[0]
        return gram_plan(p.col_brick, coef, g.shape[0], L, p.chunks).blocks(weights(p))

    def factor(p):
        D, E = assemble(p)
        return block_cholesky(D + 10.0 * jnp.eye(D.shape[-1]), E)

    def factor_solves(p):
        C, G = factor(p)
        r = jnp.ones(C.shape[:2])
        return block_solve(C, G, r), block_solve(C, G, 2.0 * r)

    solve = jax.jit(jax.vmap(lambda p: ipm.solve(p)))
    iters = int(solve(P).iters.max())
    wall = timed(solve, P) / 1e3
    print(f"bucket {key}: {len(models)} layouts in a batch of {size}, {m_pad} columns, iterations max {iters}")
    print(f"  solve: {wall * 1e3 / iters:.1f} ms per iteration of the batch")
    print(f"  assembly {best(assemble, P):.1f} ms (of it the Gram's pieces and scatter {best(gram, P):.1f}); "
          f"assembly + block Cholesky {best(factor, P):.1f}; + two block solves {best(factor_solves, P):.1f}")


if __name__ == "__main__":
    main()
