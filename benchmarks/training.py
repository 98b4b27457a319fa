"""Issue 6 benchmark: the generator trained with and without the stability loss.

    python benchmarks/training.py [--config stablelego_jax/train/configs/default.json]
        [--lams 0,LAM] [--seeds 0,1,2] [--runs out/training_runs] [--jobs 2] [--refine SECONDS]
        [--heldout heldout.jsonl] [--results benchmarks/results]

Trains one generator per (lambda, seed) with ``stablelego train`` (``python -m stablelego_jax train``)
(``--resume``: finished runs are reused if their stored config matches,
else it stops with exit 2; interrupted ones continue from their
checkpoint), at most ``--jobs`` at once (each given its share of the cores:
``train --jobs`` and ``PJRT_NPROC``), evaluates each on the
held-out shapes with ``stablelego evaluate`` (exact solver), scores
the merge heuristic of ``stablelego_jax.generate.voxels`` on the same shapes
(``--refine SECONDS``: also each run's filled decoding refined per shape by
``stabilize``'s re-merge rounds, ``evaluate --refine``; issue 19's "generator +
refinement"; ``--heldout NAME``: each run's evaluation file, in its run
folder, written when missing and read, so that evaluations with other
``--refine`` budgets sit beside one another), and writes ``RESULTS/training.json`` and
``RESULTS/training_curves.png`` (``--results``, default
``benchmarks/results``); prints a markdown table. Target (issue 6): the stability term raises the held-out
stable fraction by >= 20 percentage points at a cost of at most 0.02 IoU
(means over the seeds; judged when ``--lams`` has two or more lambdas).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)

from stablelego_jax.batch import cpu_cores  # noqa: E402
from stablelego_jax.files import atomic_write, atomic_write_text  # noqa: E402

sys.path.insert(0, HERE)
from rows import RowsError, all_rows  # noqa: E402


#: decoding name -> evaluate's method name (see stablelego_jax.train.evaluate)
DECODINGS = {"strict": "generator", "filled": "generator_filled"}


def _run_all(cmds, jobs, extra_env=None):
    """Run (name, argv, log) commands, ``jobs`` at a time, with ``extra_env``
    added to their environment; {name: (rc, wall_s)}."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", PYTHONPATH=REPO, **(extra_env or {}))
    pending, running, out = list(cmds), [], {}
    while pending or running:
        while pending and len(running) < jobs:
            name, argv, log = pending.pop(0)
            fh = open(log, "a")
            running.append((name, subprocess.Popen(argv, cwd=REPO, stdout=fh, stderr=fh, env=env), time.time(), fh))
        time.sleep(2)
        for r in list(running):
            if r[1].poll() is not None:
                r[3].close()
                out[r[0]] = (r[1].returncode, time.time() - r[2])
                running.remove(r)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=os.path.join(REPO, "stablelego_jax", "train", "configs", "default.json"))
    ap.add_argument("--lams", default=None, help="comma-separated lambdas (default: 0,1000)")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--runs", default=os.path.join(REPO, "out", "training_runs"))
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--results", default=os.path.join(HERE, "results"))
    ap.add_argument("--refine", type=float, default=None, metavar="SECONDS",
                    help="also refine each filled decoding (evaluate --refine SECONDS)")
    ap.add_argument("--heldout", default="heldout.jsonl", metavar="NAME",
                    help="each run's evaluation file in its run folder (default heldout.jsonl)")
    a = ap.parse_args(argv)
    lams = [float(x) for x in (a.lams or "0,1000").split(",")]
    seeds = [int(x) for x in a.seeds.split(",")]
    from stablelego_jax.train.train import ConfigError, config_diff, load_config

    try:
        base = load_config(a.config)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    runs = {(lam, s): os.path.join(a.runs, f"lam{lam:g}_seed{s}") for lam in lams for s in seeds}
    todo = []
    for (lam, s), d in runs.items():  # every finished run checked before anything is written
        hist = os.path.join(d, "history.json")
        if not os.path.exists(hist):
            todo.append((lam, s, d))
            continue
        with open(hist) as fh:
            diff = config_diff(json.load(fh)["config"], dict(base, lam=lam, seed=s))
        if diff:
            print(f"error: {d} was trained with a different config ({', '.join(diff)}); "
                  f"pass another --runs folder", file=sys.stderr)
            return 2
    py = sys.executable
    # the cores shared among the runs at once: each run's subset solves (train --jobs) and XLA pool
    share = max(1, cpu_cores() // max(1, a.jobs))
    cmds = []
    for lam, s, d in todo:
        os.makedirs(d, exist_ok=True)
        cmds.append((f"train lam={lam:g} seed={s}", [py, "-m", "stablelego_jax", "train", "--config", a.config, "--lam", str(lam),
                                                     "--seed", str(s), "--out", d, "--resume", "--jobs", str(share)],
                     os.path.join(d, "train.log")))
    t0 = time.time()
    for name, (rc, wall) in _run_all(cmds, a.jobs, {"PJRT_NPROC": str(share)}).items():
        print(f"{name}: rc {rc}, {wall:.0f} s", file=sys.stderr)
        if rc != 0:
            print(f"error: {name} failed (see its train.log)", file=sys.stderr)
            return 1
    train_wall = time.time() - t0
    cmds = []
    for (lam, s), d in runs.items():
        res = os.path.join(d, a.heldout)
        if not os.path.exists(res):
            argv_ = [py, "-m", "stablelego_jax", "evaluate", "--checkpoint", os.path.join(d, "checkpoint.npz"), "--out", res]
            if lam == lams[0]:
                argv_.append("--untrained")  # the network at initialisation, once per seed
            if (lam, s) == (lams[0], seeds[0]):
                argv_.append("--heuristic")
            if a.refine is not None:
                argv_ += ["--refine", str(a.refine)]
            cmds.append((f"evaluate lam={lam:g} seed={s}", argv_, os.path.join(d, "evaluate.log")))
    for name, (rc, wall) in _run_all(cmds, a.jobs).items():
        if rc != 0:
            print(f"error: {name} failed", file=sys.stderr)
            return 1
    per_run, curves, untrained = [], {}, []
    heur = heur_refined = None

    def stats(rs):
        return {"n": len(rs), "stable_fraction": float(np.mean([r["stable"] for r in rs])),
                "mean_iou": float(np.mean([r["iou"] for r in rs])),
                "mean_bricks": float(np.mean([r["n_bricks"] for r in rs]))}

    try:  # every evaluation read before anything is summarised
        evaluations = {key: all_rows(os.path.join(d, a.heldout)) for key, d in runs.items()}
    except RowsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for (lam, s), d in runs.items():
        rows = evaluations[lam, s]
        h = [r for r in rows if r["method"] == "heuristic"]
        if h:
            heur = stats(h)
        h = [r for r in rows if r["method"] == "heuristic_refined"]
        if h:
            heur_refined = dict(stats(h), refine_s=float(np.mean([r.get("refine_s", 0.0) for r in h])))
        if any(r["method"] == "untrained" for r in rows):
            untrained.append({"seed": s, **{dec: stats([r for r in rows if r["method"] == m.replace("generator", "untrained")])
                                            for dec, m in DECODINGS.items()}})
        with open(os.path.join(d, "history.json")) as fh:
            hj = json.load(fh)
        rec = {"lam": lam, "seed": s, "train_wall_s": round(hj["wall_s"], 1), "steps": hj["config"]["steps"]}
        for dec, method in DECODINGS.items():
            rec[dec] = stats([r for r in rows if r["method"] == method])
        refined = [r for r in rows if r["method"] == "generator_refined"]
        if refined:
            rec["refined"] = dict(stats(refined), refine_s=float(np.mean([r.get("refine_s", 0.0) for r in refined])),
                                  exact_calls=float(np.mean([r.get("exact_calls", 0) for r in refined])))
        per_run.append(rec)
        curves[f"{lam:g}/{s}"] = hj["history"]
    by_lam, target = {}, {}
    for lam in lams:
        rs = [r for r in per_run if r["lam"] == lam]
        b = {"train_wall_s": float(np.mean([r["train_wall_s"] for r in rs]))}
        for dec in DECODINGS:
            b[dec] = {k: float(np.mean([r[dec][k] for r in rs])) for k in ("stable_fraction", "mean_iou", "mean_bricks")}
            b[dec]["stable_fraction_per_seed"] = [r[dec]["stable_fraction"] for r in rs]
            b[dec]["mean_iou_per_seed"] = [r[dec]["mean_iou"] for r in rs]
        if all("refined" in r for r in rs):
            b["refined"] = {k: float(np.mean([r["refined"][k] for r in rs]))
                            for k in ("stable_fraction", "mean_iou", "mean_bricks", "refine_s", "exact_calls")}
            b["refined"]["stable_fraction_per_seed"] = [r["refined"]["stable_fraction"] for r in rs]
        by_lam[f"{lam:g}"] = b
    base, best = by_lam[f"{lams[0]:g}"], by_lam[f"{lams[-1]:g}"]
    vs_heur = {}
    for dec in DECODINGS:
        gain = best[dec]["stable_fraction"] - base[dec]["stable_fraction"]
        cost = base[dec]["mean_iou"] - best[dec]["mean_iou"]
        if len(lams) > 1:  # issue 6: the stability term against lambda 0
            target[dec] = {"stable_gain_pp": round(100 * gain, 1), "iou_cost": round(cost, 4),
                           "met": bool(gain >= 0.20 and cost <= 0.02)}
        if heur:
            vs_heur[dec] = {"stable_gain_pp": round(100 * (best[dec]["stable_fraction"] - heur["stable_fraction"]), 1),
                            "iou_cost": round(heur["mean_iou"] - best[dec]["mean_iou"], 4)}
    for lam in lams:  # issue 19: the generator (with or without refinement) against the heuristic at IoU 1
        b = by_lam[f"{lam:g}"]
        if heur and "refined" in b:
            vs_heur[f"refined lambda={lam:g}"] = {
                "stable_gain_pp": round(100 * (b["refined"]["stable_fraction"] - heur["stable_fraction"]), 1),
                "iou_cost": round(heur["mean_iou"] - b["refined"]["mean_iou"], 4)}
    out = {"config": os.path.relpath(a.config, REPO), "lams": lams, "seeds": seeds, "decodings": DECODINGS,
           "per_run": per_run, "by_lambda": by_lam, "untrained": {
               "per_seed": untrained, **({dec: {k: float(np.mean([u[dec][k] for u in untrained]))
                                               for k in ("stable_fraction", "mean_iou", "mean_bricks")}
                                         for dec in DECODINGS} if untrained else {})},
           "heuristic": heur, "heuristic_refined": heur_refined, "target": target, "vs_heuristic": vs_heur,
           "wall_s_training_this_invocation": round(train_wall, 1), "machine": "2-core x86_64 CPU, no GPU"}
    os.makedirs(a.results, exist_ok=True)
    atomic_write_text(os.path.join(a.results, "training.json"), json.dumps(out, indent=1))
    _plot(curves, lams, seeds, os.path.join(a.results, "training_curves.png"))
    print("| generator | seed | strict: stable | strict: IoU | filled: stable | filled: IoU | bricks (filled) | train wall (s) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in per_run:
        print(f"| lambda={r['lam']:g} | {r['seed']} | {r['strict']['stable_fraction']:.3f} | {r['strict']['mean_iou']:.4f} | "
              f"{r['filled']['stable_fraction']:.3f} | {r['filled']['mean_iou']:.4f} | {r['filled']['mean_bricks']:.1f} | "
              f"{r['train_wall_s']:.0f} |")
    for r in per_run:
        if "refined" in r:
            f = r["refined"]
            print(f"| lambda={r['lam']:g} + refinement | {r['seed']} | - | - | {f['stable_fraction']:.3f} | "
                  f"{f['mean_iou']:.4f} | {f['mean_bricks']:.1f} | {f['refine_s']:.1f} s a shape |")
    for lam in lams:
        b = by_lam[f"{lam:g}"]
        if "refined" in b:
            print(f"| **lambda={lam:g} + refinement, mean** | {len(seeds)} seeds | - | - | "
                  f"**{b['refined']['stable_fraction']:.3f}** | **{b['refined']['mean_iou']:.4f}** | "
                  f"{b['refined']['mean_bricks']:.1f} | {b['refined']['refine_s']:.1f} s a shape |")
    for lam in lams:
        b = by_lam[f"{lam:g}"]
        print(f"| **lambda={lam:g}, mean** | {len(seeds)} seeds | **{b['strict']['stable_fraction']:.3f}** | "
              f"**{b['strict']['mean_iou']:.4f}** | **{b['filled']['stable_fraction']:.3f}** | "
              f"**{b['filled']['mean_iou']:.4f}** | {b['filled']['mean_bricks']:.1f} | {b['train_wall_s']:.0f} |")
    for u in untrained:
        print(f"| untrained network | {u['seed']} | {u['strict']['stable_fraction']:.3f} | {u['strict']['mean_iou']:.4f} | "
              f"{u['filled']['stable_fraction']:.3f} | {u['filled']['mean_iou']:.4f} | {u['filled']['mean_bricks']:.1f} | 0 |")
    if heur:
        print(f"| merge heuristic | - | - | - | {heur['stable_fraction']:.3f} | {heur['mean_iou']:.4f} | "
              f"{heur['mean_bricks']:.1f} | - |")
    if heur_refined:
        print(f"| merge heuristic + refinement | - | - | - | {heur_refined['stable_fraction']:.3f} | "
              f"{heur_refined['mean_iou']:.4f} | {heur_refined['mean_bricks']:.1f} | "
              f"{heur_refined['refine_s']:.1f} s a shape |")
    print()
    for dec in DECODINGS:
        if dec in target:
            t = target[dec]
            print(f"{dec} decoding: stability term {t['stable_gain_pp']:+.1f} pp stable, IoU cost {t['iou_cost']:.4f}: "
                  f"target (>= +20 pp, <= 0.02 IoU) {'MET' if t['met'] else 'NOT MET'}")
        if dec in vs_heur:
            v = vs_heur[dec]
            print(f"  vs merge heuristic: {v['stable_gain_pp']:+.1f} pp stable, IoU cost {v['iou_cost']:.4f}")
    for name, v in vs_heur.items():
        if name.startswith("refined"):
            print(f"{name} vs merge heuristic: {v['stable_gain_pp']:+.1f} pp stable, IoU cost {v['iou_cost']:.4f}")
    return 0


def _plot(curves, lams, seeds, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [("fidelity", "fidelity (sum of (coverage-1)^2 + brick cost)"), ("stability", "stability loss (mean per shape)"),
            ("heldout_stable", "held-out stable fraction, strict (exact)"), ("heldout_iou", "held-out IoU, strict"),
            ("heldout_stable_filled", "held-out stable fraction, filled (exact)"),
            ("val_stable_filled", "validation stable fraction, filled (exact)")]
    fig, axes = plt.subplots(1, 6, figsize=(26, 4))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, lam in enumerate(lams):
        for j, s in enumerate(seeds):
            h = curves.get(f"{lam:g}/{s}", [])
            for ax, (k, title) in zip(axes, keys):
                pts = [(e["step"], e[k]) for e in h if k in e]
                if pts:
                    x, y = zip(*pts)
                    ax.plot(x, y, color=colours[i % len(colours)], alpha=0.8, ls=["-", "--", ":"][j % 3],
                            label=f"lambda={lam:g} seed {s}")
                ax.set_title(title, fontsize=9)
                ax.set_xlabel("step")
    axes[0].set_yscale("log")
    axes[1].set_yscale("symlog", linthresh=1e-3)
    axes[-1].legend(fontsize=7)
    fig.tight_layout()
    atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=90), binary=True)


if __name__ == "__main__":
    sys.exit(main())
