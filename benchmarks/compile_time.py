"""Force-model compile time (layout -> arrays) for large layouts.

Usage: python benchmarks/compile_time.py
"""
import os
import platform
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from stablelego_jax.generate.procedural import cuboid  # noqa: E402
from stablelego_jax.generate.voxels import merge_voxels  # noqa: E402
from stablelego_jax.model import compile_layout  # noqa: E402
import numpy as np  # noqa: E402

print(f"machine: {platform.machine()} {os.cpu_count()} cores")
cases = [("unit-brick cube 10x10x10", cuboid(10, 10, 10)),
         ("solid 20^3 voxel shape merged", merge_voxels(np.ones((20, 20, 20), bool)))]
for name, lay in cases:
    compile_layout(lay)  # warm numpy
    ts = []
    for _ in range(5):
        t = time.perf_counter()
        m = compile_layout(lay)
        ts.append(time.perf_counter() - t)
    print(f"{name}: {lay.n} bricks, {m.m} columns, compile {1e3 * min(ts):.1f} ms (best of 5), {1e3 * np.median(ts):.1f} ms median")
