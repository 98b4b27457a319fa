"""The ``stablelego`` command: one subcommand per module of this package.

``stablelego analyze FILE...``, ``score INPUT... --out RESULTS``,
``generate MESH... --out DIR``, ``export LAYOUT``, ``repair IN --out OUT``,
``sequence LAYOUT``, ``stabilize IN --out OUT``,
``train``, ``evaluate``. Building the parser imports no JAX; each command
imports what it needs when it runs.
"""
from __future__ import annotations

import argparse
import sys

from . import analyze, export, generate, repair, score, sequence, stabilize, train
from .common import load_library

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    from ..solvers.baselines import METHODS
    from ..solvers.exact import EXACT_METHODS

    p = argparse.ArgumentParser(prog="stablelego", description="Stability analysis of Lego brick layouts.")
    sub = p.add_subparsers(dest="cmd", required=True)
    analyze.add_parser(sub, METHODS)
    score.add_parser(sub, METHODS, EXACT_METHODS)
    generate.add_parser(sub)
    export.add_parser(sub)
    repair.add_parser(sub)
    stabilize.add_parser(sub)
    sequence.add_parser(sub)
    train.add_parsers(sub)
    return p


def main(argv=None) -> int:
    """Run one command; its exit status: 0 when everything asked was done,
    1 when some input failed, 2 for a usage or library error, 130 on Ctrl-C
    (one line, no traceback; ``score`` resumes where it stopped).

    Called with no ``argv`` (the ``stablelego`` program, ``python -m
    stablelego_jax``), Ctrl-C ends the process within about a second, even
    inside a long XLA or HiGHS call (:mod:`.interrupt`), and a finished
    command ends the process without tearing JAX down
    (:func:`~stablelego_jax.runtime.quick_exit`);
    called with an ``argv`` list (from Python), it returns 130."""
    # parsed first: --help and usage errors end here, before anything imports JAX
    args = build_parser().parse_args(argv)

    from ..blas import inline_cpu_dispatch
    from ..progress import end_bars
    from ..runtime import quick_exit
    from .interrupt import end_process, prompt_interrupt

    args.own_process = argv is None  # the program itself: JAX's backend has not started
    # before JAX's backend starts (a no-op once it has, e.g. in tests):
    # computations run inline on the calling thread (see stablelego_jax.blas)
    inline_cpu_dispatch()
    resume = " (rerun the same command to resume)" if args.cmd == "score" else ""
    message = f"stablelego {args.cmd}: interrupted{resume}"
    try:
        # Ctrl-C inside a long XLA / HiGHS call: the same line and exit status, within a second
        with prompt_interrupt(message, code=130):
            if getattr(args, "library", None) is not None:
                err = load_library(args)
                if err:
                    return err
            code = args.func(args)
    except KeyboardInterrupt:
        end_bars()
        print(message, file=sys.stderr, flush=True)
        if argv is None:  # the program itself: end now, not when native work in flight winds down
            end_process(130)
        return 130
    if argv is None and not sys.flags.inspect:  # the program itself, done
        quick_exit(code)
    return code


if __name__ == "__main__":
    sys.exit(main())
