"""Both solvers on the bundled reference layouts (paper structures + BrickGPT).

Usage: python benchmarks/reference.py
Prints per layout: outcome, weakest brick, highest score, JAX iterations,
convergence, and steady-state solve time (after the first, compiling call).
"""
import glob
import os
import platform
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402

ex = os.path.join(os.path.dirname(__file__), "..", "examples")
files = sorted(glob.glob(os.path.join(ex, "stablelego", "*.json"))) + sorted(glob.glob(os.path.join(ex, "brickgpt", "*.txt")))
print(f"machine: {platform.machine()} {os.cpu_count()} cores, CPU only")
print("| layout | bricks | exact: stable / weakest / max score | jax: stable / weakest / max score | jax iters | converged | exact ms | jax ms |")
print("|---|---|---|---|---|---|---|---|")
for f in files:
    lay = load_layout(f)
    e = analyze_layout(lay, "exact")
    analyze_layout(lay, "jax")  # compile
    t = time.perf_counter()
    j = analyze_layout(lay, "jax")
    tj = time.perf_counter() - t
    t = time.perf_counter()
    e = analyze_layout(lay, "exact")
    te = time.perf_counter() - t
    print(f"| {os.path.basename(f)} | {lay.n} | {e.stable} / {e.weakest} / {max(e.scores.values()):.4f} | "
          f"{j.stable} / {j.weakest} / {max(j.scores.values()):.4f} | {j.iters} | {j.converged} | {1e3 * te:.1f} | {1e3 * tj:.1f} |", flush=True)
