"""Where a long JAX ``analyze`` run's memory mappings come from (issue 20):
one in-process ``stablelego analyze --json --solver jax FILE...`` whose
output lines are counted as they are written, each line tied to the
process's memory mappings (lines of ``/proc/self/maps``), the executables
held in the solver cache, the compiles so far and the executables evicted.

    python benchmarks/executable_growth.py [--limit K] [--n 500] [--dir benchmarks/results/small500]

``--limit K``: hold at most K executables (default: the library's 32).
Prints one row per compile (and every 100 files): files, mappings, held,
compiles, evicted. Linux only.
"""
from __future__ import annotations

import argparse
import contextlib
import glob
import io
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from stablelego_jax.cli.main import main as cli  # noqa: E402
from stablelego_jax.solvers import compiled as C  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--limit", type=int, default=0, help="executables held (0: the library's default)")
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--dir", default=os.path.join(HERE, "results", "small500"))
    args = ap.parse_args()
    if args.limit:
        C.set_limit(args.limit)
    files = sorted(glob.glob(os.path.join(args.dir, "*.json")))[: args.n]
    if not files:
        sys.exit(f"{args.dir}: no layouts (python benchmarks/make_shard.py --n 500 --recipe small --out {args.dir})")
    rows = []

    class Lines(io.StringIO):
        n = 0

        def write(self, s):
            k = s.count("\n")
            if k:
                Lines.n += k
                rows.append((Lines.n, C.mappings(), C.cache_size(), C.STATS.compiles, C.STATS.evicted))
            return len(s)

    with contextlib.redirect_stdout(Lines()):
        try:
            cli(["analyze", "--json", "--solver", "jax", *files])
        except SystemExit:
            pass
    print("files mappings held compiles evicted")
    last = None
    for r in rows:
        if last is None or r[3] != last[3] or r[0] % 100 == 0 or r is rows[-1]:
            print(*r)
        last = r


if __name__ == "__main__":
    main()
