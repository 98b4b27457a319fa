"""Every core, measured: ``stablelego score`` on one input set under several
ways of using the cores (issue 17, item 1), each in its own process(es),
first run (empty compilation cache) and second run (warm cache).

Usage:
  python benchmarks/cores.py [--inputs benchmarks/results/small500] [--configs a,b,...] [--runs 2]

Configurations (``--configs``):
  jax-1proc      JAX, one process, one device (``--jobs 1``)
  jax-pool       JAX, ``--jobs 2``: a pool of 2 worker processes, one device each (the default on 2 cores)
  jax-2dev       JAX, one process, 2 host devices, each its share of a batch (``--jobs 1``)
  jax-2proc      JAX, 2 processes at once (``--shard 0/2`` and ``1/2``, ``--jobs 1`` each)
  exact-1        HiGHS, one process
  exact-2        HiGHS, ``--jobs 2`` (a pool of 2 worker processes)
  auto-2         ``--solver auto --jobs 2``: each group of layouts by whichever of JAX and HiGHS
                 is estimated faster (HiGHS on a pool of 2 workers, JAX in a pool of 2); the run
                 records how many layouts each solver answered ("by_solver")
  vertex-2       HiGHS' optimal vertex without the canonical (least-norm) stage, ``--jobs 2``:
                 ``score_files(..., params=Params(ridge=0))`` in a child process, as no
                 command-line flag turns the canonical stage off; labels are the same
                 (one optimal cost), scores of tied layouts are not
  exact-N, vertex-N  the same with ``--jobs N`` (any N: every core of a larger machine)
  jax-gpu        JAX on its default backend (a GPU where one is installed, not forced to
                 the CPU as the others are), every local device, ``--jobs`` left at its
                 default: the command's own choice on that machine

Every JAX process has one XLA pool thread (``PJRT_NPROC=1``, set by the
package on jaxlib 0.10: ``stablelego_jax.blas``); the flags of session 8's
configurations (XLA's Eigen pool on or off) no longer change that.
Each run is the real command line in a subprocess (``python -m
stablelego_jax score ...``) with its own cache folder
(``STABLELEGO_CACHE_DIR``), so run 1 compiles everything and run 2 reads
the compiled solvers from disk. Wall time is measured around the
process(es); solve and compile time are the command's own summary line;
peak memory is the child's max RSS (``os.wait4``). Labels and highest
scores of every JAX run are compared with the exact run's.
Writes ``benchmarks/results/cores.json``; ``--keep DIR`` keeps every run's
results file there, ``--ref FILE`` compares against a kept exact run's
results when this invocation runs no exact configuration.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

CONFIGS = {
    "jax-1proc": dict(solver="jax", procs=1, jobs=1, devices="1"),
    "jax-pool": dict(solver="jax", procs=1, jobs=2, devices="1"),
    "jax-2dev": dict(solver="jax", procs=1, jobs=1, xla="--xla_force_host_platform_device_count=2", devices="2"),
    "jax-2proc": dict(solver="jax", procs=2, jobs=1, devices="1"),
    "exact-1": dict(solver="exact", procs=1, jobs=1),
    "exact-2": dict(solver="exact", procs=1, jobs=2),
    "auto-2": dict(solver="auto", procs=1, jobs=2, devices="1"),
    "vertex-2": dict(solver="exact", procs=1, jobs=2, vertex=True),
    "jax-gpu": dict(solver="jax", procs=1, jobs=None, devices="all", platform=None),
}


def config(name: str) -> dict:
    """CONFIGS[name], or ``exact-N`` / ``vertex-N`` for any N."""
    if name in CONFIGS:
        return CONFIGS[name]
    m = re.fullmatch(r"(exact|vertex)-(\d+)", name)
    if not m:
        raise SystemExit(f"unknown configuration {name!r} (known: {', '.join(CONFIGS)}, exact-N, vertex-N)")
    return dict(solver="exact", procs=1, jobs=int(m.group(2)), vertex=m.group(1) == "vertex")
VERTEX = """
import sys
from stablelego_jax.batch import score_files
from stablelego_jax.model import Params
st = score_files(sys.argv[3:], sys.argv[1], solver="exact", params=Params(ridge=0.0), jobs=int(sys.argv[2]),
                 progress=False)
print(f"solve {st.solve_s:.1f} s, compile {st.compile_s:.1f} s ({st.compiles} shapes), wall {st.wall_s:.1f} s",
      file=sys.stderr)
