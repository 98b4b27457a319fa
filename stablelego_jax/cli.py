"""Command line: ``stablelego analyze FILE... [--library L] [--solver jax|exact] [--json] [--png P]``."""
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


def cmd_analyze(args) -> int:
    from .api import analyze
    from .layout import LayoutError

    many = len(args.files) > 1
    failed = 0
    used: set = set()
    for path in args.files:
        png = None
        try:
            a = analyze(path, solver=args.solver, library=args.library)
            if args.png:
                from .render import render_heatmap

                scores = [a.scores[k] for k in a.layout.keys]
                png = _png_target(args.png, path, many, used)
                render_heatmap(a.layout, scores, png)
        except Exception as exc:  # one bad file must not stop the others
            failed += 1
            text = str(exc) if isinstance(exc, (LayoutError, OSError)) else f"{type(exc).__name__}: {exc}"
            msg = text if path in text else f"{path}: {text}"
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


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="stablelego", description="Stability analysis of Lego brick layouts.")
    sub = p.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("analyze", help="analyse layout files (StableLego JSON, text, dataset folders)")
    a.add_argument("files", nargs="+", metavar="FILE")
    a.add_argument("--library", help="brick library JSON (default: the StableLego library)")
    a.add_argument("--solver", choices=["jax", "exact"], default="jax")
    a.add_argument("--json", action="store_true", help="one JSON object per line")
    a.add_argument("--png", metavar="P", help="heat map PNG (a folder when several files are given)")
    a.set_defaults(func=cmd_analyze)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
