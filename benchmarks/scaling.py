"""Time versus number of bricks (like the paper's Fig. 7), both solvers.

Usage: python benchmarks/scaling.py [--max-k 10]

* Unit-brick cubes k x k x k (k = 1..max_k, up to 1000 bricks): one layout
  at a time; exact = HiGHS (median of 3 solves, model compile included);
  JAX = the jit-compiled interior-point solver (``--solver jax``) on the
  model padded to its bucket (dense or layer by layer, as ``score`` picks):
  compiled once (listed apart), then the median of 3.
* The realistic shard: the per-layout times of the throughput run
  (``benchmarks/throughput.py``; JAX times there are each layout's share of
  its batch).

Writes benchmarks/results/scaling.json and benchmarks/results/scaling.png
and prints a markdown table.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import numpy as np  # noqa: E402

from stablelego_jax.analysis import SINGLE_NAME, analyze_layout, solver_fn  # noqa: E402
from stablelego_jax.generate.procedural import cuboid  # noqa: E402
from stablelego_jax.model import compile_layout  # noqa: E402
from stablelego_jax.solvers import ipm  # noqa: E402
from stablelego_jax.solvers.compiled import compiled  # noqa: E402
from stablelego_jax.solvers.problem import MIN_COLUMNS, MIN_SLOTS, plan_problem, rung, solve_plan  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
RES = os.path.join(HERE, "results")


def time_cube(k: int) -> dict:
    lay = cuboid(k, k, k)
    te = []
    for _ in range(3):
        a = analyze_layout(lay, solver="exact")
        te.append(a.time_s)
    model = compile_layout(lay)
    key = solve_plan(model)
    m_pad, p_pad = rung(model.m, MIN_COLUMNS), rung(model.group.shape[1], MIN_SLOTS)
    _, prob = plan_problem(model, key, m_pad, p_pad)
    arrays = tuple(a for a in prob if a is not None)
    opts = ipm.IPMOptions()
    t0 = time.perf_counter()
    comp = compiled(SINGLE_NAME, solver_fn(model.params, opts), (model.params, opts), arrays)
    tc = time.perf_counter() - t0
    tj, sol = [], None
    for _ in range(3):
        t0 = time.perf_counter()
        sol = comp(*arrays)
        sol[0].block_until_ready()
        tj.append(time.perf_counter() - t0)
    ja = analyze_layout(lay, solver="jax")
    return {
        "k": k, "n_bricks": lay.n, "exact_s": float(np.median(te)), "jax_s": float(np.median(tj)),
        "jax_compile_s": tc, "jax_iters": int(sol[1]), "jax_converged": bool(sol[2]),
        "stable_exact": a.stable, "stable_jax": ja.stable, "plan": list(key),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--max-k", type=int, default=10)
    args = ap.parse_args()
    path = os.path.join(RES, "scaling.json")
    old = json.load(open(path)) if os.path.exists(path) else {}
    cubes = {r["k"]: r for r in old.get("cubes", [])}
    for k in range(1, args.max_k + 1):
        if k not in cubes:  # resumable
            cubes[k] = time_cube(k)
            print(json.dumps(cubes[k]), file=sys.stderr, flush=True)
            with open(path, "w") as fh:
                json.dump({"cubes": [cubes[j] for j in sorted(cubes)]}, fh, indent=1)
    rows = [cubes[j] for j in sorted(cubes)]
    shard = {}
    for s in ("exact", "jax"):
        p = os.path.join(RES, f"throughput_{s}.jsonl")
        if os.path.exists(p):
            recs = [r for r in map(json.loads, open(p)) if "error" not in r]
            shard[s] = sorted((r["n_bricks"], r["time_s"]) for r in recs)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), dpi=120)
    n = [r["n_bricks"] for r in rows]
    ax.plot(n, [r["exact_s"] for r in rows], "o-", color="tab:blue", label="cubes: exact (HiGHS)")
    ax.plot(n, [r["jax_s"] for r in rows], "s-", color="tab:red", label="cubes: JAX (one layout)")
    for s, c in (("exact", "tab:blue"), ("jax", "tab:red")):
        if s in shard:
            xs, ys = zip(*shard[s])
            lab = "shard: exact" if s == "exact" else "shard: JAX (share of its batch)"
            ax.scatter(xs, ys, s=6, alpha=0.35, color=c, label=lab)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("bricks")
    ax.set_ylabel("time per layout (s)")
    ax.set_title("Solve time vs layout size (2-core CPU)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(RES, "scaling.png"))
    print("| cube | bricks | exact s | JAX s | JAX compile s | JAX iters | labels (exact/JAX) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['k']}^3 | {r['n_bricks']} | {r['exact_s']:.3f} | {r['jax_s']:.3f} | {r['jax_compile_s']:.1f} "
              f"| {r['jax_iters']} | {r['stable_exact']}/{r['stable_jax']} |")
    for s in shard:
        xs, ys = np.array(shard[s]).T
        for lo, hi in ((1, 30), (31, 100), (101, 300), (301, 2000)):
            m = (xs >= lo) & (xs <= hi)
            if m.any():
                print(f"shard {s} {lo}-{hi} bricks: {m.sum()} layouts, median {np.median(ys[m]) * 1e3:.1f} ms")


if __name__ == "__main__":
    main()
