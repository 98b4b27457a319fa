"""Measurement behind the ADMM settings: iterations to a certified solution
versus the residual-row penalty rho and the force-block ratio rho_x / rho.

Usage: python benchmarks/solver_tuning.py [--max-iter 4000]
Prints, per setting, iterations to convergence on each reference structure
(-1 = not converged within max-iter) and the relative objective error vs HiGHS.
"""
import argparse
import functools
import glob
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)  # the script jits the solver itself, on float64 inputs

from stablelego_jax.solvers.exact import solve_exact  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402
from stablelego_jax.model import compile_layout  # noqa: E402
from stablelego_jax.solvers.admm import SolverOptions, solve  # noqa: E402
from stablelego_jax.solvers.problem import to_problem  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--max-iter", type=int, default=4000)
args = ap.parse_args()
ex_dir = os.path.join(os.path.dirname(__file__), "..", "examples")
files = sorted(glob.glob(os.path.join(ex_dir, "stablelego", "*.json"))) + [os.path.join(ex_dir, "brickgpt", "guitar.txt")]
cases = []
for f in files:
    m = compile_layout(load_layout(f))
    cases.append((os.path.basename(f), m, solve_exact(m).objective, to_problem(m)))
print("setting".ljust(34), " ".join(c[0][:10].rjust(10) for c in cases), " converged")
for adapt in (False, True):
    for rho in (0.1, 1.0):
        for ratio in (1.0, 1e-2, 1e-4):
            o = SolverOptions(rho=rho, rho_x_ratio=ratio, adapt_rho=adapt, max_iter=args.max_iter)
            row, ok = [], 0
            for name, m, ex, p in cases:
                s = jax.jit(functools.partial(solve, params=m.params, opts=o))(p)
                it = int(s.iters) if bool(s.converged) else -1
                ok += it > 0
                row.append(f"{it:>5d}/{abs(float(s.objective) - ex) / ex:.0e}")
            print(f"adapt={adapt!s:5} rho={rho:<4} ratio={ratio:<6}".ljust(34), " ".join(r.rjust(10) for r in row), f" {ok}/{len(cases)}", flush=True)
