"""Which LAPACK calls deadlock XLA's CPU pool on this jaxlib (issue 18,
session 46: may one problem at a time use every core?).

Usage:
  python benchmarks/pool_deadlock.py [--threads 2] [--calls 60] [--timeout 90]

Each case runs in its own process with ``PJRT_NPROC=--threads`` (the
package imported, so its guard keeps that setting): one jitted program
holding four independent Cholesky factorisations and four triangular
solves, called ``--calls`` times, each call waited on. A case that has
not finished within ``--timeout`` seconds is killed and reported as hung.
Cases: unbatched 720 x 720 matrices (what one soft problem's loss and
gradient calls), a batch of one and of two 720 x 720 matrices a call, and
the reproducer of ``tests/test_blas.py`` (a batch of eight 160 x 160).
Prints a Markdown table and the jaxlib version.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..")

PROGRAM = """
import sys
import stablelego_jax  # noqa: F401
import jax, jax.numpy as jnp
from jax.scipy.linalg import solve_triangular
jax.config.update("jax_enable_x64", True)
B, n, calls = (int(a) for a in sys.argv[1:4])
shape = (B, n, n) if B else (n, n)
T = (lambda a: a.transpose(0, 2, 1)) if B else (lambda a: a.T)
A = [jax.random.normal(k, shape) for k in jax.random.split(jax.random.key(0), 4)]
L = [jnp.linalg.cholesky(a @ T(a) + n * jnp.eye(n)) for a in A]
f = jax.jit(lambda A, L, x: sum(solve_triangular(Li, x * (i + 1), lower=True).sum()
                                + jnp.linalg.cholesky(Ai @ T(Ai) + n * jnp.eye(n)).sum()
                                for i, (Ai, Li) in enumerate(zip(A, L))))
x = jnp.ones(shape)
for i in range(calls):
    float(f(A, L, x + i))
print("done")
"""

CASES = [("unbatched", 0, 720), ("a batch of 1", 1, 720), ("a batch of 2", 2, 720), ("a batch of 8", 8, 160)]


def run(batch: int, n: int, calls: int, threads: int, timeout: float) -> tuple[str, float]:
    env = dict(os.environ, PJRT_NPROC=str(threads))
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    t0 = time.perf_counter()
    try:
        out = subprocess.run([sys.executable, "-c", PROGRAM, str(batch), str(n), str(calls)], env=env,
                             capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return f"hung (killed at {timeout:g} s)", time.perf_counter() - t0
    if out.returncode != 0 or out.stdout.strip() != "done":
        return f"failed (exit {out.returncode})", time.perf_counter() - t0
    return "finished", time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--calls", type=int, default=60)
    ap.add_argument("--timeout", type=float, default=90.0)
    a = ap.parse_args()
    sys.path.insert(0, ROOT)
    from stablelego_jax.blas import installed_jaxlib_version, lapack_pool_deadlock

    jl = installed_jaxlib_version()
    print(f"jaxlib {jl} (listed as deadlocking: {lapack_pool_deadlock(jl)}), PJRT_NPROC={a.threads}, "
          f"{a.calls} calls a case")
    print("| matrices per LAPACK call | size | result | wall s |")
    print("|---|---|---|---|")
    for name, batch, n in CASES:
        result, wall = run(batch, n, a.calls, a.threads, a.timeout)
        print(f"| {name} | {n} x {n} | {result} | {wall:.1f} |", flush=True)


if __name__ == "__main__":
    main()
