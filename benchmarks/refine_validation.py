"""Issue 19, item 3: the refinement budget chosen on validation, and the held-out result at it.

    python benchmarks/refine_validation.py [--runs benchmarks/results/train_full_s56] [--budgets 60,120]

Applies the rule of ``RUNS/val/PROTOCOL.md`` (committed before the runs):
B = the smallest budget at which the mean over the seeds of
generator_refined's stable fraction on the validation split is at least the
merge heuristic's on the same shapes; if none, the budget with the higher
mean (the larger on a tie). Reads

- ``RUNS/val/seed{K}_val_refine{B}.jsonl`` (``stablelego evaluate --split val
  --refine 60``, then ``benchmarks/refine_budget.py --split val``),
- ``RUNS/val/val_heuristic.jsonl`` (``stablelego evaluate --split val
  --heuristic``),
- ``RUNS/lam1000_seed{K}/heldout_refine{B}.jsonl`` and the heuristic rows in
  them (the held-out figures, read only after the choice),

and prints one table per split and the choice. Exit 2 when a file is
missing or the validation rows of the seeds are not the same shapes.
"""
from __future__ import annotations

import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from rows import all_rows  # noqa: E402


def _stable(rows: list[dict], method: str) -> dict[str, bool]:
    """shape -> stood by HiGHS, for one method's rows."""
    return {r["shape"]: bool(r["stable"]) for r in rows if r["method"] == method}


def choose(val: dict[float, list[float]], heuristic: float) -> tuple[float, bool]:
    """The rule: (budget, whether it reaches the heuristic). ``val`` maps a
    budget (s) to the seeds' validation stable fractions."""
    means = {b: sum(f) / len(f) for b, f in val.items()}
    reached = sorted(b for b, m in means.items() if m >= heuristic)
    if reached:
        return reached[0], True
    best = max(means.values())
    return max(b for b, m in means.items() if m == best), False


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", default=os.path.join(HERE, "results", "train_full_s56"))
    ap.add_argument("--budgets", default="60,120")
    ap.add_argument("--seeds", default="0,1,2")
    a = ap.parse_args(argv)
    budgets = [float(b) for b in a.budgets.split(",")]
    seeds = [int(s) for s in a.seeds.split(",")]
    try:
        heur_val = _stable(all_rows(os.path.join(a.runs, "val", "val_heuristic.jsonl")), "heuristic")
        val = {b: [_stable(all_rows(os.path.join(a.runs, "val", f"seed{s}_val_refine{b:g}.jsonl")), "generator_refined")
                   for s in seeds] for b in budgets}
    except OSError as e:
        print(f"error: {e.filename}: {e.strerror}", file=sys.stderr)
        return 2
    for b, per_seed in val.items():
        for s, d in zip(seeds, per_seed):
            if set(d) != set(heur_val):
                print(f"error: seed {s} at {b:g} s: validation shapes differ from the heuristic's", file=sys.stderr)
                return 2
    n = len(heur_val)
    h = sum(heur_val.values()) / n
    fracs = {b: [sum(d.values()) / n for d in per_seed] for b, per_seed in val.items()}
    print(f"validation ({n} shapes): merge heuristic {sum(heur_val.values())}/{n} = {h:.3f}")
    print("| budget s | " + " | ".join(f"seed {s}" for s in seeds) + " | mean |")
    print("|---|" + "---|" * (len(seeds) + 1))
    for b, f in fracs.items():
        print(f"| {b:g} | " + " | ".join(f"{x:.3f}" for x in f) + f" | {sum(f) / len(f):.3f} |")
    b, reached = choose(fracs, h)
    print(f"chosen budget: {b:g} s ({'reaches' if reached else 'does not reach'} the heuristic on validation)")
    try:
        held = [all_rows(os.path.join(a.runs, f"lam1000_seed{s}", f"heldout_refine{b:g}.jsonl")) for s in seeds]
    except OSError as e:
        print(f"error: {e.filename}: {e.strerror}", file=sys.stderr)
        return 2
    hh = _stable(held[0], "heuristic")
    g = [sum(_stable(r, "generator_refined").values()) / len(hh) for r in held]
    hf = sum(hh.values()) / len(hh)
    print(f"held-out ({len(hh)} shapes) at {b:g} s: generator + refinement "
          + ", ".join(f"{x:.3f}" for x in g) + f" (mean {sum(g) / len(g):.3f}); merge heuristic {hf:.3f}: "
          + ("target met" if sum(g) / len(g) >= hf else "target not met"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
