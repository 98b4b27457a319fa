"""Public LDraw models (issue 22): how many load whole, how many with
--skip-unsupported and what is left out, bricks, plates, stable, time.

Usage: python benchmarks/ldraw_models.py ROOT [ROOT ...] [--out FILE] [--max-parts 1000]
                                         [--jax-max-parts 700] [--table] [--recheck-export]

Each ROOT is a checkout of a repository of LDraw models, e.g.

    git clone https://github.com/LasseD/buildinginstructions.js
    git clone https://github.com/mjhorvath/Mike-LDraw-Models

Every ``.ldr`` / ``.mpd`` file under a ROOT is read as ``stablelego analyze``
reads it (:func:`stablelego_jax.formats.ldraw.read_ldr`, sub-models beside it
resolved): first whole; if that fails, with ``skip_unsupported``, recording
what was left out ({part: count}). A model that loads is analysed with the
exact solver (HiGHS, the referee) and with the JAX solver, when it has at most
``--max-parts`` (exact) / ``--jax-max-parts`` (JAX) parts; the JAX verdict is
compared with the exact one. Export is checked too: the model written back
to LDraw (:func:`~stablelego_jax.formats.ldraw.layout_to_ldr`) and read
again must give the same parts (positions, sizes, yaws, masses).

Times are wall seconds of one analysis in this process, JAX including its
compilation (each model is a new shape). Rows go to ``--out`` (JSON lines,
default ``results/ldraw_models.jsonl``) as they finish; a rerun skips files
already there. ``--table`` prints the summary and the per-model table
(markdown) from the file.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections import Counter

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402

from rows import append_row, read_rows  # noqa: E402
from stablelego_jax.analysis import analyze_layout  # noqa: E402
from stablelego_jax.formats.ldraw import LDRAW_EXTS, layout_to_ldr, parse_ldr, read_ldr  # noqa: E402
from stablelego_jax.formats.ldraw_parts import BRICK_H, PLATE_H  # noqa: E402
from stablelego_jax.scene import Scene, scene_from_layout  # noqa: E402


def model_files(roots):
    """(name, path) of every LDraw model under the roots, name = root's folder / relative path."""
    for root in roots:
        root = os.path.abspath(root)
        for d, _, files in sorted(os.walk(root)):
            if "/." in d:
                continue
            for f in sorted(files):
                if f.lower().endswith(LDRAW_EXTS):
                    p = os.path.join(d, f)
                    yield os.path.join(os.path.basename(root), os.path.relpath(p, root)), p


def _as_scene(lay) -> Scene:
    return lay if isinstance(lay, Scene) else scene_from_layout(lay)


def same_parts(a, b) -> bool:
    """Do two readings hold the same parts under the same keys (the export
    writes them layer by layer): positions, sizes, yaws, masses?"""
    sa, sb = _as_scene(a), _as_scene(b)
    if sorted(sa.keys) != sorted(sb.keys):
        return False
    where = {k: i for i, k in enumerate(sb.keys)}
    sb = sb.subset([where[k] for k in sa.keys])
    return (np.allclose(sa.pos, sb.pos, atol=1e-6)
            and np.allclose(sa.size, sb.size) and np.allclose(sa.mass, sb.mass)
            and np.allclose((sa.yaw - sb.yaw + 180) % 360 - 180, 0, atol=1e-6))


def heights(lay) -> Counter:
    """{height in plate heights: count}."""
    if isinstance(lay, Scene):
        return Counter(int(round(h)) for h in lay.size[:, 2])
    return Counter({BRICK_H: lay.n})


def round_trip(lay) -> tuple[bool, str]:
    """(same parts after export and re-import, error text)."""
    try:
        return bool(same_parts(lay, parse_ldr(layout_to_ldr(lay), source="<export>"))), ""
    except Exception as exc:
        return False, str(exc)[:200]


def run_one(name: str, path: str, max_parts: int, jax_max_parts: int) -> dict:
    row: dict = {"name": name}
    t = time.perf_counter()
    report: dict = {}
    try:
        lay = read_ldr(path)
        row["load"] = "whole"
    except Exception as exc:
        row["whole_error"] = str(exc).replace(path, "").lstrip(": ")[:300]
        try:
            lay = read_ldr(path, skip_unsupported=True, report=report)
            row["load"] = "skip"
        except Exception as exc2:
            row.update(load="error", error=str(exc2).replace(path, "").lstrip(": ")[:300])
            return row
    row["load_s"] = round(time.perf_counter() - t, 3)
    h = heights(lay)
    row.update(parts=lay.n, bricks=h.get(BRICK_H, 0), plates=h.get(PLATE_H, 0),
               grid=not isinstance(lay, Scene),
               left_out={k: c for k, (c, _) in sorted(report.items(), key=lambda kv: -kv[1][0])},
               n_left_out=sum(c for c, _ in report.values()))
    row["round_trip"], err = round_trip(lay)
    if err:
        row["round_trip_error"] = err
    for solver, cap in (("exact", max_parts), ("jax", jax_max_parts)):
        if lay.n > cap:
            row[solver] = {"skipped": f"more than {cap} parts"}
            continue
        t = time.perf_counter()
        try:
            a = analyze_layout(lay, solver=solver)
        except Exception as exc:
            row[solver] = {"error": str(exc)[:300]}
            continue
        row[solver] = {"stable": bool(a.stable), "failing": int(sum(v >= 1.0 for v in a.scores.values())),
                       "max_score": round(float(max(a.scores.values())), 6), "weakest": a.weakest,
                       "converged": bool(a.converged), "time_s": round(time.perf_counter() - t, 3)}
    return row


