"""Large single layouts: JAX against the exact solver, one layout a process.

    python benchmarks/large_layouts.py [--case pyramid20 ...] [--ldr FILE]
                                       [--plan auto|layers] [--solvers jax exact vertex]
                                       [--timeout 1200] [--json]

Cases: ``pyramidN`` (the stepped pyramid of 2x2 bricks of
:func:`~stablelego_jax.generate.procedural.pyramid`, N levels: 2870 bricks
at N = 20, the brick set of LDraw's generated ``pyramid20.ldr``), ``cubeK``
(K x K x K unit bricks), ``solidK`` (a full K x K x K box of cells merged
into bricks by :func:`~stablelego_jax.generate.voxels.merge_voxels`, the
interlocked shapes of mesh datasets: 700 bricks at K = 20), or ``--ldr
FILE`` (any layout file). Each solver
runs in its own process (its peak resident memory from ``wait4``), with
``--timeout`` seconds:

* ``jax``: the model compiled, its solve plan (as ``analyze`` picks it:
  ``fit_plan(solve_plan)``; ``--plan ladder``: the batch's bucket,
  ``--plan layers``: layer by layer, to compare), the solver
  compiled (``compile_s``, apart), one solve (``solve_s``);
* ``jax-gram``: the same with every layer's step by its Gram product
  (``IPMOptions.below`` off: the factorisation before session 48);
* ``exact``: ``analyze_layout(solver="exact")`` as ``stablelego analyze
  --solver exact`` runs it (HiGHS, its canonical stage included);
* ``vertex``: HiGHS' optimal vertex alone (no canonical stage: the plain
  LP, as ``cores.py``'s ``vertex-2``).

Prints one JSON object per case and solver (``--json``) or a table, and
appends the rows to ``benchmarks/results/large_layouts.jsonl``; labels and
highest scores are compared between the solvers of one case.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)
OUT = os.path.join(HERE, "results", "large_layouts.jsonl")


def load_case(case: str, ldr: str | None):
    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.generate.procedural import cuboid, pyramid

    if case == "ldr":
        return load_layout(ldr)
    if case.startswith("pyramid"):
        return pyramid(int(case[7:]))
    if case.startswith("cube"):
        k = int(case[4:])
        return cuboid(k, k, k)
    if case.startswith("solid"):
        import numpy as np

        from stablelego_jax.generate.voxels import merge_voxels

        k = int(case[5:])
        return merge_voxels(np.ones((k, k, k), bool), source=case)
    raise SystemExit(f"large_layouts.py: unknown case {case!r} (pyramidN, cubeK, solidK or --ldr FILE)")


def child(case: str, ldr: str | None, solver: str, plan: str) -> dict:
    """One solve in this process; returns the row."""
    import numpy as np

    from stablelego_jax.analysis import SINGLE_NAME, analyze_layout, make_analysis, solver_fn
    from stablelego_jax.model import compile_layout
    from stablelego_jax.solvers import ipm
    from stablelego_jax.solvers.compiled import compiled
    from stablelego_jax.solvers.problem import (MIN_COLUMNS, MIN_SLOTS, fit_plan, layer_bucket, layer_plan,
                                               plan_problem, rung, solve_plan)

    lay = load_case(case, ldr)
    row = {"case": case if case != "ldr" else os.path.basename(ldr), "bricks": lay.n, "solver": solver}
    t0 = time.perf_counter()
    if solver in ("exact", "vertex"):
        from stablelego_jax.model import Params

        a = analyze_layout(lay, solver="exact", params=Params() if solver == "exact" else Params(ridge=0.0))
        row.update(wall_s=time.perf_counter() - t0, converged=a.converged)
    else:
        model = compile_layout(lay)
        m_pad, p_pad = rung(model.m, MIN_COLUMNS), rung(model.group.shape[1], MIN_SLOTS)
        key = {"auto": lambda: fit_plan(model, solve_plan(model), m_pad), "ladder": lambda: solve_plan(model),
               "layers": lambda: ("layered",) + layer_bucket(*layer_plan(model))}[plan]()
        fm, prob = plan_problem(model, key, m_pad, p_pad)
        arrays = tuple(x for x in prob if x is not None)
        # as analyze sets it; jax-gram: every layer's step by its Gram product (before session 48)
        opts = ipm.options_for(ipm.IPMOptions(), prob) if solver == "jax" else ipm.IPMOptions()
        t1 = time.perf_counter()
        exe = compiled(SINGLE_NAME, solver_fn(model.params, opts), (model.params, opts), arrays, export=False)
        t2 = time.perf_counter()
        sol = exe(*arrays)
        sol[0].block_until_ready()
        t3 = time.perf_counter()
        a = make_analysis(lay, fm, np.asarray(sol[0]), "jax", bool(sol[2]), 0.0)
        row.update(wall_s=t3 - t0, compile_s=t2 - t1, solve_s=t3 - t2, plan=list(key),
                   iters=int(sol[1]), converged=bool(sol[2]), below=opts.below)
    scores = np.array([a.scores[k] for k in lay.keys])
    row.update(stable=bool(a.stable), failing=int((scores > 1).sum()), highest=float(scores.max()),
               weakest=a.weakest, scores=[round(float(s), 9) for s in scores])
    return row


def run(case: str, ldr: str | None, solver: str, plan: str, timeout: float) -> dict:
    """``child`` in a subprocess; adds its wall time and peak resident memory."""
    import tempfile

    cmd = [sys.executable, os.path.abspath(__file__), "--child", case, solver, plan] + (["--ldr", ldr] if ldr else [])
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        p = subprocess.Popen(cmd, stdout=out, stderr=err, text=True)
        while True:  # reap it ourselves: wait4 gives its own peak memory
            pid, status, ru = os.wait4(p.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() - t0 > timeout:
                p.kill()
                os.wait4(p.pid, 0)
                return {"case": case, "solver": solver, "plan": plan, "error": f"no answer in {timeout:.0f} s"}
            time.sleep(0.2)
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        text, etext = out.read(), err.read()
    if p.returncode != 0 or not text.strip():
        return {"case": case, "solver": solver, "plan": plan,
                "error": f"exit {p.returncode}: " + (etext.strip().splitlines() or ["?"])[-1]}
    row = json.loads(text.strip().splitlines()[-1])
    row.update(process_s=time.perf_counter() - t0, cpu_s=ru.ru_utime + ru.ru_stime, peak_mb=ru.ru_maxrss / 1024)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", nargs="*", default=["pyramid20"], help="pyramidN, cubeK (K^3 unit bricks), solidK (a full K^3 box merged into bricks) (default pyramid20)")
    ap.add_argument("--ldr", default=None, help="a layout file to run instead of the cases")
    ap.add_argument("--plan", choices=("auto", "ladder", "layers"), default="auto",
                    help="JAX plan: as analyze picks it (auto: solve_plan fitted to the layout), the "
                         "ladder's bucket (ladder: solve_plan) or layer by layer on the ladder (layers)")
    ap.add_argument("--solvers", nargs="*", default=["jax", "exact"], choices=("jax", "jax-gram", "exact", "vertex"))
    ap.add_argument("--timeout", type=float, default=1200.0, help="seconds per solve")
    ap.add_argument("--json", action="store_true", help="print one JSON object per row")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(child(a.child[0], a.ldr, a.child[1], a.child[2])))
        return 0
    cases = ["ldr"] if a.ldr else a.case
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    for case in cases:
        rows = {}
        for s in a.solvers:
            print(f"{case}: {s} ...", file=sys.stderr, flush=True)
            r = run(case, a.ldr, s, a.plan, a.timeout)
            r.update(date=time.strftime("%Y-%m-%d %H:%M"), host=os.uname().nodename)
            rows[s] = r
        if all(s in rows and "scores" in rows[s] for s in ("jax", "exact")):
            import numpy as np

            d = np.abs(np.array(rows["jax"]["scores"]) - np.array(rows["exact"]["scores"]))
            rows["jax"].update(label_agrees=rows["jax"]["stable"] == rows["exact"]["stable"],
                               max_score_diff=float(d.max()))
        with open(OUT, "a") as fh:
            for r in rows.values():
                fh.write(json.dumps(r) + "\n")
        for r in rows.values():
            short = {k: v for k, v in r.items() if k != "scores"}
            if a.json:
                print(json.dumps(short))
            else:
                print(" ".join(f"{k}={round(v, 2) if isinstance(v, float) else v}" for k, v in short.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
