"""Issue 19, item 3: generator + refinement with a longer budget, continued from an evaluation.

    python benchmarks/refine_budget.py --checkpoint RUN/checkpoint.npz --rows RUN/heldout_refine60.jsonl \\
        --first-seconds 60 (--seconds 120 | --solves N) --out OUT.jsonl
        [--methods generator_refined,heuristic_refined] [--split heldout|val|train]

``stablelego evaluate --refine SECONDS`` refines each shape's start cover
with :func:`stablelego_jax.generate.stabilize.stabilize` (no heuristic seeds,
no gradient move). That search follows one path whatever its budget: its
random draws come from a generator seeded 0, every candidate is judged by a
deterministic solve, and only the stopping test reads the clock. A shape
whose refinement stood within the budget of ``--rows`` stands at the same
point within a longer one; so this script refines again, from their start
and with ``--seconds``, only the shapes of ``--methods`` that did not stand,
and copies every other row. The starts are rebuilt as evaluate builds them
(the checkpoint's filled decoding; the merge for "heuristic_refined").
Every row of those methods gets ``budget_s``: the budget it was refined
with (``--first-seconds``: the one ``--rows`` was made with).

``--solves N`` instead gives the budget in exact solves, with no clock
(``evaluate --refine-solves N``): the same rows on any machine and under
any load. A shape that stood within the first budget after k exact solves
began its last candidate after k - 2 of them (a judge's solve and the
canonical one that confirmed it), so it stands at the same point within N
solves when k <= N: those rows are copied; every other row of ``--methods``
is refined again from its start with ``max_solves`` N and no time limit.
Every row of those methods then gets ``budget_solves`` N (and the copied
ones ``carried_from_s``, the first budget). Writes
``--out`` atomically (the same row format: ``benchmarks/training.py
--heldout`` summarises it) and prints the stable fraction per method. A missing or
malformed ``--rows`` file: one error line and exit 2, nothing written.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)
sys.path.insert(0, HERE)
from rows import RowsError, all_rows  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--rows", required=True, help="an evaluate --refine output of this checkpoint")
    ap.add_argument("--first-seconds", type=float, required=True, help="the budget --rows was refined with, s")
    budget = ap.add_mutually_exclusive_group(required=True)
    budget.add_argument("--seconds", type=float, help="the longer refinement budget, s a shape")
    budget.add_argument("--solves", type=int, help="the budget in exact solves a shape, no clock (>= 1)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--methods", default="generator_refined,heuristic_refined")
    ap.add_argument("--split", default="heldout", choices=("heldout", "val", "train"),
                    help="the split --rows was evaluated on (evaluate --split)")
    a = ap.parse_args(argv)
    if a.solves is not None and a.solves < 1:
        ap.error(f"--solves must be >= 1, got {a.solves}")

    from stablelego_jax.blas import one_blas_thread
    from stablelego_jax.files import atomic_write_text
    from stablelego_jax.generate.voxels import merge_voxels
    from stablelego_jax.runtime import float64
    from stablelego_jax.train import train as T
    from stablelego_jax.train.evaluate import refined_rows, summary

    try:
        rows = all_rows(a.rows)
    except RowsError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    methods = [m for m in a.methods.split(",") if any(r["method"] == m for r in rows)]
    if not methods:
        print(f"error: {a.rows}: no rows of {a.methods}", file=sys.stderr)
        return 2
    params, _, step, _, cfg, _ = T.load_checkpoint(a.checkpoint)
    shapes = {s.name: s for s in T.split_shapes(cfg, a.split)}
    t0 = time.perf_counter()
    starts = {}
    if "generator_refined" in methods:
        names = list(shapes)
        arr = T.Arrays([shapes[n] for n in names], cfg["crop"], cfg["grid"])
        with float64(), one_blas_thread():
            decoded = T.decoded_layouts(params, arr, cfg, T.make_fns(cfg)[0], fill=True)
        starts["generator_refined"] = {n: lay for n, (lay, _) in zip(names, decoded)}
        for r in rows:  # the starts must be the decodings that --rows scored
            lay = starts["generator_refined"].get(r["shape"]) if r["method"] == "generator_filled" else None
            if lay is not None and lay.n != r["n_bricks"]:
                print(f"error: {a.rows}: {r['shape']}'s filled decoding has {lay.n} bricks here, "
                      f"{r['n_bricks']} there: another checkpoint?", file=sys.stderr)
                return 2
    if "heuristic_refined" in methods:
        starts["heuristic_refined"] = {n: merge_voxels(s.vox, source=n) for n, s in shapes.items()}

    def carried(r) -> bool:
        """Whether row ``r`` (of a method refined here) holds within the new budget as it is."""
        return r["stable"] and (a.solves is None or r["exact_calls"] <= a.solves)

    budget = f"{a.seconds:g} s" if a.solves is None else f"{a.solves} exact solves (no clock)"
    out = []
    for m in methods:
        redo = [r["shape"] for r in rows if r["method"] == m and not carried(r)]
        print(f"{m}: {len(redo)} shapes not stable within the first budget"
              f"{'' if a.solves is None else ' or after more solves'}; refining them for {budget}",
              file=sys.stderr, flush=True)
        extra = {"lam": cfg["lam"], "seed": cfg["seed"], "step": step} if m == "generator_refined" else {}
        new = refined_rows(m, [shapes[n] for n in redo], [starts[m][n] for n in redo], a.seconds, sys.stderr, extra,
                           a.solves)
        out += [dict(r, budget_s=a.seconds) if a.solves is None else r for r in new]
    redone = {(r["method"], r["shape"]) for r in out}
    first = {"budget_s": a.first_seconds} if a.solves is None else {"budget_solves": a.solves,
                                                                     "carried_from_s": a.first_seconds}
    kept = [dict(r, **first) if r["method"] in methods else r
            for r in rows if (r["method"], r["shape"]) not in redone]
    rows_out = kept + out
    atomic_write_text(a.out, "".join(json.dumps(r) + "\n" for r in rows_out))
    for m, s in summary(rows_out).items():
        print(f"{m}: {s['n']} {a.split} shapes, stable {s['stable_fraction']:.3f}, mean IoU {s['mean_iou']:.4f}")
    print(f"wrote {a.out} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
