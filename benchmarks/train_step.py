"""Compile time and time per step of the generator's training step.

    python benchmarks/train_step.py [--config stablelego_jax/train/configs/default.json]
        [--steps 12] [--lam 1000] [--mesh-dir DIR|none] [--solves each|batch] [--json]
        [--jobs 1,2 [--checkpoint CKPT]]

Builds the training data of the config (``stablelego_jax.train.train.dataset``),
then runs the training loop's own step (``make_fns``: forward pass, subsets
of placements, loss + gradient with the soft interior point, optimizer
update) on batches drawn as ``train`` draws them. Reports the first step
(tracing and compiling the step included) and the median of the others, in
seconds, and the process's peak resident memory; with ``stability_solves``
"each" also the solver executables compiled (or loaded from disk) and the
seconds that took. ``--solves`` overrides the config's ``stability_solves``.
Run two code versions one after the other on the quiet machine to compare
them.

``--jobs 1,2`` compares subsets solved one at a time with two at a time
(``solve_jobs``, ``train.solve_subsets``) side by side in one run: each
batch's loss and gradient are computed once per count, the order
alternated from batch to batch, the first batch a warm-up (its solver
executables compiled or loaded) not counted; the parameters are not
updated, so every count sees the same subsets, and the loss and gradient
must agree bit for bit. ``--checkpoint CKPT`` starts from a training
checkpoint (its parameters and the batches its run would draw next)
instead of the initial parameters; the config is the checkpoint's own.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time

import jax
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)

from stablelego_jax.blas import one_blas_thread  # noqa: E402
from stablelego_jax.runtime import x64  # noqa: E402
from stablelego_jax.solvers.compiled import STATS  # noqa: E402
from stablelego_jax.train import train as T  # noqa: E402


@x64
def measure(cfg: dict, steps: int, lam: float) -> dict:
    """{first_step_s, step_s (median of the rest), loss (last)} for ``steps`` steps."""
    probs_fn, step_fn, opt = T.make_fns(cfg)[:3]
    shapes = T.dataset(cfg, validation=True)[0]
    tr = T.Arrays(shapes, cfg["crop"], cfg["grid"])
    params = T.initial_params(cfg)
    opt_state = opt.init(params)
    rng = np.random.default_rng(cfg["seed"])
    times, loss = [], None
    with one_blas_thread():
        for step in range(steps):
            t0 = time.perf_counter()
            x, valid, target, _, sub = T.draw_batch(tr, cfg, rng, params, probs_fn)
            bw = np.float64(T.bin_weight(cfg, step))
            params, opt_state, loss, aux = step_fn(params, opt_state, np.float64(lam), bw, x, valid, target, sub)
            loss = float(loss)
            times.append(time.perf_counter() - t0)
            print(f"step {step + 1}/{steps}: {times[-1]:.3f} s, loss {loss:.6f}", file=sys.stderr, flush=True)
    return {"first_step_s": round(times[0], 3), "step_s": round(float(np.median(times[1:])), 4),
            "steps_s": [round(t, 3) for t in times], "loss": loss, "shapes": len(shapes),
            "solves": cfg["stability_solves"], "solver_compiles": STATS.compiles,
            "solver_compile_s": round(STATS.compile_s, 2)}


@x64
def compare_jobs(cfg: dict, steps: int, lam: float, jobs: list[int], checkpoint: str | None) -> dict:
    """Per batch the seconds of one loss + gradient per count of ``jobs``
    (the order alternated), the same parameters throughout; batch 0 is a
    warm-up. {jobs: [...], step_s: {count: [s per timed batch]}, ratio:
    median of the first count's time over each other's, identical: bool}."""
    fns = {j: T.make_fns(dict(cfg, solve_jobs=j)) for j in jobs}
    if checkpoint:
        run = T.replay(checkpoint, cfg)
        params, start, rng, tr = run.params, run.step, run.rng, run.arrays
    else:
        tr = T.Arrays(T.dataset(cfg, validation=True)[0], cfg["crop"], cfg["grid"])
        params, start, rng = T.initial_params(cfg), 0, np.random.default_rng(cfg["seed"])
    probs_fn = fns[jobs[0]][0]
    times = {j: [] for j in jobs}
    identical = True
    with one_blas_thread():
        for step in range(steps):
            x, valid, target, _, sub = T.draw_batch(tr, cfg, rng, params, probs_fn)
            bw = np.float64(T.bin_weight(cfg, start + step))
            order = jobs if step % 2 == 0 else jobs[::-1]
            res = {}
            for j in order:
                t0 = time.perf_counter()
                loss, aux, g = fns[j][4](params, np.float64(lam), bw, x, valid, target, *sub)
                g = [np.asarray(v) for v in jax.tree_util.tree_leaves(g)]
                res[j] = (float(loss), [float(a) for a in aux], g, time.perf_counter() - t0)
            ref = res[jobs[0]]
            same = all(r[0] == ref[0] and r[1] == ref[1] and all(np.array_equal(u, v) for u, v in zip(r[2], ref[2]))
                       for r in res.values())
            identical &= same
            if step > 0:
                for j in jobs:
                    times[j].append(res[j][3])
            print(f"batch {step}{' (warm-up)' if step == 0 else ''}: "
                  + ", ".join(f"jobs {j} {res[j][3]:.2f} s" for j in jobs)
                  + f", loss {ref[0]:.6f}, converged {ref[1][3]:.2f}, identical {same}", file=sys.stderr, flush=True)
    med = {j: float(np.median(t)) for j, t in times.items()}
    return {"jobs": jobs, "start_step": int(start), "step_s": {str(j): [round(t, 3) for t in times[j]] for j in jobs},
            "median_s": {str(j): round(med[j], 3) for j in jobs},
            "ratio": {str(j): round(med[jobs[0]] / med[j], 3) for j in jobs[1:]}, "identical": bool(identical),
            "solver_compiles": STATS.compiles, "solver_compile_s": round(STATS.compile_s, 2)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=os.path.join(REPO, "stablelego_jax", "train", "configs", "default.json"))
    ap.add_argument("--steps", type=int, default=12, help="steps to run (at least 2)")
    ap.add_argument("--lam", type=float, default=1000.0, help="weight of the stability term")
    ap.add_argument("--mesh-dir", default=None,
                    help="the config's mesh_dir instead (none: procedural shapes only), e.g. on another machine")
    ap.add_argument("--solves", choices=("each", "batch"), default=None,
                    help="how the batch's stability subsets are solved (default: the config's)")
    ap.add_argument("--jobs", default=None,
                    help="comma-separated subset solves at once (solve_jobs) to compare side by side, e.g. 1,2")
    ap.add_argument("--checkpoint", default=None, help="start from this training checkpoint (with --jobs)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap.parse_args(argv)
    if a.checkpoint and not a.jobs:
        ap.error("--checkpoint needs --jobs")
    if a.steps < 2:
        ap.error("--steps must be at least 2")
    # "" (not None, which load_config ignores as an override): no mesh folder
    over = {} if a.mesh_dir is None else {"mesh_dir": "" if a.mesh_dir == "none" else a.mesh_dir}
    if a.solves is not None:
        over["stability_solves"] = a.solves
    # the config's lam too: lam 0 compiles a graph without the stability term (train.make_fns)
    over["lam"] = a.lam
    cfg = T.load_config(a.config, **over)
    if a.jobs:
        jobs = [int(j) for j in a.jobs.split(",")]
        if a.checkpoint:  # the run's own config, as training resumes it
            cfg = T.load_checkpoint(a.checkpoint)[4]
        res = compare_jobs(cfg, a.steps, a.lam, jobs, a.checkpoint)
        out = dict(config=os.path.relpath(a.config, REPO), checkpoint=a.checkpoint, steps=a.steps, lam=a.lam,
                   date=time.strftime("%Y-%m-%d %H:%M"), **res)
        out["peak_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
        if a.json:
            print(json.dumps(out))
        else:
            print(f"median s per batch {out['median_s']}, ratio {out['ratio']}, identical {out['identical']}")
        return 0
    out = dict(config=os.path.relpath(a.config, REPO), steps=a.steps, lam=a.lam, **measure(cfg, a.steps, a.lam))
    out["peak_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    if a.json:
        print(json.dumps(out))
    else:
        print(f"{out['config']}: first step {out['first_step_s']} s (compile included), "
              f"then {out['step_s']} s a step; peak {out['peak_mb']} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
