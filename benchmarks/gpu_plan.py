"""The plan ``score`` makes for a folder of layouts on a CPU and on an
accelerator, without one (issue 17: fewer compiled shapes on a GPU).

Usage:
  python benchmarks/gpu_plan.py [--inputs DIR] [--batch 64 1024] [--budget-gb 28]

Each layout is compiled to its force model as ``score`` does, then planned
by :func:`stablelego_jax.batch.solve_units` as on a CPU (``cpu=True``) and
as on an accelerator (``cpu=False``: batches held by ``--budget-gb`` of
device memory, an H200's :func:`~stablelego_jax.batch.device_budget`, and
compiles priced by :func:`~stablelego_jax.batch.accelerator_compile_s`).
Prints, per plan and ``--batch``: solver calls, compiled shapes (bucket x
padded batch size), the buckets, and the padded batches' estimated solve
in a CPU core's seconds (:func:`~stablelego_jax.solvers.problem.plan_seconds`).
A model only: nothing is solved or timed. ``--speedup S --compile-s C``
add a device estimate, ``padded / S + shapes x C`` seconds (session 44's
H200: S = 12.8 on the shard, C = 5.0).
"""
from __future__ import annotations

import argparse
import glob
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, ".."))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", default=os.path.join(HERE, "results", "shard1000"))
    ap.add_argument("--batch", type=int, nargs="+", default=[64, 1024])
    ap.add_argument("--budget-gb", type=float, default=28.0)
    ap.add_argument("--speedup", type=float, default=12.8)
    ap.add_argument("--compile-s", type=float, default=5.0)
    a = ap.parse_args()
    import jax

    jax.config.update("jax_enable_x64", True)
    from stablelego_jax import batch
    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.model import compile_layout
    from stablelego_jax.solvers.problem import batch_rung, plan_seconds

    files = sorted(glob.glob(os.path.join(a.inputs, "*.json")))
    if not files:
        raise SystemExit(f"{a.inputs}: no layout files (make one with benchmarks/make_shard.py)")
    loaded = [(i, None, compile_layout(load_layout(f))) for i, f in enumerate(files)]
    batch.device_budget = lambda: a.budget_gb * 1e9  # the device's, not this machine's
    print(f"{len(files)} layouts of {a.inputs}; accelerator compile and load priced at "
          f"{batch.accelerator_compile_s()[0]:.1f} and {batch.accelerator_compile_s()[1]:.2f} CPU-core s")
    for cpu in (True, False):
        for bsz in a.batch:
            units = batch.solve_units(loaded, bsz, 1, True, cpu=cpu)
            shapes = {(u.shape, batch_rung(len(u.items), 1, u.bsz)) for u in units}
            padded = sum(batch_rung(len(u.items), 1, u.bsz) * plan_seconds(u.key, u.m_pad) for u in units)
            est = "" if cpu else f", device estimate {padded / a.speedup + len(shapes) * a.compile_s:.0f} s"
            print(f"{'cpu' if cpu else 'accelerator'} batch {bsz}: {len(units)} calls, {len(shapes)} shapes, "
                  f"padded solve {padded:.0f} CPU-core s{est}")
            print("   buckets:", " ".join(",".join(map(str, k)) for k in sorted({u.key for u in units})))


if __name__ == "__main__":
    main()
