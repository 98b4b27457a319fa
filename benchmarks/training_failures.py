"""Which bricks make a trained generator's filled layouts fall (issue 6).

    python benchmarks/training_failures.py --checkpoint OUT/checkpoint.npz [--split val]

Decodes the filled layout of every shape of the split (see
:func:`stablelego_jax.train.net.decode`), scores it with HiGHS and, over the layouts
that fall, counts the failing bricks (Eq. 10 score >= 1): how many are 1x1,
how many are fill-ins (probability < the config's threshold: put there by
the fill, not chosen by the network), and in how many falling layouts every
failing brick is a fill-in. Prints one summary line.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)

from stablelego_jax.train.shapes import SPLITS  # noqa: E402


def failures(ckpt: str, split: str = "val") -> dict:
    """Counts over the split's falling filled layouts (keys as printed)."""
    from stablelego_jax.analysis import analyze_layout
    from stablelego_jax.train import train as T
    from stablelego_jax.runtime import float64
    from stablelego_jax.train.net import decode

    params, _, _, _, cfg, _ = T.load_checkpoint(ckpt)
    shapes = T.split_shapes(cfg, split)
    arr = T.Arrays(shapes, cfg["crop"], cfg["grid"])
    with float64():  # the trained network runs in the library's float64
        p = np.asarray(T.make_fns(cfg)[0](params, arr.x, arr.valid))
    c = dict(shapes=len(shapes), falling=0, failing_bricks=0, one_by_one=0, fill_ins=0, one_by_one_fill_ins=0,
             all_fill_ins=0)
    for j in range(len(p)):
        idx, pos, size = decode(p[j], cfg["threshold"], True, arr.valid[j])
        pr = p[j][tuple(idx.T)]
        lay = T.layout_of(pos + arr.offset[j], size)
        if lay is None:
            continue
        r = analyze_layout(lay, solver="exact")
        if r.stable:
            continue
        bad = [i for i, k in enumerate(lay.keys) if r.scores[k] >= 1.0]
        small = [tuple(size[i]) == (1, 1) for i in bad]
        low = [pr[i] < cfg["threshold"] for i in bad]
        c["falling"] += 1
        c["failing_bricks"] += len(bad)
        c["one_by_one"] += sum(small)
        c["fill_ins"] += sum(low)
        c["one_by_one_fill_ins"] += sum(a and b for a, b in zip(small, low))
        c["all_fill_ins"] += all(low)
    return c


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--split", default="val", choices=SPLITS)
    a = ap.parse_args(argv)
    if not os.path.isfile(a.checkpoint):
        print(f"error: {a.checkpoint}: checkpoint not found", file=sys.stderr)
        return 2
    from stablelego_jax.blas import one_blas_thread

    with one_blas_thread():
        c = failures(a.checkpoint, a.split)
    print(", ".join(f"{k} {v}" for k, v in c.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
