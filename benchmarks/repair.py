"""Repair benchmark (issues 5 and 19): gradient-guided repair vs greedy search vs LLM rollback.

Usage: python benchmarks/repair.py [--set small|large] [--n 100] [--out FILE] [--methods gradient,greedy,rollback]
                                   [--max-add K|auto] [--verify 3] [--max-bricks 60] [--time S] [--table]

``--set large`` (issue 19): the shared meshes voxelised at grids 10-24
(even) with each of the up axes z, y and x, merged into bricks
(merge_voxels, seed 0), in a seeded random order; the first ``--n`` that
the exact solver says fail and have at most ``--max-bricks`` bricks
(default 800 for this set). Many have parts that touch nothing leading to
the ground (a handle, a hovering roof): rollback deletes them, repair must
carry them. Default budget: auto (max(4, n/4) bricks), ``--time 300`` s per
method and layout; the candidate list of each step is kept in
``results/repair_large_set.jsonl`` (resumable). Results go to
``results/repair_large.jsonl``. ``--methods`` runs some methods only; a
later run with the others completes the rows.

The rest of this docstring describes ``--set small`` (the default).

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
shapes) and the fraction of the original bricks kept; for the gradient
method also the padded shape of each differentiable solve, and the table
counts the distinct shapes and ladder rungs (issue 18: at most one compile
per rung touched).

Rows are appended to ``--out`` (JSON lines) as they finish; rerunning skips
layouts already there. ``--table`` prints the summary table from the file.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time

# one BLAS thread: the differentiable solver's small dense factorisations are ~100x
# slower with OpenBLAS' spinning threads on a busy machine (set before numpy loads)
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402

from stablelego_jax.generate.procedural import lever, stairs, tower, voxel_layout  # noqa: E402
from stablelego_jax.analysis import analyze_layout  # noqa: E402
from rows import append_row, read_rows  # noqa: E402
from stablelego_jax.design.repair import RepairOptions, greedy_repair, repair, rollback_repair  # noqa: E402
from stablelego_jax.solvers.compiled import STATS  # noqa: E402
import stablelego_jax.design.repair as _repair_module  # noqa: E402

#: The padded shape of every soft problem the gradient method solves in this
#: process (recorded around ``repair``'s ``plan_soft``): (bricks, columns,
#: contact slots, layers, slots per layer, column chunks).
SOFT_SHAPES: list = []
_plan_soft = _repair_module.plan_soft


def _recorded_plan_soft(prob, calls=1):
    q = _plan_soft(prob, calls)
    L, B = (0, 0) if q.layers is None else q.layers.shape
    SOFT_SHAPES.append((q.mass.shape[0], q.col_kind.shape[0], q.group.shape[1], L, B,
                        0 if q.chunk is None else q.chunk.shape[0]))
    return q


_repair_module.plan_soft = _recorded_plan_soft


def rung_of(shape) -> list:
    """The ladder rung a padded soft shape belongs to: its bricks (dense) or
    its layers and slots per layer (layered)."""
    n, _, _, L, B, _ = shape
    return ["layered", L, B] if L else ["dense", n]

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


MESHES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "meshes")
LARGE_GRIDS = (10, 12, 14, 16, 18, 20, 22, 24)
UPS = ("z", "y", "x")


def mesh_layout(name: str):
    """The layout of a large-set name ``mesh/<file>/g<grid>/<up>``."""
    from stablelego_jax.generate.mesh import voxelize
    from stablelego_jax.generate.voxels import merge_voxels

    _, f, g, up = name.split("/")
    return merge_voxels(voxelize(os.path.join(MESHES, f), grid=int(g[1:]), up=up).vox, seed=0)


def large_layouts(n: int, max_bricks: int, set_file: str):
    """Yields (name, layout) of the first ``n`` unstable mesh layouts of at most
    ``max_bricks`` bricks, configurations in a seeded random order; each
    configuration's verdict is kept in ``set_file``."""
    from stablelego_jax.generate.mesh import MESH_SUFFIXES

    files = sorted(f for f in os.listdir(MESHES) if f.lower().endswith(MESH_SUFFIXES))
    names = [f"mesh/{f}/g{g}/{up}" for f in files for g in LARGE_GRIDS for up in UPS]
    names = [names[i] for i in np.random.default_rng(19).permutation(len(names))]
    seen = read_rows(set_file, "name")
    found = 0
    for name in names:
        if found >= n:
            break
        row = seen.get(name)
        if row is not None and (row["n_bricks"] > max_bricks or row["stable"]):
            continue
        lay = mesh_layout(name)
        if row is None:
            row = {"name": name, "n_bricks": lay.n, "stable": None, "failing": None}
            if lay.n <= max_bricks:
                a = analyze_layout(lay, solver="exact")
                row.update(stable=bool(a.stable), failing=int(sum(v >= 1.0 for v in a.scores.values())))
            append_row(set_file, row)
            print(f"  set: {name}: {lay.n} bricks, " + ("too many" if row["stable"] is None else
                  "stands" if row["stable"] else f"{row['failing']} failing"), file=sys.stderr, flush=True)
        if lay.n <= max_bricks and not row["stable"]:
            found += 1
            yield name, lay


