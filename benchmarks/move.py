"""repair --move (issue 21): make falling block scenes stand by moving one block.

Usage: python benchmarks/move.py [--random 15] [--seed 21] [--blocks 1] [--out FILE] [--table]

Scenes, each unstable by the exact solver:
* ``paper``: the four unstable Sec. IV.E cases of ``examples/extensions``
  (the 8-level stack with a block pushed out, the pushed stack, the
  45-degree pair, the pallet with its top box moved);
* ``harmonic``: harmonic stacks of 3-8 blocks at 1.05 of the knife-edge
  offsets (every interface tips), straight and turned by 30 degrees;
* ``random``: the first ``--random`` unstable scenes of
  :func:`stablelego_jax.generate.scenes.random_scene` (families stack, pile
  and pallet in turn, seeded).

For each, :func:`stablelego_jax.design.move.move_repair` with ``--blocks``
blocks allowed to move (default 1; ``MoveOptions(max_blocks=K)``, rounds
max(3, K + 2)): success (the exact solver
says the moved scene stands), the block moved and how far, exact solves,
gradient solves and wall time (including JAX compilation: each scene is a
new shape). Rows go to ``--out`` (default ``results/move.jsonl``, with
``--blocks K`` > 1 ``results/move_K.jsonl``) as they
finish; a rerun skips scenes already there. ``--table`` prints the table.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402

from rows import append_row, read_rows  # noqa: E402
from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.design.move import MoveOptions, move_repair  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402
from stablelego_jax.generate.scenes import harmonic_stack, random_scene  # noqa: E402

EXT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "examples", "extensions")
PAPER = ("stack8_moved", "stack_pushed", "blocks45_falls", "pallet_top_moved")


def scenes(n_random: int, seed: int):
    """(name, set, scene) of every benchmark scene (unstable ones only for ``random``)."""
    for f in PAPER:
        yield f"paper/{f}", "paper", load_layout(os.path.join(EXT, f + ".json"))
    for yaw in (0.0, 30.0):
        for n in range(3, 9):
            yield f"harmonic/n{n}/yaw{yaw:g}", "harmonic", harmonic_stack(n, frac=1.05, yaw=yaw)
    rng = np.random.default_rng(seed)
    fams = ("stack", "pile", "pallet")
    found, k = 0, 0
    while found < n_random and k < 50 * max(n_random, 1):
        fam = fams[k % len(fams)]
        sc = random_scene(rng, fam)
        k += 1
        if analyze_layout(sc, solver="exact").stable:
            continue
        found += 1
        yield f"random/{k}/{fam}", "random", sc


def table(rows: list) -> str:
    out = ["| set | scenes | stand | distance moved (mean, successes) | exact solves (mean) | "
           "gradient solves (mean) | wall time (mean, max) |", "|---|---|---|---|---|---|---|"]
    for s in ("paper", "harmonic", "random", "all"):
        rs = [r for r in rows if s == "all" or r["set"] == s]
        if not rs:
            continue
        ok = [r for r in rs if r["stable"]]
        dist = [sum(m["mm"] for m in r["moves"]) for r in ok if r["moves"]]
        out.append(f"| {s} | {len(rs)} | {len(ok)} ({100 * len(ok) / len(rs):.0f}%) | "
                   f"{np.mean(dist) if dist else float('nan'):.1f} mm | {np.mean([r['exact_calls'] for r in rs]):.1f} | "
                   f"{np.mean([r['soft_calls'] for r in rs]):.1f} | "
                   f"{np.mean([r['time_s'] for r in rs]):.1f} s, {max(r['time_s'] for r in rs):.1f} s |")
    out += ["", "| scene | bodies | failing before | stands | move |", "|---|---|---|---|---|"]
    for r in rows:
        mv = "; ".join(f"'{m['key']}' {m['mm']:.1f} mm" for m in r["moves"]) or "none"
        out.append(f"| {r['name']} | {r['n']} | {r['failing_before']} | {'yes' if r['stable'] else 'NO'} | {mv} |")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--random", type=int, default=15)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--blocks", type=int, default=1, help="most distinct blocks moved")
    ap.add_argument("--out", default=None)
    ap.add_argument("--table", action="store_true")
    args = ap.parse_args()
    args.out = args.out or os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                        "move.jsonl" if args.blocks == 1 else f"move_{args.blocks}.jsonl")
    done = read_rows(args.out, "name")
    if not args.table:
        print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs", file=sys.stderr)
        for name, which, sc in scenes(args.random, args.seed):
            if name in done:
                continue
            t = time.perf_counter()
            r = move_repair(sc, MoveOptions(max_blocks=args.blocks, rounds=max(3, args.blocks + 2)))
            row = {"name": name, "set": which, "n": sc.n,
                   "failing_before": int(sum(v >= 1.0 for v in r.before.scores.values())),
                   "stable": r.stable, "exact_calls": r.exact_calls, "soft_calls": r.soft_calls,
                   "time_s": round(time.perf_counter() - t, 3),
                   "moves": [{"key": m.key, "mm": round(float(np.hypot(*m.shift)) * 1e3, 2),
                              "shift_m": [round(v, 6) for v in m.shift]} for m in r.moves]}
            done[name] = row
            append_row(args.out, row)
            print(f"{name}: {sc.n} bodies, {'stands' if r.stable else 'FAILS'} "
                  f"{[m.describe() for m in r.moves]} {row['time_s']:.1f}s", file=sys.stderr, flush=True)
    print(table(list(done.values())))


if __name__ == "__main__":
    main()
