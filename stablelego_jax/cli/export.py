"""``stablelego export LAYOUT [--ldr OUT] [--json OUT] [--txt OUT] [--skip-unsupported]``"""
from __future__ import annotations

import sys

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
    from ..formats.ldraw import unsupported_message, write_ldr
    from ..formats.reader import load_layout, write_layout
    from ..layout import LayoutError

    if not (args.ldr or args.json or args.txt):
        print("error: export needs at least one of --ldr OUT, --json OUT, --txt OUT", file=sys.stderr)
        return 2
    try:
        left_out: dict = {}
        layout = load_layout(args.layout, args.library, args.skip_unsupported, left_out)
        if left_out:
            print(f"warning: {args.layout}: left out, {unsupported_message(left_out)}", file=sys.stderr)
        if args.ldr:
            write_ldr(layout, args.ldr, color=args.color, step=args.step)
            print(f"{args.ldr}: {layout.n} bricks (LDraw)")
        if args.json:
            write_layout(layout, args.json, fmt="json")
            print(f"{args.json}: {layout.n} bricks (StableLego JSON)")
        if args.txt:
            write_layout(layout, args.txt, fmt="text")
            print(f"{args.txt}: {layout.n} bricks (text)")
    except (LayoutError, OSError) as exc:
        text = str(exc)
        print(f"error: {text if args.layout in text else args.layout + ': ' + text}", file=sys.stderr)
        return 1
    return 0