def run(name, lay, opts: RepairOptions, methods=tuple(METHODS), row=None) -> dict:
    row = dict(row or {"name": name, "family": name.split("/")[0], "n_bricks": lay.n})
    for m in methods:
        fn = METHODS[m]
        c0, s0, e0, k0 = STATS.compiles, STATS.compile_s, STATS.evicted, len(SOFT_SHAPES)
        t = time.perf_counter()
        r = fn(lay, opts)
        row[m] = {
            "compiles": STATS.compiles - c0, "compile_s": round(STATS.compile_s - s0, 3), "evicted": STATS.evicted - e0,
            "stable": bool(r.stable), "added": r.added, "exact_calls": r.exact_calls, "soft_calls": r.soft_calls,
            "solver_calls": r.solver_calls, "time_s": round(time.perf_counter() - t, 3), "kept": round(r.kept, 4),
            "changes": [c.describe() for c in r.changes],
            "soft_shapes": [list(k) for k in SOFT_SHAPES[k0:]],
        }
    return row


def table(rows) -> str:
    rows = [r for r in rows if all(m in r for m in METHODS)]
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
        if all("soft_shapes" in r["gradient"] for r in rows):
            shapes = {tuple(k) for r in rows for k in r["gradient"]["soft_shapes"]}
            rungs = {tuple(rung_of(k)) for k in shapes}
            lines.append(f"- gradient: {sum(len(r['gradient']['soft_shapes']) for r in rows)} differentiable solves in "
                         f"{len(shapes)} padded shapes over {len(rungs)} ladder rungs (dense: bricks; layered: "
                         f"layers x slots); {sum(r['gradient']['compiles'] for r in rows)} compiles")
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
    for f in FAMILIES + ("mesh",):
        rs = [r for r in rows if r["family"] == f]
        if rs:
            lines.append(f"- {f}: " + ", ".join(f"{m} {sum(r[m]['stable'] for r in rs)}/{len(rs)}" for m in METHODS))
    return "\n".join(lines)


