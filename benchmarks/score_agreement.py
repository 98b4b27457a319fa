"""Per-brick agreement of two ``score`` results files, and why they differ
(issue 20: one answer per layout).

Usage:
  python benchmarks/score_agreement.py --exact EXACT.jsonl --other OTHER.jsonl [--classify]
  python benchmarks/score_agreement.py --exact EXACT.jsonl --ridge 1e-10 --out OUT.jsonl

``--exact``: a results file of ``stablelego score --solver exact`` (or
``benchmarks/cores.py --keep``); ``--other``: another run on the same
layouts (JAX, auto, ...). Prints, over the layouts in both: labels, highest
score within 1e-3, weakest brick, failing set (bricks at score >= 1), every
brick's score within 1e-3, converged, and the names of the layouts whose
scores differ by more than 1e-3. ``--classify`` solves each of those again,
one layout at a time, with the exact solver and the JAX interior point, and
prints the relative difference of their Eq. 9 costs (JAX minus exact) and
their force norms, and for a brick that fails by one solver only its
residual and largest drag by each: a cost difference within ~1e-7 is a tie the canonical
term does not settle; a larger one is the canonical term trading cost for
a smaller norm. ``--ridge R --out OUT``: first scores the exact file's
layouts with the JAX solver at ``Params(ridge=R)`` (``score_files``, all
cores, resumable) into OUT, then compares OUT as ``--other``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import numpy as np  # noqa: E402


def read(path: str) -> dict:
    """{absolute path: record} of the scored lines of a results file (its
    relative paths taken from the current folder, as ``score`` wrote them)."""
    with open(path) as fh:
        return {os.path.abspath(r["file"]): r for r in map(json.loads, fh) if "scores" in r}


def failing(r: dict) -> list:
    return sorted(k for k, v in r["scores"].items() if v >= 1.0)


def compare(ex: dict, other: dict) -> tuple[dict, list]:
    """(counts, files whose scores differ by more than 1e-3)."""
    files = sorted(set(ex) & set(other))
    diff = {f: max(abs(other[f]["scores"][k] - v) for k, v in ex[f]["scores"].items()) for f in files}
    counts = dict(
        compared=len(files),
        labels=sum(ex[f]["stable"] == other[f]["stable"] for f in files),
        highest=sum(abs(max(ex[f]["scores"].values()) - max(other[f]["scores"].values())) <= 1e-3 for f in files),
        weakest=sum(ex[f]["weakest"] == other[f]["weakest"] for f in files),
        failing=sum(failing(ex[f]) == failing(other[f]) for f in files),
        per_brick=sum(d <= 1e-3 for d in diff.values()),
        converged=sum(bool(other[f].get("converged", True)) for f in files),
        by_solver={s: sum(other[f].get("solver") == s for f in files) for s in ("jax", "exact")},
    )
    if files:  # each layout's largest per-brick difference: the tolerance met on 50/90/99/100% of layouts
        q = np.quantile(list(diff.values()), [0.5, 0.9, 0.99, 1.0])
        counts["largest_difference"] = dict(zip(("median", "p90", "p99", "max"), (float(f"{x:.3g}") for x in q)))
        counts["per_brick_1e-2"] = sum(d <= 1e-2 for d in diff.values())
    return counts, [f for f in files if diff[f] > 1e-3]


def classify(files: list) -> None:
    """Solve each file again with both solvers; print cost and norm differences."""
    from stablelego_jax.analysis import analyze_layout
    from stablelego_jax.batch import analyze_many
    from stablelego_jax.formats.reader import load_layout

    lays = [load_layout(f) for f in files]
    for f, lay, j in zip(files, lays, analyze_many(lays, "jax")):
        e = analyze_layout(lay, solver="exact")
        rel = (j.objective - e.objective) / abs(e.objective)
        print(f"{os.path.basename(f)}: {lay.n} bricks, cost (jax - exact) / exact {rel:.2e}, "
              f"norm exact {np.linalg.norm(e.forces):.4g} jax {np.linalg.norm(j.forces):.4g}, "
              f"failing set {'same' if failing(e.to_json()) == failing(j.to_json()) else 'differs'}", flush=True)
        for k in sorted(set(failing(e.to_json())) ^ set(failing(j.to_json()))):
            i = lay.keys.index(k)
            print(f"  brick {k}: score exact {e.scores[k]:.4g} jax {j.scores[k]:.4g}; residual (N, N m) "
                  f"exact {np.array2string(np.asarray(e.residual[i]), precision=2)} "
                  f"jax {np.array2string(np.asarray(j.residual[i]), precision=2)}; "
                  f"largest drag (T) exact {e.max_drag[k]:.4g} jax {j.max_drag[k]:.4g}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--exact", required=True)
    ap.add_argument("--other")
    ap.add_argument("--classify", action="store_true")
    ap.add_argument("--ridge", type=float, help="score the exact file's layouts with JAX at this ridge first")
    ap.add_argument("--out", help="results file of the --ridge run")
    a = ap.parse_args()
    ex = read(a.exact)
    if a.ridge is not None:
        if not a.out:
            raise SystemExit("--ridge needs --out")
        from stablelego_jax.batch import score_files
        from stablelego_jax.model import Params

        st = score_files(sorted(ex), a.out, solver="jax", params=Params(ridge=a.ridge))
        print(f"ridge {a.ridge:g}: wall {st.wall_s:.1f} s, solve {st.solve_s:.1f} s, compile {st.compile_s:.1f} s, "
              f"not converged {st.not_converged}, solved again {st.retried}")
        a.other = a.out
    if not a.other:
        raise SystemExit("give --other or --ridge")
    counts, misses = compare(ex, read(a.other))
    print(json.dumps(counts))
    print("scores apart by more than 1e-3:", " ".join(os.path.basename(f) for f in misses))
    if a.classify:
        classify(misses)


if __name__ == "__main__":
    main()
