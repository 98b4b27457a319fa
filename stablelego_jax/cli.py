"""Command line.

``stablelego analyze FILE... [--library L] [--solver jax|exact] [--json] [--png P]``
``stablelego generate MESH... --out DIR [--grid 20] [--up auto|z|y|x] [--bricks SET] ...``
``stablelego export LAYOUT [--ldr OUT] [--json OUT] [--txt OUT]``
``stablelego repair IN --out OUT [--region bbox|shape|any] [--max-add K] [--allow-remove] [--png P]``
"""
from __future__ import annotations

import argparse
import json
import os
import sys

__all__ = ["main"]


def _png_target(png: str, path: str, many: bool, used: set) -> str:
    """PNG path for ``path``: ``png`` itself for one file, else ``png/<stem>.png``.

    One file and ``png`` an existing folder (or ending in a separator) also
    gives ``png/<stem>.png``. Two inputs with the same stem get ``<stem>-2.png``,
    ``<stem>-3.png``, ... instead of overwriting each other.
    """
    if not many and not (os.path.isdir(png) or png.endswith(("/", os.sep))):
        return png
    os.makedirs(png, exist_ok=True)
    stem = os.path.splitext(os.path.basename(os.path.normpath(path)))[0] or "layout"
    name, k = stem + ".png", 1
    while name in used:
        k += 1
        name = f"{stem}-{k}.png"
    used.add(name)
    return os.path.join(png, name)


def _summary(a) -> str:
    if getattr(a, "method", "ours") != "ours":
        return _baseline_summary(a)
    lines = [
        f"{a.file}: {'STABLE' if a.stable else 'UNSTABLE'}  ({a.layout.n} bricks, solver {a.solver}, "
        f"{'converged' if a.converged else 'NOT CONVERGED'}, {a.time_s * 1e3:.1f} ms)",
        f"  weakest brick {a.weakest!r}: score {a.scores[a.weakest]:.4f}",
    ]
    failing = [k for k, s in a.scores.items() if s >= 1.0]
    if failing:
        shown = ", ".join(repr(k) for k in failing[:10]) + (" ..." if len(failing) > 10 else "")
        lines.append(f"  failing bricks ({len(failing)}): {shown}")
    return "\n".join(lines)


def _baseline_summary(a) -> str:
    """Summary of a baseline analysis (luo / eb): solvable or not."""
    if a.solvable is None:
        verdict = "NO ANSWER (solver gave up)"
    else:
        verdict = "SOLVABLE (stable)" if a.solvable else "UNSOLVABLE (no force distribution meets equilibrium and D <= T)"
    lines = [f"{a.file}: {verdict}  ({a.layout.n} bricks, method {a.method}, solver {a.solver}, {a.time_s * 1e3:.1f} ms)"]
    if a.solvable:
        lines.append(f"  most loaded brick {a.weakest!r}: drag / T {a.scores[a.weakest]:.4f}")
    return "\n".join(lines)


def _solver_for(args) -> str:
    """--solver as given, else jax for ours and exact for the baselines."""
    return args.solver or ("jax" if args.method == "ours" else "exact")


def cmd_analyze(args) -> int:
    from .api import analyze, error_message

    if args.method != "ours" and _solver_for(args) != "exact":
        print(f"error: --method {args.method} runs on the exact solver only (--solver exact)", file=sys.stderr)
        return 2
    many = len(args.files) > 1
    failed = 0
    used: set = set()
    for path in args.files:
        png = None
        try:
            a = analyze(path, solver=_solver_for(args), library=args.library, method=args.method)
            if args.png and not a.scores:  # a baseline's unsolvable layout has no scores
                print(f"warning: {path}: no heat map, unsolvable under --method {args.method}", file=sys.stderr)
            elif args.png:
                from .render import render_heatmap

                scores = [a.scores[k] for k in a.layout.keys]
                png = _png_target(args.png, path, many, used)
                render_heatmap(a.layout, scores, png)
        except Exception as exc:  # one bad file must not stop the others
            failed += 1
            msg = error_message(path, exc)
            if args.json:
                print(json.dumps({"file": path, "error": msg}), flush=True)
            else:
                print(f"error: {msg}", file=sys.stderr, flush=True)
            continue
        if args.json:
            rec = a.to_json()
            rec["file"] = path  # the argument as given (a dataset folder, not its task_graph.json)
            if png is not None:
                rec["png"] = png
            print(json.dumps(rec), flush=True)
        else:
            print(_summary(a) + (f"\n  heat map: {png}" if png is not None else ""), flush=True)
        if not a.converged:
            print(f"warning: {path}: solver did not converge (gap {a.gap:.2e}); scores are approximate",
                  file=sys.stderr, flush=True)
    return 1 if failed else 0


def _object_name(mesh: str, used: set) -> str:
    """Folder name for ``mesh``: its file name without suffix; a second mesh
    with the same stem in one run gets ``<stem>-2``, ``<stem>-3``, ..."""
    stem = os.path.splitext(os.path.basename(os.path.normpath(mesh)))[0] or "mesh"
    name, k = stem, 1
    while name in used:
        k += 1
        name = f"{stem}-{k}"
    used.add(name)
    return name


