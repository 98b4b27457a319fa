"""Memory mappings of one process that compiles many distinct solver shapes
(issue 20: are evicted executables the mappings that grow in a long
``analyze``?). The executable cache is bounded at 4; after each solve:
nothing ("none"), ``gc.collect()`` ("gc") or, once something was evicted,
``jax.clear_caches()`` ("clear"). Prints the mappings (lines of
/proc/self/maps) after every 5th shape.

Usage: python benchmarks/executable_maps.py none|gc|clear N [export]
("export": through the disk export cache, as the CLI does)
"""
import gc
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
import jax  # noqa: E402
from stablelego_jax.generate.procedural import stairs  # noqa: E402
from stablelego_jax.model import compile_layout  # noqa: E402
from stablelego_jax.solvers import compiled as C, ipm  # noqa: E402
from stablelego_jax.solvers.problem import to_problem  # noqa: E402
from stablelego_jax.analysis import SINGLE_NAME, solver_fn  # noqa: E402

def maps():
    with open("/proc/self/maps") as fh:
        return sum(1 for _ in fh)

mode, N = sys.argv[1], int(sys.argv[2])
export = len(sys.argv) > 3 and sys.argv[3] == "export"
C.set_limit(4)
model = compile_layout(stairs(5))
opts = ipm.IPMOptions()
out = []
t0 = time.time()
for i in range(N):
    pm = model.pad(8, 128 + 8 * i)
    arrays = tuple(a for a in to_problem(pm) if a is not None)
    exe = C.compiled(SINGLE_NAME, solver_fn(pm.params, opts), (pm.params, opts), arrays, export=export)
    jax.block_until_ready(exe(*arrays))
    del exe
    if mode == "gc":
        gc.collect()
    elif mode == "clear" and C.STATS.evicted:
        jax.clear_caches()
    out.append(maps())
print(mode, "export" if export else "", "maps every 5:", out[::5], "last", out[-1], f"{time.time()-t0:.0f}s", "evicted", C.STATS.evicted)
