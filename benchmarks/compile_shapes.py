"""Lower and compile time of the batched interior point per shape, and the
host-side planning of a run (issue 17: the compile tax).

Usage:
  python benchmarks/compile_shapes.py [--inputs benchmarks/results/shard1000] [--n 400] [--json OUT]

The first ``--n`` layout files of ``--inputs`` are read, their force
models compiled and planned as ``score`` plans them
(:func:`stablelego_jax.batch.solve_units`: buckets, merges, batch
pieces); the times of those steps are printed (read, force models,
planning: the parent's work before any solve). Then for two dense and two
layered buckets of the plan, the batched solver of its first piece is
lowered and compiled with every cache off (``STABLELEGO_CACHE=0``, no
persistent XLA cache), run once, and timed on a second run; the compiled
program's kernels are counted (``fusions``: XLA's compile time grows with
them). The library's XLA options
(:func:`stablelego_jax.runtime.compiler_options`) apply unless
``--xla-defaults``. One OpenBLAS
thread. XLA flags (``XLA_FLAGS``, e.g.
``--xla_backend_optimization_level=0``) apply as set in the environment.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import time

os.environ["STABLELEGO_CACHE"] = "0"
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--inputs", default=os.path.join(HERE, "results", "shard1000"))
    ap.add_argument("--n", type=int, default=400)
    ap.add_argument("--json", help="write the results here too")
    ap.add_argument("--xla-defaults", action="store_true", help="compile with XLA's default options")
    a = ap.parse_args()
    if a.xla_defaults:
        os.environ["STABLELEGO_XLA_DEFAULTS"] = "1"
    t0 = time.perf_counter()
    import jax
    import numpy as np

    from stablelego_jax import batch
    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.runtime import compiler_options
    from stablelego_jax.solvers import ipm
    from stablelego_jax.solvers.problem import Solution, batch_rung, plan_problem, stack_problems

    jax.config.update("jax_enable_x64", True)
    t1 = time.perf_counter()
    files = sorted(glob.glob(os.path.join(a.inputs, "*.json")))[: a.n]
    if not files:
        raise SystemExit(f"{a.inputs}: no layout files (make one with benchmarks/make_shard.py)")
    lays = [load_layout(f) for f in files]
    t2 = time.perf_counter()
    loaded = [(i, lay, compile_layout(lay)) for i, lay in enumerate(lays)]
    t3 = time.perf_counter()
    units = batch.solve_units(loaded, 64, 1, True)
    t4 = time.perf_counter()
    out = dict(files=len(files), imports_s=round(t1 - t0, 2), read_s=round(t2 - t1, 2),
               force_models_s=round(t3 - t2, 2), plan_s=round(t4 - t3, 2), units=len(units),
               xla_flags=os.environ.get("XLA_FLAGS", ""), compiler_options=compiler_options(), shapes={})
    print(json.dumps({k: v for k, v in out.items() if k != "shapes"}), flush=True)
    first: dict = {}
    for u in units:
        first.setdefault(u.key, u)
    picks = [k for k in first if k[0] == "dense"][:2] + [k for k in first if k[0] == "layered"][:2]
    fn = batch.batch_solver_fn(Params(), ipm.IPMOptions(), 1)
    for k in picks:
        u = first[k]
        probs = [plan_problem(it[2], u.key, u.m_pad, u.p_pad, u.c_pad)[1] for it in u.items]
        size = batch_rung(len(probs), 1, u.bsz)
        probs = probs + [probs[-1]] * (size - len(probs))
        arrays = tuple(x for x in stack_problems(probs) if x is not None)
        s0 = time.perf_counter()
        lowered = jax.jit(fn).lower(*arrays)
        s1 = time.perf_counter()
        exe = lowered.compile(compiler_options())
        s2 = time.perf_counter()
        jax.block_until_ready(exe(*arrays))
        s3 = time.perf_counter()
        sol = Solution(*jax.block_until_ready(exe(*arrays)))
        s4 = time.perf_counter()
        hlo = exe.as_text()
        row = dict(batch=size, lower_s=round(s1 - s0, 2), compile_s=round(s2 - s1, 2), solve_s=round(s4 - s3, 3),
                   iters=int(np.max(sol.iters)), fusions=hlo.count(" fusion("),
                   hlo_lines=hlo.count("\n"))
        out["shapes"][str(k)] = row
        print(k, json.dumps(row), flush=True)
        jax.clear_caches()
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