def cmd_generate(args) -> int:
    from generators.dataset import generate_from_mesh
    from generators.voxels import parse_bricks

    from .progress import Progress

    try:
        bricks = parse_bricks(args.bricks)
    except ValueError as exc:
        print(f"error: --bricks: {exc}", file=sys.stderr)
        return 2
    if args.grid < 2:
        print(f"error: --grid must be >= 2, got {args.grid}", file=sys.stderr)
        return 2
    bar = Progress(len(args.meshes), enabled=not args.quiet)
    used: set = set()
    failed = 0
    for mesh in args.meshes:
        name = _object_name(mesh, used)
        path = os.path.join(args.out, name)
        bar.start(os.path.basename(mesh))
        try:
            r = generate_from_mesh(mesh, path, grid=args.grid, up=args.up, fill=args.fill, bricks=bricks,
                                   seed=args.seed, solver=args.solver, vis=not args.no_vis,
                                   overwrite=args.overwrite)
        except Exception as exc:  # one bad mesh must not stop the others
            failed += 1
            text = str(exc) if isinstance(exc, (ValueError, OSError)) else f"{type(exc).__name__}: {exc}"
            msg = text if mesh in text or path in text else f"{mesh}: {text}"
            bar.done(f"{os.path.basename(mesh)}: FAILED")
            if args.json:
                print(json.dumps({"mesh": mesh, "error": msg}), flush=True)
            print(f"error: {msg}", file=sys.stderr, flush=True)
            continue
        verdict = "STABLE" if r.stable else f"UNSTABLE ({r.n_failing} failing)"
        line = (f"{r.path}: {r.n_voxels} voxels, {r.n_bricks} bricks, {verdict}, weakest {r.weakest!r} "
                f"({r.max_score:.4f}), {r.time_s:.1f} s")
        bar.done(f"{os.path.basename(mesh)}: {r.n_bricks} bricks, {'stable' if r.stable else 'unstable'}")
        if args.json:
            rec = r.to_json()
            rec["mesh"] = mesh
            print(json.dumps(rec), flush=True)
        else:
            print(line, flush=True)
        if not r.converged:
            print(f"warning: {mesh}: solver did not converge; scores are approximate", file=sys.stderr, flush=True)
    bar.close()
    return 1 if failed else 0


def cmd_export(args) -> int:
    from .io import load_layout, write_layout
    from .layout import LayoutError
    from .ldraw import write_ldr

    if not (args.ldr or args.json or args.txt):
        print("error: export needs at least one of --ldr OUT, --json OUT, --txt OUT", file=sys.stderr)
        return 2
    try:
        layout = load_layout(args.layout, args.library)
        if args.ldr:
            write_ldr(layout, args.ldr, color=args.color, step=args.step)
            print(f"{args.ldr}: {layout.n} bricks (LDraw)")
        if args.json:
            write_layout(layout, args.json, fmt="json")
            print(f"{args.json}: {layout.n} bricks (StableLego JSON)")
        if args.txt:
            write_layout(layout, args.txt, fmt="text")
            print(f"{args.txt}: {layout.n} bricks (text)")
    except (LayoutError, OSError) as exc:
        text = str(exc)
        print(f"error: {text if args.layout in text else args.layout + ': ' + text}", file=sys.stderr)
        return 1
    return 0


def cmd_score(args) -> int:
    from .batch import score_files

    if args.batch < 1:
        print("error: --batch must be >= 1", file=sys.stderr)
        return 2
    if args.method != "ours" and _solver_for(args) != "exact":
        print(f"error: --method {args.method} runs on the exact solver only (--solver exact)", file=sys.stderr)
        return 2
    try:
        st = score_files(
            args.inputs, args.out, solver=_solver_for(args), batch=args.batch, devices=args.devices,
            write_scores=args.write_scores, library=args.library, progress=not args.quiet,
            exact_method=args.exact_method, method=args.method,
        )
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        f"{st.scored} scored, {st.skipped} already in {args.out}, {st.errors} errors, "
        f"{st.not_converged} not converged; solve {st.solve_s:.1f} s, compile {st.compile_s:.1f} s "
        f"({st.compiles} shapes), wall {st.wall_s:.1f} s",
        file=sys.stderr,
    )
    return 1 if st.errors or st.not_converged else 0


