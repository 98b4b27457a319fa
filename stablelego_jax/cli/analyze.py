"""``stablelego analyze FILE... [--library L] [--solver jax|admm|exact] [--method ours|luo|eb] [--json] [--png P] [--html P]``"""
from __future__ import annotations

import json
import sys

from .common import png_target, report_error, solver_for

__all__ = ["add_parser", "cmd_analyze"]


def add_parser(sub, methods) -> None:
    a = sub.add_parser("analyze", help="analyse layout files (StableLego JSON, text, dataset folders)")
    a.add_argument("files", nargs="+", metavar="FILE")
    a.add_argument("--library", help="brick library JSON (default: the StableLego library)")
    a.add_argument("--solver", choices=["jax", "admm", "exact"], default=None,
                   help="jax (interior point in JAX, default for --method ours), admm (first-order JAX solver) "
                        "or exact (HiGHS; the only one for luo and eb)")
    a.add_argument("--method", choices=list(methods), default="ours",
                   help="ours (paper Eq. 9, default), luo (Luo et al. 2015) or eb (enhanced baseline): "
                        "the baselines answer solvable or not (JSON 'solvable')")
    a.add_argument("--json", action="store_true", help="one JSON object per line")
    a.add_argument("--png", metavar="P", help="heat map PNG (a folder when several files are given)")
    a.add_argument("--html", metavar="P",
                   help="interactive 3D heat map page (a folder when several files are given)")
    a.set_defaults(func=cmd_analyze)


def _summary(a) -> str:
    if getattr(a, "method", "ours") != "ours":
        return _baseline_summary(a)
    lines = [
        f"{a.file}: {'STABLE' if a.stable else 'UNSTABLE'}  ({a.layout.n} bricks, solver {a.solver}"
        f"{' (' + '; '.join(a.retried) + ' did not converge)' if a.retried else ''}, "
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


def cmd_analyze(args) -> int:
    from ..analysis import analyze

    if args.method != "ours" and solver_for(args) != "exact":
        print(f"error: --method {args.method} runs on the exact solver only (--solver exact)", file=sys.stderr)
        return 2
    many = len(args.files) > 1
    failed = 0
    used: set = set()
    used_html: set = set()
    for path in args.files:
        png = page = None
        try:
            a = analyze(path, solver=solver_for(args), library=args.library, method=args.method)
            if args.png and not a.scores:  # a baseline's unsolvable layout has no scores
                print(f"warning: {path}: no heat map, unsolvable under --method {args.method}", file=sys.stderr)
            elif args.png:
                from ..render import render_heatmap

                scores = [a.scores[k] for k in a.layout.keys]
                png = png_target(args.png, path, many, used)
                render_heatmap(a.layout, scores, png)
            if args.html and a.scores:
                from ..render_html import html_heatmap

                page = png_target(args.html, path, many, used_html, ext=".html")
                html_heatmap(a.layout, [a.scores[k] for k in a.layout.keys], page, title=path,
                             note=_summary(a).splitlines()[0])
        except Exception as exc:  # one bad file must not stop the others
            failed += 1
            report_error(path, exc, args.json)
            continue
        if args.json:
            rec = a.to_json()
            rec["file"] = path  # the argument as given (a dataset folder, not its task_graph.json)
            if png is not None:
                rec["png"] = png
            if page is not None:
                rec["html"] = page
            print(json.dumps(rec), flush=True)
        else:
            print(_summary(a) + (f"\n  heat map: {png}" if png is not None else "")
                  + (f"\n  3D page: {page}" if page is not None else ""), flush=True)
        if not a.converged:
            print(f"warning: {path}: solver did not converge (gap {a.gap:.2e}); scores are approximate",
                  file=sys.stderr, flush=True)
    return 1 if failed else 0
