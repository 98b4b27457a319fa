"""One answer per layout, whatever the solver (issue 20, item 1): the
canonical (least-norm) force distribution of the exact and JAX solvers
compared on the same layouts.

Usage: python benchmarks/canonical.py [INPUT ...] [--out benchmarks/results/canonical.jsonl] [--limit N]
    [--no-vertex] [--part K/N]

INPUT: layout files or folders (default: the 500-layout shard of
``benchmarks/make_shard.py`` and every layout of ``examples/``). Per layout:
the exact solver's canonical distribution (the least-norm optimum in two
stages, HiGHS then Clarabel, :func:`stablelego_jax.solvers.exact.least_norm`), the
optimal LP vertices of HiGHS' dual simplex and interior point
(``canonical=False``: what the exact solver returned before the canonical
distribution; ``--no-vertex`` leaves them out, and the LP optimum is then
HiGHS' interior point's alone), and the JAX interior point (Eq. 9 plus the
canonical ridge term, polished to a tight gap). ``--part K/N`` runs every
N-th layout from the K-th (1-based), for two processes side by side, each
with its own ``--out``; a run over the concatenated files prints the
summary. It records the largest per-brick score difference,
whether the weakest brick and the failing set agree, the Eq. 9 cost of the
canonical distributions against the LP optimum, and times. Layouts run smallest file first; resumable: layouts already in the output
file are skipped. The summary
counts the targets: scores within 1e-3 and the same weakest brick on at
least 99% of layouts.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import platform
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import numpy as np  # noqa: E402

from stablelego_jax.analysis import analyze_layout, make_analysis  # noqa: E402
from stablelego_jax.batch import find_layouts, read_results  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402
from stablelego_jax.model import compile_layout  # noqa: E402
from stablelego_jax.solvers.exact import solve_exact  # noqa: E402
from stablelego_jax.solvers.ipm import IPMOptions  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
TOL = 1e-3  # per-brick score agreement of the target
SETTINGS = repr(IPMOptions())


def default_inputs() -> list[str]:
    shard = os.path.join(HERE, "results", "shard500")
    if not os.path.isdir(shard):
        sys.exit(f"{shard}: missing; write it with python benchmarks/make_shard.py --n 500")
    ex = sorted(glob.glob(os.path.join(ROOT, "examples", "stablelego", "*.json"))
                + glob.glob(os.path.join(ROOT, "examples", "brickgpt", "*.txt"))
                + glob.glob(os.path.join(ROOT, "examples", "extensions", "*.json")))
    return sorted(glob.glob(os.path.join(shard, "*.json"))) + ex


def scores_of(a, keys) -> np.ndarray:
    return np.array([a.scores[k] for k in keys])


def compare(a, b, keys) -> dict:
    sa, sb = scores_of(a, keys), scores_of(b, keys)
    return {
        "max_ds": float(np.abs(sa - sb).max()) if len(keys) else 0.0,
        "weakest_same": a.weakest == b.weakest,
        "failing_same": bool(((sa >= 1) == (sb >= 1)).all()),
        "label_same": a.stable == b.stable,
    }


def run_one(path: str, vertex: bool = True) -> dict:
    lay = load_layout(path)
    model = compile_layout(lay)
    keys = lay.keys
    t = time.perf_counter()
    r = solve_exact(model)
    t_exact = time.perf_counter() - t
    ex = make_analysis(lay, model, r.f, "exact", r.success, t, objective=r.objective)
    t = time.perf_counter()
    v = solve_exact(model, method="highs" if vertex else "highs-ipm", canonical=False)
    t_lp = time.perf_counter() - t
    if vertex:
        vx = make_analysis(lay, model, v.f, "exact", v.success, t)
        v2 = solve_exact(model, method="highs-ipm", canonical=False)
        vx2 = make_analysis(lay, model, v2.f, "exact", v2.success, t)
    t = time.perf_counter()
    jx = analyze_layout(lay, solver="jax", fallback=False)
    t_jax = time.perf_counter() - t
    row = {
        "file": os.path.relpath(path, ROOT), "n_bricks": lay.n, "settings": SETTINGS,
        "stable": ex.stable, "exact_canonical": bool(r.canonical), "exact_status": r.status,
        "jax_converged": jx.converged, "jax_iters": jx.iters,
        "weakest_exact": ex.weakest, "max_exact": float(scores_of(ex, keys).max()),
        "jax": compare(ex, jx, keys), "lp_optimum": v.objective, "exact_cost": r.objective, "jax_cost": jx.objective,
        "time_exact_s": t_exact, "time_lp_s": t_lp, "time_jax_s": t_jax,
    }
    if vertex:
        row.update(vertex=compare(ex, vx, keys), vertex_ipm=compare(vx2, vx, keys))
    return row


def pct(k, n):
    return f"{k}/{n} = {100 * k / max(n, 1):.1f}%"


def summarise(rows: list[dict]) -> str:
    n = len(rows)
    out = [f"layouts: {n}, bricks median {int(np.median([r['n_bricks'] for r in rows]))}, "
           f"max {max(r['n_bricks'] for r in rows)}; exact canonical {sum(r['exact_canonical'] for r in rows)}/{n}, "
           f"JAX converged {sum(r['jax_converged'] for r in rows)}/{n}"]
    for name in ("jax", "vertex", "vertex_ipm"):
        sub = [r[name] for r in rows if name in r]
        if not sub:
            continue
        what = {"jax": "JAX vs exact, both canonical",
                "vertex": "HiGHS optimal vertex (dual simplex: the old exact answer) vs exact canonical",
                "vertex_ipm": "HiGHS optimal vertices of two methods (interior point vs dual simplex)"}[name]
        ds = np.array([c["max_ds"] for c in sub])
        out += [
            f"{what}:",
            f"  per-brick scores within {TOL:g}: {pct(int((ds <= TOL).sum()), len(sub))}",
            f"  same weakest brick: {pct(sum(c['weakest_same'] for c in sub), len(sub))}",
            f"  same failing set: {pct(sum(c['failing_same'] for c in sub), len(sub))}; "
            f"same label: {pct(sum(c['label_same'] for c in sub), len(sub))}",
            f"  largest score difference: median {np.median(ds):.1e}, p99 {np.quantile(ds, 0.99):.1e}, max {ds.max():.1e}",
        ]
    for who in ("exact", "jax"):
        rel = np.array([(r[f"{who}_cost"] - r["lp_optimum"]) / max(abs(r["lp_optimum"]), 1e-6) for r in rows])
        out.append(f"{who} canonical: Eq. 9 cost minus the LP optimum, relative (to at least 1e-6): "
                   f"median {np.median(rel):.1e}, min {rel.min():.1e}, max {rel.max():.1e}")
    te, tl = np.array([r["time_exact_s"] for r in rows]), np.array([r["time_lp_s"] for r in rows])
    out.append(f"exact time (canonical, two stages / HiGHS LP alone, same layouts, one run): total {te.sum():.0f} s / {tl.sum():.0f} s, "
               f"median {1e3 * np.median(te):.0f} / {1e3 * np.median(tl):.0f} ms")
    worst = sorted(rows, key=lambda r: -r["jax"]["max_ds"])[:5]
    for r in worst:
        if r["jax"]["max_ds"] > TOL or not r["jax"]["weakest_same"]:
            out.append(f"  {r['file']} n={r['n_bricks']}: max |ds| {r['jax']['max_ds']:.2e}, weakest same "
                       f"{r['jax']['weakest_same']}, JAX converged {r['jax_converged']}")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="*")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "canonical.jsonl"))
    ap.add_argument("--limit", type=int, default=0, help="only the first N inputs")
    ap.add_argument("--no-vertex", action="store_true", help="leave out HiGHS' optimal vertices")
    ap.add_argument("--part", default="1/1", help="K/N: every N-th layout from the K-th")
    args = ap.parse_args()
    paths = find_layouts(args.inputs) if args.inputs else default_inputs()
    paths.sort(key=os.path.getsize)  # small layouts first: an interrupted run has covered most layouts
    if args.limit:
        paths = paths[: args.limit]
    part, n_parts = (int(v) for v in args.part.split("/"))
    paths = paths[part - 1::n_parts]
    done = {k: r for k, r in read_results(args.out, key="file").items() if r.get("settings") == SETTINGS}
    t0 = time.time()
    with open(args.out, "a") as fh:
        for i, p in enumerate(paths):
            key = os.path.relpath(p, ROOT)
            if key in done:
                continue
            r = run_one(p, vertex=not args.no_vertex)
            done[key] = r
            fh.write(json.dumps(r) + "\n")
            fh.flush()
            print(f"\r[{i + 1}/{len(paths)}] {time.time() - t0:.0f}s", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    rows = [done[os.path.relpath(p, ROOT)] for p in paths]
    print(f"machine: {platform.machine()} {os.cpu_count()} cores, python {platform.python_version()}")
    print(summarise(rows))


if __name__ == "__main__":
    main()
