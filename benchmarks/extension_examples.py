"""Write the paper's Sec. IV.E extension cases as layouts in examples/extensions/
and check them with the exact solver and the JAX interior point.

    python benchmarks/extension_examples.py [--write] [--check]

--write: (re)write the JSON files and examples/labels_extensions.json from
the definitions below (the geometry of each case is rebuilt from the
paper's description: the paper gives pictures, not coordinates).
--check: analyse every file with both solvers and print a table: the
outcome each gives and the label.
"""
import argparse
import json
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "..", "examples", "extensions")
LABELS = os.path.join(HERE, "..", "examples", "labels_extensions.json")


def column(offsets, size, mass, yaws=None):
    """A column of blocks bottom first: block i + 1 offset by offsets[i] (m) along x from block i."""
    x, blocks = 0.0, {}
    for i in range(len(offsets) + 1):
        if i:
            x += offsets[i - 1]
        blocks[str(i + 1)] = {"center": [round(x, 6), 0.0, round(size[2] * (i + 0.5), 6)], "size": list(size),
                              "yaw": 0.0 if yaws is None else yaws[i], "mass": mass}
    return {"units": "m", "friction": 0.0, "blocks": blocks}


def pallet(top_x):
    blocks = {"pallet": {"center": [0.0, 0.0, 0.075], "size": [1.2, 0.8, 0.15], "yaw": 0.0, "mass": 25.0}}
    for layer in range(2):
        for i, (x, y) in enumerate((x, y) for y in (-0.2, 0.2) for x in (-0.4, 0.0, 0.4)):
            blocks[f"box{layer + 1}.{i + 1}"] = {"center": [x, y, 0.15 + 0.3 * layer + 0.15],
                                                 "size": [0.4, 0.4, 0.3], "yaw": 0.0, "mass": 10.0}
    blocks["top"] = {"center": [top_x, 0.0, 0.15 + 0.6 + 0.15], "size": [0.4, 0.4, 0.3], "yaw": 0.0, "mass": 10.0}
    return {"units": "m", "friction": 0.0, "blocks": blocks}


def lego_arm(load: bool):
    """A 2x4 on the baseplate and a 1x8 turned 45 degrees joined to it by one knob (its first stud on the
    2x4's corner stud at (1.5, 3.5)); with ``load``, a 200 g load block (id 1, 2x2) on the arm's far end."""
    th = math.radians(45.0)
    c, s = math.cos(th), math.sin(th)

    def centre_for(stud_xy, cell_off):  # the part's centre that puts its cell (offset from centre) on stud_xy
        return [round(stud_xy[0] - (c * cell_off[0] - s * cell_off[1]), 9),
                round(stud_xy[1] - (s * cell_off[0] + c * cell_off[1]), 9)]

    arm_c = centre_for((1.5, 3.5), (0.0, -3.5))
    bricks = {"base": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},
              "arm": {"center": arm_c, "yaw": 45.0, "z": 1, "brick_id": 4}}
    if load:
        # the load block's cells (0, 0) and (0, 1) on the arm's last two studs (cells 6 and 7)
        far = (arm_c[0] + c * 0 - s * 2.5, arm_c[1] + s * 0 + c * 2.5)  # arm cell 6: offset (0, 2.5)
        bricks["load"] = {"center": centre_for(far, (-0.5, -0.5)), "yaw": 45.0, "z": 2, "brick_id": 1}
    return bricks


def blocks45(offset):
    return {"units": "m", "friction": 0.0, "blocks": {
        "base": {"center": [0.0, 0.0, 0.05], "size": [0.1, 0.1, 0.1], "yaw": 0.0, "mass": 0.5},
        "turned": {"center": [offset, 0.0, 0.15], "size": [0.1, 0.1, 0.1], "yaw": 45.0, "mass": 0.5}}}


L8 = (0.2, 0.1, 0.05)
CASES = {
    # Sec. IV.E block stacking: a stack that stands, the same with its top block pushed out
    "stack_stands.json": (column([0.02, -0.01, 0.03, 0.01], (0.15, 0.05, 0.03), 0.05),
                          {"stable": True}),
    "stack_pushed.json": (column([0.02, -0.01, 0.03, 0.085], (0.15, 0.05, 0.03), 0.05),
                          {"stable": False, "collapses_at": "5"}),
    # the 8-level stack: stands; one block moved (the 7th) makes it fall; moving the top one as well stands again
    "stack8_stands.json": (column([0.0] * 7, L8, 0.1), {"stable": True}),
    "stack8_moved.json": (column([0.0] * 5 + [0.12, -0.12], L8, 0.1), {"stable": False, "collapses_at": "8"}),
    "stack8_top_moved.json": (column([0.0] * 5 + [0.12, -0.06], L8, 0.1), {"stable": True}),
    # Lego bricks at an arbitrary orientation joined by a single knob
    "lego_single_knob.json": (lego_arm(False), {"stable": True}),
    "lego_single_knob_load.json": (lego_arm(True), {"stable": False, "collapses_at": "arm"}),
    # plain blocks at 45 degrees
    "blocks45_stands.json": (blocks45(0.03), {"stable": True}),
    "blocks45_falls.json": (blocks45(0.065), {"stable": False, "collapses_at": "turned"}),
    # palletisation: a pallet that stands, and falls when the top box is moved
    "pallet_stands.json": (pallet(0.2), {"stable": True}),
    "pallet_top_moved.json": (pallet(0.65), {"stable": False, "collapses_at": "top"}),
}


def write():
    os.makedirs(OUT, exist_ok=True)
    labels = {"_about": "Paper Sec. IV.E (extensions) rebuilt as layouts by benchmarks/extension_examples.py: "
                        "the outcomes the paper reports for block stacking (a stack that stands and falls when its "
                        "top block is pushed out; an 8-level stack made unstable by moving one block and stable "
                        "again by moving the top one), Lego bricks at an arbitrary orientation joined by a single "
                        "knob, plain blocks at 45 degrees, and a pallet that stands and falls when its top box is "
                        "moved. The paper gives pictures, not coordinates: sizes and offsets are ours. "
                        "'collapses_at' is the body that must fail (score 1)."}
    for name, (doc, label) in CASES.items():
        with open(os.path.join(OUT, name), "w") as fh:
            json.dump(doc, fh, indent=1)
            fh.write("\n")
        labels[name] = label
    with open(LABELS, "w") as fh:
        json.dump(labels, fh, indent=1)
        fh.write("\n")


def check():
    from stablelego_jax.analysis import analyze

    with open(LABELS) as fh:
        labels = json.load(fh)
    print("| layout | label | exact: stable / failing | jax: stable / failing | agrees |")
    print("|---|---|---|---|---|")
    ok = True
    for name, lab in labels.items():
        if name.startswith("_"):
            continue
        path = os.path.join(OUT, name)
        row = []
        good = True
        for solver in ("exact", "jax"):
            a = analyze(path, solver=solver)
            fail = [k for k, v in a.scores.items() if v >= 1.0]
            good &= a.stable == lab["stable"] and (lab.get("collapses_at") is None or lab["collapses_at"] in fail)
            row.append(f"{a.stable} / {', '.join(fail) or '-'}")
        ok &= good
        want = "stands" if lab["stable"] else f"falls at {lab['collapses_at']}"
        print(f"| {name} | {want} | {row[0]} | {row[1]} | {'yes' if good else 'NO'} |")
    return ok


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true")
    ap.add_argument("--check", action="store_true")
    args = ap.parse_args()
    if args.write:
        write()
    if args.check and not check():
        sys.exit(1)