def _verdict(r: dict, solver: str) -> str:
    s = r.get(solver) or {}
    if "stable" in s:
        return ("stands" if s["stable"] else f"falls ({s['failing']})") + f", {s['time_s']:.1f} s"
    return s.get("skipped") or s.get("error", "")[:40] or ""


def table(rows: list) -> str:
    n = len(rows)
    by = Counter(r["load"] for r in rows)
    lo: Counter = Counter()
    for r in rows:
        for k, c in (r.get("left_out") or {}).items():
            lo[k.split()[0] if not k.startswith(("drawing", "stud")) else k] += c
    both = [r for r in rows if "stable" in (r.get("exact") or {}) and "stable" in (r.get("jax") or {})]
    agree = sum(r["exact"]["stable"] == r["jax"]["stable"] for r in both)
    out = [f"{n} model files: {by['whole']} load whole, {by['skip']} only with --skip-unsupported, "
           f"{by['error']} not at all (nothing left to analyse, or malformed).",
           f"Export round trip (write LDraw, read back, same parts): "
           f"{sum(bool(r.get('round_trip')) for r in rows if r['load'] != 'error')} of "
           f"{sum(r['load'] != 'error' for r in rows)}.",
           f"Exact vs JAX verdict agree on {agree} of {len(both)} models analysed by both.",
           "Most frequent parts left out: " + ", ".join(f"{k} x{c}" for k, c in lo.most_common(15)) + ".",
           "", "| model | loads | parts (bricks / plates) | left out | exact | JAX | round trip |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["load"] == "error":
            out.append(f"| {r['name']} | no: {r['error'][:70]} | | | | | |")
            continue
        left = ", ".join(f"{k} x{c}" for k, c in list(r["left_out"].items())[:3])
        more = len(r["left_out"]) - 3
        left += f", +{more} kinds" if more > 0 else ""
        out.append(f"| {r['name']} | {r['load']}{' (grid)' if r['grid'] else ''} | {r['parts']} "
                   f"({r['bricks']} / {r['plates']}) | {r['n_left_out']}{': ' + left if left else ''} | "
                   f"{_verdict(r, 'exact')} | {_verdict(r, 'jax')} | {'yes' if r.get('round_trip') else 'NO'} |")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("roots", nargs="*")
    ap.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                                  "ldraw_models.jsonl"))
    ap.add_argument("--max-parts", type=int, default=1000, help="largest model the exact solver analyses")
    ap.add_argument("--jax-max-parts", type=int, default=700, help="largest model the JAX solver analyses")
    ap.add_argument("--table", action="store_true", help="only print the table of --out")
    ap.add_argument("--recheck-export", action="store_true",
                    help="only redo the export round trip of the rows of --out (after a change to the LDraw code)")
    args = ap.parse_args()
    done = read_rows(args.out, "name")
    if args.recheck_export:
        paths = dict(model_files(args.roots))
        for name, row in done.items():
            if row["load"] != "error" and name in paths:
                row["round_trip"], err = round_trip(read_ldr(paths[name], skip_unsupported=True))
                row.pop("round_trip_error", None)
                row.update({"round_trip_error": err} if err else {})
                append_row(args.out, row)
    elif not args.table:
        if not args.roots:
            ap.error("give at least one ROOT (a checkout of a repository of LDraw models)")
        print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs", file=sys.stderr)
        files = list(model_files(args.roots))
        for i, (name, path) in enumerate(files, 1):
            if name in done:
                continue
            row = run_one(name, path, args.max_parts, args.jax_max_parts)
            done[name] = row
            append_row(args.out, row)
            print(f"[{i}/{len(files)}] {name}: {row['load']} {row.get('parts', '')} "
                  f"exact: {_verdict(row, 'exact')}; jax: {_verdict(row, 'jax')}", file=sys.stderr, flush=True)
    print(table(sorted(done.values(), key=lambda r: r["name"])))


if __name__ == "__main__":
    main()
