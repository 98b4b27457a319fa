"""Long fuzz run (issue 20): random and malformed layouts (tests/fuzz_cases.py)
through every command, as a user runs them (``python -m stablelego_jax``
subprocesses, each with a time limit).

Per round, ``--per-round`` new cases in a fresh folder:
- ``analyze`` (exact solver) on all of them in one call and ``score`` on the
  folder (exact; then a second ``score`` run must skip everything);
- ``export --ldr --json --txt`` of each case;
- ``sequence`` and ``repair --png`` of every ``--slow-every``-th case;
- ``generate`` of a junk, empty or valid mesh every round.

Counts per (case, command): tried, ok (a valid result), clear error (one line
naming the file, no Python exception name), traceback (a traceback or an
exception name in the message), wrong result (a result that does not fit
its input: keys, labels, exported layout, a missing or extra line, exit 0
with errors), half-written (an output or a temporary file left by a failed
command, or an unreadable output of a successful one), hang (time limit).

    python benchmarks/fuzz.py --budget 600 --seed 20
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "tests"))

from fuzz_cases import EXC_NAME, KINDS, classify_error, make_case  # noqa: E402
from stablelego_jax.formats.reader import load_layout  # noqa: E402

VALID = {"valid_json", "valid_text", "valid_far"}
COUNTS = ("tried", "ok", "clear error", "traceback", "wrong result", "half-written", "hang")


def run(argv, timeout):
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    try:
        p = subprocess.run([sys.executable, "-m", "stablelego_jax", *argv], capture_output=True, text=True,
                           timeout=timeout, env=env)
        return p.returncode, p.stdout, p.stderr
    except subprocess.TimeoutExpired:
        return None, "", ""


def fits(rec, path) -> bool:
    try:
        lay = load_layout(path)
    except Exception:
        return False
    s = rec.get("scores", {})
    return set(s) == set(lay.keys) and rec["stable"] == all(v < 1 for v in s.values()) and rec["weakest"] in s


def judge_error(c, cmd, line, *paths):
    if "Traceback" in line or EXC_NAME.search(line):
        c[cmd, "traceback"] += 1
        return line
    c[cmd, classify_error(line, *paths) == "clear" and "clear error" or "wrong result"] += 1
    return None


def leftovers(folder):
    return [f for f in os.listdir(folder) if f.startswith(".tmp")]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", type=float, default=600, help="seconds (default 600)")
    ap.add_argument("--seed", type=int, default=20)
    ap.add_argument("--per-round", type=int, default=60)
    ap.add_argument("--slow-every", type=int, default=15)
    ap.add_argument("--timeout", type=float, default=120, help="seconds per command before it counts as a hang")
    ap.add_argument("--json", help="write the counts here")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    c: collections.Counter = collections.Counter()
    bad: list = []
    t0 = time.time()
    work = tempfile.mkdtemp(prefix="stablelego-fuzz-")
    mesh_dir = os.path.join(ROOT, "..", "shared", "meshes")
    rnd = 0
    try:
        while time.time() - t0 < args.budget:
            d = os.path.join(work, f"r{rnd}")
            outd = os.path.join(work, f"o{rnd}")
            os.makedirs(d)
            os.makedirs(outd)
            cases = [make_case(rng, d, i) for i in range(args.per_round)]
            kinds = dict(cases)
            # analyze, all in one call
            rc, out, err = run(["analyze", *kinds, "--solver", "exact", "--json"], args.timeout)
            c["analyze", "tried"] += len(cases)
            if rc is None:
                c["analyze", "hang"] += len(cases)
            else:
                recs = [json.loads(ln) for ln in out.splitlines() if ln.startswith("{")]
                if "Traceback" in err:
                    c["analyze", "traceback"] += 1
                    bad.append(("analyze", err[-300:]))
                if [r["file"] for r in recs] != list(kinds):
                    c["analyze", "wrong result"] += 1
                    bad.append(("analyze", "lines do not match the files"))
                n_err = 0
                for r in recs:
                    if "error" in r:
                        n_err += 1
                        if kinds.get(r["file"]) in VALID:
                            c["analyze", "wrong result"] += 1
                            bad.append(("analyze", r["error"]))
                        elif judge_error(c, "analyze", r["error"], r["file"]) is not None:
                            bad.append(("analyze", r["error"]))
                    elif fits(r, r["file"]):
                        c["analyze", "ok"] += 1
                    else:
                        c["analyze", "wrong result"] += 1
                        bad.append(("analyze", json.dumps(r)[:300]))
                if (rc == 0) != (n_err == 0):
                    c["analyze", "wrong result"] += 1
                    bad.append(("analyze", f"exit {rc} with {n_err} errors"))
            # score the folder, then again (resume: nothing left to do)
            res = os.path.join(outd, "r.jsonl")
            rc, out, err = run(["score", d, "--out", res, "--solver", "exact", "--quiet"], args.timeout)
            c["score", "tried"] += len(cases)
            if rc is None:
                c["score", "hang"] += len(cases)
            else:
                recs = {}
                with open(res, encoding="utf-8") as fh:
                    for ln in fh:
                        if not ln.endswith("\n"):
                            c["score", "half-written"] += 1
                        r = json.loads(ln)
                        recs[r["file"]] = r
                if "Traceback" in err:
                    c["score", "traceback"] += 1
                    bad.append(("score", err[-300:]))
                if set(recs) != set(kinds):
                    c["score", "wrong result"] += 1
                    bad.append(("score", "lines do not match the files"))
                n_err = sum("error" in r for r in recs.values())
                for f, r in recs.items():
                    if "error" in r:
                        if kinds.get(f) in VALID or judge_error(c, "score", r["error"], f) is not None:
                            bad.append(("score", r["error"]))
                    elif fits(r, f):
                        c["score", "ok"] += 1
                    else:
                        c["score", "wrong result"] += 1
                if (rc == 0) != (n_err == 0):
                    c["score", "wrong result"] += 1
                    bad.append(("score", f"exit {rc} with {n_err} errors"))
                rc2, _, err2 = run(["score", d, "--out", res, "--solver", "exact", "--quiet"], args.timeout)
                if rc2 is None or f"0 scored, {len(cases)} already" not in err2:
                    c["score", "wrong result"] += 1
                    bad.append(("score", "rerun: " + err2[-200:]))
            # export each case to three formats (all or nothing)
            for i, (path, kind) in enumerate(cases):
                outs = [os.path.join(outd, f"e{i}{ext}") for ext in (".ldr", ".json", ".txt")]
                rc, out, err = run(["export", path, "--ldr", outs[0], "--json", outs[1], "--txt", outs[2]],
                                   args.timeout)
                c["export", "tried"] += 1
                if rc is None:
                    c["export", "hang"] += 1
                elif rc == 0:
                    try:
                        a = load_layout(path)

                        def cells(lay, ground):  # LDraw reading puts the lowest layer on the baseplate
                            p = lay.pos - [0, 0, int(lay.pos[:, 2].min())] if ground else lay.pos
                            return sorted(map(tuple, p.tolist()))

                        ok = all(cells(load_layout(o), o.endswith(".ldr")) == cells(a, o.endswith(".ldr"))
                                 for o in outs)
                    except Exception as exc:
                        ok = False
                        bad.append(("export", f"{path}: {exc}"))
                    c["export", "ok" if ok else "wrong result"] += 1
                    if not ok:
                        bad.append(("export", f"{path} ({kind}): exported layout differs"))
                else:
                    if any(os.path.exists(o) for o in outs):
                        c["export", "half-written"] += 1
                        bad.append(("export", f"{path}: output left after exit {rc}"))
                    lines = err.strip().splitlines()
                    if kind in VALID and not any("cannot express" in ln or "text" in ln for ln in lines):
                        c["export", "wrong result"] += 1
                        bad.append(("export", err[-300:]))
                    elif len(lines) != 1 or judge_error(c, "export", lines[0], path, *outs) is not None:
                        if len(lines) != 1:
                            c["export", "traceback" if "Traceback" in err else "wrong result"] += 1
                        bad.append(("export", err[-300:]))
                for o in outs:
                    if os.path.exists(o):
                        os.unlink(o)
            # sequence and repair of a few cases
            for i, (path, kind) in enumerate(cases[:: args.slow_every]):
                for cmd, extra in (("sequence", ["--solver", "exact"]),
                                   ("repair", ["--out", os.path.join(outd, f"rep{i}" + os.path.splitext(path)[1]),
                                               "--png", os.path.join(outd, f"rep{i}.png"), "--max-add", "1",
                                               "--method", "greedy"])):
                    rc, out, err = run([cmd, path, *extra], args.timeout)
                    c[cmd, "tried"] += 1
                    if rc is None:
                        c[cmd, "hang"] += 1
                        continue
                    if "Traceback" in err:
                        c[cmd, "traceback"] += 1
                        bad.append((cmd, err[-300:]))
                    elif rc != 0 and not out.strip():
                        lines = err.strip().splitlines()
                        if len(lines) == 1 and judge_error(c, cmd, lines[0], path) is None:
                            pass
                        else:
                            c[cmd, "wrong result"] += len(lines) != 1
                            bad.append((cmd, err[-300:]))
                    else:
                        c[cmd, "ok"] += 1
                    if cmd == "repair":
                        written = [f for f in os.listdir(outd) if f.startswith(f"rep{i}")]
                        # OUT only on success; the before/after PNG also after "still UNSTABLE" (exit 1
                        # with a report on stdout), never after an error line
                        out_file = [f for f in written if not f.endswith(".png")]
                        if rc != 0 and (out_file or (written and not out.strip())):
                            c[cmd, "half-written"] += 1
                            bad.append((cmd, f"{path}: {written} left after exit {rc}"))
                        for f in written:
                            os.unlink(os.path.join(outd, f))
            # generate from a junk, empty, truncated or valid mesh
            m = os.path.join(d, f"mesh{rnd}" + str(rng.choice([".stl", ".obj", ".ply", ".off"])))
            meshes = sorted(f for f in os.listdir(mesh_dir)) if os.path.isdir(mesh_dir) else []
            pick = int(rng.integers(0, 4))
            if pick == 0:
                open(m, "wb").write(rng.integers(0, 256, int(rng.integers(0, 3000)), dtype=np.uint8).tobytes())
            elif pick == 1:
                open(m, "wb").close()
            elif meshes:
                src = os.path.join(mesh_dir, str(rng.choice([f for f in meshes if f.lower().endswith(
                    (".stl", ".obj", ".ply", ".off"))])))
                m = os.path.join(d, f"mesh{rnd}{os.path.splitext(src)[1]}")
                data = open(src, "rb").read()
                open(m, "wb").write(data if pick == 2 else data[: int(rng.integers(0, len(data)))])
            gout = os.path.join(outd, "gen")
            rc, out, err = run(["generate", m, "--out", gout, "--grid", "8", "--solver", "exact", "--quiet",
                                "--no-vis"], args.timeout)
            c["generate", "tried"] += 1
            if rc is None:
                c["generate", "hang"] += 1
            elif "Traceback" in err:
                c["generate", "traceback"] += 1
                bad.append(("generate", err[-300:]))
            elif rc == 0:
                c["generate", "ok"] += 1
            else:
                lines = [ln for ln in err.strip().splitlines() if ln.startswith("error")]
                if len(lines) == 1:
                    if judge_error(c, "generate", lines[0], m) is not None:
                        bad.append(("generate", lines[0]))
                    if os.path.isdir(gout) and os.listdir(gout):
                        c["generate", "half-written"] += 1
                else:
                    c["generate", "wrong result"] += 1
                    bad.append(("generate", err[-300:]))
            leftover = leftovers(outd) + leftovers(d)
            if leftover:
                c["all", "half-written"] += len(leftover)
                bad.append(("all", str(leftover)))
            shutil.rmtree(d)
            shutil.rmtree(outd)
            rnd += 1
            print(f"round {rnd}: {time.time() - t0:.0f} s, {sum(v for (_, k), v in c.items() if k == 'tried')} tried",
                  file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    cmds = sorted({cmd for cmd, _ in c})
    table = {cmd: {k: c[cmd, k] for k in COUNTS} for cmd in cmds}
    table["total"] = {k: sum(c[cmd, k] for cmd in cmds) for k in COUNTS}
    print(f"{'command':10s} " + " ".join(f"{k:>13s}" for k in COUNTS))
    for cmd, row in table.items():
        print(f"{cmd:10s} " + " ".join(f"{row[k]:13d}" for k in COUNTS))
    print(f"{rnd} rounds, seed {args.seed}, {time.time() - t0:.0f} s")
    for cmd, msg in bad[:30]:
        print(f"  {cmd}: {msg}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"counts": table, "rounds": rnd, "examples": bad[:100]}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