def large_table(rows) -> str:
    """The large set's table: every method over the layouts it ran on (greedy
    may have run on the first ones only), with the gradient method on the
    same layouts beside it."""
    lines = ["| method | layouts | success | success keeping every original brick | bricks added (mean, median; "
             "successes) | exact solves (mean) | differentiable solves (mean) | wall time (mean, median, max) | "
             "original bricks kept (mean) |",
             "|---|---|---|---|---|---|---|---|---|"]
    grad = [r for r in rows if "gradient" in r]
    for m in METHODS:
        rs = [r for r in rows if m in r]
        if not rs:
            continue
        subsets = [(m, rs)]
        if m != "gradient" and len(rs) < len(grad):
            subsets.append(("gradient, same layouts", [r for r in rs if "gradient" in r]))
        for label, sub in subsets:
            key = m if label == m else "gradient"
            x = [r[key] for r in sub]
            ok = [v["stable"] for v in x]
            keep_all = [v["stable"] and v["kept"] == 1.0 for v in x]
            add = [v["added"] for v in x if v["stable"]]
            ts = [v["time_s"] for v in x]
            lines.append(
                f"| {label} | {len(x)} | {sum(ok)} ({100 * np.mean(ok):.1f}%) | {sum(keep_all)} "
                f"({100 * np.mean(keep_all):.1f}%) | {np.mean(add) if add else float('nan'):.1f}, "
                f"{np.median(add) if add else float('nan'):.0f} | {np.mean([v['exact_calls'] for v in x]):.1f} | "
                f"{np.mean([v['soft_calls'] for v in x]):.2f} | {np.mean(ts):.1f} s, {np.median(ts):.1f} s, "
                f"{max(ts):.1f} s | {100 * np.mean([v['kept'] for v in x]):.1f}% |")
    n = [r["n_bricks"] for r in grad]
    if n:
        lines.append("")
        lines.append(f"{len(grad)} layouts of {min(n)}-{max(n)} bricks (median {np.median(n):.0f}).")
        comp = sum(r["gradient"]["compile_s"] for r in grad)
        lines.append(f"gradient: {comp:.0f} s of its {sum(r['gradient']['time_s'] for r in grad):.0f} s wall "
                     f"compiling ({sum(r['gradient']['compiles'] for r in grad)} executables).")
        fails = [r["name"] for r in grad if not r["gradient"]["stable"]]
        lines.append(f"gradient failures: {fails}")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--set", choices=["small", "large"], default="small")
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--out", default=None, help="default results/repair.jsonl (small), repair_large.jsonl (large)")
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--max-add", default=None, help="integer or auto (default: 4 for small, auto for large)")
    ap.add_argument("--verify", type=int, default=3)
    ap.add_argument("--max-bricks", type=int, default=None, help="default 60 (small), 800 (large)")
    ap.add_argument("--time", type=float, default=None, help="seconds per method and layout (default: none "
                    "for small, 300 for large)")
    ap.add_argument("--table", action="store_true", help="only print the table of --out")
    args = ap.parse_args()
    large = args.set == "large"
    res = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
    out = args.out or os.path.join(res, "repair_large.jsonl" if large else "repair.jsonl")
    methods = [m for m in args.methods.split(",") if m]
    bad = [m for m in methods if m not in METHODS]
    if bad:
        ap.error(f"unknown methods {bad}; choose from {list(METHODS)}")
    max_add = args.max_add or ("auto" if large else "4")
    max_bricks = args.max_bricks or (800 if large else 60)
    time_s = args.time if args.time is not None else (300.0 if large else None)
    done = read_rows(out, "name")
    if not args.table:
        opts = RepairOptions(max_add=None if max_add == "auto" else int(max_add), verify=args.verify, time_s=time_s)
        print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; {opts}", flush=True)
        todo = (large_layouts(args.n, max_bricks, os.path.join(res, "repair_large_set.jsonl")) if large
                else layouts(args.n, max_bricks, opts.max_add))
        for name, lay in todo:
            missing = [m for m in methods if m not in done.get(name, {})]
            if not missing:
                continue
            row = run(name, lay, opts, missing, done.get(name))
            done[name] = row
            append_row(out, row)
            print(name, lay.n, " ".join(f"{m}: {'ok' if row[m]['stable'] else 'FAIL'} +{row[m]['added']} "
                                        f"{row[m]['solver_calls']} calls {row[m]['time_s']:.1f}s"
                                        for m in missing), flush=True)
    rows = [r for r in done.values()][: args.n]
    print(large_table(rows) if large else table(rows))


if __name__ == "__main__":
    main()
