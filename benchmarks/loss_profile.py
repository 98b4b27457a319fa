"""Where one loss + gradient of a large soft problem spends its time (issue 18): an XLA profile.

    python benchmarks/loss_profile.py [--placements 2000] [--calls 16] [--top 25] [--json FILE]

Builds ``loss_scale.py``'s soft problem (the bunny at grid 20, ``--placements`` in all),
planned for ``--calls`` solves (16: the fitted padding and each layer factored at its own
size, as an optimisation's caller gets), compiles loss + gradient, runs it once untraced
(timed) and once under ``jax.profiler.trace``. Each XLA operation's *self* time (its
duration less the operations nested in it, on the thread it ran on) is summed over the run
and grouped by where it sits in the program, from its HLO ``op_name``:

* ``factor``: inside the block Cholesky's per-layer branches (``cond/branch``: the Schur
  update, the pivot's Cholesky, ``C^-1 E'``);
* ``inner loops``: inside a loop nested in the interior point's (the layer scans of the
  factorisation and of the block solves, and the two directions of an iteration);
* ``iteration``: the interior point's loop body outside those (the assembly of W M);
* ``outside``: before and after the loop (the adjoint's own assembly, the scores).

Prints the run's time, the totals by group and the ``--top`` operations (count, shape,
op_name). Set ``PJRT_NPROC=2`` to profile both cores (``loss_scale.py``'s note on threads).
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import re
import sys
import time

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import loss_scale  # noqa: E402  (sets float64, the threads and the problem)
import jax  # noqa: E402
import numpy as np  # noqa: E402

from stablelego_jax.blas import pool_threads  # noqa: E402
from stablelego_jax.solvers.problem import plan_soft  # noqa: E402
from xla_trace import self_times, traced_events  # noqa: E402


def group(op_name: str) -> str:
    if "cond/branch" in op_name:
        return "factor"
    if "while/body/while/body" in op_name:
        return "inner loops"
    if "while/body" in op_name:
        return "iteration"
    return "outside"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mesh", default=os.path.join(loss_scale.MESHES, "bunny.ply"))
    ap.add_argument("--placements", type=int, default=2000)
    ap.add_argument("--calls", type=int, default=16)
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--json", default=None, help="also write the totals and top operations here")
    a = ap.parse_args(argv)

    prob, w, loads, _ = loss_scale.soft_instance(a.mesh, 20, "y", a.placements, 0)
    n = prob.mass.shape[0]
    prob = plan_soft(prob, calls=a.calls)
    npad = prob.mass.shape[0]
    W, LD = np.zeros(npad), np.zeros(npad)
    W[:n], LD[:n] = w, loads
    vg = jax.jit(jax.value_and_grad(loss_scale.loss_aux, argnums=(0, 1), has_aux=True)).lower(W, LD, prob).compile()
    jax.block_until_ready(vg(W, LD, prob))
    t0 = time.perf_counter()
    jax.block_until_ready(vg(W, LD, prob))
    run_s = time.perf_counter() - t0

    events = traced_events(lambda: jax.block_until_ready(vg(W, LD, prob)))

    hlo = vg.as_text()
    names, shapes = {}, {}
    for line in hlo.splitlines():
        m = re.match(r"\s*(?:ROOT )?%?([\w.\-]+) = (\S+) .*?op_name=\"([^\"]*)\"", line)
        if m:
            names[m.group(1)], shapes[m.group(1)] = m.group(3), m.group(2).split("{")[0]
    times = {k: v for k, v in self_times(events).items() if k in names}
    totals = collections.Counter()
    for k, (us, _) in times.items():
        totals[group(names[k])] += us
    top = sorted(times.items(), key=lambda kv: -kv[1][0])[: a.top]
    print(f"{a.placements} placements, padded {npad} bricks, XLA pool {pool_threads()} thread(s): "
          f"loss + gradient {run_s:.2f} s untraced; operations' self time {sum(totals.values()) / 1e6:.2f} s")
    for g, us in totals.most_common():
        print(f"  {g:12s} {us / 1e6:7.2f} s")
    for k, (us, c) in top:
        print(f"{us / 1e3:9.1f} ms {c:6d}  {shapes[k][:28]:28s} {names[k][-80:]}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(dict(placements=a.placements, calls=a.calls, padded=npad, pool_threads=pool_threads(),
                           loss_grad_s=round(run_s, 3), groups_s={g: round(us / 1e6, 3) for g, us in totals.items()},
                           top=[dict(op=k, ms=round(us / 1e3, 1), count=c, shape=shapes[k], op_name=names[k])
                                for k, (us, c) in top]), fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
