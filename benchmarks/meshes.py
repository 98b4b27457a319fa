"""All meshes of ../shared/meshes through mesh -> voxels -> bricks -> analysis.

Usage: python benchmarks/meshes.py [--meshes DIR] [--grid 20] [--solver exact|jax] [--shard DIR]

Per mesh: voxelise (stablelego_jax.generate.mesh.voxelize, up axis below), merge into
bricks (stablelego_jax.generate.voxels.merge_voxels, seed 0, all eight Table I bricks),
analyse (default: exact solver, HiGHS interior point), and draw the heat
map. Writes
  benchmarks/results/meshes.jsonl              one record per mesh
  benchmarks/results/meshes.md                 the markdown table section
  benchmarks/results/meshes_contact_sheet.png  all heat maps
and prints the markdown section. ``--shard DIR`` also writes every object
as a StableLego dataset folder into DIR.

Up axes: "auto" is y for glTF/GLB (Y-up by the specification) and z
otherwise; the scans and OBJ models below were authored Y-up (checked by
looking at side views of their voxels), so they get y.
"""
import argparse
import json
import os
import platform
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from stablelego_jax.formats.dataset import write_object  # noqa: E402
from stablelego_jax.generate.mesh import MESH_SUFFIXES, MeshError, voxelize  # noqa: E402
from stablelego_jax.generate.voxels import floating_bricks, merge_voxels  # noqa: E402
from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.render import contact_sheet  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(HERE, "results")
Y_UP = {"bunny.ply", "chair_model.obj", "rabbit.obj", "target.obj", "tube.obj", "wallhole.obj"}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", default=os.path.join(HERE, "..", "..", "shared", "meshes"))
    ap.add_argument("--grid", type=int, default=20)
    ap.add_argument("--solver", choices=["exact", "jax"], default="exact")
    ap.add_argument("--shard", help="also write the dataset objects into this folder")
    args = ap.parse_args(argv)
    names = sorted(f for f in os.listdir(args.meshes) if f.lower().endswith(MESH_SUFFIXES))
    os.makedirs(RESULTS, exist_ok=True)
    recs, sheet = [], []
    t_all = time.perf_counter()
    for k, name in enumerate(names, 1):
        path = os.path.join(args.meshes, name)
        up = "y" if name in Y_UP else "auto"
        rec = {"mesh": name}
        try:
            t0 = time.perf_counter()
            v = voxelize(path, grid=args.grid, up=up)
            t1 = time.perf_counter()
            lay = merge_voxels(v.vox, seed=0, source=path)
            t2 = time.perf_counter()
            a = analyze_layout(lay, solver=args.solver, exact_method="highs-ipm", exact_scale=True)
            t3 = time.perf_counter()
        except MeshError as exc:
            rec["error"] = str(exc)
            recs.append(rec)
            print(f"[{k}/{len(names)}] {name}: ERROR {exc}", file=sys.stderr, flush=True)
            continue
        w = lay.keys.index(a.weakest)
        s = np.array([a.scores[key] for key in lay.keys])
        drag = np.array([a.max_drag[key] for key in lay.keys])
        torn = (s >= 1) & (drag >= a.model.params.T)  # knobs pulled apart (drag reaches T)
        rec.update({
            "format": os.path.splitext(name)[1].lower().lstrip("."),
            "up": v.up, "watertight": v.watertight, "fill": v.fill, "faces": v.n_faces,
            "voxels": int(v.vox.sum()), "bricks": lay.n,
            "stable": a.stable, "n_failing": int((s >= 1).sum()), "n_torn": int(torn.sum()),
            "n_unbalanced": int(((s >= 1) & ~torn).sum()), "floating": int(floating_bricks(lay).sum()),
            "weakest": a.weakest, "weakest_score": float(s[w]),
            "weakest_brick": f"{lay.size[w, 0]}x{lay.size[w, 1]} at ({lay.pos[w, 0]},{lay.pos[w, 1]},{lay.pos[w, 2]})",
            "solver": a.solver, "converged": a.converged,
            "voxelize_s": t1 - t0, "merge_s": t2 - t1, "analysis_s": t3 - t2, "total_s": t3 - t0,
        })
        recs.append(rec)
        sheet.append((f"{name} ({lay.n})", lay, s))
        if args.shard:
            stem = os.path.splitext(name)[0]
            write_object(os.path.join(args.shard, stem), lay, scores=s, vox=v.vox, overwrite=True,
                         meta={"source": path, "up": v.up, "fill": v.fill, "seed": 0})
        print(f"[{k}/{len(names)}] {name}: {rec['voxels']} voxels, {lay.n} bricks, "
              f"{'stable' if a.stable else 'UNSTABLE'}, {rec['total_s']:.1f} s", file=sys.stderr, flush=True)
    wall = time.perf_counter() - t_all
    with open(os.path.join(RESULTS, "meshes.jsonl"), "w") as fh:
        for r in recs:
            fh.write(json.dumps(r) + "\n")
    t = time.perf_counter()
    contact_sheet(sheet, os.path.join(RESULTS, "meshes_contact_sheet.png"), cols=6, dpi=80, panel_in=2.6)
    t_sheet = time.perf_counter() - t
    md = table(recs, args, wall, t_sheet)
    with open(os.path.join(RESULTS, "meshes.md"), "w") as fh:
        fh.write(md)
    print(md)


