"""One ``stablelego analyze --json`` over many files (issue 20): one line per
file, executables bounded, resident memory flat after warm-up.

Usage:
  python benchmarks/analyze_many.py [--n 1000] [--solver jax exact]
      [--method ours] [--dir DIR] [--out benchmarks/results/analyze_many.json]

The files: the ``small`` recipe of ``benchmarks/make_shard.py`` (stairs,
towers, levers, voxel shapes, bridges, walls, pallets, floating bricks;
median about a dozen bricks), written once to ``--dir`` (default: a
folder under the system's temp dir, reused when it holds ``--n`` files).
For each solver, one process as a user starts it
(``python -m stablelego_jax analyze --json --solver S FILE...``, all files
in one call); while it runs, its resident memory (``VmRSS``) and memory
mappings (lines of ``/proc/PID/maps``: the resource whose exhaustion once
crashed a long run) are sampled every 0.2 s and tied to the number of
output lines so far. Reported per solver: exit code, output lines, files
without a line, lines that are errors, wall time, peak RSS and mappings,
RSS / mappings after 10%, 25%, 50%, 75% and 100% of the files, and the
RSS growth over the last quarter and over the second half of the run.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)
sys.path.insert(0, HERE)

from stablelego_jax.files import atomic_write_text  # noqa: E402


def make_files(n: int, folder: str) -> list[str]:
    """``n`` layout files in ``folder`` (written by make_shard.py once)."""
    have = sorted(f for f in os.listdir(folder) if f.endswith(".json")) if os.path.isdir(folder) else []
    if len(have) != n:
        if os.path.isdir(folder):
            raise SystemExit(f"{folder}: holds {len(have)} layouts, not {n}; remove it or pick another --dir")
        subprocess.run([sys.executable, os.path.join(HERE, "make_shard.py"), "--n", str(n),
                        "--recipe", "small", "--out", folder, "--seed", "20"], check=True)
        have = sorted(f for f in os.listdir(folder) if f.endswith(".json"))
    return [os.path.join(folder, f) for f in have]


def _status(pid: int) -> tuple[float, int]:
    """(resident MB, memory mappings) of a live process; (nan, -1) once gone."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            rss = next(int(line.split()[1]) for line in fh if line.startswith("VmRSS:")) / 1024.0
        with open(f"/proc/{pid}/maps") as fh:
            maps = sum(1 for _ in fh)
        return rss, maps
    except (OSError, StopIteration):
        return float("nan"), -1


def run_one(files: list[str], solver: str, method: str) -> dict:
    """Run one analyze process over ``files``; the record of it."""
    cmd = [sys.executable, "-m", "stablelego_jax", "analyze", "--json", "--method", method]
    if method == "ours":
        cmd += ["--solver", solver]
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd + files, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    lines: list[str] = []
    samples: list[tuple[float, int, float, int]] = []  # (t, lines so far, rss MB, maps)
    err: list[str] = []

    def read_out():
        for line in proc.stdout:
            lines.append(line)

    def read_err():
        for line in proc.stderr:
            err.append(line)

    threads = [threading.Thread(target=read_out, daemon=True), threading.Thread(target=read_err, daemon=True)]
    for t in threads:
        t.start()
    last = -1
    while proc.poll() is None:
        rss, maps = _status(proc.pid)
        if maps >= 0:
            samples.append((time.perf_counter() - t0, len(lines), rss, maps))
        n_done = len(lines)
        if n_done // 100 != last:
            last = n_done // 100
            print(f"  {solver}/{method}: {n_done}/{len(files)} files, {rss:.0f} MB, {maps} mappings",
                  file=sys.stderr, flush=True)
        time.sleep(0.2)
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    seen, bad = set(), 0
    for line in lines:
        try:
            rec = json.loads(line)
        except ValueError:
            bad += 1
            continue
        seen.add(os.path.abspath(rec.get("file", "")))
        if "error" in rec:
            bad += 1
    missing = [f for f in files if os.path.abspath(f) not in seen]

    def at(frac):
        k = frac * len(files)
        best = [s for s in samples if s[1] <= k]
        s = best[-1] if best else samples[0]
        return {"files": s[1], "rss_mb": round(s[2], 1), "maps": s[3]}

    marks = {f"{int(100 * f)}%": at(f) for f in (0.1, 0.25, 0.5, 0.75, 1.0)} if samples else {}
    out = dict(solver=solver, method=method, files=len(files), exit=proc.returncode, lines=len(lines),
               missing=len(missing), error_lines=bad, wall_s=round(wall, 1),
               peak_rss_mb=round(max((s[2] for s in samples), default=float("nan")), 1),
               peak_maps=max((s[3] for s in samples), default=-1), marks=marks,
               stderr_tail=[e.rstrip() for e in err[-3:]])
    if marks:
        half, end = marks["50%"]["rss_mb"], marks["100%"]["rss_mb"]
        q3 = marks["75%"]["rss_mb"]
        out["rss_growth_last_quarter_mb"] = round(end - q3, 1)
        out["rss_growth_second_half_mb"] = round(end - half, 1)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--solver", nargs="+", default=["jax", "exact"])
    ap.add_argument("--method", nargs="+", default=["ours"], help="ours, luo, eb (the baselines run on exact)")
    ap.add_argument("--dir", default=os.path.join(tempfile.gettempdir(), "stablelego_analyze_many"))
    ap.add_argument("--out", default=os.path.join(HERE, "results", "analyze_many.json"))
    a = ap.parse_args(argv)
    files = make_files(a.n, os.path.join(a.dir, f"n{a.n}"))
    rows = []
    for method in a.method:
        for solver in (a.solver if method == "ours" else ["exact"]):
            rows.append(run_one(files, solver, method))
            print(json.dumps({k: v for k, v in rows[-1].items() if k != "marks"}), flush=True)
    atomic_write_text(a.out, json.dumps({"date": time.strftime("%Y-%m-%d"), "n": a.n, "runs": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
