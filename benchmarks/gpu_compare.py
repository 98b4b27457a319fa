"""Labels and highest scores of the GPU runs of ``benchmarks/gpu.sh``
against its HiGHS runs (the referee), and each run's summary line.

Usage:
  python benchmarks/gpu_compare.py DIR [--ref NAME=FILE ...] [--json OUT]

DIR: the unpacked gpu.tgz. ``--ref shard_exact=FILE`` adds a results file
to a HiGHS run's lines (for example the layouts a run cut short did not
reach, scored apart on another machine). ``--json``: the table, the loss
steps' JSON objects and the log's first lines (the device) in one file.
"""
from __future__ import annotations

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from cores import SUMMARY, agreement, results  # noqa: E402


def reference(name: str) -> str | None:
    """The HiGHS run a JAX run is compared with: ``SET_exact`` for ``SET_jax_*``."""
    return name.split("_jax_")[0] + "_exact" if "_jax_" in name else None


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir")
    ap.add_argument("--ref", nargs="*", default=[], metavar="NAME=FILE")
    ap.add_argument("--json")
    ap.add_argument("--log", nargs="*", default=[], help="the calls' log.txt files (kept in the JSON)")
    a = ap.parse_args(argv)
    extra: dict = {}
    for spec in a.ref:
        name, path = spec.split("=", 1)
        extra.setdefault(name, []).append(path)
    rows = []
    for name in sorted(f[:-6] for f in os.listdir(a.dir) if f.endswith(".jsonl")):
        got = results([os.path.join(a.dir, name + ".jsonl")])
        err_path = os.path.join(a.dir, name + ".err")
        m = SUMMARY.search(open(err_path).read()) if os.path.exists(err_path) else None
        row = dict(run=name, lines=len(got))
        if m:
            row.update(solve_s=float(m.group(1)), compile_s=float(m.group(2)), shapes=int(m.group(3)),
                       wall_s=float(m.group(4)))
        ref_name = reference(name)
        if ref_name and os.path.exists(os.path.join(a.dir, ref_name + ".jsonl")):
            ref = results([os.path.join(a.dir, ref_name + ".jsonl")] + extra.get(ref_name, []))
            row.update(ref=ref_name, **agreement(ref, got))
        rows.append(row)
        line = f"{name:18s} {len(got):5d} lines"
        line += (f"  solve {row['solve_s']} s, compile {row['compile_s']} s ({row['shapes']} shapes), "
                 f"wall {row['wall_s']} s" if m else "  (no summary line: cut short)")
        if "ref" in row:
            line += (f"  vs {ref_name}: labels {row['labels_agree']}/{row['compared']}, "
                     f"highest score (1e-3) {row['highest_score_agree']}/{row['compared']}")
        print(line)
    if a.json:
        loss = {}
        for f in ("loss2000.json", "batch32.json"):
            p = os.path.join(a.dir, f)
            if os.path.exists(p) and os.path.getsize(p):
                loss[f[:-5]] = json.load(open(p))
        logs = [open(p).read().splitlines() for p in a.log]
        with open(a.json, "w") as fh:
            json.dump(dict(runs=rows, loss=loss, logs=logs), fh, indent=1)


if __name__ == "__main__":
    main()