def build_parser() -> argparse.ArgumentParser:
    from .baselines import METHODS
    from .exact import EXACT_METHODS

    p = argparse.ArgumentParser(prog="stablelego", description="Stability analysis of Lego brick layouts.")
    sub = p.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("analyze", help="analyse layout files (StableLego JSON, text, dataset folders)")
    a.add_argument("files", nargs="+", metavar="FILE")
    a.add_argument("--library", help="brick library JSON (default: the StableLego library)")
    a.add_argument("--solver", choices=["jax", "admm", "exact"], default=None,
                   help="jax (interior point in JAX, default for --method ours), admm (first-order JAX solver) "
                        "or exact (HiGHS; the only one for luo and eb)")
    a.add_argument("--method", choices=list(METHODS), default="ours",
                   help="ours (paper Eq. 9, default), luo (Luo et al. 2015) or eb (enhanced baseline): "
                        "the baselines answer solvable or not (JSON 'solvable')")
    a.add_argument("--json", action="store_true", help="one JSON object per line")
    a.add_argument("--png", metavar="P", help="heat map PNG (a folder when several files are given)")
    a.set_defaults(func=cmd_analyze)

    sc = sub.add_parser(
        "score",
        help="score many layouts in batches into a JSON-lines file (resumable)",
        description="Score every layout of INPUT (files, folders of layout files, StableLego dataset folders "
                    "with one object per sub-folder) into RESULTS, one JSON object per line as 'analyze "
                    "--json'. Layouts are grouped by size and solved in vmap-ed batches sharded over the "
                    "local devices. Rerunning skips the layouts already in RESULTS.",
    )
    sc.add_argument("inputs", nargs="+", metavar="INPUT")
    sc.add_argument("--out", required=True, metavar="RESULTS", help="JSON-lines results file (appended)")
    sc.add_argument("--solver", choices=["jax", "admm", "exact"], default=None,
                    help="jax (interior point in JAX, default for --method ours), admm (first-order JAX solver) "
                        "or exact (HiGHS; the only one for luo and eb)")
    sc.add_argument("--method", choices=list(METHODS), default="ours",
                    help="ours (default), luo or eb (baselines, exact solver; lines get 'solvable')")
    sc.add_argument("--exact-method", choices=list(EXACT_METHODS), default="highs",
                    help="HiGHS method of --solver exact (default highs: HiGHS chooses)")
    sc.add_argument("--batch", type=int, default=64, help="most layouts per solver call (default 64)")
    sc.add_argument("--devices", default="all", help="'all' or the number of local devices to shard over")
    sc.add_argument("--write-scores", action="store_true",
                    help="also write stability_score.npy beside each dataset object")
    sc.add_argument("--library", help="brick library JSON (default: the StableLego library)")
    sc.add_argument("--quiet", action="store_true", help="no progress bar")
    sc.set_defaults(func=cmd_score)

    from generators.mesh import FILL_MODES, UP_AXES

    g = sub.add_parser(
        "generate",
        help="mesh files -> StableLego dataset objects (vox.npy, task_graph.json, stability_score.npy, vis.png)",
        description="Voxelise each mesh (STL, OBJ, PLY, OFF, GLB), merge the voxels into bricks, analyse the "
                    "layout and write one dataset object folder per mesh, named after the mesh file, into DIR.",
    )
    g.add_argument("meshes", nargs="+", metavar="MESH")
    g.add_argument("--out", required=True, metavar="DIR", help="shard folder (created if missing)")
    g.add_argument("--grid", type=int, default=20, help="cells per axis (default 20, as StableLego)")
    g.add_argument("--up", choices=UP_AXES, default="auto",
                   help="mesh axis that points up (default auto: y for .glb/.gltf, z otherwise)")
    g.add_argument("--fill", choices=FILL_MODES, default="auto",
                   help="interior fill (default auto: solid for watertight meshes, parity vote otherwise)")
    g.add_argument("--bricks", default="all",
                   help="brick set: all, 1xn, 2xn, basic, unit, or sizes like 2x4,2x2,1x2,1x1 (default all)")
    g.add_argument("--seed", type=int, default=0, help="tie-break seed of the brick merge (default 0)")
    g.add_argument("--solver", choices=["exact", "jax"], default="exact",
                   help="stability solver for stability_score.npy (default exact: HiGHS, fastest on big layouts)")
    g.add_argument("--no-vis", action="store_true", help="skip vis.png")
    g.add_argument("--overwrite", action="store_true", help="replace existing object folders")
    g.add_argument("--json", action="store_true", help="one JSON object per mesh and line on stdout")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    g.set_defaults(func=cmd_generate)

    e = sub.add_parser("export", help="write a layout as LDraw (.ldr), StableLego JSON or text",
                       description="Read LAYOUT (StableLego JSON, text, .ldr or a dataset folder) and write it "
                                   "in other formats. LDraw files open in LeoCAD, LDView and BrickLink Studio.")
    e.add_argument("layout", metavar="LAYOUT")
    e.add_argument("--ldr", metavar="OUT", help="LDraw file to write")
    e.add_argument("--json", metavar="OUT", help="StableLego JSON file to write")
    e.add_argument("--txt", metavar="OUT", help="text layout (HxW (x,y,z)) to write")
    e.add_argument("--library", help="brick library JSON of LAYOUT (default: the StableLego library)")
    e.add_argument("--color", type=int, default=115, help="LDraw colour code (default 115)")
    e.add_argument("--step", choices=["layer", "brick", "none"], default="layer",
                   help="building steps in the .ldr (default: one per layer)")
    e.set_defaults(func=cmd_export)

    from .repair_cli import add_parser as add_repair_parser

    add_repair_parser(sub)  # stablelego repair IN --out OUT ... (see repair_cli.py)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
