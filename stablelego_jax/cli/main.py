"""The ``stablelego`` command: one subcommand per module of this package.

``stablelego analyze FILE...``, ``score INPUT... --out RESULTS``,
``generate MESH... --out DIR``, ``export LAYOUT``, ``repair IN --out OUT``,
``sequence LAYOUT``,
``train``, ``evaluate``. Building the parser imports no JAX; each command
imports what it needs when it runs.
"""
from __future__ import annotations

import argparse
import sys

from . import analyze, export, generate, repair, score, sequence, train

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
    sequence.add_parser(sub)
    train.add_parsers(sub)
    return p


def main(argv=None) -> int:
    from ..blas import xla_cpu_flags

    args = build_parser().parse_args(argv)
    # before JAX's backend starts (a no-op once it has, e.g. in tests):
    # XLA's Eigen kernels on the calling thread (see stablelego_jax.blas)
    xla_cpu_flags()
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
