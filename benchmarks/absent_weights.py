"""Issue 19, item 3: the soft interior point on nearly absent placements.

    python benchmarks/absent_weights.py clusters [--shard benchmarks/results/shard500] [--iters 30,60,100]
    python benchmarks/absent_weights.py threshold [--checkpoint CKPT] [--config CFG] [--batches 2]
        [--below 1e-6,1e-4,1e-2]

``clusters``: the 40 layouts of at most 120 bricks among the first 60 of
the shard (``make_shard.py --n 500 --seed 0``), each four times with its
top 2 to n/3 bricks (by level) at weight 0, 1e-17 or 1e-60 and the rest at 1
(160 problems, seeded); prints how many do not converge at each iteration
budget, and by weight.

``threshold``: batches drawn from a training checkpoint as training draws
them (the subsets of ``batch_subsets``, weights from ``train.batch_weights``,
the shares of the subset's probabilities), each subset that did not converge at the
first threshold or has placements of weight at most 1e-2 solved by
``train.solve_subsets`` at every ``--below`` (``absent_below``); prints
converged, placements dropped, the summed brick loss, and, where both
converge, its change and the gradient's (weights above 1e-2) relative to
the first threshold. Default: seed 1's lambda-1000 checkpoint
(``results/train_full_s56/lam1000_seed1``, at step 50 as of session 57).
"""
from __future__ import annotations

import argparse
import glob
import os
import sys
from collections import Counter

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

HERE = os.path.dirname(os.path.abspath(__file__))


def clusters(a) -> int:
    import jax

    from stablelego_jax import load_layout
    from stablelego_jax.loss import LossOptions, solve_soft
    from stablelego_jax.runtime import float64
    from stablelego_jax.soft import soft_problem
    from stablelego_jax.solvers.problem import pad_soft

    paths = sorted(glob.glob(os.path.join(a.shard, "*.json")))[:60]
    if not paths:
        print(f"error: {a.shard}: no layouts (make_shard.py --n 500 --seed 0)", file=sys.stderr)
        return 1
    rng = np.random.default_rng(0)
    cases = []
    for path in paths:
        prob = soft_problem(load_layout(path))
        n = prob.mass.shape[0]
        if n > 120:
            continue
        prob = pad_soft(prob, 128, 4096, 64)
        level = np.asarray(prob.level)[:n]
        for _ in range(4):
            w = np.zeros(128)
            w[:n] = 1.0
            k = rng.integers(2, max(3, n // 3))
            value = rng.choice([0.0, 1e-17, 1e-60])
            w[np.argsort(-level)[:k]] = value
            cases.append((w, prob, float(value)))
    with float64():
        for iters in (int(v) for v in a.iters.split(",")):
            opts = LossOptions(iters=iters)
            f = jax.jit(lambda w, p: solve_soft(w, None, p, opts=opts).converged)
            bad = Counter(v for w, p, v in cases if not bool(f(w, p)))
            by = ", ".join(f"{v:g}: {bad[v]} of {sum(c[2] == v for c in cases)}" for v in (0.0, 1e-17, 1e-60))
            print(f"{iters} iterations: {sum(bad.values())} of {len(cases)} not converged ({by})", flush=True)
    return 0


def threshold(a) -> int:
    from stablelego_jax.blas import one_blas_thread
    from stablelego_jax.runtime import float64
    from stablelego_jax.train import train as T

    cfg = T.load_config(a.config, lam=1000.0)
    below = [float(v) for v in a.below.split(",")]
    with float64(), one_blas_thread():
        run = T.replay(a.checkpoint, cfg)
        probs_fn = T.make_fns(cfg)[0]
        opts = T.loss_options(cfg)
        print(f"{a.checkpoint}: step {run.step}", flush=True)
        for bi in range(a.batches):
            x, valid, _, _, sub = T.draw_batch(run.arrays, cfg, run.rng, run.params, probs_fn)
            w = T.batch_weights(cfg, run.params, x, valid, sub)
            for j, prob in enumerate(sub.prob):
                wj = w[j:j + 1]
                real = wj[0][: int(sub.mask[j].sum())]
                res = [T.solve_subsets(wj, [prob], opts, bl) for bl in below]
                small = int(((real > 0) & (real <= 1e-2)).sum())
                if res[0][1][0] and small == 0:
                    continue
                keep = wj[0] > 1e-2
                v0, c0, g0 = res[0][0][0], res[0][1][0], res[0][2][0]
                parts = []
                for bl, (v, c, g) in zip(below, res):
                    s = f"{bl:g}: {'converged' if c[0] else 'not converged'}, {int(((real > 0) & (real <= bl)).sum())} dropped"
                    if c[0]:
                        s += f", loss {v[0]:.6g}"
                        if c0 and bl != below[0]:
                            gk = np.abs(g0[keep]).max()
                            s += (f" (loss {abs(v[0] - v0) / max(abs(v0), 1e-300):.2g}, gradient "
                                  f"{np.abs(g[0][keep] - g0[keep]).max() / max(gk, 1e-300):.2g} relative)")
                    parts.append(s)
                print(f"batch {bi} subset {j}: {len(real)} placements, {small} at most 1e-2 | " + " | ".join(parts),
                      flush=True)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sp = ap.add_subparsers(dest="what", required=True)
    c = sp.add_parser("clusters")
    c.add_argument("--shard", default=os.path.join(HERE, "results", "shard500"))
    c.add_argument("--iters", default="30,60,100")
    t = sp.add_parser("threshold")
    t.add_argument("--checkpoint", default=os.path.join(HERE, "results", "train_full_s56", "lam1000_seed1",
                                                       "checkpoint.npz"))
    t.add_argument("--config", default=os.path.join(HERE, "configs", "full_scale_absent.json"))
    t.add_argument("--batches", type=int, default=2)
    t.add_argument("--below", default="1e-6,1e-4,1e-2")
    a = ap.parse_args(argv)
    return clusters(a) if a.what == "clusters" else threshold(a)


if __name__ == "__main__":
    sys.exit(main())
