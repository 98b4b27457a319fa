"""Issue 19, session 58: a soft problem's loss + gradient, dense against layered.

    python benchmarks/soft_plan.py cuboids [--dims 5x6x2,6x8x3,8x8x2,7x9x4]
    python benchmarks/soft_plan.py subsets --checkpoint CKPT [--config CFG] [--want b1s2,b1s3,b1s5]
        [--below 1e-4]

``cuboids``: unit-brick cuboids' soft problems (weights 0.7) padded to the
ladder, dense and layered (the ladder's layers and slots), jitted loss +
gradient, best of 5 after the compile. ``subsets``: the stability subsets
of the batches a training checkpoint draws next (as ``absent_weights.py
threshold`` draws them), solved by ``train.solve_subsets`` as planned by
``soft_plan``, forced dense and forced layered (the rung's shared shape, cut), best of 2
after a first call. Session 58 measured seed 1's step-50 checkpoint
(``git show 1a76baa:benchmarks/results/train_full_s56/lam1000_seed1/checkpoint.npz``).
Prints each problem's levels, ``soft_plan``'s choice, times and losses.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

HERE = os.path.dirname(os.path.abspath(__file__))


def cuboids(a) -> int:
    import jax
    import jax.numpy as jnp

    from stablelego_jax.generate.procedural import cuboid
    from stablelego_jax.loss import stability_loss
    from stablelego_jax.runtime import float64
    from stablelego_jax.soft import compile_soft
    from stablelego_jax.solvers import problem as P

    with float64():
        for d in a.dims.split(","):
            nx, ny, nz = (int(v) for v in d.split("x"))
            soft = compile_soft(cuboid(nx, ny, nz)).problem
            shape = P.bucket_shape(soft.mass.shape[0], soft.col_kind.shape[0], soft.group.shape[1])
            L, B = P.soft_layer_plan(soft)
            out = []
            for name, pr in (("dense", P.pad_soft(soft, *shape)),
                             ("layered", P.pad_soft(P.layer_soft(soft, *P.layer_bucket(L, B)), *shape))):
                f = jax.jit(jax.value_and_grad(lambda w, pr: stability_loss(w, None, pr)))
                w = jnp.full(pr.mass.shape[0], 0.7)
                v, _ = jax.block_until_ready(f(w, pr))
                ts = []
                for _ in range(5):
                    t = time.perf_counter()
                    jax.block_until_ready(f(w, pr))
                    ts.append(time.perf_counter() - t)
                out.append(f"{name} {min(ts) * 1e3:.1f} ms, loss {float(v):.10g}")
            print(f"{d}: {L} levels x {B} bricks, soft_plan {P.soft_plan(soft)} | " + " | ".join(out), flush=True)
    return 0


def subsets(a) -> int:
    from stablelego_jax.blas import one_blas_thread
    from stablelego_jax.runtime import float64
    from stablelego_jax.solvers import problem as P
    from stablelego_jax.train import train as T

    cfg = T.load_config(a.config, lam=1000.0)
    want = set(a.want.split(","))
    raw = []
    planned = T.plan_soft

    def capture(prob, *args, **kw):  # the subset's problem before planning
        raw.append(prob)
        return planned(prob, *args, **kw)

    T.plan_soft = capture
    choose = P.soft_plan
    with float64(), one_blas_thread():
        run = T.replay(a.checkpoint, cfg)
        probs_fn = T.make_fns(cfg)[0]
        opts = T.loss_options(cfg)
        print(f"{a.checkpoint}: step {run.step}", flush=True)
        for bi in range(1 + max(int(s[1:].split("s")[0]) for s in want)):
            raw.clear()
            x, valid, _, _, sub = T.draw_batch(run.arrays, cfg, run.rng, run.params, probs_fn)
            w = T.batch_weights(cfg, run.params, x, valid, sub)
            for j, prob in enumerate(sub.prob):
                if f"b{bi}s{j}" not in want:
                    continue
                L, B = P.soft_layer_plan(raw[j])
                forced = {}
                for name, rule in (("dense", lambda prob: ("dense",)),
                                   ("layered", lambda prob: ("layered", *P.layer_bucket(*P.soft_layer_plan(prob))))):
                    P.soft_plan = rule
                    forced[name] = planned(raw[j], shared=True)  # the rung's shared shape (cut), as training's
                P.soft_plan = choose
                out = []
                for name, pr in (("as planned", prob), *forced.items()):
                    T.solve_subsets(w[j:j + 1], [pr], opts, a.below)
                    ts = []
                    for _ in range(2):
                        t = time.perf_counter()
                        v, c, _ = T.solve_subsets(w[j:j + 1], [pr], opts, a.below)
                        ts.append(time.perf_counter() - t)
                    out.append(f"{name} {min(ts):.1f} s ({'converged' if c[0] else 'not converged'}, loss {v[0]:.10g})")
                print(f"b{bi}s{j}: {int(np.asarray(raw[j].brick_mask).sum())} placements, {L} levels x {B}, "
                      f"soft_plan {choose(raw[j])} | " + " | ".join(out), flush=True)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sp = ap.add_subparsers(dest="what", required=True)
    c = sp.add_parser("cuboids")
    c.add_argument("--dims", default="5x6x2,6x8x3,8x8x2,7x9x4")
    s = sp.add_parser("subsets")
    s.add_argument("--checkpoint", required=True)
    s.add_argument("--config", default=os.path.join(HERE, "configs", "full_scale_absent.json"))
    s.add_argument("--want", default="b1s2,b1s3,b1s5")
    s.add_argument("--below", type=float, default=1e-4)
    a = ap.parse_args(argv)
    return cuboids(a) if a.what == "cuboids" else subsets(a)


if __name__ == "__main__":
    sys.exit(main())
