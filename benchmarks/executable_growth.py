"""Where a long ``analyze`` run's memory mappings and resident memory come
from (issue 20): one in-process ``stablelego analyze --json --solver S
FILE...`` whose output lines are counted as they are written, each line
tied to the process's memory mappings (lines of ``/proc/self/maps``),
resident memory (``VmRSS``), the executables held in the solver cache, the
compiles so far and the executables evicted. Every call of the batch
engine's ``compiled`` is wrapped: the resident memory it adds when it
compiles (traces, exports, compiles or loads a new shape) is summed apart
from what the rest of the run adds (solving, scoring, output).

    python benchmarks/executable_growth.py [--solver jax|auto] [--limit K] [--n 500]
        [--dir benchmarks/results/small500] [--json OUT] [--keep-tracing-caches]

``--limit K``: hold at most K executables (default: the library's 32).
Prints one row per compile (and every 100 files): files, mappings, RSS MB,
held, compiles, evicted; then the RSS split. Linux only.
"""
from __future__ import annotations

import argparse
import contextlib
import glob
import io
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from stablelego_jax.cli.main import main as cli  # noqa: E402
from stablelego_jax import batch  # noqa: E402
from stablelego_jax.solvers import compiled as C  # noqa: E402


def rss_mb() -> float:
    """Resident memory of this process (MB)."""
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS:")) / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--limit", type=int, default=0, help="executables held (0: the library's default)")
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--dir", default=os.path.join(HERE, "results", "small500"))
    ap.add_argument("--solver", default="jax", choices=["jax", "auto"])
    ap.add_argument("--json", help="write the rows and the RSS split here")
    ap.add_argument("--keep-tracing-caches", action="store_true",
                    help="do not empty JAX's tracing caches after each compile (as before 2026-11-24)")
    args = ap.parse_args()
    if args.limit:
        C.set_limit(args.limit)
    if args.keep_tracing_caches:
        C.drop_tracing_caches = lambda: False  # compiled() looks it up at each call
    files = sorted(glob.glob(os.path.join(args.dir, "*.json")))[: args.n]
    if not files:
        sys.exit(f"{args.dir}: no layouts (python benchmarks/make_shard.py --n 500 --recipe small --out {args.dir})")
    rows = []
    split = {"compile_mb": 0.0, "compile_calls": 0, "hit_mb": 0.0, "hit_calls": 0}
    inner = batch.compiled

    def watched(*a, **k):
        n0, r0 = C.STATS.compiles, rss_mb()
        exe = inner(*a, **k)
        kind = "compile" if C.STATS.compiles > n0 else "hit"
        split[kind + "_mb"] += rss_mb() - r0
        split[kind + "_calls"] += 1
        return exe

    batch.compiled = watched

    class Lines(io.StringIO):
        n = 0

        def write(self, s):
            k = s.count("\n")
            if k:
                Lines.n += k
                rows.append((Lines.n, C.mappings(), round(rss_mb(), 1), C.cache_size(), C.STATS.compiles,
                             C.STATS.evicted, round(split["compile_mb"], 1)))
            return len(s)

    r_start, t0 = rss_mb(), time.perf_counter()
    with contextlib.redirect_stdout(Lines()):
        try:
            cli(["analyze", "--json", "--solver", args.solver, *files])
        except SystemExit:
            pass
    wall = time.perf_counter() - t0
    print("files mappings rss_mb held compiles evicted compile_mb_so_far")
    last = None
    for r in rows:
        if last is None or r[4] != last[4] or r[0] % 100 == 0 or r is rows[-1]:
            print(*r)
        last = r
    total = rss_mb() - r_start
    split.update(solver=args.solver, keep_tracing_caches=args.keep_tracing_caches, files=len(files), lines=Lines.n,
                 wall_s=round(wall, 1),
                 rss_start_mb=round(r_start, 1), rss_end_mb=round(rss_mb(), 1), total_mb=round(total, 1),
                 rest_mb=round(total - split["compile_mb"] - split["hit_mb"], 1),
                 compiles=C.STATS.compiles, evicted=C.STATS.evicted)
    split["compile_mb"], split["hit_mb"] = round(split["compile_mb"], 1), round(split["hit_mb"], 1)
    print(json.dumps(split))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(dict(split, rows=rows), fh)


if __name__ == "__main__":
    main()
