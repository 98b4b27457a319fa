"""One problem with and without ``vmap``: compile and solve time side by side
(issue 17, item 2: why ``batch_solver_fn`` solves one dense problem
unbatched and keeps layered ones batched).

Usage:
  python benchmarks/batch_of_one.py [--inputs DIR] [--n 200] [--shapes 6] [--repeat 7] [--json OUT]

For the first ``--shapes`` buckets of the first ``--n`` layout files of
``--inputs`` (default: ``benchmarks/results/small500``, made by
``benchmarks/make_shard.py``), planned as ``score`` plans them, the first
layout of the bucket is padded to the bucket's shape and its interior point
compiled twice in one process, with the library's compiler options: ``vmap``
over a batch of one, and the solver called on the problem itself. Both are
then run ``--repeat`` times, alternating; printed: compile seconds, best
and median solve milliseconds, iterations, and the largest difference of
their forces (N). One OpenBLAS thread; run nothing else.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ["STABLELEGO_CACHE"] = "0"
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--inputs", default=os.path.join(HERE, "results", "small500"))
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--shapes", type=int, default=6)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--json", help="write the rows here too")
    a = ap.parse_args()
    import jax
    import numpy as np

    from stablelego_jax import batch
    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.runtime import compiler_options
    from stablelego_jax.solvers import ipm
    from stablelego_jax.solvers.problem import Problem, Solution, plan_problem, stack_problems

    jax.config.update("jax_enable_x64", True)
    files = sorted(glob.glob(os.path.join(a.inputs, "*.json")))[: a.n]
    if not files:
        raise SystemExit(f"{a.inputs}: no layout files (make one with benchmarks/make_shard.py)")
    loaded = [(i, lay, compile_layout(lay)) for i, lay in enumerate(map(load_layout, files))]
    first: dict = {}
    for u in batch.solve_units(loaded, 64, 1, True):
        first.setdefault(u.key, u)
    params, opts = Params(), ipm.IPMOptions()

    def batched(*arrays):
        return tuple(jax.vmap(lambda *p: ipm.solve(Problem(*p), params, opts))(*arrays))

    def alone(*arrays):
        return tuple(x[None] for x in ipm.solve(Problem(*(p[0] for p in arrays)), params, opts))

    rows = []
    for key, u in list(first.items())[: a.shapes]:
        it = u.items[0]
        arrays = tuple(x for x in stack_problems([plan_problem(it[2], u.key, u.m_pad, u.p_pad, u.c_pad)[1]])
                       if x is not None)
        exes, comp = {}, {}
        for name, fn in (("vmap", batched), ("alone", alone)):
            t = time.perf_counter()
            exes[name] = jax.jit(fn).lower(*arrays).compile(compiler_options())
            comp[name] = time.perf_counter() - t
        times: dict = {"vmap": [], "alone": []}
        for _ in range(a.repeat):
            for name in times:
                t = time.perf_counter()
                jax.block_until_ready(exes[name](*arrays))
                times[name].append(time.perf_counter() - t)
        sv, sa = Solution(*exes["vmap"](*arrays)), Solution(*exes["alone"](*arrays))
        row = dict(key=list(key), compile_s={k: round(v, 2) for k, v in comp.items()},
                   best_ms={k: round(1e3 * min(v), 1) for k, v in times.items()},
                   median_ms={k: round(1e3 * float(np.median(v)), 1) for k, v in times.items()},
                   iters=[int(sv.iters[0]), int(sa.iters[0])],
                   max_force_diff_n=float(np.abs(np.asarray(sv.f) - np.asarray(sa.f)).max()))
        rows.append(row)
        print(json.dumps(row), flush=True)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(dict(command=" ".join(sys.argv), inputs=a.inputs, rows=rows), fh, indent=1)


if __name__ == "__main__":
    main()
