"""Which LAPACK calls deadlock XLA's CPU pool on this jaxlib (issue 18,
session 46: may one problem at a time use every core?).

Usage:
  python benchmarks/pool_deadlock.py [--threads 2] [--calls 60] [--timeout 90]

Each case runs in its own process with ``PJRT_NPROC=--threads`` (the
package imported, so its guard keeps that setting): the program of
``tests/lapack_calls.py``, four independent Cholesky factorisations and
four triangular solves in one jitted program, called ``--calls`` times,
each call waited on. A case that has not finished within ``--timeout``
seconds is killed and reported as hung.
Cases: unbatched 720 x 720 matrices (what one soft problem's loss and
gradient calls), a batch of one and of two 720 x 720 matrices a call, and
a batch of eight 160 x 160 (the size of ``tests/test_blas.py``'s
reproducer, which makes triangular solves only).
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
sys.path.insert(0, os.path.join(ROOT, "tests"))

from lapack_calls import command  # noqa: E402  (the program of tests/test_blas.py)

CASES = [("unbatched", 0, 720), ("a batch of 1", 1, 720), ("a batch of 2", 2, 720), ("a batch of 8", 8, 160)]


def run(batch: int, n: int, calls: int, threads: int, timeout: float) -> tuple[str, float]:
    env = dict(os.environ, PJRT_NPROC=str(threads))
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    t0 = time.perf_counter()
    try:
        out = subprocess.run(command(batch, n, calls), env=env, capture_output=True, text=True, timeout=timeout)
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
