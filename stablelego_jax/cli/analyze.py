"""``stablelego analyze FILE... [--library L] [--solver jax|exact|auto] [--method ours|luo|eb] [--json] [--png P] [--html P] [--skip-unsupported]``"""
from __future__ import annotations

import json
import sys

from .common import add_solver_option, png_target, report_error, solver_for

__all__ = ["add_parser", "cmd_analyze"]


def add_parser(sub, methods) -> None:
    a = sub.add_parser("analyze", help="analyse layout files (StableLego JSON, text, LDraw, dataset folders, "
                                       "scenes of blocks and rotated bricks)")
    a.add_argument("files", nargs="+", metavar="FILE")
    a.add_argument("--library", help="brick library JSON (default: the StableLego library)")
    add_solver_option(a)
    a.add_argument("--method", choices=list(methods), default="ours",
                   help="ours (paper Eq. 9, default), luo (Luo et al. 2015) or eb (enhanced baseline): "
                        "the baselines answer solvable or not (JSON 'solvable')")
    a.add_argument("--json", action="store_true", help="one JSON object per line")
    a.add_argument("--skip-unsupported", action="store_true",
                   help="LDraw: analyse the parts that can be modelled, with a warning naming the others")
    a.add_argument("--png", metavar="P", help="heat map PNG (a folder when several files are given)")
    a.add_argument("--html", metavar="P",
                   help="interactive 3D heat map page (a folder when several files are given)")
    a.set_defaults(func=cmd_analyze)


def _support(a) -> dict:
    """{block key: support score} of a scene's plain blocks (empty for
    layouts of bricks; see :mod:`stablelego_jax.support`)."""
    from ..scene import BLOCK, Scene

    if not isinstance(a.layout, Scene) or not (a.layout.kind == BLOCK).any() or a.method != "ours":
        return {}
    from ..support import support_scores

    s = support_scores(a.layout, a.model, a.forces)
    return {k: float(v) for k, v, b in zip(a.layout.keys, s, a.layout.kind == BLOCK) if b}


def _summary(a, support: dict | None = None) -> str:
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
    if support:
        k = max(support, key=support.get)
        lines.append(f"  support margin: highest {support[k]:.4f} at block {k!r} "
                     "(0: load at the middle of its support, 1: at the edge)")
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
    """(path, Analysis or exception, {left-out LDraw part: count}) for every
    file, in input order. One
    file: the single-layout solver; several: read ``CHUNK`` at a time and
    solved in one batched call per chunk (:func:`~stablelego_jax.batch.analyze_many`:
    one compiled solver per size bucket instead of one per file; the exact
    solver in a pool of worker processes)."""
    from ..analysis import analyze, analyze_layout

    solver = solver_for(args)
    if len(args.files) == 1:
        path, left_out = args.files[0], {}
        try:
            yield path, analyze(path, solver=solver, library=args.library, method=args.method,
                                skip_unsupported=args.skip_unsupported, report=left_out), left_out
        except Exception as exc:
            yield path, exc, left_out
        return
    from ..batch import analyze_many, cpu_cores
    from ..blas import one_blas_thread
    from ..formats.reader import load_layout

    for c0 in range(0, len(args.files), CHUNK):
        part = args.files[c0: c0 + CHUNK]
        loaded: list = []
        reports: list = []
        for path in part:
            reports.append({})
            try:
                loaded.append(load_layout(path, args.library, args.skip_unsupported, reports[-1]))
            except Exception as exc:
                loaded.append(exc)
        good = [i for i, x in enumerate(loaded) if not isinstance(x, Exception)]
        try:
            with one_blas_thread():
                # worker processes for the exact solver only: JAX workers would start
                # (and load their executables) afresh for every chunk of CHUNK files
                jobs = cpu_cores() if solver in ("exact", "auto") else 1
                res = analyze_many([loaded[i] for i in good], solver, method=args.method, jobs=jobs, jax_jobs=1)
        except Exception:  # a failure inside the batched call: one file at a time, so only its file fails
            res = []
            for i in good:
                try:
                    res.append(analyze_layout(loaded[i], solver=solver, method=args.method))
                except Exception as exc:
                    res.append(exc)
        for i, a in zip(good, res):
            loaded[i] = a
        yield from zip(part, loaded, reports)


def cmd_analyze(args) -> int:
    from ..analysis import pick_solver
    from ..formats.ldraw import unsupported_message
    from ..scene import Scene

    try:
        pick_solver(solver_for(args), args.method)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    many = len(args.files) > 1
    failed = 0
    used: set = set()
    used_html: set = set()
    for path, a, left_out in _analyses(args):
        png = page = None
        try:
            if isinstance(a, Exception):
                raise a
            if left_out:
                print(f"warning: {path}: left out, {unsupported_message(left_out)}", file=sys.stderr, flush=True)
            if args.png and not a.scores:  # a baseline's unsolvable layout has no scores
                print(f"warning: {path}: no heat map, unsolvable under --method {args.method}", file=sys.stderr)
            elif args.png:
                scores = [a.scores[k] for k in a.layout.keys]
                png = png_target(args.png, path, many, used)
                if isinstance(a.layout, Scene):
                    from ..render_scene import render_scene

                    render_scene(a.layout, scores, png)
                else:
                    from ..render import render_heatmap

                    render_heatmap(a.layout, scores, png)
            if args.html and a.scores:
                from ..render_html import html_heatmap

                page = png_target(args.html, path, many, used_html, ext=".html")
                html_heatmap(a.layout, [a.scores[k] for k in a.layout.keys], page, title=path,
                             note=_summary(a).splitlines()[0])
            support = _support(a)
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
            if support:
                rec["support"] = {k: round(v, 6) for k, v in support.items()}
            print(json.dumps(rec), flush=True)
        else:
            print(_summary(a, support) + (f"\n  heat map: {png}" if png is not None else "")
                  + (f"\n  3D page: {page}" if page is not None else ""), flush=True)
        if not a.converged:
            print(f"warning: {path}: solver did not converge (gap {a.gap:.2e}); scores are approximate",
                  file=sys.stderr, flush=True)
    return 1 if failed else 0
