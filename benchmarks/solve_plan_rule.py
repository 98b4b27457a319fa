"""Issue 17, session 59: would the verdict LP's bucket choice gain from the
time model that ``soft_plan`` uses since session 58?

    python benchmarks/solve_plan_rule.py [INPUT ...] [--json OUT]

``solvers.problem.solve_plan`` picks dense or layered for a layout by flop
count (``L B^3 < n^3 / 9``). For each layout of the inputs (files or
folders; default ``benchmarks/results/shard1000`` and
``benchmarks/results/small500``, ``make_shard.py``), this prices its dense
rung and, where it has layers, its layered bucket with
``solvers.problem.plan_seconds`` (the iteration time model fitted to
measured warm solves), and counts the layouts whose cheaper option by that
model is not the flop count's choice, with the modelled seconds that
choice would save. An estimate from the model, no solve is run (slab
buckets are left as they are). Prints one line per input and the most
common changes.
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from stablelego_jax.batch import find_layouts  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402
from stablelego_jax.model import Params, compile_layout  # noqa: E402
from stablelego_jax.solvers import problem as P  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def compare(folder: str) -> dict:
    """{layouts, modelled_s (the flop count's plans), changed, saved_s, changes: {(from, to): count}}."""
    params = Params()
    total = saved = 0.0
    changes = collections.Counter()
    files = sorted(find_layouts([folder]))
    for f in files:
        model = compile_layout(load_layout(f), params)
        key = P.solve_plan(model)
        if key[0] == "slabs":
            continue
        options = [("dense", P.rung(model.n, P.MIN_BRICKS))]
        L, B = P.layer_plan(model)
        if 1 < L < P.NOT_LAYERED:
            options.append(("layered",) + P.layer_bucket(L, B))
        price = {o: P.plan_seconds(o) for o in options}
        now = P.plan_seconds(key)
        total += now
        best = min(price, key=price.get)
        if best != key:
            changes[(key, best)] += 1
            saved += now - price[best]
    return {"input": folder, "layouts": len(files), "modelled_s": round(total, 3), "changed": sum(changes.values()),
            "saved_s": round(saved, 3),
            "changes": {f"{a} -> {b}": n for (a, b), n in changes.most_common()}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="*")
    ap.add_argument("--json", help="write the rows here")
    a = ap.parse_args(argv)
    inputs = a.inputs or [os.path.join(HERE, "results", d) for d in ("shard1000", "small500")]
    rows = []
    for folder in inputs:
        if not find_layouts([folder]):
            sys.exit(f"error: {folder}: no layouts (make them with benchmarks/make_shard.py)")
        r = compare(folder)
        rows.append(r)
        print(f"{r['input']}: {r['layouts']} layouts, {r['modelled_s']} s modelled as planned; "
              f"{r['changed']} would change, saving {r['saved_s']} s "
              f"({100 * r['saved_s'] / max(r['modelled_s'], 1e-9):.2f}%)")
        for k, n in list(r["changes"].items())[:6]:
            print(f"  {n} x {k}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
