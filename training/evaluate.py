"""Score a trained generator on the held-out shapes with the exact solver.

    python -m training.evaluate --checkpoint OUT/checkpoint.npz --out RESULTS.jsonl
        [--heuristic] [--untrained] [--split heldout|val|train]

Decodes two layouts per shape: "generator" (greedy, probabilities >= the
config's ``threshold``, no overlaps, nothing forced in: cells can stay
empty, IoU < 1) and "generator_filled" (the same, then the remaining
cells filled greedily by the most probable valid placements that fit:
IoU 1 by construction), scores it with HiGHS
(:func:`stablelego_jax.api.analyze_layout` with ``solver="exact"``) and
writes one JSON line per shape: name, kind, method, stable, iou, n_bricks,
n_cells. ``--heuristic`` adds the StableLego merge rule
(:func:`generators.voxels.merge_voxels`, exact cover: IoU 1) on the same
shapes; ``--untrained`` adds the same two decodings of the checkpoint's
network at initialisation ("untrained", "untrained_filled": same config
and seed, no training step), the reference that shows what training
added. The summary (stable fraction, mean IoU per method) goes to stdout;
the file is written atomically.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from stablelego_jax.io import atomic_write_text

from .train import SPLITS


def evaluate(ckpt: str, split: str = "heldout", heuristic: bool = False, untrained: bool = False) -> list[dict]:
    """Rows (one per shape and method) for the checkpoint ``ckpt``."""
    from .train import Arrays, decode_and_score, initial_params, load_checkpoint, make_fns, score_layout, split_shapes

    params, _, step, _, cfg, _ = load_checkpoint(ckpt)
    shapes = split_shapes(cfg, split)
    arr = Arrays(shapes, cfg["crop"], cfg["grid"])
    probs_fn = make_fns(cfg)[0]
    from stablelego_jax.blas import one_blas_thread

    nets = [("generator", params, step)]
    if untrained:
        nets.append(("untrained", initial_params(cfg), 0))
    rows = []
    for name, prm, st in nets:
        for method, fill in ((name, False), (name + "_filled", True)):
            with one_blas_thread():
                res = decode_and_score(prm, arr, cfg, probs_fn, fill=fill)
            for s, (stable, iou, nb) in zip(shapes, res):
                rows.append({"shape": s.name, "kind": s.kind, "method": method, "lam": cfg["lam"],
                             "seed": cfg["seed"], "step": st, "stable": stable, "iou": round(iou, 6),
                             "n_bricks": nb, "n_cells": int(s.vox.sum())})
    if heuristic:
        from generators.voxels import merge_voxels

        for s in shapes:
            lay = merge_voxels(s.vox, source=s.name)
            rows.append({"shape": s.name, "kind": s.kind, "method": "heuristic", "stable": score_layout(lay),
                         "iou": 1.0, "n_bricks": lay.n, "n_cells": int(s.vox.sum())})
    return rows


def summary(rows: list[dict]) -> dict:
    """{method: {"n", "stable_fraction", "mean_iou"}}."""
    out = {}
    for m in sorted({r["method"] for r in rows}):
        rs = [r for r in rows if r["method"] == m]
        out[m] = {"n": len(rs), "stable_fraction": float(np.mean([r["stable"] for r in rs])),
                  "mean_iou": float(np.mean([r["iou"] for r in rs]))}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m training.evaluate", description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--out", required=True, help="results, one JSON object per line")
    ap.add_argument("--heuristic", action="store_true", help="also score the merge heuristic on the same shapes")
    ap.add_argument("--untrained", action="store_true",
                    help="also score the same network at initialisation (same config and seed)")
    ap.add_argument("--split", choices=SPLITS, default="heldout")
    a = ap.parse_args(argv)
    if not os.path.isfile(a.checkpoint):
        print(f"error: {a.checkpoint}: checkpoint not found", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    try:
        rows = evaluate(a.checkpoint, a.split, a.heuristic, a.untrained)
    except (OSError, ValueError, KeyError) as exc:
        print(f"error: {a.checkpoint}: cannot evaluate: {exc}", file=sys.stderr)
        return 2
    d = os.path.dirname(os.path.abspath(a.out))
    os.makedirs(d, exist_ok=True)
    atomic_write_text(a.out, "".join(json.dumps(r) + "\n" for r in rows))
    for m, s in summary(rows).items():
        print(f"{m}: {s['n']} {a.split} shapes, stable {s['stable_fraction']:.3f}, mean IoU {s['mean_iou']:.4f}")
    print(f"wrote {a.out} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
