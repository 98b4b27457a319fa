"""``stablelego repair IN --out OUT [--region bbox|shape|any] [--max-add K|auto] [--time S] [--allow-remove] [--move] [--png P] [--html P]``:
the command line of :mod:`stablelego_jax.design.repair` (and, with ``--move``, :mod:`stablelego_jax.design.move`)."""
from __future__ import annotations

import json
import os

from .common import int_at_least, int_or_auto, positive_seconds, report_error

__all__ = ["add_parser", "cmd_repair"]


def add_parser(sub) -> None:
    r = sub.add_parser(
        "repair",
        help="add bricks to an unstable layout until it stands (gradient-guided)",
        description="Repair an unstable layout: candidate bricks near the weakest bricks (supports, bridges, "
                    "longer replacements with --allow-remove) are ranked by the gradient of the differentiable "
                    "stability loss with respect to their existence weights, the best are checked with the exact "
                    "solver, and the best is added (when several clusters of bricks fail, the best of each cluster "
                    "together first); repeated until the exact solver says the layout stands, --max-add bricks "
                    "are spent or --time runs out. Original bricks keep their keys and places; new bricks get new "
                    "keys. OUT is written in the format of IN only when the result stands. With --move (scenes "
                    "of plain blocks): slide blocks instead, along the gradient of the loss with respect to "
                    "their positions.",
    )
    r.add_argument("layout", metavar="IN", help="layout file (JSON, text, .ldr) or dataset object folder")
    r.add_argument("--out", required=True, metavar="OUT", help="where to write the repaired layout (format of IN)")
    r.add_argument("--region", choices=["bbox", "shape", "any"], default="bbox",
                   help="where new bricks may go: bbox (default: the layout's bounding box down to the "
                        "baseplate), shape (above or below the layout's own columns), any")
    r.add_argument("--max-add", type=int_or_auto(0), default=None, metavar="K",
                   help="most bricks to add, or auto (default: max(4, a quarter of the layout's bricks))")
    r.add_argument("--time", type=positive_seconds, default=None, metavar="S",
                   help="wall-time budget in seconds (default: none)")
    r.add_argument("--allow-remove", action="store_true",
                   help="allow replacing a user brick by a longer one, or a weak brick's row by a re-merge of it "
                        "(otherwise user bricks are never touched)")
    r.add_argument("--move", action="store_true",
                   help="scenes: move plain blocks (along the loss gradient with respect to their positions, each "
                        "line searched with the exact solver) instead of adding bricks")
    r.add_argument("--move-blocks", type=int_at_least(1), default=1, metavar="K",
                   help="with --move: most distinct blocks to move (default 1)")
    r.add_argument("--png", metavar="P", help="before/after heat maps (PNG)")
    r.add_argument("--html", metavar="P", help="before/after 3D heat map page (a slider between the two)")
    r.add_argument("--library", help="brick library JSON of IN (default: the StableLego library)")
    r.add_argument("--method", choices=["gradient", "greedy"], default="gradient",
                   help="gradient (default): rank candidates by the loss gradient; greedy: full solve of every one")
    r.add_argument("--verify", type=int_at_least(1), default=3, metavar="V",
                   help="best-ranked candidates checked with the exact solver per step (default 3)")
    r.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    r.set_defaults(func=cmd_repair)


def _relabel_text(result, path: str):
    """Text layouts are keyed by line number: new bricks take the numbers of
    the lines they are appended as."""
    import dataclasses

    with open(path, encoding="utf-8") as fh:
        n_lines = len(fh.read().splitlines())
    new = [k for k in result.layout.keys if k not in set(result.original.keys)]
    mapping = {k: str(n_lines + 1 + i) for i, k in enumerate(new)}
    lay = dataclasses.replace(result.layout, keys=tuple(mapping.get(k, k) for k in result.layout.keys))
    for c in result.changes:
        c.keys = [mapping.get(k, k) for k in c.keys]
    result.layout = lay
    return result


def _write_text(result, src: str, out: str) -> None:
    from ..files import atomic_write_text
    from ..formats.stablelego import layout_to_text
    from ..layout import LayoutError

    with open(src, encoding="utf-8") as fh:
        lines = fh.read().splitlines()
    removed = set(result.removed)
    for i, k in enumerate(result.original.keys):
        if k in removed:
            lines[int(k) - 1] = f"# {lines[int(k) - 1].strip()}  (removed by stablelego repair)"
    new = [k for k in result.layout.keys if k not in set(result.original.keys)]
    sub = result.layout.subset([result.layout.keys.index(k) for k in new])
    try:
        add = layout_to_text(sub).splitlines() if new else []
    except LayoutError as exc:
        raise LayoutError(out, exc.message, exc.key) from None
    atomic_write_text(out, "\n".join(lines + add) + "\n")


