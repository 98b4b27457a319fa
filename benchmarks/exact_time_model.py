"""The exact solver's time model (``solvers.exact.estimated_seconds``), fitted.

    python benchmarks/exact_time_model.py [--results benchmarks/results/exact_times_s27.jsonl]
    python benchmarks/exact_time_model.py --measure FILE... --results OUT.jsonl

``--measure``: ``stablelego score FILE... --solver exact --jobs 1 --out OUT``
first (one core; every line has ``time_s``), then the fit. The fit: least
squares in log time of ``a m^p + b m^q`` (m: a layout's real force columns)
over the lines of ``--results``; prints the coefficients, measured / model
percentiles, and sums by size, next to the library's current model.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)

from stablelego_jax import load_layout  # noqa: E402
from stablelego_jax.model import Params, compile_layout  # noqa: E402
from stablelego_jax.solvers.exact import estimated_seconds  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default=os.path.join(HERE, "results", "exact_times_s27.jsonl"))
    ap.add_argument("--measure", nargs="+", metavar="FILE", help="score these with the exact solver first")
    a = ap.parse_args(argv)
    if a.measure:
        subprocess.run([sys.executable, "-m", "stablelego_jax", "score", *a.measure, "--solver", "exact",
                        "--jobs", "1", "--out", a.results], cwd=ROOT, check=True)
    from scipy.optimize import least_squares

    rows = [json.loads(line) for line in open(a.results)]
    rows = [r for r in rows if "error" not in r]
    models = [compile_layout(load_layout(os.path.join(ROOT, r["file"])), Params()) for r in rows]
    n = np.array([mo.n for mo in models], float)
    m = np.array([mo.m for mo in models], float)
    t = np.array([r["time_s"] for r in rows])

    def f(p, x):
        return np.exp(p[0]) * x ** p[1] + np.exp(p[2]) * x ** p[3]

    fit = least_squares(lambda p: np.log(f(p, m)) - np.log(t), [np.log(1e-3), 1.0, np.log(1e-9), 3.0])
    a_, p_, b_, q_ = np.exp(fit.x[0]), fit.x[1], np.exp(fit.x[2]), fit.x[3]
    print(f"{len(t)} layouts, {int(n.min())}-{int(n.max())} bricks; fit: t = {a_:.3g} m^{p_:.3f} + {b_:.3g} m^{q_:.3f}")
    for name, pred in (("fit", f(fit.x, m)), ("library", np.array([estimated_seconds(mo) for mo in models]))):
        r = t / pred
        print(f"  {name:8s} measured/model p10 {np.percentile(r, 10):.2f} p50 {np.percentile(r, 50):.2f} "
              f"p90 {np.percentile(r, 90):.2f}; sum measured {t.sum():.1f} s, model {pred.sum():.1f} s")
        for lo, hi in ((1, 30), (30, 120), (120, 400), (400, 10 ** 6)):
            s = (n >= lo) & (n < hi)
            if s.any():
                print(f"    {lo}-{hi} bricks: {int(s.sum())} layouts, measured {t[s].sum():.2f} s, model {pred[s].sum():.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
