"""Issue 19, item 3: the refinement budget and the lambda chosen on validation, and the held-out result at them.

    python benchmarks/refine_validation.py [--runs benchmarks/results/train_full_s56] [--budgets 60,120]
        [--lams 1000,0] [--seeds 0,1,2] [--replicates RUNS/val/replicate [RUNS/val/replicate2 ...]]
        [--solves N [--priors 0,4,8] [--fresh-priors 0,8]]

Applies two rules (three with ``--solves``, four with ``--priors``, five
with ``--fresh-priors``), each committed before its runs:

1. ``RUNS/val/PROTOCOL.md``: for the first lambda of ``--lams`` (the one
   chosen without refinement), B = the smallest budget at which the mean
   over the seeds of generator_refined's stable fraction on the validation
   split is at least the merge heuristic's on the same shapes; if none, the
   budget with the higher mean (the larger on a tie).
2. ``RUNS/val/PROTOCOL_LAMBDA.md``: at B, L = the lambda of ``--lams`` with
   the higher validation mean; the first one on a tie.
3. ``RUNS/val/PROTOCOL_SOLVES.md`` (``--solves N``): the same choice of
   lambda with a budget of N exact solves a shape and no clock, from
   ``RUNS/val/solves{N}/lam{L}_seed{K}_val.jsonl``
   (``benchmarks/refine_budget.py --solves N`` on the 60 s validation
   rows); the held-out result at the chosen lambda from
   ``RUNS/lam{L}_seed{K}/heldout_solves{N}.jsonl``, and the other lambda's
   where those files exist (for the record).
4. ``RUNS/val/PROTOCOL_PRIOR.md`` (``--priors``, with ``--solves N``): at
   rule 3's lambda L and N solves, B = the decoding's size prior (beta of
   ``evaluate --size-prior``) in ``--priors`` with the higher validation
   mean, the smaller on a tie, from
   ``RUNS/val/prior/lam{L}_seed{K}_b{beta}_val.jsonl`` (beta 0: rule 3's
   files); the held-out result at B (beta 0: rule 3's; else
   ``RUNS/lam{L}_seed{K}/heldout_prior_b{B}_solves{N}.jsonl``), and the
   other betas' where those files exist (for the record).
5. ``RUNS/val/PROTOCOL_FRESH.md`` (``--fresh-priors``, with ``--solves
   N``): the same choice on the validation shapes and the fresh ones
   together (``evaluate --split fresh``:
   ``RUNS/val/fresh/lam{L}_seed{K}_b{beta}_fresh.jsonl``, whose shapes must
   be those of the heuristic rows in the first seed's beta-0 file), and the
   held-out result at the chosen beta as in rule 4 (or that it is not run
   yet).

Reads

- ``RUNS/val/seed{K}_val_refine{B}.jsonl`` (lambda 1000) and
  ``RUNS/val/lam{L}_seed{K}_val_refine{B}.jsonl`` (any other lambda):
  ``stablelego evaluate --split val --refine 60`` (then
  ``benchmarks/refine_budget.py --split val`` for a longer budget),
- ``RUNS/val/val_heuristic.jsonl`` (``stablelego evaluate --split val
  --heuristic``),
- ``RUNS/lam{L}_seed{K}/heldout_refine{B}.jsonl``, and the heuristic rows of
  the first lambda's first seed (the held-out figures, read only after the
  choices),

and prints one table per choice and the held-out result at each; with
``--replicates DIR ...``, each rerun there (a validation file's name) against
its original, shape by shape, and per lambda and seed every run's stable
fraction at B and the mean over the seeds of their means over the runs (the
rules read the first runs only). Exit 2
when a file is missing or malformed, or the validation rows of a run are
not the heuristic's shapes.
"""
from __future__ import annotations

import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from rows import RowsError, all_rows  # noqa: E402


def _stable(rows: list[dict], method: str) -> dict[str, bool]:
    """shape -> stood by HiGHS, for one method's rows."""
    return {r["shape"]: bool(r["stable"]) for r in rows if r["method"] == method}


def _fraction(path: str, ref: dict[str, bool]) -> float:
    """generator_refined's stable fraction in the rows of ``path``, whose
    shapes must be ``ref``'s (RowsError otherwise)."""
    d = _stable(all_rows(path), "generator_refined")
    if set(d) != set(ref):
        raise RowsError(f"{path}: shapes differ from the heuristic's")
    return sum(d.values()) / len(ref)


def val_path(runs: str, lam: float, seed: int, budget: float) -> str:
    """The validation rows of one lambda, seed and budget (lambda 1000's
    carry no lambda in their name: they were the first)."""
    tag = "" if lam == 1000 else f"lam{lam:g}_"
    return os.path.join(runs, "val", f"{tag}seed{seed}_val_refine{budget:g}.jsonl")


