"""Warm JAX solve time per layout, for comparing two versions of the solver
side by side (issue 20's polish against issue 17's throughput).

Usage: python benchmarks/solve_time.py [INPUT ...] [--every 10] [--repeat 2] --json OUT

INPUT: layout files or folders (default: every ``--every``-th layout of the
500-layout shard of ``benchmarks/make_shard.py``). Per layout, the JAX
analysis (``analyze_layout(solver="jax", fallback=False)``, the interior
point) runs once to
compile (or load) its executable and then ``--repeat`` times, timed; the
row keeps the fastest of those, the iterations and whether it converged.
Writes one JSON object: the command, machine, date, code version (git
HEAD), rows and totals. Two checkouts run side by side, each pinned to one
core (``taskset``, one XLA and BLAS thread), then with the cores swapped,
give a time ratio that the machine's noise does not bias.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import platform
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.batch import find_layouts  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="*")
    ap.add_argument("--every", type=int, default=10, help="default set: every N-th shard layout")
    ap.add_argument("--repeat", type=int, default=2, help="timed runs per layout (the fastest is kept)")
    ap.add_argument("--json", required=True, help="output file")
    args = ap.parse_args()
    if args.inputs:
        files = find_layouts(args.inputs)
    else:
        shard = os.path.join(HERE, "results", "shard500")
        if not os.path.isdir(shard):
            sys.exit(f"{shard}: missing; write it with python benchmarks/make_shard.py --n 500")
        files = sorted(glob.glob(os.path.join(shard, "*.json")))[:: args.every]
    rows = []
    for i, f in enumerate(files):
        lay = load_layout(f)
        analyze_layout(lay, solver="jax", fallback=False)  # compile or load
        best, a = float("inf"), None
        for _ in range(args.repeat):
            t = time.perf_counter()
            a = analyze_layout(lay, solver="jax", fallback=False)
            best = min(best, time.perf_counter() - t)
        rows.append({"file": os.path.relpath(f, ROOT), "n_bricks": lay.n, "solve_s": best, "iters": a.iters,
                     "converged": a.converged})
        print(f"[{i + 1}/{len(files)}] {rows[-1]['file']} n={lay.n} {best:.3f} s, {a.iters} iterations",
              file=sys.stderr, flush=True)
    head = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    out = {
        "command": " ".join([os.path.relpath(sys.argv[0], ROOT)] + sys.argv[1:]),
        "machine": f"{platform.machine()} {os.cpu_count()} cores", "python": platform.python_version(),
        "date": time.strftime("%Y-%m-%d %H:%M"), "code": head.stdout.strip(), "solver": "jax",
        "total_s": sum(r["solve_s"] for r in rows), "iters_total": sum(r["iters"] for r in rows),
        "converged": sum(r["converged"] for r in rows), "rows": rows,
    }
    with open(args.json, "w") as fh:
        json.dump(out, fh, indent=1)
    print(f"{len(rows)} layouts: {out['total_s']:.2f} s warm, {out['iters_total']} iterations, "
          f"{out['converged']} converged")


if __name__ == "__main__":
    main()
