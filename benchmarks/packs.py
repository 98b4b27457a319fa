"""Small layouts packed several to a problem against each solved alone
(issue 17, item 3: "several small layouts packed into one block-diagonal
problem").

Usage:
  python benchmarks/packs.py [INPUT ...] [--repeat 2] [--json OUT]

Default input: ``benchmarks/results/shard1000`` (``python
benchmarks/make_shard.py --n 1000 --seed 1 --out benchmarks/results/shard1000``).
The layouts are planned as ``score`` plans them (``batch.solve_units``:
buckets, merges, padding, packs); for every packed unit, its layouts are
solved as the pack (``solve_unit`` of the unit) and each alone with the same
compiled shape, warm (the first round compiles and is not counted), best of
``--repeat``. Prints per bucket: layouts, packs, summed solve seconds and
interior-point iterations of both, and the largest per-brick score
difference between a layout's packed and lone answers. Run it pinned to
one core (``taskset -c 0``) with ``OPENBLAS_NUM_THREADS=1``.
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import datetime
import json
import os
import platform
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from stablelego_jax.batch import ScoreStats, find_layouts, solve_unit, solve_units  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402
from stablelego_jax.model import Params, compile_layout  # noqa: E402
from stablelego_jax.solvers import ipm  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def solve(units, params, opts) -> tuple[dict, float]:
    """({i: Analysis}, summed solve seconds) of ``units`` solved one after the other."""
    st = ScoreStats()
    out = {}
    for u in units:
        for part in solve_unit(u, params, opts, 1, False, st):
            out.update(part)
    return out, st.solve_s


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="*")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--json", help="output file")
    a = ap.parse_args()
    inputs = a.inputs or [os.path.join(HERE, "results", "shard1000")]
    files = find_layouts(inputs)
    if not files:
        sys.exit(f"error: no layouts in {' '.join(inputs)}")
    params, opts = Params(), ipm.IPMOptions()
    loaded = [(i, lay, compile_layout(lay, params)) for i, lay in enumerate(load_layout(f) for f in files)]
    packed = [u for u in solve_units(loaded, 64, 1) if u.pack]
    if not packed:
        sys.exit("no packed unit in this plan (packs form in dense buckets of at most "
                 f"{ipm.CUT_MIN} bricks solved one problem at a time)")
    alone = [dataclasses.replace(u, items=[it], pack=False) for u in packed for it in u.items]
    best: dict = {}
    for r in range(a.repeat + 1):  # round 0 compiles
        for name, units in (("packed", packed), ("alone", alone)):
            res, sec = solve(units, params, opts)
            if r and sec < best.get(name, (None, float("inf")))[1]:
                best[name] = (res, sec)
    rows = collections.OrderedDict()
    for u in packed:
        row = rows.setdefault(str(u.shape), {"bucket": list(u.key), "m_pad": u.m_pad, "layouts": 0, "packs": 0,
                                             "packed_iters": 0, "alone_iters": 0, "max_score_diff": 0.0})
        row["layouts"] += len(u.items)
        row["packs"] += 1
        row["packed_iters"] += best["packed"][0][u.items[0][0]].iters
        for it in u.items:
            p, q = best["packed"][0][it[0]], best["alone"][0][it[0]]
            row["alone_iters"] += q.iters
            row["max_score_diff"] = max(row["max_score_diff"], max(abs(p.scores[k] - q.scores[k]) for k in p.scores))
    print(f"packed units: {sum(r['packs'] for r in rows.values())} packs of "
          f"{sum(r['layouts'] for r in rows.values())} layouts; warm solve {best['packed'][1]:.3f} s packed, "
          f"{best['alone'][1]:.3f} s alone ({best['alone'][1] / best['packed'][1]:.2f}x)")
    print("| bucket | columns | layouts | packs | iterations packed / alone | largest score difference |")
    print("|---|---|---|---|---|---|")
    for r in rows.values():
        print(f"| {tuple(r['bucket'])} | {r['m_pad']} | {r['layouts']} | {r['packs']} | "
              f"{r['packed_iters']} / {r['alone_iters']} | {r['max_score_diff']:.1e} |")
    if a.json:
        out = {"command": " ".join(["benchmarks/packs.py"] + sys.argv[1:]), "machine": platform.platform(),
               "date": datetime.date.today().isoformat(), "packed_s": best["packed"][1],
               "alone_s": best["alone"][1], "buckets": list(rows.values())}
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
