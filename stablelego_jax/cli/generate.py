"""``stablelego generate MESH... --out DIR [--grid 20] [--up auto|z|y|x] [--bricks SET] ...``"""
from __future__ import annotations

import json
import os
import sys

__all__ = ["add_parser", "cmd_generate"]


def add_parser(sub) -> None:
    from ..generate.mesh import FILL_MODES, UP_AXES

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
    g.add_argument("--stabilize", action="store_true",
                   help="search for a cover of the same voxels that stands (stablelego stabilize, default budget) "
                        "where the merge falls; the object keeps the best cover found either way")
    g.add_argument("--no-vis", action="store_true", help="skip vis.png")
    g.add_argument("--overwrite", action="store_true", help="replace existing object folders")
    g.add_argument("--json", action="store_true", help="one JSON object per mesh and line on stdout")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    g.set_defaults(func=cmd_generate)


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
    from ..generate.objects import generate_from_mesh
    from ..generate.voxels import parse_bricks
    from ..progress import Progress

    try:
        bricks = parse_bricks(args.bricks)
    except ValueError as exc:
        print(f"error: --bricks: {exc}", file=sys.stderr)
        return 2
    from ..generate.mesh import MAX_GRID

    if not 2 <= args.grid <= MAX_GRID:  # checked before anything is allocated
        print(f"error: --grid must be between 2 and {MAX_GRID}, got {args.grid}", file=sys.stderr)
        return 2
    stab = None
    if args.stabilize:
        from ..generate.stabilize import StabilizeOptions

        stab = StabilizeOptions()
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
                                   overwrite=args.overwrite, stabilize=stab)
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
