"""The shape of the paper's Table II for ours / luo / eb on labelled layouts.

Usage:
  python benchmarks/table2.py reference            # the 8 StableLego structures, physical outcomes
  python benchmarks/table2.py generated [--n 240]  # generated layouts, label = ours (exact)
  python benchmarks/table2.py files DIR_OR_FILES... --labels labels.json
  python benchmarks/table2.py meshes               # the shared meshes (grid 20), label = ours

Per set and method: # layouts, # solvable and solvability (a baseline is
solvable when a force distribution meets equilibrium and D <= T; ours
always gives an answer), # false among the solvable ones (predicted label
differs from the reference label; a baseline predicts "stable" exactly when
solvable) and stability accuracy = (solvable - false) / solvable, as in the
paper. Extra column: "stable, unsolvable": reference-stable layouts a method
leaves unsolved (not counted by the paper's accuracy). Sets:

* reference: labels.json of ../shared/reference/stablelego (what happened
  when the structures were built).
* generated: ``--n`` seeded layouts, label = our exact answer (so ours is
  100% by construction; the point is where the baselines fail). Half are
  ``stablelego_jax.generate.procedural.random_family_layout`` draws (stairs, loaded
  stairs, levers, towers, bridges, walls, cuboids, pallets, voxel shapes,
  layouts with floating bricks), half voxel shapes (blob, boxes, spheres,
  arch, overhang, floating) on 10-16 grids merged into bricks, every other
  one by the greedy pass alone (``repair=False``: bricks left hanging from
  overhangs, as a plain greedy merge leaves them) and the others with the
  repair pass.
* files: any layouts with a labels JSON ``{name: {"stable": bool}}`` (name =
  file name or path as given).
* meshes: every mesh of ../shared/meshes voxelised (grid 20, up axes as
  benchmarks/meshes.py) and merged; label = ours.

Rows go to benchmarks/results/table2_<set>.jsonl (resumable per set; rows of
other settings are recomputed) and the markdown tables to stdout.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import numpy as np  # noqa: E402

from stablelego_jax.generate.procedural import random_family_layout  # noqa: E402
from stablelego_jax.generate.voxels import SHAPE_KINDS, floating_bricks, merge_voxels, random_voxel_shape  # noqa: E402
from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.solvers.baselines import METHODS  # noqa: E402
from stablelego_jax.files import atomic_write_text
from stablelego_jax.formats.reader import load_layout  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
RES = os.path.join(HERE, "results")
SHARED = os.path.join(HERE, "..", "..", "shared")
REF = os.path.join(SHARED, "reference", "stablelego")
SETTINGS = "v1 exact highs scaled; generated: half random_family_layout, half voxel shapes (alternate repair)"


def overhang_bricks(layout) -> int:
    """Bricks with a cell that has nothing directly below it (above layer 0)."""
    occ = layout.occupancy()
    out = 0
    for (x, y, z), (sx, sy) in zip(layout.pos.tolist(), layout.size.tolist()):
        if z > 0 and (occ[x:x + sx, y:y + sy, z - 1] < 0).any():
            out += 1
    return out


def generated_layouts(n: int):
    """Yield (name, family, Layout) of the generated set (module doc)."""
    for i in range(n):
        if i % 2 == 0:
            fam, lay = random_family_layout(1000 + i)
            yield f"gen_{i:04d}", fam, lay
        else:
            rng = np.random.default_rng(5000 + i)
            kind = SHAPE_KINDS[(i // 2) % len(SHAPE_KINDS)]
            s = int(rng.integers(2**31))
            grid = int(rng.integers(10, 17))
            vox = random_voxel_shape(s, grid, kind)
            if not vox.any():
                vox[:2, :2, :2] = True
            repair = (i // 2) % 2 == 0
            lay = merge_voxels(vox, seed=s, repair=repair, source=f"<voxels {kind} seed={s}>")
            yield f"gen_{i:04d}", f"voxels/{kind}" + ("" if repair else " (greedy only)"), lay


def reference_layouts():
    labels = json.load(open(os.path.join(REF, "labels.json")))
    for name in sorted(k for k in labels if not k.startswith("_")):
        yield name, "reference", load_layout(os.path.join(REF, name)), labels[name]["stable"]


def _mesh_layouts(grid: int = 20):
    from stablelego_jax.generate.mesh import MESH_SUFFIXES, voxelize

    sys.path.insert(0, HERE)
    from meshes import Y_UP  # the up axes chosen for benchmarks/meshes.py

    d = os.path.join(SHARED, "meshes")
    for name in sorted(f for f in os.listdir(d) if f.lower().endswith(MESH_SUFFIXES)):
        try:
            v = voxelize(os.path.join(d, name), grid=grid, up="y" if name in Y_UP else "auto")
        except Exception as exc:  # a mesh that cannot be read is skipped, as in meshes.py
            print(f"skip {name}: {exc}", file=sys.stderr)
            continue
        if not v.vox.any():
            continue
        yield name, "mesh", merge_voxels(v.vox, seed=0, source=name)


def run_one(name: str, family: str, lay, label: bool | None) -> dict:
    row = {"name": name, "family": family, "n_bricks": lay.n, "settings": SETTINGS,
           "floating": int(floating_bricks(lay).sum()), "overhanging": overhang_bricks(lay)}
    for m in METHODS:
        a = analyze_layout(lay, solver="exact", method=m)
        row[m] = {"stable": a.stable, "solvable": a.solvable, "converged": a.converged,
                  "weakest": a.weakest, "time_s": a.time_s}
    row["label"] = row["ours"]["stable"] if label is None else bool(label)
    row["label_source"] = "ours (exact)" if label is None else "physical"
    return row


def table(rows: list[dict], title: str) -> str:
    n = len(rows)
    lines = [f"**{title}** ({n} layouts, {sum(r['label'] for r in rows)} stable by the reference label)", "",
             "| method | # solvable | solvability | # false | stability accuracy | stable, unsolvable |",
             "|---|---|---|---|---|---|"]
    for m in METHODS:
        solv = [r for r in rows if r[m]["solvable"]]
        false = sum(r[m]["stable"] != r["label"] for r in solv)
        missed = sum(r["label"] and not r[m]["solvable"] for r in rows)
        acc = f"{100 * (len(solv) - false) / len(solv):.1f}%" if solv else "n/a"
        lines.append(f"| {m} | {len(solv)}/{n} | {100 * len(solv) / max(n, 1):.1f}% | {false} | {acc} | {missed} |")
    return "\n".join(lines)


def breakdown(rows: list[dict]) -> str:
    """Solvability of the baselines by what the layout contains."""
    groups = {
        "floating bricks (no knob chain to the ground)": [r for r in rows if r["floating"]],
        "no floating brick, overhanging bricks": [r for r in rows if not r["floating"] and r["overhanging"]],
        "neither": [r for r in rows if not r["floating"] and not r["overhanging"]],
    }
    lines = ["| layouts | # | ours stable | luo solvable | eb solvable |", "|---|---|---|---|---|"]
    for g, rs in groups.items():
        if rs:
            lines.append(f"| {g} | {len(rs)} | {sum(r['ours']['stable'] for r in rs)} | "
                         f"{sum(bool(r['luo']['solvable']) for r in rs)} | {sum(bool(r['eb']['solvable']) for r in rs)} |")
    return "\n".join(lines)


def per_layout(rows: list[dict]) -> str:
    lines = ["| layout | bricks | label | ours: stable / weakest | luo: solvable / most loaded | eb: solvable / most loaded |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        cell = lambda m: f"{r[m]['solvable'] if m != 'ours' else r[m]['stable']} / {r[m]['weakest']}"  # noqa: E731
        lines.append(f"| {r['name']} | {r['n_bricks']} | {'stable' if r['label'] else 'breaks'} | "
                     f"{cell('ours')} | {cell('luo')} | {cell('eb')} |")
    return "\n".join(lines)


def timing(rows: list[dict]) -> str:
    return ", ".join(f"{m} median {1e3 * np.median([r[m]['time_s'] for r in rows]):.1f} ms" for m in METHODS)


def load_rows(path: str) -> dict:
    done = {}
    if os.path.exists(path):
        for line in open(path):
            try:
                r = json.loads(line)
            except json.JSONDecodeError:
                continue  # a torn last line
            if r.get("settings") == SETTINGS:
                done[r["name"]] = r
        atomic_write_text(path, "".join(json.dumps(r) + "\n" for r in done.values()))
    return done


def run_set(tag: str, items, path: str) -> list[dict]:
    done = load_rows(path)
    rows = []
    t0 = time.time()
    with open(path, "a") as fh:
        for k, (name, fam, lay, label) in enumerate(items, 1):
            if name not in done:
                done[name] = run_one(name, fam, lay, label)
                fh.write(json.dumps(done[name]) + "\n")
                fh.flush()
            rows.append(done[name])
            print(f"\r[{tag} {k}] {time.time() - t0:.0f}s", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return rows


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("set", choices=["reference", "generated", "files", "meshes"])
    ap.add_argument("paths", nargs="*", help="layouts or folders (set 'files')")
    ap.add_argument("--labels", help="labels JSON {name: {'stable': bool}} (set 'files')")
    ap.add_argument("--n", type=int, default=240, help="generated layouts (default 240)")
    ap.add_argument("--per-layout", action="store_true", help="also print one row per layout")
    args = ap.parse_args(argv)
    os.makedirs(RES, exist_ok=True)
    path = os.path.join(RES, f"table2_{args.set}.jsonl")
    if args.set == "reference":
        items = list(reference_layouts())
        title = "Reference structures (physical outcomes)"
    elif args.set == "generated":
        items = [(nm, fam, lay, None) for nm, fam, lay in generated_layouts(args.n)]
        title = "Generated layouts (reference label: ours, exact)"
    elif args.set == "meshes":
        items = [(nm, fam, lay, None) for nm, fam, lay in _mesh_layouts()]
        title = "Shared meshes, grid 20 (reference label: ours, exact)"
    else:
        from stablelego_jax.batch import find_layouts

        if not args.labels or not args.paths:
            ap.error("set 'files' needs layout paths and --labels")
        labels = json.load(open(args.labels))
        items = []
        for p in find_layouts(args.paths):
            key = p if p in labels else os.path.basename(os.path.normpath(p))
            if key in labels:
                items.append((p, "files", load_layout(p), labels[key]["stable"]))
        path = os.path.join(RES, "table2_files.jsonl")
        title = f"{len(items)} labelled layouts"
    rows = run_set(args.set, items, path)
    print(f"machine: {platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}")
    print(table(rows, title))
    print()
    print(breakdown(rows))
    print()
    print(f"time per layout ({timing(rows)}); bricks median {int(np.median([r['n_bricks'] for r in rows]))}, "
          f"max {max(r['n_bricks'] for r in rows)}")
    if args.per_layout or args.set == "reference":
        print()
        print(per_layout(rows))


if __name__ == "__main__":
    main()
