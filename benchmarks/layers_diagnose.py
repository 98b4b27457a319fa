"""Issue 19, item 3 (session 68): why the layer-by-layer generator's imitation stops falling.

    python benchmarks/layers_diagnose.py [VARIANT ...]   (default: every variant)

Trains 200 steps (seed 0) of each variant of ``stablelego_jax/train/configs/layers.json`` (the
config's 600-step schedule, stopped after 200 steps; the folder ``/tmp/layers_diagnose/VARIANT``)
and prints the mean loss of its first and last 5 logged batches and, on the 32 validation shapes
with the merge's layer below (teacher forcing), the fraction of the merge's placements that get a
probability above 0.5 and the cross-entropy a shape. ``trained``: the same figures for
``benchmarks/results/train_layers_s68/seed0`` (600 steps). Variants: ``default`` (the config),
``noclip`` (no gradient clipping), ``imitate_cov`` (no binarisation, no brick cost), ``lr01``
(Adam 0.01), ``imitate20`` (imitation weighted 20, no binarisation, no brick cost). Results:
BENCHMARKS.md, issue 19 item 3, session 68; log ``results/train_layers_s68/diagnose_s68.log``.
"""
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)

from stablelego_jax.runtime import x64  # noqa: E402
from stablelego_jax.train import train as T  # noqa: E402

VARIANTS = {
    "default": {},
    "noclip": {"clip": 1e9},
    "imitate_cov": {"bin_weight": 0.0, "bin_weight_final": 0.0, "brick_weight": 0.0},
    "lr01": {"lr": 0.01},
    "imitate20": {"imitate": 20.0, "bin_weight": 0.0, "bin_weight_final": 0.0, "brick_weight": 0.0},
}


@x64
def match(cfg, params, arr):
    """(fraction of the teacher's placements above 0.5, mean cross-entropy a shape) on ``arr``."""
    probs_fn = T.make_fns(cfg)[0]
    hit, tot, bce = 0, 0, []
    for s in range(0, len(arr.names), 8):
        p = np.asarray(probs_fn(params, arr.x[s:s + 8], arr.valid[s:s + 8]))
        t = arr.teacher[s:s + 8]
        hit += int((p[t] > 0.5).sum())
        tot += int(t.sum())
        pc = np.clip(p, 1e-7, 1 - 1e-7)
        b = -(t * np.log(pc) + (~t) * np.log(1 - pc)) * arr.valid[s:s + 8]
        bce += list(b.reshape(len(p), -1).sum(1))
    return hit / tot, float(np.mean(bce))


def main(names):
    base = T.load_config(os.path.join(REPO, "stablelego_jax", "train", "configs", "layers.json"))
    _, val, _ = T.dataset(base, validation=True)
    for name in names:
        if name == "trained":
            params, cfg = T.load_checkpoint(os.path.join(HERE, "results", "train_layers_s68", "seed0",
                                                         "checkpoint.npz"))[0], base
        else:
            cfg = dict(base, **VARIANTS[name])
            t0 = time.time()
            params, hist = T.train(cfg, f"/tmp/layers_diagnose/{name}", log=open(os.devnull, "w"), max_steps=200)
            losses = [h["loss"] for h in hist if "loss" in h]
            print(name, "loss first/last 5 mean", round(np.mean(losses[:5]), 1), round(np.mean(losses[-5:]), 1),
                  "train s", round(time.time() - t0), flush=True)
        m, b = match(cfg, params, T.shape_arrays(val, cfg))
        print(name, "val teacher-forced match", round(m, 3), "val BCE a shape", round(b, 1), flush=True)


if __name__ == "__main__":
    unknown = [n for n in sys.argv[1:] if n not in VARIANTS and n != "trained"]
    if unknown:
        print(f"error: unknown variant {unknown[0]!r} (known: trained, {', '.join(VARIANTS)})", file=sys.stderr)
        sys.exit(2)
    main(sys.argv[1:] or ["trained", *VARIANTS])
