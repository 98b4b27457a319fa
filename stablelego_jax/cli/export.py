"""``stablelego export LAYOUT [--ldr OUT] [--json OUT] [--txt OUT] [--skip-unsupported]``"""
from __future__ import annotations

import sys

from .common import report_error

__all__ = ["add_parser", "cmd_export"]


def add_parser(sub) -> None:
    e = sub.add_parser("export", help="write a layout as LDraw (.ldr), StableLego JSON or text",
                       description="Read LAYOUT (StableLego JSON, text, .ldr / .mpd or a dataset folder) and write it "
                                   "in other formats. LDraw files open in LeoCAD, LDView and BrickLink Studio.")
    e.add_argument("layout", metavar="LAYOUT")
    e.add_argument("--ldr", metavar="OUT", help="LDraw file to write")
    e.add_argument("--json", metavar="OUT", help="StableLego JSON file to write")
    e.add_argument("--txt", metavar="OUT", help="text layout (HxW (x,y,z)) to write")
    e.add_argument("--skip-unsupported", action="store_true",
                   help="LDraw: write the parts that can be modelled, with a warning naming the others")
    e.add_argument("--library", help="brick library JSON of LAYOUT (default: the StableLego library)")
    e.add_argument("--color", type=int, default=115, help="LDraw colour code (default 115)")
    e.add_argument("--step", choices=["layer", "brick", "none"], default="layer",
                   help="building steps in the .ldr (default: one per layer)")
    e.set_defaults(func=cmd_export)


def cmd_export(args) -> int:
    from ..files import staged_outputs
    from ..formats.ldraw import unsupported_message, write_ldr
    from ..formats.reader import load_layout, write_layout

    if not (args.ldr or args.json or args.txt):
        print("error: export needs at least one of --ldr OUT, --json OUT, --txt OUT", file=sys.stderr)
        return 2
    outs = [(args.ldr, "LDraw"), (args.json, "StableLego JSON"), (args.txt, "text")]
    try:
        left_out: dict = {}
        layout = load_layout(args.layout, args.library, args.skip_unsupported, left_out)
        if left_out:
            print(f"warning: {args.layout}: left out, {unsupported_message(left_out)}", file=sys.stderr)
        # every output is checked first and renamed into place only when all are written
        with staged_outputs([p for p, _ in outs]) as stage:
            if args.ldr:
                write_ldr(layout, stage(args.ldr), color=args.color, step=args.step)
            if args.json:
                write_layout(layout, stage(args.json), fmt="json")
            if args.txt:
                write_layout(layout, stage(args.txt), fmt="text")
    except Exception as exc:  # one line, never a traceback
        report_error(args.layout, exc, False)
        return 1
    for p, what in outs:
        if p:
            print(f"{p}: {layout.n} bricks ({what})")
    return 0