def table(recs, args, wall, t_sheet) -> str:
    ok = [r for r in recs if "error" not in r]
    bad = [r for r in recs if "error" in r]
    solver = "exact (HiGHS interior point + crossover, torque rows in N stud)" if args.solver == "exact" else "jax (interior point)"
    lines = [
        "## Meshes to bricks (issue 3)",
        "",
        f"`python benchmarks/meshes.py` (grid {args.grid}, brick merge seed 0 with all eight Table I bricks, "
        f"stability by the **{solver}** solver; machine: {platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}, CPU only). "
        f"{len(ok)} of {len(recs)} meshes went through mesh -> voxels -> bricks -> analysis"
        + (f"; {len(bad)} failed (see below)." if bad else " without error.")
        + f" Wall time {wall:.0f} s for all, plus {t_sheet:.0f} s for the contact sheet "
        "`benchmarks/results/meshes_contact_sheet.png`; per-mesh records in `benchmarks/results/meshes.jsonl`.",
        "",
        "| mesh | up | watertight / fill | voxels | bricks | stable | failing: drag >= T / unbalanced (floating) | weakest brick: key, size at cell, score | voxelise ms | analysis s | total s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in recs:
        if "error" in r:
            lines.append(f"| {r['mesh']} | | | | | error | | {r['error']} | | | |")
            continue
        lines.append(
            f"| {r['mesh']} | {r['up']} | {'yes' if r['watertight'] else 'no'} / {r['fill']} | {r['voxels']} | "
            f"{r['bricks']} | {'yes' if r['stable'] else '**no**'} | {r['n_torn']} / {r['n_unbalanced']} ({r['floating']}) | "
            f"{r['weakest']}, {r['weakest_brick']}, {r['weakest_score']:.4f} | {1e3 * r['voxelize_s']:.0f} | "
            f"{r['analysis_s']:.2f} | {r['total_s']:.2f} |"
        )
    n_st = sum(r["stable"] for r in ok)
    n_fl = sum(r["floating"] > 0 for r in ok if not r["stable"])
    n_torn = sum(r["n_torn"] > 0 for r in ok if not r["stable"])
    lines += [
        "",
        f"{n_st} of {len(ok)} layouts stand. Of the {len(ok) - n_st} that do not, {n_fl} have floating "
        "bricks (no chain of knob connections down to the baseplate: they cannot be balanced, and the L1 "
        "residual of a floating group may sit on one of its bricks, so 'unbalanced' can be smaller than "
        f"'floating') and {n_torn} {'has' if n_torn == 1 else 'have'} bricks whose knob drag reaches T. "
        "Weakest-brick ties at score 0 "
        "are broken arbitrarily.",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
