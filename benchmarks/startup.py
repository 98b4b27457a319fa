"""Wall time of a whole ``stablelego analyze`` process: first run (empty
cache) against the runs after it (warm cache).

Usage: python benchmarks/startup.py [--layout examples/stablelego/stair_20.json [MORE ...]] [--warm 5]
        [--json benchmarks/results/startup.json]

Each run is a fresh process (``python -m stablelego_jax analyze LAYOUT
--solver S``), timed from outside, with its own empty cache folder
(``STABLELEGO_CACHE_DIR``) for the first run; the warm runs reuse it. Also
timed: the same with the disk cache off (``STABLELEGO_CACHE=0``: every run
compiles), the exact solver, and ``stablelego --help``. Prints a markdown
table; the target of issue 16 is a warm JAX run under 1.5 s. Several
``--layout`` files go to one ``analyze`` call (issue 17: ``analyze`` of 20
small files in one call no slower than the exact solver).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def run(args, env) -> float:
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "stablelego_jax", *args], cwd=ROOT, env=env,
                       stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    dt = time.perf_counter() - t0
    if r.returncode not in (0, 1):
        raise SystemExit(f"stablelego {' '.join(args)} failed: {r.stderr[-2000:]}")
    return dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--layout", nargs="+", default=[os.path.join("examples", "stablelego", "stair_20.json")])
    ap.add_argument("--warm", type=int, default=5, help="warm runs after the first")
    ap.add_argument("--json", default=os.path.join(HERE, "results", "startup.json"))
    a = ap.parse_args()
    base = dict(os.environ, PYTHONPATH=ROOT, OPENBLAS_NUM_THREADS="1")
    rows = []
    cache = tempfile.mkdtemp(prefix="stablelego-startup-")
    env = dict(base, STABLELEGO_CACHE_DIR=cache)
    first = run(["analyze", *a.layout, "--solver", "jax"], env)
    warm = [run(["analyze", *a.layout, "--solver", "jax"], env) for _ in range(a.warm)]
    rows.append(("jax, first run (empty cache)", [first]))
    rows.append(("jax, warm cache", warm))
    off = dict(base, STABLELEGO_CACHE="0")
    rows.append(("jax, disk cache off", [run(["analyze", *a.layout, "--solver", "jax"], off) for _ in range(2)]))
    rows.append(("exact (HiGHS)", [run(["analyze", *a.layout, "--solver", "exact"], env) for _ in range(3)]))
    rows.append(("stablelego --help", [run(["--help"], env) for _ in range(3)]))
    out = {"command": " ".join(sys.argv), "machine": f"{platform.machine()} {os.cpu_count()} cores",
           "python": platform.python_version(), "date": time.strftime("%Y-%m-%d %H:%M"), "layout": a.layout if len(a.layout) > 1 else a.layout[0],
           "runs": {name: [round(t, 3) for t in ts] for name, ts in rows}}
    print(f"{out['machine']}, {out['date']}, `stablelego analyze {' '.join(a.layout)}`, whole process")
    print("| run | wall s (median) | runs |")
    print("|---|---|---|")
    for name, ts in rows:
        print(f"| {name} | {statistics.median(ts):.2f} | {', '.join(f'{t:.2f}' for t in ts)} |")
    med = statistics.median(warm)
    print(f"warm / first: {med / first:.3f}; target warm < 1.5 s: {'met' if med < 1.5 else 'NOT met'} ({med:.2f} s)")
    os.makedirs(os.path.dirname(a.json), exist_ok=True)
    with open(a.json, "w") as fh:
        json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
