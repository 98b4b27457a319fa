"""Time versus bricks for ours / luo / eb (the paper's Fig. 7), exact solver.

Usage: python benchmarks/fig7_methods.py [--max-k 10] [--shapes 24] [--milp-cap 20] [--repeats 3]
       [--exact-method highs-ipm]

* Unit-brick cubes k x k x k (k = 1..max_k, up to 1000 bricks).
* Generated shapes: ``--shapes`` layouts spread over the Table II generated
  set (benchmarks/table2.py: procedural families and voxel shapes, with
  floating and overhanging parts; alternately a procedural and a voxel
  one), plus four large voxel blobs (grid 20, 380-1000 bricks).

Per layout and method: wall time of ``analyze_layout(..., solver="exact",
method=m, exact_method=...)`` (compile the model, build and solve the LP,
scores), median of ``--repeats`` runs (one run when the first takes over
2 s). All three use the same HiGHS method, by default interior point
("highs-ipm", the project's choice for layouts of hundreds of bricks: dual
simplex took 38 s for ours on a 630-brick blob). Also the enhanced baseline
with Eq. 4 stated literally as a MILP (``formulation="milp"``), one run
capped at ``--milp-cap`` seconds: a capped run is reported as such, never as
a time. Writes benchmarks/results/fig7_methods.json and
benchmarks/results/fig7_methods.png and prints markdown tables.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))
sys.path.insert(0, HERE)

import numpy as np  # noqa: E402

from stablelego_jax.generate.procedural import cuboid  # noqa: E402
from stablelego_jax.generate.voxels import merge_voxels, random_blob  # noqa: E402
from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.solvers.baselines import METHODS, solve_baseline  # noqa: E402
from stablelego_jax.model import compile_layout  # noqa: E402
from table2 import generated_layouts  # noqa: E402

RES = os.path.join(HERE, "results")


def time_layout(lay, repeats: int, milp_cap: float, exact_method: str) -> dict:
    row = {"n_bricks": lay.n}
    for m in METHODS:
        ts, a = [], None
        for _ in range(repeats):
            a = analyze_layout(lay, solver="exact", method=m, exact_method=exact_method)
            ts.append(a.time_s)
            if a.time_s > 2.0:
                break
        row[m] = {"time_s": float(np.median(ts)), "stable": a.stable, "solvable": a.solvable}
    if milp_cap > 0:
        t0 = time.perf_counter()
        r = solve_baseline(compile_layout(lay), "eb", formulation="milp", time_limit=milp_cap)
        dt = time.perf_counter() - t0
        row["eb_milp"] = {"time_s": dt, "solvable": r.solvable, "capped": r.solvable is None,
                          "agrees_with_lp": r.solvable is None or r.solvable == row["eb"]["solvable"]}
    return row


def shapes(n_shapes: int):
    step = max(240 // max(n_shapes, 1), 2)
    picks = {k * step + k % 2 for k in range(n_shapes)}  # even: procedural, odd: voxel shape
    for i, (name, fam, lay) in enumerate(generated_layouts(240)):
        if i in picks:
            yield name, fam, lay
    for j, fill in enumerate((0.3, 0.45, 0.6, 0.75)):
        s = 777 + j
        yield f"blob_{fill}", "large blob", merge_voxels(random_blob(20, s, fill=fill), seed=s)


def plot(cubes, shp, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.3), dpi=120, sharey=True)
    style = {"ours": ("o-", "tab:blue"), "luo": ("s-", "tab:green"), "eb": ("^-", "tab:orange"),
             "eb_milp": ("x--", "tab:red")}
    label = {"ours": "ours (Eq. 9 LP)", "luo": "Luo et al. (LP)", "eb": "enhanced baseline (LP reduction)",
             "eb_milp": "enhanced baseline, Eq. 4 as MILP"}
    for ax, rows, title in ((axes[0], cubes, "unit-brick cubes k^3"), (axes[1], shp, "generated shapes")):
        rows = sorted(rows, key=lambda r: r["n_bricks"])
        for m in (*METHODS, "eb_milp"):
            got = [r for r in rows if m in r]
            if not got:
                continue
            mk, c = style[m]
            xs = [r["n_bricks"] for r in got]
            ys = [r[m]["time_s"] for r in got]
            if ax is axes[0]:
                ax.plot(xs, ys, mk, color=c, label=label[m], ms=4)
            else:
                ax.scatter(xs, ys, marker=mk[0], color=c, label=label[m], s=14, alpha=0.8)
            capped = [r for r in got if r[m].get("capped")]
            if capped:
                ax.scatter([r["n_bricks"] for r in capped], [r[m]["time_s"] for r in capped], marker="o",
                           facecolors="none", edgecolors="black", s=60, zorder=5,
                           label="MILP stopped at the cap (no answer)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("bricks")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("time per layout (s)")
    axes[1].legend(fontsize=7, loc="upper left")
    fig.suptitle("Analysis time vs layout size, HiGHS via scipy (2 shared CPU cores: noisy)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-k", type=int, default=10)
    ap.add_argument("--shapes", type=int, default=24, help="generated shapes (plus 4 large blobs)")
    ap.add_argument("--milp-cap", type=float, default=20.0, help="seconds per MILP solve (0: skip the MILP)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--exact-method", default="highs-ipm", choices=["highs", "highs-ds", "highs-ipm"])
    args = ap.parse_args(argv)
    os.makedirs(RES, exist_ok=True)
    t_all = time.time()
    cubes = []
    for k in range(1, args.max_k + 1):
        r = time_layout(cuboid(k, k, k), args.repeats, args.milp_cap, args.exact_method)
        r["k"] = k
        cubes.append(r)
        print(f"cube {k}: {json.dumps(r)}", file=sys.stderr, flush=True)
    shp = []
    for name, fam, lay in shapes(args.shapes):
        r = time_layout(lay, args.repeats, args.milp_cap / 2, args.exact_method)
        r.update(name=name, family=fam)
        shp.append(r)
        print(f"{name} {fam}: {json.dumps(r)}", file=sys.stderr, flush=True)
    wall = time.time() - t_all
    meta = {"machine": f"{platform.machine()} {os.cpu_count()} cores (shared with other jobs)",
            "python": platform.python_version(), "repeats": args.repeats, "exact_method": args.exact_method, "milp_cap_cubes_s": args.milp_cap,
            "milp_cap_shapes_s": args.milp_cap / 2, "wall_s": wall}
    with open(os.path.join(RES, "fig7_methods.json"), "w") as fh:
        json.dump({"meta": meta, "cubes": cubes, "shapes": shp}, fh, indent=1)
    plot(cubes, shp, os.path.join(RES, "fig7_methods.png"))

    def milp_cell(r):
        e = r.get("eb_milp")
        if e is None:
            return "-"
        if e["capped"]:
            return f"> {e['time_s']:.0f} (cap, no answer)"
        return f"{e['time_s']:.2f}" + ("" if e["agrees_with_lp"] else " (DISAGREES)")

    print(f"machine: {meta['machine']}, Python {meta['python']}; HiGHS {args.exact_method}; wall {wall:.0f} s")
    print("| cube | bricks | ours s | luo s | eb s (LP) | eb s (MILP) | ours stable / luo, eb solvable |")
    print("|---|---|---|---|---|---|---|")
    for r in cubes:
        print(f"| {r['k']}^3 | {r['n_bricks']} | {r['ours']['time_s']:.3f} | {r['luo']['time_s']:.3f} | "
              f"{r['eb']['time_s']:.3f} | {milp_cell(r)} | {r['ours']['stable']} / {r['luo']['solvable']}, "
              f"{r['eb']['solvable']} |")
    print()
    print("| generated shapes, bricks | # | ours median s | luo median s | eb (LP) median s | eb MILP: solved in cap / capped |")
    print("|---|---|---|---|---|---|")
    for lo, hi in ((1, 30), (31, 100), (101, 300), (301, 2000)):
        rs = [r for r in shp if lo <= r["n_bricks"] <= hi]
        if not rs:
            continue
        med = {m: np.median([r[m]["time_s"] for r in rs]) for m in METHODS}
        mi = [r["eb_milp"] for r in rs if "eb_milp" in r]
        ok = [e for e in mi if not e["capped"]]
        cell = f"{len(ok)} / {len(mi) - len(ok)}" + (f" (median {np.median([e['time_s'] for e in ok]):.2f} s)" if ok else "")
        print(f"| {lo}-{hi} | {len(rs)} | {med['ours']:.3f} | {med['luo']:.3f} | {med['eb']:.3f} | {cell} |")
    bad = [r for r in cubes + shp if "eb_milp" in r and not r["eb_milp"]["agrees_with_lp"]]
    print(f"\nMILP answers that differ from the LP reduction: {len(bad)}")


if __name__ == "__main__":
    main()
