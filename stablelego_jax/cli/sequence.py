"""``stablelego sequence LAYOUT [--order FILE|layers] [--press N] [--plan] [--json] [--html P] [--skip-unsupported]``:
the command line of :mod:`stablelego_jax.sequence`."""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys

from .common import report_error, solver_choice

__all__ = ["add_parser", "cmd_sequence"]


def add_parser(sub) -> None:
    s = sub.add_parser(
        "sequence",
        help="score every step of a build order (each prefix in one batched call), with a robot's press",
        description="Score every step of a build order of LAYOUT: step k is the layout of the first k bricks "
                    "(plus fixed pillars), and all steps are solved in one batched call. Reports the first step "
                    "that falls and the weakest brick of every step. --press N adds the insertion press of each "
                    "step (N newtons pushing the new brick down) and says which steps then need a support under "
                    "the pressed brick, and where. --plan looks for an order in which every step stands. LAYOUT "
                    "may be any layout file (scenes of plates, turned bricks and plain blocks too, ordered by the height of "
                    "their bottoms; support pillars are tried in grid layouts only) or an APEX-MR step file (config/lego_tasks/steps/<task>_seq.json: "
                    "its own order, press locations and the env_setup pillars beside it).",
    )
    s.add_argument("layout", metavar="LAYOUT")
    s.add_argument("--order", default=None, metavar="FILE|layers",
                   help="build order: 'layers' (bottom up, file order within a layer) or a file of brick keys "
                        "(JSON list or one a line); default: the APEX-MR file's own order, else layers")
    s.add_argument("--env", default="auto", metavar="FILE",
                   help="APEX-MR env_setup JSON for the fixed pillars (default: the task's file beside LAYOUT "
                        "in the APEX-MR tree; 'none' for no pillars)")
    s.add_argument("--press", type=_force, default=None, metavar="N",
                   help="insertion press in newtons on each new brick (e.g. 21.56, APEX-MR's 2.2 kg press model)")
    s.add_argument("--no-support", action="store_true", help="with --press: do not search for support locations")
    s.add_argument("--plan", action="store_true", help="look for a build order in which every step stands")
    s.add_argument("--solver", type=solver_choice, choices=["jax", "exact"], default="jax",
                   help="jax (batched interior point, default) or exact (HiGHS, one step at a time on each core)")
    s.add_argument("--library", help="brick library JSON (default: the StableLego library)")
    s.add_argument("--skip-unsupported", action="store_true",
                   help="LDraw: sequence the parts that can be modelled, with a warning naming the others")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.add_argument("--html", metavar="P", help="3D page with a step slider")
    s.add_argument("--save-order", metavar="FILE", help="write the order used (e.g. the --plan result) as JSON")
    s.set_defaults(func=cmd_sequence)


