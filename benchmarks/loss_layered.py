"""Fidelity of the layered factorisation of the soft interior point (issue 18)
against the dense one, on the layouts of ``benchmarks/loss_gradients.py``.

Usage: python benchmarks/loss_layered.py [--n-fd 12] [--n-verdict 60]
       [--out benchmarks/results/loss_layered.json]

* Verdict layouts (the paper's 8 structures + ``--n-verdict`` generated,
  at most 60 bricks): loss at the default temperature and at 1e-5,
  per-brick scores and the Eq. 10 verdict and failing set from the
  layered solve against the dense solve of the same padded problem, and
  the layered failing set against HiGHS.
* Gradient layouts (8 + ``--n-fd``), the random interior weights and loads
  of ``loss_gradients.py`` (same seed): gradients of both factorisations
  (largest absolute difference), and the layered gradient against central
  differences (steps 1e-4 and 1e-5, the better; components below 1e-3 of
  the largest or below 1e-8 compared in absolute terms), 6 components of
  weights and 6 of loads per layout; ``fd_tight_*``: the same differences
  of the loss solved to a centring 100x tighter (``TIGHT``: every s z / w
  within a factor 1e-4 of mu, up to 100 iterations), whose stopping noise
  is far below a difference's (a layout that stands has a loss at the
  barrier's floor, ~1e-7, which the default stopping rule pins only to its
  tolerance); the gradient under test is the default one either way.

``--dump FILE.npz``: also write every loss, score and gradient (dense and
layered) to FILE; ``--compare OLD.npz NEW.npz``: the largest differences
between two such files (two versions of the code, run one after the other
from their checkouts): losses (relative), scores and gradients (absolute),
labels.

``--control``: only the dense solver against itself with the bricks
numbered in reverse, on the 8 structures (how far rounding alone moves the
loss and gradient), written next to ``--out`` as ``*_control.json``.

``--tight``: every solve (dense and layered, the control's too) to the
tight centring ``TIGHT`` instead of the default stopping rule, to separate
what the two factorisations compute from where the default rule stops;
the central differences are left out (``fd_*`` null). ``--centred C``:
the same with the centring C (up to 100 iterations).

The summary counts the losses within 1e-8 relative (the issue's target),
and within 1e-8 relative or 1e-14 absolute: a layout that stands has a
loss of 1e-9..1e-7 (the barrier's floor, a sum of equilibrium residuals
of forces of order 1), which float64 holds only to ~1e-16 absolute.

Every problem is padded to one shape; layered, to the ladder rung of its
own (layers, bricks per layer) (one compile per rung: a common rung for
all would make the small ones pay for the largest).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))

import loss_gradients as lg  # noqa: E402  (sets up jax, x64, paths)
import jax  # noqa: E402
import numpy as np  # noqa: E402

from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.files import atomic_write_text  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402
from stablelego_jax.generate.procedural import random_family_layout  # noqa: E402
from stablelego_jax.loss import soft_report, stability_loss  # noqa: E402
from stablelego_jax.soft import soft_problem  # noqa: E402
from stablelego_jax.solvers.compiled import map_budget, mappings  # noqa: E402
from stablelego_jax.solvers.problem import layer_bucket, layer_soft, pad_soft, soft_layer_plan  # noqa: E402

SHAPE = lg.SHAPE
OPTS = lg.OPTS
#: the loss solved to a 100x tighter centring, for the reference differences (``fd_tight_*``)
TIGHT = dataclasses.replace(OPTS, centred=OPTS.centred / 100, iters=100)
LOSS_TIGHT = jax.jit(lambda w, loads, prob: stability_loss(w, loads, prob, opts=TIGHT))


def use(opts) -> None:
    """Solve the comparisons (``REPORT``, ``VG``) with ``opts``."""
    global REPORT, VG
    REPORT = jax.jit(lambda w, loads, prob, tau: soft_report(w, loads, prob, tau, opts=opts))
    VG = jax.jit(jax.value_and_grad(lambda w, loads, prob: stability_loss(w, loads, prob, opts=opts), argnums=(0, 1)))


use(OPTS)


DUMP = {}  # --dump: name|what -> array


def LOSS(w, loads, prob):
    return VG(w, loads, prob)[0]


def GRAD(w, loads, prob):
    return VG(w, loads, prob)[1]


def problems(lay):
    """(dense, layered) padded problems of ``lay``; layered on the ladder
    rung of its own (layers, bricks per layer)."""
    p = soft_problem(lay)
    return pad_soft(p, *SHAPE), pad_soft(layer_soft(p), *SHAPE)


def verdict_case(name, lay):
    dense, layered = problems(lay)
    w = np.zeros(SHAPE[0])
    w[: lay.n] = 1.0
    z = np.zeros(SHAPE[0])
    out = {"name": name, "n_bricks": lay.n, "maps": mappings()}
    for tau in (OPTS.temperature, 1e-5):
        rd, rl = REPORT(w, z, dense, tau), REPORT(w, z, layered, tau)
        ld, ll = float(np.sum(rd.brick_loss)), float(np.sum(rl.brick_loss))
        out[f"loss_rel_diff_tau{tau:g}"] = abs(ll - ld) / max(abs(ld), 1e-300)
        out[f"loss_abs_diff_tau{tau:g}"] = abs(ll - ld)
        DUMP[f"{name}|loss_tau{tau:g}"] = np.array([ld, ll])
    sd, sl = np.asarray(rd.scores)[: lay.n], np.asarray(rl.scores)[: lay.n]
    DUMP[f"{name}|scores"] = np.stack([sd, sl])
    ex = analyze_layout(lay, solver="exact")
    failing = np.array([ex.scores[k] >= 1.0 for k in lay.keys])
    out.update(converged=bool(rl.converged), max_score_diff=float(np.abs(sd - sl).max()),
               verdict_same=bool((sd < 1).all() == (sl < 1).all()),
               failing_same_as_dense=bool(((sd >= 1) == (sl >= 1)).all()),
               failing_same_as_exact=bool(((sl >= 1) == failing).all()))
    bound_maps()
    return out


def bound_maps() -> None:
    """Let go of JAX's compiled executables once the process holds more
    memory mappings than the library's own executable cache allows
    (:func:`~stablelego_jax.solvers.compiled.map_budget`: half of
    ``vm.max_map_count``): each compiled loss keeps about 1000, and a full
    run with the tight differences passed the limit (LLVM "Cannot allocate
    memory", no summary; session 46). Executables needed again are
    compiled again."""
    budget = map_budget()
    if budget is not None and (mappings() or 0) > budget:
        jax.clear_caches()


def fd_case(name, lay, rng, differences=True):
    dense, layered = problems(lay)
    n = lay.n
    w, loads, soft_idx = lg.random_point(n, rng)
    gd = [np.asarray(v) for v in GRAD(w, loads, dense)]
    gl_ = [np.asarray(v) for v in GRAD(w, loads, layered)]
    ld, ll = float(LOSS(w, loads, dense)), float(LOSS(w, loads, layered))
    DUMP[f"{name}|fd_loss"] = np.array([ld, ll])
    DUMP[f"{name}|fd_grad"] = np.stack([np.concatenate(gd), np.concatenate(gl_)])
    out = {"name": name, "n_bricks": n, "maps": mappings(), "loss_rel_diff": abs(ll - ld) / max(abs(ld), 1e-300),
           "loss_abs_diff": abs(ll - ld),
           "grad_max_abs_diff": float(max(np.abs(a - b).max() for a, b in zip(gd, gl_)))}
    worst = dict.fromkeys(("fd_max_rel_err", "fd_tight_max_rel_err"), 0.0 if differences else None)
    for what, g, pool in (("weights", gl_[0], soft_idx), ("loads", gl_[1], np.arange(n))):
        idx = rng.choice(pool, size=min(6, len(pool)), replace=False)  # drawn either way: the same draws after
        if not differences:
            continue
        for field, loss in (("fd_max_rel_err", LOSS), ("fd_tight_max_rel_err", LOSS_TIGHT)):
            fds = np.array([[lg.central_difference(loss, w, loads, layered, what, i, h) for i in idx]
                            for h in lg.STEPS])
            gi = g[idx]
            scale = max(np.abs(fds).max(), 1e-300)
            big = np.abs(fds[0]) > max(1e-3 * scale, lg.FLOOR)
            rel = (np.abs(gi[None, :] - fds) / np.maximum(np.abs(fds), 1e-300)).min(axis=0)
            if big.any():
                worst[field] = max(worst[field], float(rel[big].max()))
    out.update(worst)
    bound_maps()
    return out


def control_case(name, lay):
    """The dense solver against itself with the bricks numbered in reverse:
    how far rounding alone moves the loss and its gradient."""
    from stablelego_jax.layout import make_layout

    n = lay.n
    perm = np.arange(n)[::-1]
    rev = make_layout([lay.keys[i] for i in perm], lay.pos[perm], lay.size[perm], lay.mass[perm])
    w = np.zeros(SHAPE[0])
    w[:n] = 1.0
    z = np.zeros(SHAPE[0])
    a = VG(w, z, pad_soft(soft_problem(lay), *SHAPE))
    b = VG(w, z, pad_soft(soft_problem(rev), *SHAPE))
    ga, gb = np.asarray(a[1][0])[:n], np.asarray(b[1][0])[:n][np.argsort(perm)]
    return {"name": name, "loss_rel_diff": abs(float(a[0]) - float(b[0])) / max(abs(float(a[0])), 1e-300),
            "grad_max_abs_diff": float(np.abs(ga - gb).max()), "grad_scale": float(np.abs(ga).max())}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-fd", type=int, default=12)
    ap.add_argument("--n-verdict", type=int, default=60)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "loss_layered.json"))
    ap.add_argument("--control", action="store_true",
                    help="only the control: dense vs dense with reversed brick numbering on the 8 structures")
    ap.add_argument("--tight", action="store_true",
                    help="solve everything to the tight centring (TIGHT); no central differences")
    ap.add_argument("--centred", type=float, default=None,
                    help="solve everything to this centring (up to 100 iterations); no central differences")
    ap.add_argument("--dump", default=None, help="also write every loss, score and gradient to this .npz")
    ap.add_argument("--compare", nargs=2, default=None, metavar=("OLD", "NEW"),
                    help="compare two --dump files and exit")
    a = ap.parse_args()
    if a.compare:
        return compare(*a.compare)
    t0 = time.time()
    opts = TIGHT if a.tight else OPTS
    if a.centred is not None:
        opts = dataclasses.replace(OPTS, centred=a.centred, iters=100)
    differences = opts is OPTS  # central differences at the default stopping only
    if not differences:
        use(opts)
    if a.control:
        rows = [control_case(f, load_layout(os.path.join(lg.REF, f))) for f in sorted(os.listdir(lg.REF))
                if f.endswith(".json")]
        text = json.dumps(rows, indent=1)
        print(text)
        atomic_write_text(os.path.splitext(a.out)[0] + "_control.json", text + "\n")
        return
    refs = [(f, load_layout(os.path.join(lg.REF, f))) for f in sorted(os.listdir(lg.REF)) if f.endswith(".json")]
    gen, seed = [], 0
    while len(gen) < max(a.n_fd, a.n_verdict):
        fam, lay = random_family_layout(seed)
        seed += 1
        if lay.n <= 60 and lg.fits(lay):
            gen.append((f"{fam}/{seed - 1}", lay))
    rng = np.random.default_rng(0)  # the draws of loss_gradients.py
    fd = [fd_case(name, lay, rng, differences=differences) for name, lay in refs + gen[: a.n_fd]]
    ver = [verdict_case(name, lay) for name, lay in refs + gen[: a.n_verdict]]
    shapes = {layer_bucket(*soft_layer_plan(soft_problem(lay))) for _, lay in refs + gen}
    summary = {
        "shape": list(SHAPE), "layered_shapes": len(shapes),
        "verdict_layouts": len(ver), "converged": sum(r["converged"] for r in ver),
        "max_loss_rel_diff": max(max(r[k] for k in r if k.startswith("loss_rel_diff")) for r in ver + fd),
        "max_score_diff": max(r["max_score_diff"] for r in ver),
        "verdict_same": sum(r["verdict_same"] for r in ver),
        "failing_same_as_dense": sum(r["failing_same_as_dense"] for r in ver),
        "failing_same_as_exact": sum(r["failing_same_as_exact"] for r in ver),
        "fd_layouts": len(fd), "grad_max_abs_diff": max(r["grad_max_abs_diff"] for r in fd),
        "opts": repr(opts), "time_s": round(time.time() - t0, 1),
    }
    losses = [(r[k], r[k.replace("rel", "abs")]) for r in ver + fd for k in r if k.startswith("loss_rel_diff")]
    summary.update(losses=len(losses), losses_within_1e8_rel=sum(rel <= 1e-8 for rel, _ in losses),
                   losses_within_1e8_rel_or_1e14_abs=sum(rel <= 1e-8 or ab <= 1e-14 for rel, ab in losses),
                   grads_within_1e6=sum(r["grad_max_abs_diff"] <= 1e-6 for r in fd))
    if differences:
        for k in ("fd_max_rel_err", "fd_tight_max_rel_err"):
            summary[k] = max(r[k] for r in fd)
            summary[k.replace("max_rel_err", "layouts_under_5pct")] = sum(r[k] < 0.05 for r in fd)
    atomic_write_text(a.out, json.dumps({"summary": summary, "fd": fd, "verdict": ver}, indent=1) + "\n")
    if a.dump:
        np.savez(a.dump, **DUMP)
    print(json.dumps(summary, indent=1))


def compare(old: str, new: str) -> None:
    """Largest differences between two ``--dump`` files (dense and layered
    solves alike)."""
    A, B = np.load(old), np.load(new)
    keys = sorted(set(A.files) & set(B.files))
    loss = [k for k in keys if "loss" in k]
    rel = {k: float(np.max(np.abs(A[k] - B[k]) / np.maximum(np.abs(A[k]), 1e-300))) for k in loss}
    big = {k: v for k, v in rel.items() if v > 1e-8}
    scores = [k for k in keys if k.endswith("|scores")]
    grads = [k for k in keys if k.endswith("|fd_grad")]
    out = {
        "keys": len(keys), "only_in_one": len(set(A.files) ^ set(B.files)),
        "loss_max_rel_diff": max(rel.values()),
        "losses_over_1e-8_rel": {k: [float(A[k][0]), float(B[k][0]), v] for k, v in sorted(big.items())},
        "score_max_abs_diff": max(float(np.abs(A[k] - B[k]).max()) for k in scores),
        "labels_changed": sum(int(((A[k] >= 1) != (B[k] >= 1)).any()) for k in scores),
        "verdicts_changed": sum(int(((A[k] < 1).all(axis=1) != (B[k] < 1).all(axis=1)).any()) for k in scores),
        "grad_max_abs_diff": max(float(np.abs(A[k] - B[k]).max()) for k in grads),
        "grad_scale": max(float(np.abs(A[k]).max()) for k in grads),
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
