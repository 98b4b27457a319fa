"""Where the batched JAX solve time of many small layouts goes, per bucket
(issue 17, item 3), and how well the cost model behind bucket merging
(``solvers.problem.plan_seconds``) predicts it.

Usage:
  python benchmarks/bucket_times.py [FILE_OR_DIR ...] [--n 200] [--merge 0|1] [--batch 64] [--json OUT]

Default inputs: the first ``--n`` layouts of ``benchmarks/results/small500``
(``python benchmarks/make_shard.py --recipe small --n 500 --out
benchmarks/results/small500``). In one process: the layouts are grouped
into solver units exactly as ``score`` groups them (``batch.solve_units``,
with ``--merge`` and the compiled-bucket test), solved once to compile (or
load) every shape, then solved again warm; per bucket the warm solve time
(the sum of each layout's share of its batch), the most and mean
interior-point iterations, and ``plan_seconds`` of the bucket for its
layouts. Run it pinned to one core (``taskset -c 0``) with
``OPENBLAS_NUM_THREADS=1`` for numbers comparable with the fit.
"""
from __future__ import annotations

import argparse
import collections
import datetime
import json
import os
import platform
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from stablelego_jax.batch import ScoreStats, compiled_ready, find_layouts, iter_analyses, solve_units  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402
from stablelego_jax.model import Params, compile_layout  # noqa: E402
from stablelego_jax.solvers import ipm  # noqa: E402
from stablelego_jax.solvers.problem import batch_rung, plan_seconds  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="*")
    ap.add_argument("--n", type=int, default=200, help="layouts (the first N of the inputs, sorted)")
    ap.add_argument("--merge", type=int, choices=[0, 1], default=1)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--json", help="output file")
    args = ap.parse_args()
    inputs = args.inputs or [os.path.join(HERE, "results", "small500")]
    files = sorted(find_layouts(inputs))[: args.n]
    if not files:
        sys.exit(f"error: no layouts in {' '.join(inputs)}")
    lays = [load_layout(f) for f in files]
    params, opts = Params(), ipm.IPMOptions()
    loaded = [(i, lay, compile_layout(lay, params)) for i, lay in enumerate(lays)]
    units = solve_units(loaded, args.batch, 1, bool(args.merge), ready=compiled_ready(params, opts, 1))
    unit_of = {it[0]: u for u, unit in enumerate(units) for it in unit.items}
    runs = []
    for run in ("first", "warm"):
        st = ScoreStats()
        t0 = time.perf_counter()
        res = {}
        for part in iter_analyses(lays, "jax", params=params, opts=opts, batch=args.batch,
                                  merge=bool(args.merge), stats=st):
            res.update(part)
        wall = time.perf_counter() - t0
        runs.append({"run": run, "wall_s": wall, "solve_s": st.solve_s, "compile_s": st.compile_s,
                     "compiles": st.compiles})
        print(f"{run}: wall {wall:.2f} s, solve {st.solve_s:.2f} s, compile {st.compile_s:.2f} s "
              f"({st.compiles} shapes)", flush=True)
    agg = collections.OrderedDict()
    for i, a in sorted(res.items()):
        u = units[unit_of[i]]
        row = agg.setdefault((u.key, u.m_pad), {"key": list(u.key), "m_pad": u.m_pad, "layouts": 0,
                                                "padded": 0, "solve_s": 0.0, "max_iters": 0, "iters": 0})
        row["layouts"] += 1
        row["solve_s"] += a.time_s
        row["max_iters"] = max(row["max_iters"], a.iters)
        row["iters"] += a.iters
    for u in units:
        agg[(u.key, u.m_pad)]["padded"] += batch_rung(len(u.items), 1, u.bsz)
    rows = sorted(agg.values(), key=lambda r: -r["solve_s"])
    print("| bucket | padded columns | layouts (padded) | warm solve s | ms per layout | iterations max / mean "
          "| plan_seconds x layouts, s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        model = r["layouts"] * plan_seconds(tuple(r["key"]), r["m_pad"])
        r["model_s"] = model
        r["mean_iters"] = r["iters"] / r["layouts"]
        print(f"| {tuple(r['key'])} | {r['m_pad']} | {r['layouts']} ({r['padded']}) | {r['solve_s']:.2f} | "
              f"{1000 * r['solve_s'] / r['layouts']:.1f} | {r['max_iters']} / {r['mean_iters']:.1f} | {model:.2f} |")
    if args.json:
        try:
            code = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                  cwd=HERE).stdout.strip()
        except OSError:
            code = ""
        out = {"command": " ".join(["benchmarks/bucket_times.py"] + sys.argv[1:]), "machine": platform.platform(),
               "python": platform.python_version(), "date": datetime.date.today().isoformat(), "code": code,
               "layouts": len(files), "merge": bool(args.merge), "runs": runs, "buckets": rows}
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
