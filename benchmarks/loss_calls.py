"""Eager calls of the public loss functions: first call and repeated calls.

    python benchmarks/loss_calls.py [--repeat 3] [--json]

What a user's script or notebook does: call ``stability_loss`` and
``jax.grad(stability_loss)`` on one soft problem several times (the README's
stair_20 with one candidate brick, padded by ``pad_soft``), and
``position_loss`` with its gradient on the 8-level stack of plain blocks
``examples/extensions/stack8_moved.json`` (one block pushed out). No ``jax.jit`` of the
caller's. Prints the seconds of each call, in a float32 program as a
user's runs. Run two code versions one after the other to compare.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)

import jax  # noqa: E402
import numpy as np  # noqa: E402

import stablelego_jax as sl  # noqa: E402
from stablelego_jax.loss import position_loss  # noqa: E402
from stablelego_jax.soft import scene_positions, soft_problem  # noqa: E402

STAIR20 = os.path.join(REPO, "examples", "stablelego", "stair_20.json")
STACK8 = os.path.join(REPO, "examples", "extensions", "stack8_moved.json")


def _times(fn, repeat: int) -> list:
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        out.append(round(time.perf_counter() - t0, 4))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="calls of each (at least 2)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap.parse_args(argv)
    lay = sl.load_layout(STAIR20)
    soft = sl.compile_soft(lay, [sl.candidate_brick([(4, 21, 0, 1, 2)])])
    prob = sl.pad_soft(soft.problem)
    w = np.zeros(prob.mass.shape[0])
    w[: soft.n] = soft.weights()
    sc = sl.load_layout(STACK8)
    sprob, geo = soft_problem(sc), scene_positions(sc)
    ws, zero = np.ones(sc.n), np.zeros((sc.n, 2))
    out = {
        "stability_loss_s": _times(lambda: sl.stability_loss(w, None, prob), a.repeat),
        "grad_stability_loss_s": _times(lambda: jax.grad(sl.stability_loss)(w, None, prob), a.repeat),
        "position_loss_s": _times(lambda: position_loss(zero, ws, None, sprob, geo), a.repeat),
        "grad_position_loss_s": _times(lambda: jax.grad(position_loss)(zero, ws, None, sprob, geo), a.repeat),
    }
    if a.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k}: first {v[0]} s, then {', '.join(map(str, v[1:]))} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
