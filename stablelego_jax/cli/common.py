"""Helpers shared by the subcommands: the solver choice and heat-map paths."""
from __future__ import annotations

import json
import os
import sys

__all__ = ["add_solver_option", "solver_choice", "solver_for", "png_target", "report_error", "load_library", "int_at_least", "int_or_auto",
           "positive_seconds"]


def int_at_least(lo: int):
    """argparse ``type``: an integer >= ``lo``, else a usage error saying so."""
    import argparse

    def parse(v: str) -> int:
        try:
            k = int(v)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer >= {lo}, got {v!r}") from None
        if k < lo:
            raise argparse.ArgumentTypeError(f"expected an integer >= {lo}, got {k}")
        return k

    return parse


def int_or_auto(lo: int):
    """argparse ``type``: "auto" (returned as None) or an integer >= ``lo``."""
    parse_int = int_at_least(lo)

    def parse(v: str):
        return None if v == "auto" else parse_int(v)

    return parse


def non_negative_number(v: str) -> float:
    """argparse ``type``: a finite number >= 0."""
    import argparse
    import math

    try:
        x = float(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {v!r}") from None
    if not (math.isfinite(x) and x >= 0):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0, got {v}")
    return x


def positive_seconds(v: str) -> float:
    """argparse ``type``: a number of seconds > 0."""
    import argparse

    try:
        t = float(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds > 0, got {v!r}") from None
    if not t > 0:
        raise argparse.ArgumentTypeError(f"expected seconds > 0, got {v}")
    return t


def solver_choice(v: str) -> str:
    """argparse ``type`` of ``--solver``: the name as given, or a usage error
    saying what replaces a solver of an earlier version
    (:data:`~stablelego_jax.analysis.REMOVED_SOLVERS`)."""
    import argparse

    from ..analysis import REMOVED_SOLVERS

    if v in REMOVED_SOLVERS:
        raise argparse.ArgumentTypeError(REMOVED_SOLVERS[v])
    return v


def add_solver_option(parser) -> None:
    """The ``--solver`` option of ``analyze`` and ``score`` (choices:
    :data:`~stablelego_jax.analysis.SOLVERS`; unset: :func:`solver_for`)."""
    from ..analysis import SOLVERS

    parser.add_argument("--solver", type=solver_choice, choices=list(SOLVERS), default=None,
                        help="jax (interior point in JAX), "
                             "exact (HiGHS; the only one for luo and eb) or auto (per group of layouts, whichever "
                             "of jax and exact is estimated faster, compiling included; each result says which; "
                             "the default for --method ours)")


def solver_for(args) -> str:
    """--solver as given, else auto for ours (HiGHS or the JAX interior
    point, whichever is estimated faster) and exact for the baselines."""
    return args.solver or ("auto" if args.method == "ours" else "exact")


def png_target(png: str, path: str, many: bool, used: set, ext: str = ".png") -> str:
    """PNG (or ``ext``) path for ``path``: ``png`` itself for one file, else ``png/<stem>.png``.

    One file and ``png`` an existing folder (or ending in a separator) also
    gives ``png/<stem>.png``. Two inputs with the same stem get ``<stem>-2.png``,
    ``<stem>-3.png``, ... instead of overwriting each other.
    """
    if not many and not (os.path.isdir(png) or png.endswith(("/", os.sep))):
        return png
    os.makedirs(png, exist_ok=True)
    stem = os.path.splitext(os.path.basename(os.path.normpath(path)))[0] or "layout"
    name, k = stem + ext, 1
    while name in used:
        k += 1
        name = f"{stem}-{k}{ext}"
    used.add(name)
    return os.path.join(png, name)


def report_error(path: str, exc: Exception, as_json: bool) -> None:
    """One line for a failed input: ``{"file", "error"}`` on stdout with
    ``--json``, else ``error: ...`` on stderr."""
    from ..analysis import error_message

    msg = error_message(path, exc)
    if as_json:
        print(json.dumps({"file": path, "error": msg}), flush=True)
    else:
        print(f"error: {msg}", file=sys.stderr, flush=True)


def load_library(args) -> int:
    """Read ``--library`` once, before any layout: ``args.library`` becomes
    the Library. Returns 0, or 2 after one error line naming the library
    file (a bad library is never blamed on a layout)."""
    from ..formats.stablelego import as_library
    from ..layout import LayoutError

    try:
        args.library = as_library(args.library)
    except LayoutError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        return 2
    return 0
