"""Labels and highest scores of the GPU runs of ``benchmarks/gpu.sh``
against its HiGHS runs (the referee), and each run's summary line.

Usage:
  python benchmarks/gpu_compare.py DIR   (DIR: the unpacked gpu.tgz)
"""
from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from cores import SUMMARY, agreement, results  # noqa: E402

PAIRS = {"small_jax_first": "small_exact", "small_jax_warm": "small_exact", "shard_jax_first": "shard_exact"}


def main(d: str) -> None:
    for name in sorted(f[:-6] for f in os.listdir(d) if f.endswith(".jsonl")):
        got = results([os.path.join(d, name + ".jsonl")])
        err = open(os.path.join(d, name + ".err")).read() if os.path.exists(os.path.join(d, name + ".err")) else ""
        m = SUMMARY.search(err)
        line = f"{name:18s} {len(got):5d} lines"
        if m:
            line += f"  solve {m.group(1)} s, compile {m.group(2)} s ({m.group(3)} shapes), wall {m.group(4)} s"
        else:
            line += "  (no summary line: cut short)"
        ref_name = PAIRS.get(name)
        if ref_name and os.path.exists(os.path.join(d, ref_name + ".jsonl")):
            a = agreement(results([os.path.join(d, ref_name + ".jsonl")]), got)
            line += (f"  vs {ref_name}: labels {a['labels_agree']}/{a['compared']}, "
                     f"highest score (1e-3) {a['highest_score_agree']}/{a['compared']}")
        print(line)


if __name__ == "__main__":
    main(sys.argv[1])