def choose(val: dict[float, list[float]], heuristic: float) -> tuple[float, bool]:
    """Rule 1: (budget, whether it reaches the heuristic). ``val`` maps a
    budget (s) to the seeds' validation stable fractions."""
    means = {b: sum(f) / len(f) for b, f in val.items()}
    reached = sorted(b for b, m in means.items() if m >= heuristic)
    if reached:
        return reached[0], True
    best = max(means.values())
    return max(b for b, m in means.items() if m == best), False


def choose_lambda(val: dict[float, list[float]]) -> float:
    """Rule 2: the lambda whose seeds' validation stable fractions have the
    higher mean; the first key of ``val`` on a tie."""
    means = {lam: sum(f) / len(f) for lam, f in val.items()}
    best = max(means.values())
    return next(lam for lam, m in means.items() if m == best)


def _fractions(runs, lam, seeds, budget, heur_val) -> list[float]:
    """The seeds' generator_refined stable fractions on validation."""
    return [_fraction(val_path(runs, lam, s, budget), heur_val) for s in seeds]


def _table(label: str, fracs: dict[float, list[float]], seeds: list[int], unit: str) -> None:
    print(f"| {label} | " + " | ".join(f"seed {s}" for s in seeds) + " | mean |")
    print("|---|" + "---|" * (len(seeds) + 1))
    for k, f in fracs.items():
        print(f"| {k:g}{unit} | " + " | ".join(f"{x:.3f}" for x in f) + f" | {sum(f) / len(f):.3f} |")


def _heldout(runs, lam, seeds, budget, hh: dict[str, bool], name: str = "", unit: str = " s") -> str:
    """The held-out line at (lambda, budget); ``hh``: the heuristic's
    held-out verdicts; ``name``: each run's file (default
    heldout_refine{budget}.jsonl)."""
    name = name or f"heldout_refine{budget:g}.jsonl"
    g = [_fraction(os.path.join(runs, f"lam{lam:g}_seed{s}", name), hh) for s in seeds]
    hf = sum(hh.values()) / len(hh)
    return (f"held-out ({len(hh)} shapes), lambda {lam:g} at {budget:g}{unit}: generator + refinement "
            + ", ".join(f"{x:.3f}" for x in g) + f" (mean {sum(g) / len(g):.3f}); merge heuristic {hf:.3f}: "
            + ("target met" if sum(g) / len(g) >= hf else "target not met"))


def _replicate(original: str, again: str) -> str:
    """One line: a rerun's generator_refined stable count against its original's, and the shapes that differ."""
    d0 = _stable(all_rows(original), "generator_refined")
    d1 = _stable(all_rows(again), "generator_refined")
    if set(d0) != set(d1):
        raise RowsError(f"{again}: shapes differ from {original}'s")
    diff = sorted(s for s in d0 if d0[s] != d1[s])
    return (f"rerun of {os.path.basename(original)}: {sum(d1.values())}/{len(d1)} against {sum(d0.values())}/{len(d0)}; "
            + (", ".join(f"{s} ({'stands' if d1[s] else 'falls'} in the rerun)" for s in diff) if diff else "the same verdicts"))


def _runs_table(runs, folders, lams, seeds, budget, heur_val) -> None:
    """Per lambda and seed, the stable fraction of the first run and of each
    rerun found in ``folders``, and the mean over the seeds of each seed's
    mean over its runs."""
    print(f"every run at {budget:g} s (first run, then reruns; the rules read the first):")
    print("| lambda | " + " | ".join(f"seed {s}" for s in seeds) + " | mean of the seeds' run means |")
    print("|---|" + "---|" * (len(seeds) + 1))
    for lam in lams:
        cells, means, n = [], [], 0
        for s in seeds:
            first = val_path(runs, lam, s, budget)
            paths = [first] + [os.path.join(f, os.path.basename(first)) for f in folders
                               if os.path.isfile(os.path.join(f, os.path.basename(first)))]
            fr = [_fraction(p, heur_val) for p in paths]
            cells.append(" / ".join(f"{x:.3f}" for x in fr))
            means.append(sum(fr) / len(fr))
            n += len(fr)
        print(f"| {lam:g} | " + " | ".join(cells) + f" | {sum(means) / len(means):.3f} ({n} runs) |")


def _lambda_rule(title: str, by_lam: dict[float, list[float]], seeds, heuristic: float, label: str = "lambda") -> float:
    """Prints ``title``, the validation table of ``by_lam`` (lambda, or the
    setting named ``label``, -> the seeds' stable fractions) and the key
    :func:`choose_lambda` picks, against the heuristic's fraction; returns it."""
    print(title)
    _table(label, by_lam, seeds, "")
    lam = choose_lambda(by_lam)
    m = sum(by_lam[lam]) / len(seeds)
    print(f"chosen {label}: {lam:g} ({'reaches' if m >= heuristic else 'does not reach'} the heuristic on validation)")
    return lam


