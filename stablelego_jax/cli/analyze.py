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


#: files read and solved together by one batched call of ``analyze`` (bounds memory)
CHUNK = 64


def _analyses(args):
    """(path, Analysis or exception) for every file, in input order. One
    file: the single-layout solver; several: read ``CHUNK`` at a time and
    solved in one batched call per chunk (:func:`~stablelego_jax.batch.analyze_many`:
    one compiled solver per size bucket instead of one per file; the exact
    solver in a pool of worker processes)."""
    from ..analysis import analyze, analyze_layout

    solver = solver_for(args)
    if len(args.files) == 1:
        path = args.files[0]
        try:
            yield path, analyze(path, solver=solver, library=args.library, method=args.method)
        except Exception as exc:
            yield path, exc
        return
    from ..batch import analyze_many, cpu_cores
    from ..blas import one_blas_thread
    from ..formats.reader import load_layout

    for c0 in range(0, len(args.files), CHUNK):
        part = args.files[c0: c0 + CHUNK]
        loaded: list = []
        for path in part:
            try:
                loaded.append(load_layout(path, args.library))
            except Exception as exc:
                loaded.append(exc)
        good = [i for i, x in enumerate(loaded) if not isinstance(x, Exception)]
        try:
            with one_blas_thread():
                res = analyze_many([loaded[i] for i in good], solver, method=args.method, jobs=cpu_cores())
        except Exception:  # a failure inside the batched call: one file at a time, so only its file fails
            res = []
            for i in good:
                try:
                    res.append(analyze_layout(loaded[i], solver=solver, method=args.method))
                except Exception as exc:
                    res.append(exc)
        for i, a in zip(good, res):
            loaded[i] = a
        yield from zip(part, loaded)


def cmd_analyze(args) -> int:
    if args.method != "ours" and solver_for(args) != "exact":
        print(f"error: --method {args.method} runs on the exact solver only (--solver exact)", file=sys.stderr)
        return 2
    many = len(args.files) > 1
    failed = 0
    used: set = set()
    used_html: set = set()
    for path, a in _analyses(args):
        png = page = None
        try:
            if isinstance(a, Exception):
                raise a
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
