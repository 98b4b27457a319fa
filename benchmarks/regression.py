"""Per-brick answers of every solver on fixed layouts, to compare two versions
of the code (a refactor must not change them).

Usage:
    python benchmarks/regression.py record OUT.jsonl [--seeds 300] [--chunk 56]
    python benchmarks/regression.py compare BEFORE.jsonl AFTER.jsonl [--tol 1e-9]

``record`` runs, on the bundled examples and the layouts of
``benchmarks/agreement.py`` (``random_family_layout(seed)``, seeds
0..N-1): the exact and JAX solvers (scores, verdict, weakest brick,
objective, iterations, forces) and the baselines luo and eb (first 60 seeds
and the examples; files recorded before version 0.3 also hold ADMM rows,
which ``compare`` leaves out). It appends, resumes, and runs in chunks
of fresh processes (``--chunk`` layouts each), so a long record never holds
hundreds of compiled executables in one process. Run it from each checkout
(``git worktree add``) into its own file, then ``compare``: the largest
per-brick score difference per solver, and every layout whose label or
weakest brick changed or whose scores moved more than ``--tol``. Exit 1 if
any did.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _items(lo: int, hi: int, examples: bool):
    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.generate.procedural import random_family_layout

    out = []
    if examples:
        files = sorted(glob.glob(os.path.join(ROOT, "examples", "stablelego", "*.json")))
        files += sorted(glob.glob(os.path.join(ROOT, "examples", "brickgpt", "*.txt")))
        out += [(os.path.basename(f), load_layout(f)) for f in files]
    return out + [(f"seed{s}", random_family_layout(s)[1]) for s in range(lo, hi)]


def _record_chunk(out: str, lo: int, hi: int, examples: bool) -> None:
    import numpy as np

    from stablelego_jax.analysis import analyze_layout

    done = set()
    if os.path.exists(out):
        with open(out) as fh:
            done = {json.loads(line)["name"] for line in fh if line.endswith("\n")}
    with open(out, "a") as fh:
        for name, lay in _items(lo, hi, examples):
            if name in done:
                continue
            rec = {"name": name, "n": lay.n}
            for solver in ("exact", "jax"):
                a = analyze_layout(lay, solver=solver)
                rec[solver] = {"scores": [a.scores[k] for k in lay.keys], "stable": a.stable, "weakest": a.weakest,
                               "objective": a.objective, "iters": a.iters, "converged": a.converged,
                               "forces": np.asarray(a.forces).tolist()}
            example = not name.startswith("seed")
            if example or int(name[4:]) < 60:
                for m in ("luo", "eb"):
                    a = analyze_layout(lay, solver="exact", method=m)
                    rec[m] = {"scores": [a.scores.get(k) for k in lay.keys], "stable": a.stable,
                              "weakest": a.weakest, "solvable": a.solvable}
            fh.write(json.dumps(rec) + "\n")
            fh.flush()


def record(out: str, seeds: int, chunk: int) -> None:
    bounds = [(max(lo, 0), min(lo + chunk, seeds)) for lo in range(0, seeds, chunk)] or [(0, 0)]
    t0 = time.time()
    for i, (lo, hi) in enumerate(bounds):
        code = (f"import sys; sys.path.insert(0, {ROOT!r}); sys.path.insert(0, {os.path.dirname(__file__)!r});"
                f"import regression; regression._record_chunk({out!r}, {lo}, {hi}, {i == 0})")
        subprocess.run([sys.executable, "-c", code], check=True, env=dict(os.environ, OPENBLAS_NUM_THREADS="1"))
        print(f"seeds {lo}-{hi - 1} done, {time.time() - t0:.0f} s", file=sys.stderr, flush=True)


def compare(before: str, after: str, tol: float) -> int:
    def load(p):
        with open(p) as fh:
            return {r["name"]: r for r in map(json.loads, fh)}

    b, a = load(before), load(after)
    common = sorted(set(b) & set(a))
    print(f"layouts compared: {len(common)} ({len(b)} before, {len(a)} after)")
    worst, diffs = {}, []
    for k in common:
        for s in ("exact", "jax", "luo", "eb"):
            if s not in b[k] or s not in a[k]:
                continue
            x, y = b[k][s], a[k][s]
            sx = [v for v in x["scores"] if v is not None]
            sy = [v for v in y["scores"] if v is not None]
            d = max((abs(p - q) for p, q in zip(sx, sy)), default=0.0) if len(sx) == len(sy) else float("inf")
            worst[s] = max(worst.get(s, 0.0), d)
            same = (x["stable"], x["weakest"]) == (y["stable"], y["weakest"])
            if not same or d > tol:
                diffs.append(f"  {k} {s}: label/weakest {'same' if same else 'CHANGED'}, scores moved {d:.3e}")
    for s, v in worst.items():
        print(f"{s}: largest per-brick score difference {v:.3e}")
    print(f"layouts with a changed label or weakest brick, or scores moved more than {tol:g}: {len(diffs)}")
    print("\n".join(diffs))
    return 1 if diffs else 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record")
    r.add_argument("out")
    r.add_argument("--seeds", type=int, default=300)
    r.add_argument("--chunk", type=int, default=56)
    c = sub.add_parser("compare")
    c.add_argument("before")
    c.add_argument("after")
    c.add_argument("--tol", type=float, default=1e-9)
    a = ap.parse_args()
    if a.cmd == "record":
        record(a.out, a.seeds, a.chunk)
        return 0
    return compare(a.before, a.after, a.tol)


if __name__ == "__main__":
    sys.exit(main())
