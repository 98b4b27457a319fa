"""JAX batch solves with SciPy's OpenBLAS at its default thread count vs one
thread, on a quiet machine and with busy processes beside it.

Usage: python benchmarks/blas_threads.py [--n 64] [--hogs 2]

64 layouts of 30-60 bricks from the race shard (benchmarks/results/shard500,
``throughput_jax.jsonl`` lists them) are scored twice in one process with
the JAX interior point; the second pass (everything compiled) is timed.
``score_files`` now always runs with one thread; the default arm calls its
unwrapped body ``batch.score_files.__wrapped__``. ``--hogs K`` starts K busy-looping
processes for the loaded runs. Prints one JSON line per run.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from stablelego_jax import batch  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def _hog():
    while True:
        pass


def timed(files, fn) -> float:
    d = tempfile.mkdtemp()
    fn(files, os.path.join(d, "a.jsonl"), progress=False)  # compiles
    t0 = time.perf_counter()
    fn(files, os.path.join(d, "b.jsonl"), progress=False)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=64)
    ap.add_argument("--hogs", type=int, default=2)
    args = ap.parse_args()
    recs = [json.loads(line) for line in open(os.path.join(HERE, "results", "throughput_jax.jsonl"))]
    files = [os.path.join(HERE, "results", "shard500", os.path.basename(r["file"]))
             for r in recs if 30 <= r.get("n_bricks", 0) <= 60][: args.n]
    arms = (("default threads", batch.score_files.__wrapped__), ("one thread", batch.score_files))
    for load in (0, args.hogs):
        hogs = [mp.Process(target=_hog, daemon=True) for _ in range(load)]
        for h in hogs:
            h.start()
        try:
            for name, fn in arms:
                t = timed(files, fn)
                print(json.dumps({"blas": name, "busy_processes": load, "layouts": len(files),
                                  "second_pass_s": round(t, 2)}), flush=True)
        finally:
            for h in hogs:
                h.terminate()


if __name__ == "__main__":
    main()
