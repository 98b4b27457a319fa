"""Layouts per second at fixed batch sizes, bucket by bucket (issue 17: "when
a GPU is at hand: layouts per second at batch 1, 64, 1024").

Usage:
  python benchmarks/batch_rate.py --inputs DIR [DIR ...] [--top 3] [--keys dense,8 layered,16,12]
      [--sizes 1 64 1024] [--seconds 3] [--max-gb 40] [--json OUT]

Buckets: the ``--keys`` given (``solve_plan`` keys) and the ``--top`` most
populous buckets of the inputs. Each bucket's layouts are padded to one
shape as ``score`` pads a bucket, and batches of exactly each ``--sizes``
are filled with the bucket's layouts in turn (a bucket of fewer layouts than
a batch repeats them: every member is a real layout of the inputs). Each
size is compiled once (``lower().compile()``, timed apart), then batches
(up to 4 distinct ones, already on the device) are solved one after the
other until ``--seconds`` have passed and at least two have run: layouts a
second = members solved / seconds, with the batches' summed iteration
counts (a batch runs until its slowest member has converged) and the
converged fraction. The solver function is ``score``'s
(``batch.batch_solver_fn`` on one device: a batch of one dense problem runs
unbatched, factoring only its real rows). A size whose working set
(``batch.plan_bytes``) exceeds ``--max-gb`` is skipped and says so.
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
from collections import Counter

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", nargs="+", default=[os.path.join(HERE, "results", "shard1000")])
    ap.add_argument("--keys", nargs="*", default=[], help="buckets, e.g. dense,8 layered,16,12")
    ap.add_argument("--top", type=int, default=3, help="also the N most populous buckets")
    ap.add_argument("--sizes", nargs="+", type=int, default=[1, 64, 1024])
    ap.add_argument("--seconds", type=float, default=3.0, help="timed solving per size, at least")
    ap.add_argument("--max-gb", type=float, default=40.0, help="skip a size whose working set exceeds this")
    ap.add_argument("--json", help="write the rows here")
    a = ap.parse_args()
    import jax
    import numpy as np

    jax.config.update("jax_enable_x64", True)
    from stablelego_jax.batch import batch_solver_fn, plan_bytes
    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.solvers import ipm
    from stablelego_jax.solvers.problem import Solution, solve_plan, stack_problems

    sys.path.insert(0, HERE)
    from batch_sizes import bucket_problems

    files = sorted(f for d in a.inputs for f in (glob.glob(os.path.join(d, "*.json")) if os.path.isdir(d) else [d]))
    t0 = time.perf_counter()
    models = [compile_layout(load_layout(f)) for f in files]
    plans = [solve_plan(m) for m in models]
    print(f"{len(files)} layouts read and planned in {time.perf_counter() - t0:.1f} s; "
          f"device {jax.devices()[0].device_kind} ({jax.default_backend()})", flush=True)
    keys = [tuple(int(x) if x.isdigit() else x for x in k.split(",")) for k in a.keys]
    keys += [k for k, _ in Counter(plans).most_common(a.top) if k not in keys]
    fn = jax.jit(batch_solver_fn(Params(), ipm.IPMOptions(), 1))
    rows = []
    for key in keys:
        mine = [m for m, k in zip(models, plans) if k == key]
        if not mine:
            print(f"{key}: no layout of the inputs in this bucket", flush=True)
            continue
        m_pad, probs = bucket_problems(mine, key)
        bricks = sorted(m.n for m in mine)
        for b in a.sizes:
            gb = b * plan_bytes(key, m_pad) / 1e9
            row = dict(key=list(key), layouts=len(probs), median_bricks=bricks[len(bricks) // 2],
                       m_pad=m_pad, batch=b, working_set_gb=round(gb, 3))
            if gb > a.max_gb:
                row["skipped"] = f"working set {gb:.1f} GB > --max-gb {a.max_gb}"
                print(f"{key} batch {b}: skipped, {row['skipped']}", flush=True)
                rows.append(row)
                continue
            n_distinct = max(1, min(4, -(-len(probs) // b)))
            batches = []
            for j in range(n_distinct):
                part = [probs[(j * b + i) % len(probs)] for i in range(b)]
                batches.append(jax.device_put(tuple(x for x in stack_problems(part) if x is not None)))
            t1 = time.perf_counter()
            exe = fn.lower(*batches[0]).compile()
            row["compile_s"] = round(time.perf_counter() - t1, 2)
            jax.block_until_ready(exe(*batches[0]))  # first run (transfers, autotuning) apart
            solved, iters, conv, runs = 0, 0, 0, 0
            t1 = time.perf_counter()
            while runs < 2 or time.perf_counter() - t1 < a.seconds:
                sol = Solution(*jax.block_until_ready(exe(*batches[runs % n_distinct])))
                solved += b
                runs += 1
                iters += int(np.max(sol.iters))
                conv += int(np.sum(sol.converged))
            dt = time.perf_counter() - t1
            row.update(batches=runs, seconds=round(dt, 3), layouts_per_s=round(solved / dt, 1),
                       ms_per_batch=round(dt / runs * 1e3, 2), iterations_per_batch=round(iters / runs, 1),
                       converged=round(conv / solved, 4))
            rows.append(row)
            print(f"{key} {len(probs)} layouts (median {row['median_bricks']} bricks), batch {b:4d}: "
                  f"compile {row['compile_s']:.1f} s, {row['layouts_per_s']:9.1f} layouts/s "
                  f"({row['ms_per_batch']:.1f} ms a batch, {row['iterations_per_batch']} iterations), "
                  f"converged {row['converged']:.3f}, working set {gb:.2f} GB", flush=True)
    if a.json:
        meta = dict(command="python " + " ".join(sys.argv), machine=platform.machine(), cores=os.cpu_count(),
                    device=str(jax.devices()[0].device_kind), backend=jax.default_backend(),
                    jax=jax.__version__, date=datetime.date.today().isoformat())
        with open(a.json, "w") as f:
            json.dump(dict(meta=meta, rows=rows), f, indent=1)


if __name__ == "__main__":
    main()
