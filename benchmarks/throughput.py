"""Speed race on a shard: JAX batched scoring vs HiGHS one layout at a time
(issue: batched scoring).

Usage:
  python benchmarks/make_shard.py --n 500            # the shard (once)
  python benchmarks/throughput.py [--shard benchmarks/results/shard500] [--batch 64]

Each solver runs in its own process through ``batch.score_files`` (the code
behind ``stablelego score``), so the peak memory (max RSS) of each is its
own. Prints and writes ``benchmarks/results/throughput.json``: layouts/s end
to end, solve time, compile time (JAX, apart), peak memory, label agreement
and highest-score agreement on stable layouts. Results files are kept, so a
rerun resumes an interrupted solver run (the timing then covers only the
resumed part: delete the results files for a clean measurement).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..")

CHILD = """
import json, resource, sys, time
sys.path.insert(0, {root!r})
from stablelego_jax.batch import score_files
t = time.perf_counter()
st = score_files([{shard!r}], {out!r}, solver={solver!r}, batch={batch}, progress=True,
                 exact_method={method!r})
rec = st.to_json()
rec["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
print("RESULT " + json.dumps(rec))
"""


def run_solver(shard: str, out: str, solver: str, batch: int, method: str) -> dict:
    code = CHILD.format(root=ROOT, shard=shard, out=out, solver=solver, batch=batch, method=method)
    p = subprocess.run([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{solver} run failed (exit {p.returncode})")
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    return json.loads(line[len("RESULT "):])


def load(path: str) -> dict:
    with open(path) as fh:
        return {r["file"]: r for r in map(json.loads, fh)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--shard", default=os.path.join(HERE, "results", "shard500"))
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--only", choices=["jax", "exact"], help="run one solver only")
    ap.add_argument("--exact-method", default="highs", help="HiGHS method (highs, highs-ds, highs-ipm)")
    args = ap.parse_args()
    res_dir = os.path.join(HERE, "results")
    outs = {s: os.path.join(res_dir, f"throughput_{s}.jsonl") for s in ("exact", "jax")}
    summary_path = os.path.join(res_dir, "throughput.json")
    summary = json.load(open(summary_path)) if os.path.exists(summary_path) else {}
    for solver in ("exact", "jax"):
        if args.only and solver != args.only:
            continue
        print(f"== {solver}", file=sys.stderr, flush=True)
        summary[solver] = run_solver(args.shard, outs[solver], solver, args.batch, args.exact_method)
        summary[solver]["exact_method"] = args.exact_method if solver == "exact" else None
        with open(summary_path, "w") as fh:  # each solver's totals are kept as soon as they exist
            json.dump(summary, fh, indent=1)
    if not all(s in summary for s in ("exact", "jax")):
        raise SystemExit(f"run both solvers first (have: {sorted(summary)})")
    a, b = load(outs["exact"]), load(outs["jax"])
    common = [k for k in a if k in b and "error" not in a[k] and "error" not in b[k]]
    lab = sum(a[k]["stable"] == b[k]["stable"] for k in common)
    stab = [k for k in common if a[k]["stable"]]
    close = sum(abs(max(a[k]["scores"].values()) - max(b[k]["scores"].values())) <= 0.02 for k in stab)
    conv = sum(b[k]["converged"] for k in common)
    n_bricks = sorted(a[k]["n_bricks"] for k in common)
    ex, jx = summary["exact"], summary["jax"]
    summary.update(
        machine=f"{platform.machine()}, {os.cpu_count()} cores, CPU only, Python {platform.python_version()}",
        layouts=len(common),
        bricks_median=n_bricks[len(n_bricks) // 2],
        bricks_max=n_bricks[-1],
        label_agreement=lab / max(len(common), 1),
        label_agree_count=lab,
        score_close_stable=f"{close}/{len(stab)}",
        jax_converged=f"{conv}/{len(common)}",
        exact_layouts_per_s=ex["scored"] / ex["wall_s"],
        jax_layouts_per_s_end_to_end=jx["scored"] / jx["wall_s"],
        jax_layouts_per_s_excl_compile=jx["scored"] / (jx["wall_s"] - jx["compile_s"]),
        speed_ratio_end_to_end=(ex["wall_s"] / jx["wall_s"]),
        speed_ratio_excl_compile=(ex["wall_s"] / (jx["wall_s"] - jx["compile_s"])),
    )
    with open(summary_path, "w") as fh:
        json.dump(summary, fh, indent=1)
    for k in ("machine", "layouts", "bricks_median", "bricks_max", "label_agreement", "score_close_stable",
              "jax_converged", "exact_layouts_per_s", "jax_layouts_per_s_end_to_end",
              "jax_layouts_per_s_excl_compile", "speed_ratio_end_to_end", "speed_ratio_excl_compile"):
        print(f"{k}: {summary[k]}")
    for s in ("exact", "jax"):
        print(f"{s}: {json.dumps(summary[s])}")


if __name__ == "__main__":
    main()
