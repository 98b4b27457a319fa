"""MPAX (r2HPDHG, batched with vmap) against our batched interior point on
the same Eq. 9 LPs, in one run, with HiGHS as the referee (issue 17).

Usage (on a quiet machine; MPAX is a benchmark-only dependency,
``pip install -e .[bench]``):

    python benchmarks/mpax.py [--dir benchmarks/results/small500] [--per-bucket 16]
        [--eps 1e-4] [--iter-limit 30000] [--out benchmarks/results/mpax.json]

Layouts: the small set of issue 17 (``make_shard.py --recipe small``),
bucketed by bricks (<= 8, 9-16, 17-32, 33-48); ``--per-bucket`` of each,
evenly spaced in file order (0 = all). Per bucket:

* HiGHS (``solve_exact``, one layout at a time): the reference labels.
* ours: ``analyze_many(layouts, "jax")`` on the bucket, twice: the first
  call's compile time (ScoreStats.compile_s, disk cache off), the second
  call's solve time (compiled solvers reused).
* MPAX float64 (inside ``jax.enable_x64``) and float32: the LP of
  ``exact.lp_arrays`` (the arrays HiGHS solves) as ``create_lp`` with BCOO
  matrices, each bucket padded to one shape (rows, columns and non-zeros of
  its largest LP; padding columns fixed at 0, padding rows and entries 0),
  ``jit(vmap(r2HPDHG(eps_abs=eps_rel=eps, iteration_limit=L).optimize))``
  over the whole bucket in one call; compile (lower + compile) timed apart
  from the solve. Converged = termination status OPTIMAL.

Labels from the forces of every solver through the same Eq. 10 verdict
(``make_analysis``): stable = every score < 1; highest score agrees when
within 1e-3 of HiGHS'. Unconverged MPAX answers are scored as returned.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

os.environ.setdefault("STABLELEGO_CACHE", "0")  # cold compiles for both solvers
# this file is named mpax.py: its own folder must not shadow the mpax package
_here = os.path.dirname(os.path.abspath(__file__))
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != _here]
sys.path.insert(0, os.path.join(_here, ".."))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from stablelego_jax.analysis import make_analysis  # noqa: E402
from stablelego_jax.batch import ScoreStats, analyze_many  # noqa: E402
from stablelego_jax.files import atomic_write_text  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402
from stablelego_jax.model import compile_layout  # noqa: E402
from stablelego_jax.solvers.exact import lp_arrays, solve_exact  # noqa: E402

BUCKETS = (8, 16, 32, 48)
OPTIMAL = 2  # mpax.utils.TerminationStatus.OPTIMAL


def pick(items, k):
    if k <= 0 or len(items) <= k:
        return items
    return [items[i] for i in np.linspace(0, len(items) - 1, k).round().astype(int)]


def pack_bucket(lps):
    """Pad the LPs (exact.lp_arrays tuples) of a bucket to one shape: MPAX's
    form ``A x = b, G x >= h, l <= x <= u`` with BCOO (data, indices)."""
    neq = max(lp[1].shape[0] for lp in lps)
    nub = max(lp[3].shape[0] for lp in lps)
    nv = max(len(lp[0]) for lp in lps)
    ze = max(lp[1].nnz for lp in lps)
    zu = max(lp[3].nnz for lp in lps)

    def coo(M, z):
        M = M.tocoo()
        dat, idx = np.zeros(z), np.zeros((z, 2), np.int32)
        dat[:M.nnz], idx[:M.nnz, 0], idx[:M.nnz, 1] = M.data, M.row, M.col
        return dat, idx

    out = []
    for c, A_eq, b_eq, A_ub, b_ub, bounds in lps:
        n = len(c)
        cc, lo, hi = np.zeros(nv), np.zeros(nv), np.zeros(nv)  # padding columns fixed at 0
        cc[:n], lo[:n], hi[:n] = c, bounds[:, 0], bounds[:, 1]
        de, ie = coo(A_eq, ze)
        dg, ig = coo(-A_ub, zu)  # A_ub x <= b_ub  ->  -A_ub x >= -b_ub
        b, h = np.zeros(neq), np.zeros(nub)
        b[:len(b_eq)], h[:len(b_ub)] = b_eq, -b_ub
        out.append((cc, de, ie, b, dg, ig, h, lo, hi))
    arrays = [np.stack(a) for a in zip(*out)]
    return arrays, (neq, nub, nv, ze, zu)


def mpax_solve(arrays, shape, dtype, eps, iter_limit):
    """jit(vmap(r2HPDHG)) over one padded bucket: (x, status, iters, compile_s, solve_s)."""
    from jax.experimental.sparse import BCOO
    from mpax import create_lp, r2HPDHG

    neq, nub, nv, _, _ = shape
    solver = r2HPDHG(eps_abs=eps, eps_rel=eps, iteration_limit=iter_limit, verbose=False)

    def one(c, de, ie, b, dg, ig, h, lo, hi):
        lp = create_lp(c, BCOO((de, ie), shape=(neq, nv)), b, BCOO((dg, ig), shape=(nub, nv)), h, lo, hi)
        r = solver.optimize(lp)
        return r.primal_solution, r.termination_status, r.iteration_count

    args = [jnp.asarray(a.astype(dtype) if a.dtype.kind == "f" else a) for a in arrays]
    t0 = time.perf_counter()
    exe = jax.jit(jax.vmap(one)).lower(*args).compile()
    t1 = time.perf_counter()
    x, st, it = jax.block_until_ready(exe(*args))
    t2 = time.perf_counter()
    return np.asarray(x, np.float64), np.asarray(st), np.asarray(it), t1 - t0, t2 - t1


def verdicts(items, forces):
    """(stable, highest score) of each (layout, model) under forces ((m,) each)."""
    out = []
    for (lay, model), f in zip(items, forces):
        full = np.zeros(model.m_pad)
        full[:model.m] = f[:model.m]
        a = make_analysis(lay, model, full, "x", True, time.perf_counter())
        out.append((a.stable, max(a.scores.values())))
    return out


def agreement(ref, got):
    lab = sum(r[0] == g[0] for r, g in zip(ref, got))
    top = sum(abs(r[1] - g[1]) < 1e-3 for r, g in zip(ref, got))
    return lab, top


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dir", default=os.path.join(os.path.dirname(__file__), "results", "small500"))
    ap.add_argument("--per-bucket", type=int, default=16, help="layouts per bucket (0 = all)")
    ap.add_argument("--eps", type=float, default=1e-4, help="MPAX eps_abs = eps_rel (MPAX default 1e-4)")
    ap.add_argument("--iter-limit", type=int, default=30000, help="MPAX iteration limit")
    ap.add_argument("--max-bricks", type=int, default=48, help="largest bucket to run (8, 16, 32 or 48)")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "mpax.json"))
    a = ap.parse_args()

    files = sorted(f for f in os.listdir(a.dir) if f.endswith((".json", ".txt", ".ldr")))
    loaded = []
    for f in files:
        lay = load_layout(os.path.join(a.dir, f))
        loaded.append((lay, compile_layout(lay)))
    rows = []
    t_run = time.perf_counter()
    lo = 0
    for hi in (b for b in BUCKETS if b <= a.max_bricks):
        items = pick([it for it in loaded if lo < it[1].n <= hi], a.per_bucket)
        lo_b, lo = lo, hi
        if not items:
            continue
        k = len(items)
        row = {"bricks": f"{lo_b + 1}-{hi}", "layouts": k, "in_set": sum(lo_b < it[1].n <= hi for it in loaded)}
        # HiGHS, the reference
        t0 = time.perf_counter()
        ex = [solve_exact(m) for _, m in items]
        row["highs_ms"] = 1e3 * (time.perf_counter() - t0) / k
        ref = verdicts(items, [r.f for r in ex])
        row["stable_highs"] = sum(r[0] for r in ref)
        # ours: first call compiles, second call reuses the compiled solvers
        lays = [lay for lay, _ in items]
        st1, st2 = ScoreStats(), ScoreStats()
        analyze_many(lays, "jax", stats=st1)
        ours = analyze_many(lays, "jax", stats=st2)
        row.update(ours_compile_s=st1.compile_s, ours_compiles=st1.compiles, ours_ms=1e3 * st2.solve_s / k,
                   ours_converged=sum(x.converged for x in ours) / k)
        got = [(x.stable, max(x.scores.values())) for x in ours]
        row["ours_label"], row["ours_top"] = agreement(ref, got)
        # MPAX, float64 and float32, one padded vmap batch per bucket
        arrays, shape = pack_bucket([lp_arrays(m) for _, m in items])
        row["mpax_shape"] = dict(zip(("eq_rows", "ineq_rows", "vars", "nnz_eq", "nnz_ineq"), shape))
        for name, dtype in (("f64", np.float64), ("f32", np.float32)):
            if dtype is np.float64:
                with jax.enable_x64(True):
                    x, stat, its, tc, ts = mpax_solve(arrays, shape, dtype, a.eps, a.iter_limit)
            else:
                x, stat, its, tc, ts = mpax_solve(arrays, shape, dtype, a.eps, a.iter_limit)
            got = verdicts(items, list(x))
            lab, top = agreement(ref, got)
            obj_err = [abs(float(lp_c @ xi[:len(lp_c)]) - r.objective) / max(1.0, abs(r.objective))
                       for lp_c, xi, r in ((lp_arrays(m)[0], xi, r) for (_, m), xi, r in zip(items, x, ex))]
            row.update({f"mpax_{name}_compile_s": tc, f"mpax_{name}_ms": 1e3 * ts / k,
                        f"mpax_{name}_converged": float((stat == OPTIMAL).mean()),
                        f"mpax_{name}_iters_max": int(its.max()), f"mpax_{name}_iters_median": float(np.median(its)),
                        f"mpax_{name}_label": lab, f"mpax_{name}_top": top,
                        f"mpax_{name}_obj_relerr_max": float(max(obj_err))})
        rows.append(row)
        print(json.dumps({kk: (round(v, 4) if isinstance(v, float) else v) for kk, v in row.items()}), flush=True)
    out = {
        "settings": {"per_bucket": a.per_bucket, "eps_abs_rel": a.eps, "iter_limit": a.iter_limit, "max_bricks": a.max_bricks,
                     "mpax_solver": "r2HPDHG", "mpax_batch": "one jit(vmap) call per bucket",
                     "ours": "analyze_many(..., 'jax') defaults (IPMOptions: eps_feas 1e-8, gap 1e-10 abs + 1e-7 rel)",
                     "disk_cache": os.environ.get("STABLELEGO_CACHE")},
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__,
                    "mpax": _version("mpax")},
        "wall_s": time.perf_counter() - t_run,
        "buckets": rows,
    }
    atomic_write_text(a.out, json.dumps(out, indent=1) + "\n")


def _version(pkg):
    from importlib.metadata import version

    return version(pkg)


if __name__ == "__main__":
    main()
