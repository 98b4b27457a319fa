"""Loss + gradient of large soft problems (issue 18): the layered factorisation
against the dense one.

Usage:
  python benchmarks/loss_scale.py [--mesh MESH] [--grid 20] [--up y]
      [--placements N] [--solver layered|dense] [--calls 1] [--fd 4] [--seed 0] [--json]

The soft problem: the mesh voxelised at ``--grid`` (default: the Stanford
bunny of ``../shared/meshes`` upright, ``--up y``: 20 layers), covered by
the heuristic merge (:func:`stablelego_jax.generate.voxels.merge_voxels`,
all its bricks at weight 1), plus candidate placements of library bricks
inside the shape (:func:`stablelego_jax.train.net.valid_placements`; they
overlap the layout and each other: alternatives) at random weights in
[0.05, 0.5], spread evenly over the layers (a random order within each
layer, then round robin), up to ``--placements`` in all; random extra loads
(0-50 g) on a third of the layout's bricks. Compiled by
:func:`stablelego_jax.soft.compile_placements`, planned by
:func:`stablelego_jax.solvers.problem.plan_soft` for ``--calls`` solves
(``--solver layered``; 1: the ladder's padding, as an unknown caller
gets; the steps of an optimisation can pay for a padding fitted to the
problem, and many calls also each layer factored at its own size: ``cut``
in the JSON, :func:`stablelego_jax.solvers.problem.cut_layers`) or padded
to the ladder and solved dense (``--solver dense``).

Measured: ``compile_s`` (jit of loss + gradient, lowering and compiling),
``loss_grad_s`` (one loss + gradient after compile, best of ``--repeat``),
``peak_mb`` (the process's peak resident memory, compile included),
``fd_max_rel_err``: central differences (step 1e-4, and 1e-5 when 1e-4 is
more than 5% off; the better of the two) on ``--fd`` random candidate
weights, the ``--fd`` candidate weights with the largest gradients, 2
random loads and the load with the largest gradient;
components below 1e-3 of the largest gradient component are compared in
absolute terms; ``pool_threads`` and ``jaxlib``: XLA's CPU pool and the
jaxlib the run had. Prints one JSON object (``--json``) or a line.

Threads: the package keeps XLA's CPU pool at one thread on jaxlib 0.10 to
0.11.1 (:mod:`stablelego_jax.blas`); an unbatched run may use every core
with ``PJRT_NPROC=2`` (this 2-core box), ``--batch`` may not (a clear error).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import jax  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_enable_x64", True)

from stablelego_jax.blas import check_batched_linalg, installed_jaxlib_version, pool_threads  # noqa: E402
from stablelego_jax.generate.mesh import mesh_to_voxels  # noqa: E402
from stablelego_jax.generate.voxels import merge_voxels  # noqa: E402
from stablelego_jax.loss import LossOptions, soft_report  # noqa: E402
from stablelego_jax.soft import compile_placements  # noqa: E402
from stablelego_jax.solvers.problem import (  # noqa: E402
    bucket_shape, layer_bucket, layer_soft, pad_soft, plan_soft, rung, soft_layer_plan, stack_soft)
from stablelego_jax.train.net import MASS, TYPES, valid_placements  # noqa: E402

MESHES = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "meshes")
OPTS = LossOptions()
FLOOR = 1e-4  # losses below: a layout that stands (see batch())


def soft_instance(mesh: str, grid: int, up: str, placements: int, seed: int):
    """(SoftProblem, weights, loads, layout bricks) of the benchmark's soft problem."""
    rng = np.random.default_rng(seed)
    vox = mesh_to_voxels(mesh, grid, up=up)
    lay = merge_voxels(vox)
    nl = lay.n
    if placements < nl:
        raise SystemExit(f"{mesh}: the layout has {nl} bricks, more than --placements {placements}")
    key_lay = {(int(x), int(y), int(z), int(sx), int(sy)) for (x, y, z), (sx, sy) in zip(lay.pos, lay.size)}
    cand = np.argwhere(valid_placements(vox))  # (c, 4): x, y, z, type
    sizes = np.asarray(TYPES)[cand[:, 3]]
    fresh = np.array([(x, y, z, sx, sy) not in key_lay
                      for (x, y, z, _), (sx, sy) in zip(cand.tolist(), sizes.tolist())], bool)
    cand = cand[fresh]
    # evenly over the layers: a random order, then each candidate's rank in its layer
    cand = cand[rng.permutation(len(cand))]
    z = cand[:, 2]
    rank = np.zeros(len(cand), np.int64)
    for lz in np.unique(z):
        sel = np.nonzero(z == lz)[0]
        rank[sel] = np.arange(len(sel))
    take = np.lexsort((rng.random(len(cand)), rank))[: placements - nl]
    cand = cand[take]
    pos = np.concatenate([lay.pos, cand[:, :3]])
    size = np.concatenate([lay.size, np.asarray(TYPES)[cand[:, 3]]])
    mass = np.concatenate([lay.mass, MASS[cand[:, 3]]])
    prob = compile_placements(pos, size, mass)
    w = np.concatenate([np.ones(nl), rng.uniform(0.05, 0.5, len(cand))])
    loads = np.zeros(len(pos))
    hung = rng.choice(nl, size=nl // 3, replace=False)
    loads[hung] = rng.uniform(0.0, 0.05, len(hung))
    return prob, w, loads, nl


def loss_aux(wt, ld, p):
    """(summed brick loss, converged) of one padded soft problem."""
    r = soft_report(wt, ld, p, opts=OPTS)
    return r.brick_loss.sum(), r.converged


def _fd(f, w, loads, idx, which, g, steps=(1e-4, 1e-5)):
    """Central differences at each step until one is within 5% of ``g``."""
    out = []
    for h in steps:
        if out and abs(g - out[-1]) <= 0.05 * abs(out[-1]):
            break
        wp, wm, lp, lm = w.copy(), w.copy(), loads.copy(), loads.copy()
        if which == "w":
            wp[idx] += h
            wm[idx] -= h
        else:
            lp[idx] += h
            lm[idx] -= h
        out.append((float(f(wp, lp)[0][0]) - float(f(wm, lm)[0][0])) / (2 * h))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mesh", default=os.path.join(MESHES, "bunny.ply"))
    ap.add_argument("--grid", type=int, default=20)
    ap.add_argument("--up", default="y")
    ap.add_argument("--placements", type=int, default=1000)
    ap.add_argument("--solver", choices=("layered", "dense"), default="layered")
    ap.add_argument("--fd", type=int, default=4, help="sampled candidate weights for central differences (0: none)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--calls", type=int, default=1,
                    help="plan the layered problem for this many solves (plan_soft: 1 keeps the ladder's padding; "
                         "an optimisation's steps may pay for a fitted one, and for layers cut to their own size)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--batch", type=int, default=0,
                    help="instead: K problems (seeds seed..seed+K-1) of one padded shape, vmap-ed against one at a time")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    if a.batch > 0:
        return batch(a)

    t0 = time.perf_counter()
    prob, w, loads, nl = soft_instance(a.mesh, a.grid, a.up, a.placements, a.seed)
    build_s = time.perf_counter() - t0
    L, B = soft_layer_plan(prob)
    n = prob.mass.shape[0]
    if a.solver == "layered":
        # planned as a caller making --calls solves of it (a fitted padding when that pays for its compile)
        prob = plan_soft(prob, calls=a.calls)
        if prob.layers is None:
            raise SystemExit(f"{a.mesh}: plan_soft does not layer this problem")
    else:
        prob = pad_soft(prob)
    n_pad = prob.mass.shape[0]
    W = np.zeros(n_pad)
    W[:n] = w
    LD = np.zeros(n_pad)
    LD[:n] = loads

    t0 = time.perf_counter()
    vg = jax.jit(jax.value_and_grad(loss_aux, argnums=(0, 1), has_aux=True)).lower(W, LD, prob).compile()
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(max(a.repeat, 1)):
        t0 = time.perf_counter()
        (loss, conv), (gw, gl) = jax.block_until_ready(vg(W, LD, prob))
        times.append(time.perf_counter() - t0)
    gw, gl = np.asarray(gw), np.asarray(gl)

    def f(wt, ld):
        return vg(wt, ld, prob)

    rng = np.random.default_rng(a.seed + 1)
    errs = []
    if a.fd > 0:
        scale = max(np.abs(gw[:n]).max(), np.abs(gl[:n]).max(), 1e-12)
        picks = [("w", int(i)) for i in rng.choice(np.arange(nl, n), size=min(a.fd, n - nl), replace=False)]
        picks += [("l", int(i)) for i in rng.choice(np.nonzero(loads > 0)[0], size=2, replace=False)]
        # random candidates often do not touch the loss (gradient ~0): also
        # the candidates and the load with the largest gradients
        top = nl + np.argsort(-np.abs(gw[nl:n]))
        picks += [("w", int(i)) for i in top if ("w", int(i)) not in picks][: a.fd]
        picks += [("l", int(np.argmax(np.abs(gl[:n]))))]
        for which, i in picks:
            g = gw[i] if which == "w" else gl[i]
            fds = _fd(f, W, LD, i, which, g)
            err = min(abs(g - d) / max(abs(d), 1e-3 * scale) for d in fds)
            errs.append(err)
    out = dict(
        mesh=os.path.basename(a.mesh), grid=a.grid, up=a.up, solver=a.solver, calls=a.calls,
        cut=prob.cut is not None,
        placements=int(n), layout_bricks=int(nl), layers=int(L), max_per_layer=int(B),
        padded=[int(n_pad), int(prob.col_kind.shape[0]), int(prob.group.shape[1])]
        + ([list(map(int, prob.layers.shape))] if prob.layers is not None else []),
        columns=int(np.asarray(prob.col_mask).sum()),
        loss=float(loss), converged=bool(conv),
        loss_grad_s=round(min(times), 3), compile_s=round(compile_s, 2), build_s=round(build_s, 2),
        fd_max_rel_err=(float(max(errs)) if errs else None), fd_checked=len(errs),
        fd_checked_grads=[float(gw[i] if w_ == 'w' else gl[i]) for w_, i in picks] if errs else [],
        fd_errs=[float(e) for e in errs],
        peak_mb=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
        pool_threads=pool_threads(), jaxlib=installed_jaxlib_version(),
    )
    if a.json:
        print(json.dumps(out))
    else:
        print(" ".join(f"{k}={v}" for k, v in out.items()))
    return 0


def batch(a) -> int:
    """``--batch K``: one ``vmap``-ed loss + gradient over K soft problems
    padded to one shape against K calls of the unbatched function (both
    compiled once, timed after compile). Loss agreement: relative on the
    problems whose loss is above ``FLOOR`` (unstable layouts), absolute on
    the rest (a layout that stands has a loss at the barrier's floor, the
    smoothed equilibrium residual at mu, ~1e-7..1e-5, which the stopping
    rule pins only to its tolerance)."""
    try:
        check_batched_linalg(a.batch)  # a clear error, not a hang (stablelego_jax.blas)
    except RuntimeError as exc:
        raise SystemExit(f"error: {exc}") from None
    insts = [soft_instance(a.mesh, a.grid, a.up, a.placements, a.seed + i) for i in range(a.batch)]
    plans = [soft_layer_plan(p) for p, *_ in insts]
    LB = (max(p[0] for p in plans), max(p[1] for p in plans))
    probs = [layer_soft(p, *layer_bucket(*LB)) if a.solver == "layered" else p for p, *_ in insts]
    shape = [max(v) for v in zip(*(bucket_shape(p.mass.shape[0], p.col_kind.shape[0], p.group.shape[1])
                                   for p in probs))]
    c_pad = max((rung(len(p.chunk), 8) for p in probs if p.chunk is not None), default=None)
    probs = [pad_soft(p, *shape, c_pad=c_pad) for p in probs]
    W = np.zeros((a.batch, shape[0]))
    LD = np.zeros((a.batch, shape[0]))
    for i, (p, w, ld, _) in enumerate(insts):
        W[i, : len(w)] = w
        LD[i, : len(ld)] = ld
    stacked = stack_soft(probs)

    vg = jax.value_and_grad(loss_aux, argnums=(0, 1), has_aux=True)
    t0 = time.perf_counter()
    one = jax.jit(vg).lower(W[0], LD[0], probs[0]).compile()
    many = jax.jit(jax.vmap(vg)).lower(W, LD, stacked).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    singles = [jax.block_until_ready(one(W[i], LD[i], probs[i])) for i in range(a.batch)]
    one_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    (lv, conv), (gw, _) = jax.block_until_ready(many(W, LD, stacked))
    many_s = time.perf_counter() - t0
    ref = [float(s_[0][0]) for s_ in singles]
    diff = [abs(float(lv[i]) - ref[i]) for i in range(a.batch)]
    # a layout that stands has a loss at the barrier's floor (the smoothed
    # residual at mu, below ``FLOOR``): compared in absolute terms
    big = [i for i in range(a.batch) if abs(ref[i]) > FLOOR]
    gdiff = [float(np.abs(np.asarray(gw[i]) - np.asarray(singles[i][1][0])).max())
             / max(float(np.abs(np.asarray(singles[i][1][0])).max()), 1e-300) for i in range(a.batch)]
    out = dict(mesh=os.path.basename(a.mesh), solver=a.solver, batch=a.batch, placements=a.placements,
               padded=[int(v) for v in shape] + ([list(map(int, probs[0].layers.shape))] if a.solver == "layered" else []),
               one_at_a_time_s_per_problem=round(one_s / a.batch, 3), vmap_s_per_problem=round(many_s / a.batch, 3),
               speedup=round(one_s / many_s, 2), above_floor=len(big),
               max_loss_rel_diff=max((diff[i] / abs(ref[i]) for i in big), default=None),
               max_grad_rel_diff=max((gdiff[i] for i in big), default=None),
               floor_max_loss_abs_diff=max((diff[i] for i in range(a.batch) if i not in big), default=None),
               floor_max_grad_rel_diff=max((gdiff[i] for i in range(a.batch) if i not in big), default=None),
               converged_vmap=int(np.sum(conv)), converged_single=int(sum(bool(s[0][1]) for s in singles)),
               compile_s=round(compile_s, 2),
               peak_mb=round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1))
    print(json.dumps(out) if a.json else " ".join(f"{k}={v}" for k, v in out.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