"""
SUMMARY = re.compile(r"solve ([\d.]+) s, compile ([\d.]+) s \((\d+) shapes\), wall ([\d.]+) s")


def run_config(name: str, inputs: list, work: str, cache: str, run: int) -> dict:
    cfg = config(name)
    env = dict(os.environ, STABLELEGO_CACHE_DIR=cache, JAX_PLATFORMS=cfg.get("platform", "cpu") or "")
    if "xla" in cfg:
        env["XLA_FLAGS"] = cfg["xla"]
    procs, outs = [], []
    t0 = time.perf_counter()
    for k in range(cfg["procs"]):
        out = os.path.join(work, f"{name}-run{run}-{k}.jsonl")
        if os.path.exists(out):
            os.remove(out)
        if cfg.get("vertex"):
            cmd = [sys.executable, "-c", VERTEX, out, str(cfg["jobs"]), *inputs]
        else:
            cmd = [sys.executable, "-m", "stablelego_jax", "score", *inputs, "--out", out, "--quiet",
                   "--solver", cfg["solver"]] + (["--jobs", str(cfg["jobs"])] if cfg["jobs"] else [])
            if cfg["solver"] in ("jax", "auto"):
                cmd += ["--devices", cfg["devices"]]
            if cfg["procs"] > 1:
                cmd += ["--shard", f"{k}/{cfg['procs']}"]
        procs.append(subprocess.Popen(cmd, env=env, cwd=ROOT, stderr=subprocess.PIPE, text=True))
        outs.append(out)
    rec = dict(config=name, run=run, solve_s=0.0, compile_s=0.0, shapes=0, peak_rss_mb=0.0, outs=outs)
    for p in procs:
        _, status, ru = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        err = p.stderr.read()
        m = SUMMARY.search(err)
        if p.returncode not in (0, 1) or not m:
            # a configuration that fails (or is refused) is recorded, the others go on
            for q in procs:
                if q.poll() is None:
                    q.kill()
            return dict(config=name, run=run, failed=f"exit {p.returncode}: {err.strip()[-300:]}", outs=[])
        rec["solve_s"] += float(m.group(1))
        rec["compile_s"] += float(m.group(2))
        rec["shapes"] += int(m.group(3))
        # ru_maxrss of a child: its own peak (KiB on Linux), not its children's
        # (a pool's workers are not counted)
        rec["peak_rss_mb"] = max(rec["peak_rss_mb"], ru.ru_maxrss / 1024.0)
    rec["wall_s"] = time.perf_counter() - t0
    by: dict = {}
    for r in results(outs).values():
        by[r.get("solver", "error")] = by.get(r.get("solver", "error"), 0) + 1
    rec["by_solver"] = by
    return rec


def results(paths: list) -> dict:
    out = {}
    for p in paths:
        with open(p) as fh:
            for line in fh:
                r = json.loads(line)
                out[r["file"]] = r
    return out


def agreement(ref: dict, got: dict) -> dict:
    both = [k for k in ref if "error" not in ref[k] and k in got and "error" not in got[k]]
    lab = sum(ref[k]["stable"] == got[k]["stable"] for k in both)
    hi = sum(abs(max(ref[k]["scores"].values(), default=0) - max(got[k]["scores"].values(), default=0)) < 1e-3
             for k in both)
    return dict(compared=len(both), labels_agree=lab, highest_score_agree=hi)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", nargs="+", default=[os.path.join(HERE, "results", "small500")])
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--runs", type=int, default=2, help="1: first run only; 2: first and warm")
    ap.add_argument("--out", default=os.path.join(HERE, "results", "cores.json"))
    ap.add_argument("--keep", help="folder to keep every run's results file in")
    ap.add_argument("--ref", nargs="+", help="results file(s) of an exact run to compare with "
                    "(default: this invocation's exact run)")
    args = ap.parse_args()
    names = args.configs.split(",")
    for name in names:
        config(name)
    meta = dict(command="python benchmarks/cores.py " + " ".join(sys.argv[1:]), machine=platform.machine(),
                cpus=os.cpu_count(), python=platform.python_version(), date=time.strftime("%Y-%m-%d"),
                accelerator=accelerator())
    work = tempfile.mkdtemp(prefix="stablelego-cores-")
    recs = []

    def dump() -> None:  # after every run, so that a run cut short keeps what it measured
        with open(args.out, "w") as fh:
            json.dump(dict(meta=meta, runs=[{k: v for k, v in r.items() if k != "outs"} for r in recs]), fh, indent=1)
    try:
        for name in names:
            cache = os.path.join(work, f"cache-{name}")
            for run in range(1, args.runs + 1):
                rec = run_config(name, args.inputs, work, cache, run)
                recs.append(rec)
                dump()
                if args.keep:
                    os.makedirs(args.keep, exist_ok=True)
                    for o in rec["outs"]:
                        shutil.copy(o, os.path.join(args.keep, os.path.basename(o)))
                if "failed" in rec:
                    print(f"{name:10s} run {run}: FAILED {rec['failed']}", flush=True)
                    break
                print(f"{name:10s} run {run}: wall {rec['wall_s']:7.1f} s  solve {rec['solve_s']:7.1f} s  "
                      f"compile {rec['compile_s']:7.1f} s ({rec['shapes']} shapes)  peak {rec['peak_rss_mb']:.0f} MB",
                      flush=True)
        ref = results(args.ref) if args.ref else next(
            (results(r["outs"]) for r in recs if r["config"].startswith("exact")), None)
        for r in recs:
            if ref is not None and not r["config"].startswith("exact") and "failed" not in r:
                r.update(agreement(ref, results(r["outs"])))
                print(f"{r['config']:10s} run {r['run']}: labels {r['labels_agree']}/{r['compared']}, "
                      f"highest score (1e-3) {r['highest_score_agree']}/{r['compared']}")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    dump()


def accelerator() -> str | None:
    """The GPU's name by ``nvidia-smi`` (None where there is none)."""
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return (out.stdout.strip() or None) if out.returncode == 0 else None


if __name__ == "__main__":
    main()
