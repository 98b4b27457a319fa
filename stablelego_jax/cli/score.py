"""``stablelego score INPUT... --out RESULTS [--solver ...] [--batch N] [--devices D] [--write-scores]``"""
from __future__ import annotations

import sys

from .common import add_solver_option, solver_for

__all__ = ["add_parser", "cmd_score"]


def add_parser(sub, methods, exact_methods) -> None:
    sc = sub.add_parser(
        "score",
        help="score many layouts in batches into a JSON-lines file (resumable)",
        description="Score every layout of INPUT (files, folders of layout files, StableLego dataset folders "
                    "with one object per sub-folder, JSON-lines and Parquet files of one layout a row) into RESULTS, one JSON object per line as 'analyze "
                    "--json'. Layouts are grouped by size and solved in vmap-ed batches sharded over the "
                    "local devices. Rerunning skips the layouts already in RESULTS.",
    )
    sc.add_argument("inputs", nargs="+", metavar="INPUT")
    sc.add_argument("--out", required=True, metavar="RESULTS", help="JSON-lines results file (appended)")
    add_solver_option(sc)
    sc.add_argument("--method", choices=list(methods), default="ours",
                    help="ours (default), luo or eb (baselines, exact solver; lines get 'solvable')")
    sc.add_argument("--exact-method", choices=list(exact_methods), default="highs",
                    help="HiGHS method of --solver exact where it solves the LP (default highs: HiGHS chooses); "
                         "the canonical distribution (the default) is solved by Clarabel whatever this says")
    sc.add_argument("--batch", type=int, default=None,
                    help="most layouts per solver call (default: 64 on a CPU, where fewer go: a batch holds each "
                         "core's share within 4 MB, one layout a call for all but the smallest; 1024 on an "
                         "accelerator, within a quarter of its memory)")
    sc.add_argument("--devices", default="all", help="'all' or the number of local devices to shard over")
    sc.add_argument("--jobs", type=int, default=None,
                    help="worker processes, every solver, from 32 layouts up (default: every core); "
                         "JAX workers run one device and one XLA thread each (on a GPU, JAX runs in this process)")
    sc.add_argument("--shard", default=None, metavar="K/N",
                    help="score only part K of N (0-based) of the inputs, chosen by a hash of each name: "
                         "N processes or hosts split a dataset with no coordination, each with its own --out")
    sc.add_argument("--write-scores", action="store_true",
                    help="also write stability_score.npy beside each dataset object")
    sc.add_argument("--library", help="brick library JSON (default: the StableLego library)")
    sc.add_argument("--column", default=None,
                    help="layout column of JSON-lines / Parquet inputs (default: 'bricks', then 'layout'): "
                         "a text layout or StableLego JSON per row")
    sc.add_argument("--id-column", default=None,
                    help="name each row's result FILE#ID by this column (default: FILE#ROW, 0-based)")
    sc.add_argument("--skip-unsupported", action="store_true",
                    help="LDraw: score the parts that can be modelled, with a warning naming the others "
                         "(the line gets 'left_out'); without it such a file gets an error line")
    sc.add_argument("--quiet", action="store_true", help="no progress bar")
    sc.set_defaults(func=cmd_score)


def cmd_score(args) -> int:
    from ..analysis import pick_solver
    from ..batch import score_files

    if args.batch is not None and args.batch < 1:
        print("error: --batch must be >= 1", file=sys.stderr)
        return 2
    try:
        pick_solver(solver_for(args), args.method)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    from ..batch import cpu_cores, parse_shard

    if args.jobs is not None and args.jobs < 1:
        print("error: --jobs must be >= 1", file=sys.stderr)
        return 2
    try:
        shard = parse_shard(args.shard) if args.shard else None
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        st = score_files(
            args.inputs, args.out, solver=solver_for(args), batch=args.batch, devices=args.devices,
            write_scores=args.write_scores, library=args.library, progress=not args.quiet,
            exact_method=args.exact_method, method=args.method, column=args.column, id_column=args.id_column,
            jobs=args.jobs or cpu_cores(), shard=shard, skip_unsupported=args.skip_unsupported,
        )
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        f"{st.scored} scored{f' ({st.left_out} without unsupported parts)' if st.left_out else ''}"
        f"{f' ({st.auto_exact} given to HiGHS by --solver auto)' if solver_for(args) == 'auto' else ''}, "
        f"{st.skipped} already in {args.out}, {st.errors} errors, "
        f"{st.not_converged} not converged ({st.retried} solved again); solve {st.solve_s:.1f} s, compile {st.compile_s:.1f} s "
        f"({st.compiles} shapes), wall {st.wall_s:.1f} s",
        file=sys.stderr,
    )
    return 1 if st.errors or st.not_converged else 0
