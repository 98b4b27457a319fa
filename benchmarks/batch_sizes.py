"""Batch size against solve time per layout, bucket by bucket (issue 17,
item 3: small layouts fast; the CPU rule of ``batch.batch_sizes``).

Usage:
  python benchmarks/batch_sizes.py --inputs DIR [DIR ...] --keys dense,8 dense,40 layered,16,12
      [--sizes 64 32 16 8 4 2 1] [--n 200] [--repeat 2] [--json OUT]

For each bucket (``solve_plan`` key) the first ``--n`` layouts of the
inputs in that bucket are padded to one shape, as ``score`` pads a bucket
(common columns, contact slots and column chunks), and solved by the
``vmap``-ed interior point in batches of each ``--sizes`` (the last batch
filled up with copies of its last layout, as ``score`` fills a batch):
warm (after one compile per size), best of ``--repeat``, the seconds for
the whole bucket, per layout, and the summed iteration counts of the
batches (each batch runs until its slowest layout has converged). One
OpenBLAS thread; pin it to one core (``taskset -c 0``) and run nothing
else beside it.
"""
from __future__ import annotations

import argparse
import datetime
import glob
import json
import os
import platform
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))


def bucket_problems(models: list, key: tuple) -> tuple:
    """(m_pad, problems): ``models`` of bucket ``key`` padded to one shape
    (their largest column, slot and column-chunk counts), as ``score`` pads
    a bucket."""
    from stablelego_jax.solvers.problem import plan_problem

    m_pad = max(m.m_pad for m in models)
    p_pad = max(m.group.shape[1] for m in models)
    c_pad = max(plan_problem(m, key, m_pad, p_pad)[1].chunks.shape[0] for m in models)
    return m_pad, [plan_problem(m, key, m_pad, p_pad, c_pad)[1] for m in models]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", nargs="+", default=[os.path.join(HERE, "results", "small500")])
    ap.add_argument("--keys", nargs="+", required=True, help="buckets, e.g. dense,8 layered,16,12")
    ap.add_argument("--sizes", nargs="+", type=int, default=[64, 32, 16, 8, 4, 2, 1])
    ap.add_argument("--n", type=int, default=200, help="most layouts a bucket")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--json", help="write the rows here")
    a = ap.parse_args()
    import jax

    jax.config.update("jax_enable_x64", True)
    from stablelego_jax.batch import plan_bytes
    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.model import compile_layout
    from stablelego_jax.solvers import ipm
    from stablelego_jax.solvers.problem import solve_plan, stack_problems

    files = sorted(f for d in a.inputs for f in (glob.glob(os.path.join(d, "*.json")) if os.path.isdir(d) else [d]))
    models = [compile_layout(load_layout(f)) for f in files]
    plans = [solve_plan(m) for m in models]
    solve = jax.jit(jax.vmap(lambda p: ipm.solve(p)))
    rows = []
    for text in a.keys:
        key = tuple(int(x) if x.isdigit() else x for x in text.split(","))
        mine = [m for m, k in zip(models, plans) if k == key][: a.n]
        if not mine:
            print(f"{key}: no layout of the inputs in this bucket", flush=True)
            continue
        m_pad, probs = bucket_problems(mine, key)
        for b in a.sizes:
            batches = []
            for i in range(0, len(probs), b):
                part = probs[i: i + b]
                batches.append(stack_problems(part + [part[-1]] * (b - len(part))))
            jax.block_until_ready(solve(batches[0]))
            best, iters = float("inf"), 0
            for _ in range(a.repeat):
                t0 = time.perf_counter()
                iters = sum(int(jax.block_until_ready(solve(B)).iters.max()) for B in batches)
                best = min(best, time.perf_counter() - t0)
            row = dict(key=list(key), layouts=len(probs), m_pad=m_pad, batch=b, seconds=round(best, 4),
                       ms_per_layout=round(best / len(probs) * 1e3, 2), batch_iterations=iters,
                       working_set_mb=round(b * plan_bytes(key, m_pad) / 1e6, 1))
            rows.append(row)
            print(f"{key} {len(probs)} layouts, {m_pad} columns, batch {b:3d}: {best:7.2f} s, "
                  f"{row['ms_per_layout']:7.1f} ms a layout, batch iterations {iters}, "
                  f"working set {row['working_set_mb']} MB", flush=True)
    if a.json:
        meta = dict(command="python " + " ".join(sys.argv), machine=platform.machine(), cores=os.cpu_count(),
                    date=datetime.date.today().isoformat())
        with open(a.json, "w") as f:
            json.dump(dict(meta=meta, rows=rows), f, indent=1)


if __name__ == "__main__":
    main()