def _have_heldout(runs: str, lam: float, seeds, name: str) -> bool:
    """Whether every seed's held-out run ``name`` at ``lam`` is there."""
    return all(os.path.isfile(os.path.join(runs, f"lam{lam:g}_seed{s}", name)) for s in seeds)


def _solves_rule(runs, lams, seeds, n: int, heur_val: dict[str, bool], hh: dict[str, bool]) -> float:
    """Rule 3: lambda chosen on validation with ``n`` exact solves a shape,
    and the held-out result at it (then the other lambdas' where run);
    returns the lambda."""
    by_lam = {lam: [_fraction(os.path.join(runs, "val", f"solves{n}", f"lam{lam:g}_seed{s}_val.jsonl"), heur_val)
                    for s in seeds] for lam in lams}
    lam = _lambda_rule(f"rule 3, the lambda with {n} exact solves a shape (no clock):", by_lam, seeds,
                       sum(heur_val.values()) / len(heur_val))
    name = f"heldout_solves{n}.jsonl"
    print(_heldout(runs, lam, seeds, n, hh, name, " exact solves"))
    for other in lams:
        if other != lam and _have_heldout(runs, other, seeds, name):
            print("for the record, not chosen: " + _heldout(runs, other, seeds, n, hh, name, " exact solves"))
    return lam


def prior_val_path(runs: str, lam: float, beta: float, seed: int, n: int) -> str:
    """Rule 4's validation rows of one size prior and seed (beta 0: rule 3's)."""
    if beta == 0:
        return os.path.join(runs, "val", f"solves{n}", f"lam{lam:g}_seed{seed}_val.jsonl")
    return os.path.join(runs, "val", "prior", f"lam{lam:g}_seed{seed}_b{beta:g}_val.jsonl")


def prior_heldout_name(beta: float, n: int) -> str:
    """A held-out run's file at one size prior (beta 0: rule 3's)."""
    return f"heldout_solves{n}.jsonl" if beta == 0 else f"heldout_prior_b{beta:g}_solves{n}.jsonl"


def _prior_rule(runs, lam: float, priors: list[float], seeds, n: int, heur_val: dict[str, bool],
                hh: dict[str, bool]) -> None:
    """Rule 4: the size prior chosen on validation at lambda ``lam`` and ``n``
    exact solves (``priors`` ascending: the smaller on a tie), and the
    held-out result at it (then the other priors' where run)."""
    by_beta = {beta: [_fraction(prior_val_path(runs, lam, beta, s, n), heur_val) for s in seeds]
               for beta in sorted(priors)}
    beta = _lambda_rule(f"rule 4, the decoding's size prior at lambda {lam:g} with {n} exact solves a shape:",
                        by_beta, seeds, sum(heur_val.values()) / len(heur_val), "beta")
    print(f"beta {beta:g}: " + _heldout(runs, lam, seeds, n, hh, prior_heldout_name(beta, n), " exact solves"))
    for other in by_beta:
        name = prior_heldout_name(other, n)
        if other != beta and _have_heldout(runs, lam, seeds, name):
            print(f"for the record, not chosen: beta {other:g}: " + _heldout(runs, lam, seeds, n, hh, name, " exact solves"))


