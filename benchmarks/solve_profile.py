"""Where the interior point's iteration goes for one bucket of small layouts,
kernel by kernel (issue 17, item 3: a profile of the verdict solve; ``xla_trace.py``
reads the trace, as for ``loss_profile.py``).

Usage:
  python benchmarks/solve_profile.py [--inputs benchmarks/results/small500] [--key dense,40]
      [--m-pad N] [--units 20] [--top 30] [--json OUT]

The layouts of ``--inputs`` are grouped into solver units as ``score``
groups them (``batch.solve_units``, merged), the first ``--units`` units of
bucket ``--key`` (packs included) are solved once to compile, then again
under JAX's profiler (``jax.profiler.trace``, XLA's CPU thunks); each
kernel's self time (its own, its nested kernels' taken out) is summed over
the traced solves and divided by the interior-point iterations (one LAPACK
Cholesky each). ``--m-pad`` pads the bucket's units to that many columns
instead (their layouts must fit): the price of column padding. Printed:
microseconds an iteration and calls an iteration of the ``--top`` kernels,
the solve's wall time an iteration and the thunk events an iteration. The
profiler adds its own time to each kernel; compare kernels of one run,
not runs. One OpenBLAS thread; run nothing else.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from xla_trace import self_times, traced_events  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--inputs", default=os.path.join(HERE, "results", "small500"))
    ap.add_argument("--key", default="dense,40", help="bucket: dense,N or layered,L,B")
    ap.add_argument("--m-pad", type=int, default=0)
    ap.add_argument("--units", type=int, default=20)
    ap.add_argument("--top", type=int, default=30)
    ap.add_argument("--json")
    args = ap.parse_args()

    from stablelego_jax import batch as B
    from stablelego_jax.formats import rows
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.solvers import ipm

    parts = args.key.split(",")
    key = (parts[0], *map(int, parts[1:]))
    paths = B.find_layouts([args.inputs])
    if not paths:
        raise SystemExit(f"{args.inputs}: no layouts (make them: python benchmarks/make_shard.py --recipe small "
                         f"--n 500 --out benchmarks/results/small500)")
    params, opts = Params(), ipm.IPMOptions()
    loaded = [(i, lay, compile_layout(lay, params))
              for i, lay in enumerate(rows.load_source(p, None, None, None, False, {}) for p in paths)]
    units = [u for u in B.solve_units(loaded, B.default_batch(), 1, True) if u.key == key][: args.units]
    if not units:
        raise SystemExit(f"no unit of bucket {key} in {args.inputs}")
    if args.m_pad:
        if any(it[2].m > args.m_pad for u in units for it in u.items) or any(u.pack for u in units):
            raise SystemExit(f"--m-pad {args.m_pad}: a unit of {key} has more columns (or is a pack)")
        units = [dataclasses.replace(u, m_pad=args.m_pad) for u in units]

    def solve_all():
        st = B.ScoreStats()
        for u in units:
            for _ in B.solve_unit(u, params, opts, 1, True, st):
                pass
        return st

    solve_all()  # compile, or load
    stats = []
    times = self_times(traced_events(lambda: stats.append(solve_all())))
    st = stats[0]
    times = {k: v for k, v in times.items() if not k.startswith("$")}  # Python frames
    iters = sum(c for k, (_, c) in times.items() if k.startswith("cholesky")) or 1
    skip = ("ThunkExecutor::Execute (wait", "np.asarray", "PjitFunction", "CommonPjRt", "Wait for")
    rows_out = sorted(((k, us / iters, c / iters) for k, (us, c) in times.items() if not k.startswith(skip)),
                      key=lambda r: -r[1])
    out = dict(key=list(key), m_pad=units[0].m_pad, units=len(units), layouts=sum(len(u.items) for u in units),
               iterations=iters, solve_ms_per_iteration=1e3 * st.solve_s / iters,
               thunk_events_per_iteration=sum(c for _, c in times.values()) / iters,
               kernels=[dict(name=k, us_per_iteration=round(t, 2), calls_per_iteration=round(c, 2))
                        for k, t, c in rows_out[: args.top]])
    print(f"bucket {key}, {out['m_pad']} columns: {out['layouts']} layouts in {len(units)} units, "
          f"{iters} iterations, {out['solve_ms_per_iteration']:.3f} ms an iteration traced, "
          f"{out['thunk_events_per_iteration']:.0f} thunk events an iteration")
    print("| kernel (self time) | us / iteration | calls / iteration |\n|---|---|---|")
    for k, t, c in rows_out[: args.top]:
        print(f"| {k[:70]} | {t:.1f} | {c:.1f} |")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