def _force(v: str) -> float:
    try:
        f = float(v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a force in newtons, got {v!r}") from None
    if not f >= 0 or f == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite force >= 0, got {v}")
    return f


def _load(args):
    """(layout, base order) of LAYOUT: an APEX-MR task or any layout file."""
    from ..formats.apexmr import is_apex_seq, read_apex_seq
    from ..formats.reader import load_layout
    from ..formats.stablelego import read_json
    from ..sequence import BuildOrder, layer_order, read_order

    path = args.layout
    if path.lower().endswith(".json") and is_apex_seq(read_json(path)):
        task = read_apex_seq(path, None if args.env == "none" else args.env)
        base = BuildOrder(keys=task.order, fixed=task.fixed, press_at=task.press, no_press=task.press_from_below,
                          support_ref=task.support, name="apex-mr")
        layout = task.layout
    else:
        from ..formats.ldraw import unsupported_message

        left_out: dict = {}
        layout = load_layout(path, args.library, args.skip_unsupported, left_out)
        if left_out:
            print(f"warning: {path}: left out, {unsupported_message(left_out)}", file=sys.stderr)
        base = layer_order(layout)
    if args.order == "layers":
        base = dataclasses.replace(base, keys=layer_order(layout, base.fixed).keys, name="layers")
    elif args.order:
        o = read_order(args.order, layout)
        base = dataclasses.replace(base, keys=o.keys, fixed=o.fixed or base.fixed, name=o.name)
    return layout, base


def _text(res, found) -> str:
    from ..scene import Scene

    steps = res.steps
    head = f"{res.file}: {len(steps)} steps (order {res.order.name}"
    head += f", {len(res.order.fixed)} fixed bricks)" if res.order.fixed else ")"
    if found is not None:
        head += ", plan " + ("found: every step stands" if found else "NOT found: some step falls whatever comes next")
    ff = res.first_fall
    lines = [head, ("  every step stands" if ff is None else
                    f"  first fall at step {ff} (adding brick {steps[ff - 1].key!r}; weakest "
                    f"{steps[ff - 1].weakest!r}, score {steps[ff - 1].score:.3f})")
             + f"; {res.n_solved} layouts solved in {res.time_s:.1f} s ({res.solver})"]
    if res.press is not None:
        sup = [s for s in steps if s.needs_support]
        lines.append(f"  press {res.press:g} N: " + (f"{len(sup)} step(s) need a support under the pressed brick"
                                                    if sup else "no step needs a support"))
        for s in sup:
            where = (f"support at cell ({s.support[0]},{s.support[1]},{s.support[2]}) stands "
                     f"(score {s.support_score:.3f})" if s.support else
                     f"no single support of {s.support_tried} stands" if s.support_tried else
                     "no support pillar tried (" + ("pillars are tried in grid layouts only)"
                                                    if isinstance(res.layout, Scene) else "no empty cell under it)"))
            lines.append(f"    step {s.step} (brick {s.key!r}): falls at {s.pressed_weakest!r}; {where}")
    hdr = f"  {'step':>4} {'brick':>10} {'bricks':>6}  {'stands':6} {'weakest':>10} {'score':>6}"
    if res.press is not None:
        hdr += f"  {'pressed':7} {'weakest':>10} {'score':>6}"
    lines.append(hdr)
    for s in steps:
        row = f"  {s.step:>4} {s.key:>10} {s.n_bricks:>6}  {'yes' if s.stable else 'FALLS':6} {s.weakest:>10} {s.score:6.3f}"
        if res.press is not None:
            row += ("  (not modelled: pressed from below)" if s.pressed_stable is None else
                    f"  {'yes' if s.pressed_stable else 'FALLS':7} {s.pressed_weakest:>10} {s.pressed_score:6.3f}")
        lines.append(row)
    return "\n".join(lines)


def _frames(res):
    import numpy as np

    from ..render_html import Frame
    from ..sequence import PRESS_KEY

    out = []
    for s in res.steps:
        a = s.pressed if s.pressed is not None else s.analysis
        lay = a.layout
        scores = [a.scores[k] for k in lay.keys]
        extra = np.array([k == PRESS_KEY for k in lay.keys])
        note = (f"step {s.step}: brick {s.key!r} added; {'stands' if s.stable else 'FALLS'}, weakest {s.weakest!r} "
                f"({s.score:.3f})")
        if s.pressed is not None:
            note += f"; under {res.press:g} N press: {'stands' if s.pressed_stable else 'FALLS'} (grey: press block)"
        out.append(Frame(lay, scores, label=f"step {s.step}/{len(res.steps)}", note=note, extra=extra))
    return out


def cmd_sequence(args) -> int:
    from ..batch import cpu_cores
    from ..files import atomic_write_text
    from ..layout import LayoutError
    from ..sequence import analyze_sequence, plan_order

    path = args.layout
    try:
        layout, order = _load(args)
        found = None
        if args.plan:
            order, found = plan_order(layout, press=args.press, solver=args.solver, base=order)
        res = analyze_sequence(layout, order, press=args.press, solver=args.solver,
                               find_support=not args.no_support, jobs=cpu_cores())
        if args.html:
            from ..render_html import html_frames

            html_frames(_frames(res), args.html, title=f"{path}: build order {order.name}")
        if args.save_order:
            atomic_write_text(args.save_order, json.dumps({"order": list(order.keys), "fixed": list(order.fixed)},
                                                          indent=1) + "\n")
    except (LayoutError, OSError, ValueError, RuntimeError) as exc:
        report_error(path, exc, args.json)
        return 2
    if args.json:
        rec = res.to_json()
        rec["file"] = path
        if found is not None:
            rec["plan_found"] = found
        if order.support_ref:
            for st in rec["steps"]:
                ref = order.support_ref.get(st["brick"])
                st["ref_support"] = list(ref) if ref else None
        if args.html:
            rec["html"] = args.html
        print(json.dumps(rec), flush=True)
    else:
        print(_text(res, found) + (f"\n  3D page: {args.html}" if args.html else ""), flush=True)
    if found is not None:
        return 0 if found else 1
    return 0 if res.first_fall is None else 1