def _fresh_rule(runs, lam: float, priors: list[float], seeds, n: int, heur_val: dict[str, bool],
                hh: dict[str, bool]) -> None:
    """Rule 5: rule 4's choice on the validation and fresh shapes together."""
    fresh = os.path.join(runs, "val", "fresh", f"lam{lam:g}_seed{{s}}_b{{beta:g}}_fresh.jsonl")
    first = fresh.format(s=seeds[0], beta=0)
    heur_fresh = _stable(all_rows(first), "heuristic")
    if not heur_fresh:
        raise RowsError(f"{first}: no heuristic rows")
    if set(heur_fresh) & set(heur_val):
        raise RowsError(f"{first}: fresh shapes among the validation shapes")
    n_all = len(heur_val) + len(heur_fresh)
    hf = sum(heur_fresh.values())
    print(f"fresh ({len(heur_fresh)} shapes): merge heuristic {hf}/{len(heur_fresh)} = {hf / len(heur_fresh):.3f}; "
          f"validation + fresh ({n_all} shapes): {(sum(heur_val.values()) + hf) / n_all:.3f}")
    ctrl = _stable(all_rows(first), "heuristic_refined")
    if ctrl:
        print(f"fresh: merge + the same refinement {sum(ctrl.values())}/{len(ctrl)} = {sum(ctrl.values()) / len(ctrl):.3f}")
    by_fresh = {beta: [_fraction(fresh.format(s=s, beta=beta), heur_fresh) for s in seeds] for beta in sorted(priors)}
    print("the fresh shapes alone:")
    _table("beta", by_fresh, seeds, "")
    by_beta = {beta: [(_fraction(prior_val_path(runs, lam, beta, s, n), heur_val) * len(heur_val)
                       + f * len(heur_fresh)) / n_all for s, f in zip(seeds, by_fresh[beta])]
               for beta in sorted(priors)}
    beta = _lambda_rule(f"rule 5, the size prior at lambda {lam:g} with {n} exact solves on validation + fresh "
                        f"({n_all} shapes):", by_beta, seeds, (sum(heur_val.values()) + hf) / n_all, "beta")
    name = prior_heldout_name(beta, n)
    if _have_heldout(runs, lam, seeds, name):
        print(f"beta {beta:g}: " + _heldout(runs, lam, seeds, n, hh, name, " exact solves"))
    else:
        print(f"beta {beta:g}: the held-out runs ({name}) are not all there yet")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", default=os.path.join(HERE, "results", "train_full_s56"))
    ap.add_argument("--budgets", default="60,120")
    ap.add_argument("--lams", default="1000,0", help="the first: the lambda chosen without refinement")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--replicates", nargs="+", default=[],
                    help="a folder of reruns of validation files (same names): each compared with its original")
    ap.add_argument("--solves", type=int, default=None, metavar="N",
                    help="also rule 3: lambda chosen with N exact solves a shape (RUNS/val/solves{N}/)")
    ap.add_argument("--priors", default=None, metavar="B,B,...",
                    help="with --solves, also rule 4: the decoding's size prior among these (RUNS/val/prior/)")
    ap.add_argument("--fresh-priors", default=None, metavar="B,B,...",
                    help="with --solves, also rule 5: the size prior among these on validation + fresh "
                         "(RUNS/val/fresh/)")
    a = ap.parse_args(argv)
    budgets = [float(b) for b in a.budgets.split(",")]
    lams = [float(x) for x in a.lams.split(",")]
    seeds = [int(s) for s in a.seeds.split(",")]
    if (a.priors is not None or a.fresh_priors is not None) and a.solves is None:
        ap.error("--priors and --fresh-priors need --solves")
    priors = [float(x) for x in a.priors.split(",")] if a.priors is not None else []
    fresh_priors = [float(x) for x in a.fresh_priors.split(",")] if a.fresh_priors is not None else []
    try:
        heur_val = _stable(all_rows(os.path.join(a.runs, "val", "val_heuristic.jsonl")), "heuristic")
        n = len(heur_val)
        h = sum(heur_val.values()) / n
        print(f"validation ({n} shapes): merge heuristic {sum(heur_val.values())}/{n} = {h:.3f}")
        fracs = {b: _fractions(a.runs, lams[0], seeds, b, heur_val) for b in budgets}
        print(f"rule 1, the budget (lambda {lams[0]:g}):")
        _table("budget", fracs, seeds, " s")
        b, reached = choose(fracs, h)
        print(f"chosen budget: {b:g} s ({'reaches' if reached else 'does not reach'} the heuristic on validation)")
        first = os.path.join(a.runs, f"lam{lams[0]:g}_seed{seeds[0]}", f"heldout_refine{b:g}.jsonl")
        hh = _stable(all_rows(first), "heuristic")  # the heuristic's rows ride with the first lambda's
        if not hh:
            raise RowsError(f"{first}: no heuristic rows")
        print(_heldout(a.runs, lams[0], seeds, b, hh))
        if len(lams) > 1:
            by_lam = {lam: (fracs[b] if lam == lams[0] else _fractions(a.runs, lam, seeds, b, heur_val))
                      for lam in lams}
            lam = _lambda_rule(f"rule 2, the lambda at {b:g} s:", by_lam, seeds, h)
            print(_heldout(a.runs, lam, seeds, b, hh))
        for folder in a.replicates:
            for name in sorted(os.listdir(folder)):
                if name.endswith(".jsonl"):
                    print(_replicate(os.path.join(a.runs, "val", name), os.path.join(folder, name)))
        if a.replicates:
            _runs_table(a.runs, a.replicates, lams, seeds, b, heur_val)
        if a.solves is not None:
            lam = _solves_rule(a.runs, lams, seeds, a.solves, heur_val, hh)
            if priors:
                _prior_rule(a.runs, lam, priors, seeds, a.solves, heur_val, hh)
            if fresh_priors:
                _fresh_rule(a.runs, lam, fresh_priors, seeds, a.solves, heur_val, hh)
    except RowsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