def _with_library_ids(layout, new_keys, library):
    """Give new bricks the ids of ``library`` (same size, Table I mass);
    LayoutError naming the library when it has none."""
    import dataclasses
    import math

    from ..formats.stablelego import as_library
    from ..layout import LayoutError

    lib = as_library(library)
    bids, oris = list(layout.brick_id), layout.ori.copy()
    for i, k in enumerate(layout.keys):
        if k not in new_keys:
            continue
        sx, sy = (int(v) for v in layout.size[i])
        found = None
        for bid, (h, w, m) in lib.bricks.items():
            if math.isclose(m, float(layout.mass[i]), rel_tol=1e-9) and (h, w) in ((sx, sy), (sy, sx)):
                found = (bid, 0 if (h, w) == (sx, sy) else 1)
                break
        if found is None:
            raise LayoutError(lib.source, f"library has no {sx}x{sy} brick of {layout.mass[i] * 1e3:g} g "
                                          "for a repair brick")
        bids[i], oris[i] = found
    return dataclasses.replace(layout, brick_id=tuple(bids), ori=oris)


def _library_sizes(library) -> tuple:
    """Footprints of the real (Table I mass) bricks of a library, both orientations."""
    import math

    from ..formats.stablelego import as_library
    from ..layout import TABLE_I_MASS_KG

    out = set()
    for h, w, m in as_library(library).bricks.values():
        key = (min(h, w), max(h, w))
        if key in TABLE_I_MASS_KG and math.isclose(m, TABLE_I_MASS_KG[key], rel_tol=1e-9):
            out.update({(h, w), (w, h)})
    return tuple(sorted(out))


def _write(result, src: str, out: str, library) -> None:
    fmt = result.original.fmt
    new_keys = set(result.layout.keys) - set(result.original.keys)
    if fmt == "text":
        _write_text(result, src, out)
    elif fmt == "ldr":
        from ..formats.ldraw import write_ldr

        write_ldr(result.layout, out)
    elif fmt == "dataset":
        from ..formats.dataset import write_object

        write_object(out, result.layout, dict(result.after.scores), vis=True,
                     meta={"repaired_from": src, "added": sorted(new_keys)})
    else:
        from ..formats.reader import write_layout

        lay = _with_library_ids(result.layout, new_keys, library) if library else result.layout
        write_layout(lay, out, fmt="json", library=library)


def _head(path: str, before) -> str:
    """The first words of the report: the verdict before repair."""
    n_fail = sum(v >= 1.0 for v in before.scores.values())
    return f"{path}: {'STABLE' if before.stable else f'UNSTABLE (weakest {before.weakest!r}, {n_fail} failing)'}"


def _page(b, a, after_note: str, out: str, title: str) -> None:
    """The before/after 3D page of analyses ``b`` and ``a``."""
    from ..render_html import Frame, html_frames

    html_frames([Frame(b.layout, [b.scores[k] for k in b.layout.keys], label="before",
                       note=f"before: {'stable' if b.stable else 'UNSTABLE'}, weakest {b.weakest!r}"),
                 Frame(a.layout, [a.scores[k] for k in a.layout.keys], label="after", note=after_note)],
                out, title=title)


