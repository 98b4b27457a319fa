"""Issue 19, item 3 (session 68): the layer-by-layer generator's three seeds against the rule of
``benchmarks/results/train_layers_s68/PROTOCOL.md``.

    python benchmarks/layers_runs.py [--runs benchmarks/results/train_layers_s68] [--seeds 0,1,2] \
        [--merge-rows FILE]

Reads each seed's ``seedK/history.json`` (``stablelego train``) and its evaluations
``seedK/val_solves32.jsonl`` and, when present, ``seedK/heldout_solves32.jsonl`` (``stablelego
evaluate --heuristic --refine-solves 32``: every verdict is HiGHS's). Prints, per split, the stable
fraction at IoU 1 of the filled decoding, generator + refinement, the merge and the merge + refinement
for each seed and their mean, the rule's choice (the layers net is chosen when its validation mean of
generator + refinement is strictly above session 64's 0.781), and, with the held-out rows, whether
issue 19's target (a mean of either generator row at least the merge's) is met. Draws
``RUNS/training_curves.png``: each seed's loss and fidelity (with the imitation term) against the step,
a batch a point and a running mean of 5. Exit 2 with one line
when a file is missing or malformed. Session 69's runs (``train_layers_s69``, rule in its
PROTOCOL.md: the same bar, counted as 76 of 96 rows) were evaluated on validation without
``--heuristic``: the merge's rows there are taken from ``--merge-rows`` (default: session 68's seed 0
file, the same 32 shapes; the merge and its refinement do not depend on the generator).
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from rows import RowsError, all_rows  # noqa: E402

#: session 64's validation mean of generator + refinement (32 exact solves) for both lambdas of the 3D
#: net, and the merge's, on the same 32 shapes: 25 of 32 on every seed, printed 0.781 (BENCHMARKS.md;
#: val/refine_validation_s64.txt); a tie (75 of 96) is not above it
BAR = 25 / 32
METHODS = ("generator_filled", "generator_refined", "heuristic", "heuristic_refined")


def fractions(rows: list[dict], path: str, merge: list[dict] | None = None) -> dict:
    """{method: stable fraction at IoU 1} of one evaluation's rows; the merge's
    methods from ``merge`` (rows of the same shapes) where ``rows`` has none."""
    out = {}
    for m in METHODS:
        rs = [r for r in rows if r["method"] == m]
        if not rs and merge is not None and m.startswith("heuristic"):
            rs = [r for r in merge if r["method"] == m]
            if {r["shape"] for r in rs} != {r["shape"] for r in rows}:
                raise RowsError(f"{path}: the merge's rows are of other shapes")
        if not rs:
            raise RowsError(f"{path}: no rows of method {m}")
        hits = [bool(r["stable"]) and r["iou"] == 1.0 for r in rs]
        out[m], out[f"{m}_count"] = float(np.mean(hits)), int(sum(hits))
    out["n"] = len([r for r in rows if r["method"] == "generator_filled"])
    return out


def table(runs: str, seeds: list[int], name: str, merge: str | None = None) -> dict | None:
    """{seed: fractions} of ``seedK/NAME`` for every seed, None when no seed has it."""
    paths = {k: os.path.join(runs, f"seed{k}", name) for k in seeds}
    if not any(os.path.exists(p) for p in paths.values()):
        return None
    extra = all_rows(merge) if merge else None
    return {k: fractions(all_rows(p), p, extra) for k, p in paths.items()}


def show(title: str, res: dict, seeds: list[int]) -> dict:
    """Print one split's table; {method: mean over the seeds}."""
    n = res[seeds[0]]["n"]
    print(f"| {title} ({n} shapes), IoU 1, stable | " + " | ".join(f"seed {k}" for k in seeds) + " | mean |")
    print("|---|" + "---|" * (len(seeds) + 1))
    means = {}
    for m in METHODS:
        vals = [res[k][m] for k in seeds]
        means[m] = float(np.mean(vals))
        means[f"{m}_count"] = sum(res[k][f"{m}_count"] for k in seeds)
        print(f"| {m} | " + " | ".join(f"{v:.3f}" for v in vals) + f" | {means[m]:.3f} |")
    print()
    return means


def curves(runs: str, seeds: list[int], out: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for k in seeds:
        path = os.path.join(runs, f"seed{k}", "history.json")
        try:
            hist = json.load(open(path))["history"]
        except (OSError, ValueError, KeyError) as e:
            raise RowsError(f"{path}: cannot read the history ({e})") from None
        h = [r for r in hist if "loss" in r]
        steps = np.array([r["step"] for r in h])
        for a, key in zip(ax, ("loss", "fidelity")):
            v = np.array([r[key] for r in h])
            line, = a.plot(steps, v, lw=0.5, alpha=0.5)
            if len(v) >= 5:  # each point is one batch of 8 shapes: a running mean of 5 shows the trend
                a.plot(steps[4:], np.convolve(v, np.ones(5) / 5, "valid"), color=line.get_color(), lw=1.8,
                       label=f"seed {k} (running mean of 5)")
    for a, t in zip(ax, ("loss", "fidelity + imitation")):
        a.set_xlabel("step")
        a.set_title(t)
        a.set_yscale("log")
        a.legend()
    fig.suptitle(f"layer-by-layer generator, {os.path.basename(os.path.normpath(runs))}")
    fig.tight_layout()
    fig.savefig(out, dpi=100)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default=os.path.join(HERE, "results", "train_layers_s68"))
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--merge-rows", default=os.path.join(HERE, "results", "train_layers_s68", "seed0",
                                                         "val_solves32.jsonl"),
                    help="the merge's validation rows, where a run's own have none")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    try:
        val = table(args.runs, seeds, "val_solves32.jsonl", args.merge_rows)
        if val is None:
            raise RowsError(f"{args.runs}: no seed has val_solves32.jsonl")
        vm = show("validation", val, seeds)
        chosen = vm["generator_refined"] > BAR
        print(f"rule: validation mean of generator + refinement {vm['generator_refined']:.3f} "
              f"({vm['generator_refined_count']} of {len(seeds) * val[seeds[0]]['n']} rows) "
              f"{'>' if chosen else '<='} {BAR:.5f}: the layers net is {'chosen' if chosen else 'not chosen'}")
        held = table(args.runs, seeds, "heldout_solves32.jsonl")
        if held is not None:
            print()
            hm = show("held-out", held, seeds)
            best = max(hm["generator_filled"], hm["generator_refined"])
            print(f"target: generator (best row) {best:.3f} against the merge's {hm['heuristic']:.3f}: "
                  f"{'met' if best >= hm['heuristic'] else 'not met'}"
                  + ("" if chosen else " (not the protocol's result: the layers net was not chosen)"))
        curves(args.runs, seeds, os.path.join(args.runs, "training_curves.png"))
    except RowsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
