"""The differentiable stability loss (issue 5): implicit gradients vs central
finite differences, and agreement of its zero-temperature verdict with Eq. 10.

Usage: python benchmarks/loss_gradients.py [--n-fd 12] [--n-verdict 60] [--out benchmarks/results/loss_gradients.json]

* Gradients: on the paper's eight structures and on generated layouts
  (``stablelego_jax.generate.procedural.random_family_layout``, at most 60 bricks), each
  with random interior weights (a third of the bricks at weights in [0.3,
  0.9], a smooth point inside (0, 1)) and random extra loads (0-50 g on a
  third of the bricks); d loss / d weight and d loss / d load from the
  custom VJP against central differences on 6 random components each,
  with steps 1e-4 and 1e-5, taking the better of the two (the
  barrier-smoothed LP has kinks about as wide as the barrier, where 1e-4 is
  too coarse, while the loss is computed to ~1e-13, so 1e-5 differences of
  tiny components are rounding noise); components smaller than 1e-3 of the
  largest, or than 1e-8 (stable layouts have an exponentially small loss),
  are compared in absolute terms.
* Verdicts: on the references and generated layouts (at most 60 bricks),
  the Eq. 10 verdict and failing set of the smooth solution (default
  barrier parameter) against HiGHS, and whether the per-brick loss at
  temperature 1e-5 is larger on every failing brick than on every other.

All problems are padded to one shape, so each function compiles once.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import jax  # noqa: E402
import numpy as np  # noqa: E402

# this script jits and differentiates the loss itself, on float64 inputs (the
# library is float64 inside whatever the caller's setting; its inputs are not)
jax.config.update("jax_enable_x64", True)

from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.files import atomic_write_text  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402
from stablelego_jax.generate.procedural import random_family_layout  # noqa: E402
from stablelego_jax.loss import LossOptions, soft_report, stability_loss  # noqa: E402
from stablelego_jax.soft import soft_problem  # noqa: E402
from stablelego_jax.solvers.problem import pad_soft  # noqa: E402

SHAPE = (64, 2048, 32)
FLOOR = 1e-8  # gradient components below this (loss in units of T) are FD rounding noise
STEPS = (1e-4, 1e-5)
OPTS = LossOptions()
REF = os.path.join(os.path.dirname(__file__), "..", "examples", "stablelego")


def _loss(w, loads, prob):
    return stability_loss(w, loads, prob, opts=OPTS)


LOSS = jax.jit(_loss)
GRAD = jax.jit(jax.grad(_loss, argnums=(0, 1)))
REPORT = jax.jit(lambda w, loads, prob, tau: soft_report(w, loads, prob, tau, opts=OPTS))


def central_difference(loss, w, loads, prob, what: str, i: int, h: float) -> float:
    """``(loss(x + h e_i) - loss(x - h e_i)) / 2 h`` for component ``i`` of
    the weights (``what="weights"``) or of the loads."""
    x = w if what == "weights" else loads
    xp, xm = x.copy(), x.copy()
    xp[i] += h
    xm[i] -= h
    args_p = (xp, loads) if what == "weights" else (w, xp)
    args_m = (xm, loads) if what == "weights" else (w, xm)
    return (float(loss(*args_p, prob)) - float(loss(*args_m, prob))) / (2 * h)


def fits(lay) -> bool:
    p = soft_problem(lay)
    return lay.n <= SHAPE[0] and p.col_kind.shape[0] <= SHAPE[1] and p.group.shape[1] <= SHAPE[2]


def random_point(n: int, rng):
    """Where a case's loss and gradient are taken: existence weights (SHAPE[0],)
    with the n real bricks present and a third of them drawn in [0.3, 0.9],
    and loads (SHAPE[0],) kg on another third drawn in [0, 0.05]; and the
    indices of the drawn weights (the weight components compared)."""
    w = np.zeros(SHAPE[0])
    w[:n] = 1.0
    soft_idx = rng.choice(n, size=max(1, n // 3), replace=False)
    w[soft_idx] = rng.uniform(0.3, 0.9, size=len(soft_idx))
    loads = np.zeros(SHAPE[0])
    li = rng.choice(n, size=max(1, n // 3), replace=False)
    loads[li] = rng.uniform(0.0, 0.05, size=len(li))
    return w, loads, soft_idx


def fd_case(name, lay, rng):
    prob = pad_soft(soft_problem(lay), *SHAPE)
    n = lay.n
    w, loads, soft_idx = random_point(n, rng)
    gw, gl = (np.asarray(v) for v in GRAD(w, loads, prob))
    out = {"name": name, "n_bricks": n}
    for what, g, pool in (("weights", gw, soft_idx), ("loads", gl, np.arange(n))):
        idx = rng.choice(pool, size=min(6, len(pool)), replace=False)

        fds = np.array([[central_difference(LOSS, w, loads, prob, what, i, h) for i in idx]
                        for h in STEPS])  # (steps, components)
        gi = g[idx]
        scale = max(np.abs(fds).max(), 1e-300)
        big = np.abs(fds[0]) > max(1e-3 * scale, FLOOR)
        rel = np.abs(gi[None, :] - fds) / np.maximum(np.abs(fds), 1e-300)
        best = rel.min(axis=0)  # against the better of the two steps (truncation vs rounding)
        out[what] = {"components": int(len(idx)), "compared_relative": int(big.sum()),
                     "max_rel_err": float(best[big].max()) if big.any() else None,
                     "max_rel_err_step_1e-4": float(rel[0][big].max()) if big.any() else None,
                     "max_abs_err_small": float(np.abs(gi - fds[0])[~big].max()) if (~big).any() else None,
                     "scale": float(scale)}
    return out


def verdict_case(name, lay):
    prob = pad_soft(soft_problem(lay), *SHAPE)
    w = np.zeros(SHAPE[0])
    w[: lay.n] = 1.0
    r = REPORT(w, np.zeros(SHAPE[0]), prob, 1e-5)
    ex = analyze_layout(lay, solver="exact")
    failing = np.array([ex.scores[k] >= 1.0 for k in lay.keys])
    s = np.asarray(r.scores)[: lay.n]
    lb = np.asarray(r.brick_loss)[: lay.n]
    drag = np.asarray(r.max_drag)[: lay.n]
    exd = np.array([ex.max_drag[k] for k in lay.keys])
    return {"name": name, "n_bricks": lay.n, "converged": bool(r.converged), "exact_stable": bool(ex.stable),
            "soft_stable": bool((s < 1).all()), "failing_set_equal": bool(((s >= 1) == failing).all()),
            "min_loss_failing": float(lb[failing].min()) if failing.any() else None,
            "max_loss_other": float(lb[~failing].max()) if (~failing).any() else None,
            "max_drag_err_N": float(np.abs(drag - exd).max())}


def _separated(r) -> bool:
    """The per-brick loss at temperature 1e-5 is larger on every failing brick
    than on every other brick (the zero-temperature verdict read off the loss)."""
    if r["min_loss_failing"] is None or r["max_loss_other"] is None:
        return True
    return r["min_loss_failing"] > r["max_loss_other"]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-fd", type=int, default=12, help="generated layouts for the gradient check")
    ap.add_argument("--n-verdict", type=int, default=60, help="generated layouts for the verdict check")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "loss_gradients.json"))
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    t0 = time.time()
    refs = [(f, load_layout(os.path.join(REF, f))) for f in sorted(os.listdir(REF)) if f.endswith(".json")]
    gen, seed = [], 0
    while len(gen) < max(args.n_fd, args.n_verdict):
        fam, lay = random_family_layout(seed)
        seed += 1
        if lay.n <= 60 and fits(lay):
            gen.append((f"{fam}/{seed - 1}", lay))
    fd = [fd_case(name, lay, rng) for name, lay in refs + gen[: args.n_fd]]
    for r in fd:
        print("fd", r["name"], r["weights"]["max_rel_err"], r["loads"]["max_rel_err"], flush=True)
    ver = [verdict_case(name, lay) for name, lay in refs + gen[: args.n_verdict]]
    for r in ver:
        if not (r["converged"] and r["failing_set_equal"] and _separated(r)):
            print("verdict", r, flush=True)
    rel = [v for r in fd for k in ("weights", "loads") if (v := r[k]["max_rel_err"]) is not None]
    summary = {
        "fd_layouts": len(fd), "fd_components": sum(r[k]["components"] for r in fd for k in ("weights", "loads")),
        "fd_compared_relative": sum(r[k]["compared_relative"] for r in fd for k in ("weights", "loads")),
        "fd_max_rel_err": max(rel), "fd_median_of_max_rel_err": float(np.median(rel)),
        "fd_layouts_under_5pct": sum(all((r[k]["max_rel_err"] or 0) < 0.05 for k in ("weights", "loads")) for r in fd),
        "fd_max_rel_err_step_1e-4": max(v for r in fd for k in ("weights", "loads")
                                        if (v := r[k]["max_rel_err_step_1e-4"]) is not None),
        "verdict_layouts": len(ver), "converged": sum(r["converged"] for r in ver),
        "stable_verdict_agrees": sum(r["soft_stable"] == r["exact_stable"] for r in ver),
        "failing_set_agrees": sum(r["failing_set_equal"] for r in ver),
        "loss_separates_failing": sum(_separated(r) for r in ver),
        "min_loss_failing": min(r["min_loss_failing"] for r in ver if r["min_loss_failing"] is not None),
        "max_loss_other": max(r["max_loss_other"] for r in ver if r["max_loss_other"] is not None),
        "median_max_drag_err_N": float(np.median([r["max_drag_err_N"] for r in ver])),
        "time_s": round(time.time() - t0, 1),
    }
    atomic_write_text(args.out, json.dumps({"summary": summary, "fd": fd, "verdict": ver}, indent=1) + "\n")
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