def cmd_repair(args) -> int:
    from ..files import staged_outputs
    from ..formats.reader import load_layout
    from ..layout import LayoutError
    from ..design.repair import RepairOptions, greedy_repair, repair

    path = args.layout
    try:
        layout = load_layout(path, args.library)
        from ..scene import BLOCK, Scene

        if args.move:
            if not isinstance(layout, Scene) or not (layout.kind == BLOCK).any():
                raise LayoutError(path, "--move slides plain blocks, and this layout has none (repair without "
                                        "--move adds bricks)")
            return _cmd_move(args, layout)
        if isinstance(layout, Scene):
            raise LayoutError(path, "repair adds grid bricks to layouts of grid bricks; scenes of blocks or "
                                    "rotated bricks cannot be repaired by adding bricks yet (--move slides "
                                    "plain blocks)")
        if layout.fmt == "dataset" and os.path.exists(args.out):
            raise LayoutError(args.out, "already exists (dataset objects are written as new folders)")
        if layout.fmt == "dataset" and not os.path.isdir(os.path.dirname(os.path.abspath(args.out))):
            raise LayoutError(args.out, "cannot write: its folder does not exist")
        files = [args.png, args.html] + ([] if layout.fmt == "dataset" else [args.out])
        # every output is checked before the repair runs and renamed into place only when all are written
        with staged_outputs(files) as stage:
            opts = RepairOptions(region=args.region, max_add=args.max_add, allow_remove=args.allow_remove,
                                 verify=args.verify, time_s=args.time, sizes=_library_sizes(args.library) if args.library else None)
            result = (repair if args.method == "gradient" else greedy_repair)(layout, opts)
            if layout.fmt == "text":
                result = _relabel_text(result, path)
            png = None
            if args.png:
                from ..render import render_pair

                b, a = result.before, result.after
                render_pair(b.layout, [b.scores[k] for k in b.layout.keys], a.layout,
                            [a.scores[k] for k in a.layout.keys], stage(args.png),
                            titles=("before", "after repair" if result.stable else "after (still unstable)"))
                png = args.png
            page = None
            if args.html:
                _page(result.before, result.after, f"after repair: {'stable' if result.stable else 'still UNSTABLE'}, "
                      f"{result.added} brick(s) added", stage(args.html), f"{path}: repair")
                page = args.html
            if result.stable:  # the dataset folder last: the files above are complete by now
                _write(result, path, args.out if layout.fmt == "dataset" else stage(args.out), args.library)
    except (LayoutError, OSError, ValueError, RuntimeError) as exc:
        report_error(path, exc, args.json)
        return 1
    b, a = result.before, result.after
    if args.json:
        print(json.dumps({
            "file": path, "out": args.out if result.stable else None, "stable_before": b.stable,
            "stable": result.stable, "added": [{"key": k, "pos": [int(v) for v in p], "size": [int(v) for v in s],
                                                "kind": c.candidate.kind}
                                               for c in result.changes
                                               for k, p, s in zip(c.keys, c.candidate.pos, c.candidate.size)],
            "removed": result.removed, "exact_calls": result.exact_calls, "soft_calls": result.soft_calls,
            "time_s": round(result.time_s, 3), "method": result.method, "png": png, "html": page,
        }), flush=True)
    else:
        head = _head(path, b)
        if b.stable:
            print(f"{head}: nothing to repair")
        elif result.stable:
            print(f"{head} -> STABLE with {result.added} added brick{'s' * (result.added != 1)}"
                  f"{f', {len(result.removed)} replaced' if result.removed else ''} "
                  f"({result.method}; {result.exact_calls} exact + {result.soft_calls} gradient solver calls, "
                  f"{result.time_s:.1f} s)")
        else:
            print(f"{head} -> still UNSTABLE after {result.added} added brick{'s' * (result.added != 1)} "
                  f"(weakest {a.weakest!r}); not written")
        for c in result.changes:
            print(f"  added {c.describe()}")
        if result.stable:
            print(f"  wrote {args.out}")
        if png:
            print(f"  before/after: {png}")
        if page:
            print(f"  3D page: {page}")
    return 0 if result.stable else 1


def _cmd_move(args, scene) -> int:
    """``repair --move``: :func:`~stablelego_jax.design.move.move_repair` on a scene."""
    from ..design.move import MoveOptions, move_repair
    from ..files import staged_outputs
    from ..formats.reader import write_layout

    path = args.layout
    with staged_outputs([args.png, args.html, args.out]) as stage:
        result = move_repair(scene, MoveOptions(max_blocks=args.move_blocks, time_s=args.time))
        b, a = result.before, result.after
        if args.png:
            from ..render_scene import render_scene

            render_scene(a.layout, [a.scores[k] for k in a.layout.keys], stage(args.png),
                         title="after moving" if result.stable else "after (still unstable)")
        if args.html:
            _page(b, a, f"after: {'stable' if a.stable else 'still UNSTABLE'}; "
                  + "; ".join(m.describe() for m in result.moves), stage(args.html), f"{path}: repair --move")
        if result.stable:
            write_layout(result.layout, stage(args.out), fmt="json")
    if args.json:
        print(json.dumps({
            "file": path, "out": args.out if result.stable else None, "stable_before": b.stable,
            "stable": result.stable, "moved": [{"key": m.key, "shift_m": [round(v, 6) for v in m.shift],
                                                "gradient": [round(v, 6) for v in m.grad]} for m in result.moves],
            "exact_calls": result.exact_calls, "soft_calls": result.soft_calls, "time_s": round(result.time_s, 3),
            "method": "move", "png": args.png, "html": args.html,
        }), flush=True)
    else:
        head = _head(path, b)
        if b.stable:
            print(f"{head}: nothing to repair")
        else:
            print(f"{head} -> {'STABLE' if result.stable else 'still UNSTABLE'} after {len(result.moves)} "
                  f"move{'s' * (len(result.moves) != 1)} ({result.exact_calls} exact + {result.soft_calls} gradient "
                  f"solver calls, {result.time_s:.1f} s)" + ("" if result.stable else "; not written"))
        for m in result.moves:
            print(f"  {m.describe()}")
        for what, p in (("wrote", args.out if result.stable else None), ("after", args.png), ("3D page", args.html)):
            if p:
                print(f"  {what}: {p}")
    return 0 if result.stable else 1
