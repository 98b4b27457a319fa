"""Repair benchmark (issue 5): gradient-guided repair vs greedy search vs LLM rollback.

Usage: python benchmarks/repair.py [--n 100] [--out benchmarks/results/repair.jsonl]
                                   [--max-add 4] [--verify 3] [--max-bricks 60] [--table]

Layouts: seeded, exactly-unstable (HiGHS) layouts from five families, in
turn: cantilever staircases (``stairs``), leaning towers (``tower``: every
layer overhangs the one below), cantilevered beams carrying 1-3 load blocks
(``lever``, like the paper's stick_heavy), short stairs with a load block
on top (``loaded``, like external_weight_fail) and voxel shapes with
overhangs merged into bricks (``voxels``: overhang, arch, boxes and blob
kinds), at most ``--max-bricks`` bricks each. Stairs and towers overlap
each level by at least half a brick, and layouts with more failing bricks
than the brick budget ``--max-add`` are skipped (a staircase failing at
every one of its 24 levels cannot be saved by four bricks, whatever the
method).

For each layout it runs (a) :func:`stablelego_jax.design.repair.repair`
(gradient-guided), (b) :func:`~stablelego_jax.design.repair.greedy_repair` (every
candidate checked with a full exact solve each step) and (c)
:func:`~stablelego_jax.design.repair.rollback_repair` (remove the first failing
brick and everything after it until stable), and records success (the
exact solver says the result stands), bricks added, solver calls (exact
HiGHS solves; the gradient method also counts each differentiable solve +
gradient as one call), wall time (including JIT compilation of new
shapes) and the fraction of the original bricks kept.

Rows are appended to ``--out`` (JSON lines) as they finish; rerunning skips
layouts already there. ``--table`` prints the summary table from the file.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

# one BLAS thread: the differentiable solver's small dense LUs are ~100x
# slower with OpenBLAS' spinning threads on a busy machine (set before numpy loads)
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import numpy as np  # noqa: E402

from stablelego_jax.generate.procedural import lever, stairs, tower, voxel_layout  # noqa: E402
from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.batch import read_results  # noqa: E402
from stablelego_jax.design.repair import RepairOptions, greedy_repair, repair, rollback_repair  # noqa: E402
from stablelego_jax.solvers.compiled import STATS  # noqa: E402

FAMILIES = ("stairs", "tower", "lever", "loaded", "voxels")
METHODS = {"gradient": repair, "greedy": greedy_repair, "rollback": rollback_repair}


def draw(family: str, seed: int):
    """A seeded layout of ``family`` (may be stable; the caller filters)."""
    rng = np.random.default_rng([FAMILIES.index(family), seed])
    ri = lambda lo, hi: int(rng.integers(lo, hi + 1))  # noqa: E731  inclusive
    if family == "stairs":  # cantilever staircases
        sx = int(rng.choice([4, 6]))
        return stairs(ri(8, 30), step=ri(1, sx // 2), brick=(sx, int(rng.choice([1, 2]))))
    if family == "tower":  # leaning towers: every layer overhangs the one below
        fx = int(rng.choice([2, 4, 6]))
        return tower(ri(4, 14), (fx, ri(1, 2)), lean=ri(1, max(fx // 2, 1)), seed=seed)
    if family == "lever":  # cantilevered beams carrying 1-3 load blocks (like stick_heavy)
        n_loads = ri(1, 3)
        beam, base_len = ri(6, 30), ri(4, 8)
        lx = rng.choice(np.arange(0, base_len + beam - 1, 2), size=n_loads, replace=False)
        return lever(beam, base_len=base_len, base_height=ri(1, 3),
                     loads=[float(rng.choice([0.1, 0.2, 0.3])) for _ in range(n_loads)],
                     load_x=sorted(lx.tolist()), width=ri(1, 2), blen=int(rng.choice([4, 6])))
    if family == "loaded":  # short stairs with a load block on top (like external_weight_fail)
        return stairs(ri(2, 7), load_kg=float(rng.choice([0.05, 0.1, 0.2, 0.3])), load_offset=ri(0, 2))
    kind = str(rng.choice(["overhang", "overhang", "arch", "boxes", "blob"]))
    return voxel_layout(int(rng.integers(2**31)), grid=ri(8, 12), kind=kind)


def layouts(n: int, max_bricks: int, max_failing: int):
    """(name, layout) of the first ``n`` unstable layouts with at most
    ``max_failing`` failing bricks, families in turn."""
    seeds = {f: 0 for f in FAMILIES}
    out = []
    k = 0
    while len(out) < n:
        fam = FAMILIES[k % len(FAMILIES)]
        k += 1
        while True:
            seed = seeds[fam]
            seeds[fam] += 1
            lay = draw(fam, seed)
            if lay.n > max_bricks:
                continue
            a = analyze_layout(lay, solver="exact")
            if not a.stable and sum(v >= 1.0 for v in a.scores.values()) <= max_failing:
                out.append((f"{fam}/{seed}", lay))
                break
            if seeds[fam] > 5000:
                raise RuntimeError(f"family {fam}: no unstable layout in 5000 draws")
    return out


def run(name, lay, opts: RepairOptions) -> dict:
    row = {"name": name, "family": name.split("/")[0], "n_bricks": lay.n}
    for m, fn in METHODS.items():
        c0, s0, e0 = STATS.compiles, STATS.compile_s, STATS.evicted
        t = time.perf_counter()
        r = fn(lay, opts)
        row[m] = {
            "compiles": STATS.compiles - c0, "compile_s": round(STATS.compile_s - s0, 3), "evicted": STATS.evicted - e0,
            "stable": bool(r.stable), "added": r.added, "exact_calls": r.exact_calls, "soft_calls": r.soft_calls,
            "solver_calls": r.solver_calls, "time_s": round(time.perf_counter() - t, 3), "kept": round(r.kept, 4),
            "changes": [c.describe() for c in r.changes],
        }
    return row


def table(rows) -> str:
    n = len(rows)
    counts = ", ".join(f"{f} {sum(r['family'] == f for r in rows)}" for f in FAMILIES)
    lines = [f"{n} unstable layouts ({counts}):",
             "",
             "| method | success | bricks added (mean, successes) | solver calls (mean) | calls / greedy's | "
             "wall time (mean, median) | original bricks kept |",
             "|---|---|---|---|---|---|---|"]
    greedy_calls = np.mean([r["greedy"]["solver_calls"] for r in rows])
    for m in METHODS:
        ok = [r[m]["stable"] for r in rows]
        add = [r[m]["added"] for r in rows if r[m]["stable"]]
        calls = [r[m]["solver_calls"] for r in rows]
        ts = [r[m]["time_s"] for r in rows]
        kept = [r[m]["kept"] for r in rows]
        extra = ""
        if m == "gradient":
            extra = f" ({np.mean([r[m]['soft_calls'] for r in rows]):.2f} differentiable)"
        lines.append(
            f"| {m} | {sum(ok)}/{n} ({100 * np.mean(ok):.0f}%) | {np.mean(add) if add else float('nan'):.2f} | "
            f"{np.mean(calls):.1f}{extra} | {np.mean(calls) / greedy_calls:.2f} | "
            f"{np.mean(ts):.2f} s, {np.median(ts):.2f} s | {100 * np.mean(kept):.1f}% |")
    lines.append("")
    if all("compiles" in r["gradient"] for r in rows):
        for m in METHODS:
            comp = sum(r[m]["compiles"] for r in rows)
            cs = sum(r[m]["compile_s"] for r in rows)
            ts = sum(r[m]["time_s"] for r in rows)
            lines.append(f"- {m}: {comp} executables compiled ({cs:.1f} s of {ts:.1f} s wall, "
                         f"{sum(r[m]['evicted'] for r in rows)} evicted); wall without compiles "
                         f"{(ts - cs) / n:.2f} s per layout")
        lines.append("")
    both = [r for r in rows if r["gradient"]["stable"] and r["greedy"]["stable"]]
    g_only = [r["name"] for r in rows if r["gradient"]["stable"] and not r["greedy"]["stable"]]
    r_only = [r["name"] for r in rows if r["greedy"]["stable"] and not r["gradient"]["stable"]]
    lines.append(f"Both repaired {len(both)}; gradient only: {len(g_only)} {g_only[:8]}; "
                 f"greedy only: {len(r_only)} {r_only[:8]}.")
    if both:
        lines.append(f"Where both repaired: bricks added gradient {np.mean([r['gradient']['added'] for r in both]):.2f} "
                     f"vs greedy {np.mean([r['greedy']['added'] for r in both]):.2f}; solver calls gradient "
                     f"{np.mean([r['gradient']['solver_calls'] for r in both]):.1f} vs greedy "
                     f"{np.mean([r['greedy']['solver_calls'] for r in both]):.1f}.")
    for f in FAMILIES:
        rs = [r for r in rows if r["family"] == f]
        if rs:
            lines.append(f"- {f}: " + ", ".join(f"{m} {sum(r[m]['stable'] for r in rs)}/{len(rs)}" for m in METHODS))
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "repair.jsonl"))
    ap.add_argument("--max-add", type=int, default=4)
    ap.add_argument("--verify", type=int, default=3)
    ap.add_argument("--max-bricks", type=int, default=60)
    ap.add_argument("--table", action="store_true", help="only print the table of --out")
    args = ap.parse_args()
    done = read_results(args.out, key="name")  # drops a torn last line after a kill
    if not args.table:
        opts = RepairOptions(max_add=args.max_add, verify=args.verify)
        print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; {opts}", flush=True)
        for name, lay in layouts(args.n, args.max_bricks, args.max_add):
            if name in done:
                continue
            row = run(name, lay, opts)
            done[name] = row
            with open(args.out, "a") as fh:
                fh.write(json.dumps(row) + "\n")
            print(name, lay.n, " ".join(f"{m}: {'ok' if row[m]['stable'] else 'FAIL'} +{row[m]['added']} "
                                        f"{row[m]['solver_calls']} calls {row[m]['time_s']:.1f}s"
                                        for m in METHODS), flush=True)
    rows = [r for r in done.values()][: args.n]
    print(table(rows))


if __name__ == "__main__":
    main()
