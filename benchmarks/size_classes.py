"""Solve time per size class from kept ``score`` results (issue 17: "per
size class ... JAX at least as fast as HiGHS per layout in every class").

Usage:
  python benchmarks/size_classes.py REF.jsonl RUN.jsonl [RUN.jsonl ...] [--labels HiGHS "JAX first" ...]

Each file is a results file of ``stablelego score`` (for example those
``benchmarks/cores.py --keep DIR`` keeps: ``DIR/vertex-2-run1-0.jsonl``,
``DIR/jax-pool-run1-0.jsonl``). Over the layouts present in every file, by
brick count (1-16, 17-48, 49-128, 129-256, 257-512, 513 and more), prints a
Markdown table of the summed ``time_s`` of each file (the JAX solver's is
each layout's share of its batch, compile excluded) and the last file's
time over the first's.
"""
from __future__ import annotations

import argparse
import json

#: Size classes (bricks, inclusive).
CLASSES = ((1, 16), (17, 48), (49, 128), (129, 256), (257, 512), (513, None))


def read(path: str) -> dict:
    """{file: result line} of the lines with a solve time."""
    out = {}
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if "file" in rec and "time_s" in rec and "n_bricks" in rec:
                out[rec["file"]] = rec
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results", nargs="+", help="results files; the first is the reference")
    ap.add_argument("--labels", nargs="+", help="a column name for each file")
    a = ap.parse_args(argv)
    if len(a.results) < 2:
        ap.error("give a reference and at least one more results file")
    labels = a.labels or a.results
    if len(labels) != len(a.results):
        ap.error("--labels: one name a file")
    runs = [read(p) for p in a.results]
    common = set(runs[0]).intersection(*runs[1:])
    print("| bricks | layouts | " + " | ".join(f"{x} s" for x in labels) + f" | {labels[-1]} / {labels[0]} |")
    print("|---" * (len(labels) + 3) + "|")
    rows = [(f"{lo}-{hi}" if hi else f"{lo}+", [k for k in common
             if lo <= runs[0][k]["n_bricks"] and (hi is None or runs[0][k]["n_bricks"] <= hi)])
            for lo, hi in CLASSES] + [("all", sorted(common))]
    for name, ks in rows:
        if not ks:
            continue
        t = [sum(r[k]["time_s"] for k in ks) for r in runs]
        print(f"| {name} | {len(ks)} | " + " | ".join(f"{x:.1f}" for x in t) + f" | {t[-1] / t[0]:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
