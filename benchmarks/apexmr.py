"""Build sequences of the 8 APEX-MR tasks with step files: do their steps stand,
which steps need a support under the robot's press, and how fast is scoring
every prefix in one batched call?

    python benchmarks/apexmr.py --apex PATH/TO/APEX-MR [--out benchmarks/results/apexmr.json]

PATH/TO/APEX-MR is a checkout of https://github.com/intelligent-control-lab/APEX-MR
(not part of this repository). For each task (``config/lego_tasks/steps/<task>_seq.json``,
pillars from its ``env_setup``):

1. every prefix of its own order, without press: HiGHS one prefix at a time
   (the referee) and the JAX interior point on all prefixes in one batched
   call (``analyze_many``; cold = with compiles, warm = compiled solvers reused);
2. with a press of N newtons at APEX-MR's press spot (a 1x2 load block, its own
   press model; its tool is a 2.2 kg block = 21.56 N) for N in a sweep, HiGHS
   on the pressed prefixes: a step is flagged when it stands unpressed and
   falls pressed; flags against the steps where APEX-MR used a supporting arm
   (steps pressed from below are not modelled and left out). Forces are
   tried from the largest down and a step that stands under one is taken to
   stand under every smaller one: the loads a layout can carry (zero
   residual, every drag below T) form a convex set holding the unpressed
   load, so standing at 0 and at N means standing in between;
3. at 21.56 N, the support pillars our search finds (JAX, batched) against
   APEX-MR's support cell.
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

from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.batch import ScoreStats, analyze_many  # noqa: E402
from stablelego_jax.blas import one_blas_thread  # noqa: E402
from stablelego_jax.files import atomic_write_text  # noqa: E402
from stablelego_jax.formats.apexmr import read_apex_seq  # noqa: E402
from stablelego_jax.sequence import BuildOrder, analyze_sequence, prefix_layouts, press_layout  # noqa: E402

TASKS = ["cliff", "faucet", "stairs_rotated", "guitar", "fish_high", "vessel", "bridge", "big_chair"]
FORCES = [1.0, 2.0, 5.0, 10.0, 21.56, 40.0]


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def order_of(task) -> BuildOrder:
    return BuildOrder(keys=task.order, fixed=task.fixed, press_at=task.press, no_press=task.press_from_below,
                      support_ref=task.support, name="apex-mr")


def run_task(path: str) -> dict:
    task = read_apex_seq(path)
    order = order_of(task)
    prefixes = prefix_layouts(task.layout, order)
    n = len(prefixes)
    # 1. unpressed: HiGHS one at a time, JAX batched (cold and warm)
    t0 = time.perf_counter()
    exact = [analyze_layout(p, solver="exact") for p in prefixes]
    t_exact = time.perf_counter() - t0
    _log(f"  {n} prefixes, HiGHS one by one {t_exact:.1f} s")
    timings = []
    for _ in range(2):
        st = ScoreStats()
        t0 = time.perf_counter()
        with one_blas_thread():
            jx = analyze_many(prefixes, "jax", stats=st)
        timings.append((time.perf_counter() - t0, st.compile_s, st.compiles))
        _log(f"  JAX batched {timings[-1][0]:.1f} s ({st.compiles} compiles, {st.compile_s:.1f} s)")
    agree = sum(a.stable == b.stable and a.weakest == b.weakest for a, b in zip(exact, jx))
    labels = sum(a.stable == b.stable for a, b in zip(exact, jx))
    # 2. pressed prefixes, HiGHS, per force
    modelled = [k for k in order.keys if k not in order.no_press]
    ref = {k for k in modelled if k in task.support}
    falls_at = {N: set() for N in FORCES}
    t0 = time.perf_counter()
    n_pressed = 0
    for p, k, a in zip(prefixes, order.keys, exact):
        if not a.stable or k in order.no_press:
            continue
        for N in sorted(FORCES, reverse=True):
            n_pressed += 1
            if analyze_layout(press_layout(p, k, N, order)[0], solver="exact").stable:
                break
            falls_at[N].add(k)
    t_sweep = time.perf_counter() - t0
    _log(f"  press sweep: {n_pressed} HiGHS solves, {t_sweep:.1f} s")
    sweep = {}
    for N in FORCES:
        flags = falls_at[N]
        tp, fp, fn = len(flags & ref), len(flags - ref), len(ref - flags)
        sweep[N] = {"flagged": sorted(flags, key=int), "tp": tp, "fp": fp, "fn": fn,
                    "tn": len(modelled) - tp - fp - fn, "agree": len(modelled) - fp - fn}
    # 3. supports at 21.56 N (JAX batched)
    res = analyze_sequence(task.layout, order, press=21.56, solver="jax")
    _log(f"  supports at 21.56 N: {res.n_solved} layouts, {res.time_s:.1f} s")
    sup = []
    for s in res.steps:
        if s.needs_support or s.key in ref:
            sup.append({"step": s.step, "flagged": s.needs_support, "ours": s.support,
                        "apex": task.support.get(s.key), "tried": s.support_tried})
    return {
        "task": os.path.basename(path)[: -len("_seq.json")], "steps": n, "bricks": task.layout.n,
        "fixed": len(task.fixed), "from_below": len(order.no_press), "apex_support": len(ref),
        "exact_falls": [i + 1 for i, a in enumerate(exact) if not a.stable],
        "jax_falls": [i + 1 for i, a in enumerate(jx) if not a.stable],
        "jax_label_agree": labels, "jax_full_agree": agree, "exact_s": t_exact,
        "jax_cold_s": timings[0][0], "jax_cold_compile_s": timings[0][1], "jax_compiles": timings[0][2],
        "jax_warm_s": timings[1][0], "jax_not_converged": sum(not a.converged for a in jx),
        "sweep": sweep, "sweep_solves": n_pressed, "sweep_s": t_sweep, "supports_21.56": sup, "support_time_s": res.time_s, "support_solved": res.n_solved,
    }


def table(results: list) -> str:
    out = ["| task | steps | bricks (fixed) | falls unpressed (HiGHS / JAX) | JAX = HiGHS labels | HiGHS one by one (s) "
           "| JAX batched cold / warm (s) | compiles |", "|---|---|---|---|---|---|---|---|"]
    for r in results:
        out.append(f"| {r['task']} | {r['steps']} | {r['bricks']} ({r['fixed']}) | "
                   f"{len(r['exact_falls'])} / {len(r['jax_falls'])} | {r['jax_label_agree']}/{r['steps']} | "
                   f"{r['exact_s']:.2f} | {r['jax_cold_s']:.1f} / {r['jax_warm_s']:.2f} | {r['jax_compiles']} |")
    out += ["", "| press (N) | " + " | ".join(r["task"] for r in results) + " | all: agree / steps, TP FP FN |",
            "|---|" + "---|" * (len(results) + 1)]
    for N in FORCES:
        cells, tot = [], [0, 0, 0, 0, 0]
        for r in results:
            s = r["sweep"][N]
            m = r["steps"] - r["from_below"]
            cells.append(f"{s['agree']}/{m} ({s['tp']}/{r['apex_support']})")
            tot = [a + b for a, b in zip(tot, (s["agree"], m, s["tp"], s["fp"], s["fn"]))]
        out.append(f"| {N:g} | " + " | ".join(cells) + f" | {tot[0]}/{tot[1]}, {tot[2]} {tot[3]} {tot[4]} |")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--apex", required=True, help="APEX-MR checkout (holds config/lego_tasks)")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "apexmr.json"))
    ap.add_argument("--tasks", nargs="*", default=TASKS)
    args = ap.parse_args()
    steps = os.path.join(args.apex, "config", "lego_tasks", "steps")
    found = sorted(glob.glob(os.path.join(steps, "*_seq.json")))
    if not found:
        print(f"error: {steps}: no *_seq.json step files", file=sys.stderr)
        return 2
    results = []
    for t in args.tasks:
        p = os.path.join(steps, f"{t}_seq.json")
        _log(t)
        t0 = time.perf_counter()
        results.append(run_task(p))
        print(f"{t}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    meta = {"machine": f"{platform.machine()} {os.cpu_count()} cores, {platform.python_version()}",
            "date": time.strftime("%Y-%m-%d"), "forces": FORCES}
    atomic_write_text(args.out, json.dumps({"meta": meta, "results": results}, indent=1, default=str) + "\n")
    print(table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
