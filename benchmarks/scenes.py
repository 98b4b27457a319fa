"""JAX interior point vs the exact HiGHS referee on random scenes (issue 21).

Usage: python benchmarks/scenes.py [--n 500] [--seed 0] [--batch 64] [--out benchmarks/results/scenes.json]

Scenes from ``stablelego_jax.generate.scenes.random_scene``, the families in
turn: columns of plain blocks with random offsets and yaws ("stack"), beams
on two or three supports with loads ("pile"), pallets of boxes with a random
top box and friction 0 or 0.4 ("pallet"), bricks at random yaws joined by
single knobs ("lego"), columns with Coulomb friction 0, 0.2 or 0.5
("mixed"). Every scene is solved by HiGHS one at a time and by the JAX
interior point in compiled, vmap-ed batches (``batch.analyze_many``); the
script prints per family: scenes, stable (exact), label agreement, bodies
whose score agrees within 1e-3, largest difference of the highest score and
of the support score on stable scenes, and the times (exact: compile + LP
per scene; JAX: amortised batch solve time per scene, compile time apart).
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import platform
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

import numpy as np  # noqa: E402

from stablelego_jax.batch import ScoreStats, analyze_many  # noqa: E402
from stablelego_jax.files import atomic_write_text  # noqa: E402
from stablelego_jax.generate.scenes import SCENE_FAMILIES, random_scene  # noqa: E402
from stablelego_jax.model import compile_scene  # noqa: E402
from stablelego_jax.score import brick_scores  # noqa: E402
from stablelego_jax.solvers.exact import solve_exact  # noqa: E402
from stablelego_jax.support import support_scores  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "scenes.json"))
    args = ap.parse_args()

    fams = [SCENE_FAMILIES[i % len(SCENE_FAMILIES)] for i in range(args.n)]
    scenes = [random_scene(np.random.default_rng((args.seed, i)), f) for i, f in enumerate(fams)]

    exact = []
    for sc in scenes:
        t0 = time.perf_counter()
        model = compile_scene(sc)
        r = solve_exact(model)
        dt = time.perf_counter() - t0
        s = np.asarray(brick_scores(model, r.f)[0])[: sc.n]
        exact.append({"scores": s, "stable": bool((s < 1).all()), "time": dt, "ok": r.success,
                      "support": support_scores(sc, model, r.f), "obj": r.objective})

    st = ScoreStats()
    t0 = time.perf_counter()
    jax_res = analyze_many(scenes, "jax", batch=args.batch, stats=st)
    wall_jax = time.perf_counter() - t0

    rows = collections.defaultdict(lambda: collections.Counter())
    worst = collections.defaultdict(lambda: {"max_score": 0.0, "support": 0.0})
    bad = []
    for i, (sc, ex, ja) in enumerate(zip(scenes, exact, jax_res)):
        f = fams[i]
        sj = np.array([ja.scores[k] for k in sc.keys])
        row = rows[f]
        row["scenes"] += 1
        row["bodies"] += sc.n
        row["stable"] += ex["stable"]
        row["label_agree"] += ex["stable"] == ja.stable
        row["body_agree"] += int((np.abs(sj - ex["scores"]) <= 1e-3).sum())
        if ex["stable"]:
            row["body_differ_stable"] += int((np.abs(sj - ex["scores"]) > 1e-3).sum())
        row["converged"] += ja.converged
        row["exact_ok"] += ex["ok"]
        if ex["stable"] != ja.stable:
            bad.append({"i": i, "family": f, "exact": ex["stable"], "jax": ja.stable, "obj_exact": ex["obj"],
                        "obj_jax": ja.objective})
        if ex["stable"] and ja.stable:
            w = worst[f]
            w["max_score"] = max(w["max_score"], float(abs(sj.max() - ex["scores"].max())))
            sup_j = support_scores(sc, ja.model, np.asarray(ja.forces))
            both = np.isfinite(ex["support"])
            if both.any():
                w["support"] = max(w["support"], float(np.abs(sup_j[both] - ex["support"][both]).max()))
    t_exact = {f: float(np.median([e["time"] for e, g in zip(exact, fams) if g == f])) for f in SCENE_FAMILIES}
    t_jax = {f: float(np.median([a.time_s for a, g in zip(jax_res, fams) if g == f])) for f in SCENE_FAMILIES}

    print("| family | scenes | bodies | stable (exact) | labels agree | body scores agree (1e-3) | "
          "max |dscore| stable | max |dsupport| stable | exact ms / scene | jax ms / scene (batched) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    tot = collections.Counter()
    for f in SCENE_FAMILIES:
        r = rows[f]
        tot.update(r)
        print(f"| {f} | {r['scenes']} | {r['bodies']} | {r['stable']} | {r['label_agree']}/{r['scenes']} | "
              f"{r['body_agree']}/{r['bodies']} | {worst[f]['max_score']:.1e} | {worst[f]['support']:.1e} | "
              f"{t_exact[f] * 1e3:.1f} | {t_jax[f] * 1e3:.1f} |")
    exact_total = sum(e["time"] for e in exact)
    print(f"| all | {tot['scenes']} | {tot['bodies']} | {tot['stable']} | {tot['label_agree']}/{tot['scenes']} | "
          f"{tot['body_agree']}/{tot['bodies']} | | | total {exact_total:.1f} s | total solve {st.solve_s:.1f} s |")
    print(f"bodies whose scores differ by more than 1e-3 in stable scenes: {tot['body_differ_stable']}")
    print(f"JAX: {tot['converged']}/{tot['scenes']} converged; compile {st.compile_s:.1f} s ({st.compiles} shapes), "
          f"wall {wall_jax:.1f} s; exact: {tot['exact_ok']}/{tot['scenes']} solved")
    for b in bad:
        print("label disagreement:", b)
    out = {
        "n": args.n, "seed": args.seed, "batch": args.batch, "machine": platform.platform(),
        "date": time.strftime("%Y-%m-%d"), "families": {f: dict(rows[f]) for f in SCENE_FAMILIES},
        "worst": {f: worst[f] for f in SCENE_FAMILIES}, "median_exact_s": t_exact, "median_jax_s": t_jax,
        "exact_total_s": exact_total, "jax_solve_s": st.solve_s, "jax_compile_s": st.compile_s,
        "jax_compiles": st.compiles, "jax_wall_s": wall_jax, "disagreements": bad,
    }
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    atomic_write_text(args.out, json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
