"""Score a trained generator on the held-out shapes with the exact solver.

    stablelego evaluate --checkpoint OUT/checkpoint.npz --out RESULTS.jsonl
        [--heuristic] [--untrained] [--refine SECONDS] [--refine-solves N] [--size-prior BETA]
        [--split heldout|val|train|fresh [--fresh N]] [--layouts DIR]

Decodes two layouts per shape: "generator" (greedy, probabilities >= the
config's ``threshold``, no overlaps, nothing forced in: cells can stay
empty, IoU < 1) and "generator_filled" (the same, then the remaining
cells filled greedily by the most probable valid placements that fit:
IoU 1 by construction), scores it with HiGHS
(:func:`stablelego_jax.analysis.analyze_layout` with ``solver="exact"``) and
writes one JSON line per shape: name, kind, method, stable, iou, n_bricks,
n_cells. ``--heuristic`` adds the StableLego merge rule
(:func:`stablelego_jax.generate.voxels.merge_voxels`, exact cover: IoU 1) on the same
shapes; ``--untrained`` adds the same two decodings of the checkpoint's
network at initialisation ("untrained", "untrained_filled": same config
and seed, no training step), the reference that shows what training
added. ``--refine SECONDS`` adds "generator_refined": the filled decoding
refined per shape by :func:`stablelego_jax.generate.stabilize.stabilize`
started from it (its random re-merge rounds around the failing bricks, each
cover judged by the exact solver; no heuristic seeds, no gradient move, at
most SECONDS a shape; ``--refine-solves N``: at most N exact solves a
shape, alone or with SECONDS, whichever is spent first; the search follows
one path, so N alone gives the same rows on any machine and under any
load, where a wall-clock budget lets a slower run stop earlier): IoU 1,
stands by the exact solver or not; with
``--heuristic`` also "heuristic_refined", the same refinement started from
the merge (the control: what the generator's start adds). ``--size-prior
BETA`` decodes in the order probability x (brick area)^BETA instead of
probability (:func:`stablelego_jax.train.net.decode`): the generator's
rows, and with them the starts of the refinement, then carry
``size_prior``; the heuristic's rows do not depend on it. ``--split
fresh`` scores N (``--fresh``, default
:data:`~stablelego_jax.train.shapes.FRESH_COUNT`) procedural objects of the
config's recipe that are in none of its splits
(:func:`stablelego_jax.train.shapes.fresh_shapes`): more shapes for a
choice made on validation, with no retraining. ``--layouts DIR`` also
writes every layout a row scored, as StableLego JSON with the default
library's ids in the shape's voxel grid (``[x, y, z]`` cell indices), to
``DIR/METHOD/SHAPE.json``, and names it in the row's ``layout``: what the
generator built, its refinement and the merge, to look at or to learn
from (an empty decoding has no file). The summary
(stable fraction, mean IoU per method) goes to stdout, a line per shape
refined to stderr; the results file and the layouts are written together
at the end, all or nothing.
"""
from __future__ import annotations

import json
import os
import sys
import time

import numpy as np

from ..blas import one_blas_thread
from ..files import staged_outputs
from ..generate.voxels import merge_voxels
from ..layout import LayoutError
from ..runtime import x64
from .train import (decoded_layouts, initial_params, load_checkpoint, make_fns, score_decoded, score_layout,
                    shape_arrays, split_shapes)

__all__ = ["evaluate", "refined_rows", "write_results", "summary", "run"]


@x64
def evaluate(ckpt: str, split: str = "heldout", heuristic: bool = False, untrained: bool = False,
             refine: float | None = None, log=None, refine_solves: int | None = None,
             size_prior: float = 0.0, n_fresh: int | None = None, layouts: dict | None = None) -> list[dict]:
    """Rows (one per shape and method) for the checkpoint ``ckpt``
    (``refine``: seconds of refinement per shape, ``refine_solves``: exact
    solves per shape, either or both; ``size_prior``: the decoding's beta;
    ``n_fresh``: the shapes of the split "fresh" (None: the default); see
    the module docstring; ``log``: a stream for a line per shape
    refined; ``layouts``: a dict to fill with {(method, shape name):
    Layout} for every row with a layout, in the shape's voxel grid)."""
    refining = refine is not None or refine_solves is not None
    params, _, step, _, cfg, _ = load_checkpoint(ckpt)
    shapes = split_shapes(cfg, split, n_fresh)
    arr = shape_arrays(shapes, cfg)
    probs_fn = make_fns(cfg)[0]
    prior = {"size_prior": float(size_prior)} if size_prior else {}
    nets = [("generator", params, step)]
    if untrained:
        nets.append(("untrained", initial_params(cfg), 0))
    rows = []
    for name, prm, st in nets:
        for method, fill in ((name, False), (name + "_filled", True)):
            with one_blas_thread():
                decoded = decoded_layouts(prm, arr, cfg, probs_fn, fill=fill, size_prior=size_prior)
                scored = score_decoded(decoded)
            if method == "generator_filled":
                filled = [lay for lay, _ in decoded]  # the starts of --refine
            for s, (lay, _), (stable, iou, nb) in zip(shapes, decoded, scored):
                if layouts is not None and lay is not None:
                    layouts[method, s.name] = lay
                rows.append({"shape": s.name, "kind": s.kind, "method": method, "lam": cfg["lam"],
                             "seed": cfg["seed"], "step": st, **prior, "stable": stable, "iou": round(iou, 6),
                             "n_bricks": nb, "n_cells": int(s.vox.sum())})
    if refining:
        rows += refined_rows("generator_refined", shapes, filled, refine, log,
                             {"lam": cfg["lam"], "seed": cfg["seed"], "step": step, **prior}, refine_solves, layouts)
    if heuristic:
        merged = [merge_voxels(s.vox, source=s.name) for s in shapes]
        for s, lay in zip(shapes, merged):
            if layouts is not None:
                layouts["heuristic", s.name] = lay
            rows.append({"shape": s.name, "kind": s.kind, "method": "heuristic", "stable": score_layout(lay),
                         "iou": 1.0, "n_bricks": lay.n, "n_cells": int(s.vox.sum())})
        if refining:  # the control: the same refinement started from the merge
            rows += refined_rows("heuristic_refined", shapes, merged, refine, log, {}, refine_solves, layouts)
    return rows


def refined_rows(method, shapes, starts, seconds, log=None, extra=None, solves: int | None = None,
                 layouts: dict | None = None) -> list[dict]:
    """Rows ``method``: each start cover (a Layout or None) of ``shapes``
    refined by stabilize (no heuristic seeds, no gradient move, at most
    ``seconds`` (None: no limit) and ``solves`` exact solves (None: no
    limit) a shape); ``extra``: fields added to every row, and
    ``budget_solves`` when ``solves`` is given; ``layouts``: as
    :func:`evaluate`'s, filled with each refined cover."""
    from ..generate.stabilize import StabilizeOptions, stabilize

    opts = StabilizeOptions(seeds=1, gradient=False, time_s=float("inf") if seconds is None else float(seconds),
                            max_solves=solves)
    if solves is not None:
        extra = {**(extra or {}), "budget_solves": int(solves)}
    rows = []
    for i, (s, lay) in enumerate(zip(shapes, starts)):
        row = {"shape": s.name, "kind": s.kind, "method": method, **(extra or {}), "n_cells": int(s.vox.sum())}
        try:
            if lay is None:
                raise ValueError("empty decoding")
            r = stabilize(s.vox, opts, source=s.name, start=lay)
        except ValueError as exc:  # a decoding that is not an exact cover cannot be refined
            row.update(stable=False, iou=0.0, n_bricks=0, error=str(exc))
        else:
            row.update(stable=bool(r.stable), iou=1.0, n_bricks=r.layout.n, started_stable=r.method == "start",
                       bricks_changed=r.bricks_changed, exact_calls=r.exact_calls, refine_s=round(r.time_s, 2))
            if layouts is not None:
                layouts[method, s.name] = r.layout
        rows.append(row)
        if log is not None:
            print(f"{method} [{i + 1}/{len(shapes)}] {s.name}: {'stable' if row['stable'] else 'not stable'}"
                  + (f" ({row['refine_s']} s, {row['exact_calls']} exact solves)" if "refine_s" in row else ""),
                  file=log, flush=True)
    return rows


def write_results(out: str, rows: list[dict], layouts_dir: str | None = None, layouts: dict | None = None) -> None:
    """Write ``rows`` to ``out`` (JSON lines) and, with ``layouts_dir``, each
    layout of ``layouts`` ({(method, shape): Layout}) to
    ``layouts_dir/METHOD/SHAPE.json``, its path in the row's ``layout``:
    all files or none (:func:`~stablelego_jax.files.staged_outputs`)."""
    from ..formats.reader import write_layout

    files = {}
    if layouts_dir:
        for r in rows:
            if (r["method"], r["shape"]) in (layouts or {}):
                r["layout"] = files[r["method"], r["shape"]] = os.path.join(layouts_dir, r["method"],
                                                                          r["shape"] + ".json")
    made = _make_folders(sorted({os.path.dirname(os.path.abspath(p)) for p in [out, *files.values()]}))
    try:
        with staged_outputs([out, *files.values()]) as stage:
            for key, path in files.items():
                write_layout(layouts[key], stage(path), fmt="json")
            with open(stage(out), "w", encoding="utf-8") as fh:
                fh.write("".join(json.dumps(r) + "\n" for r in rows))
    except BaseException:
        for d in reversed(made):  # nothing half-written: not even the empty folders
            try:
                os.rmdir(d)
            except OSError:
                pass
        raise


def _missing(path: str) -> tuple[list[str], str]:
    """(the folders from ``path`` (absolute) up that do not exist, top first;
    the nearest one that does)."""
    missing = []
    while not os.path.lexists(path):
        missing.append(path)
        path = os.path.dirname(path)
    return missing[::-1], path


def _make_folders(dirs) -> list[str]:
    """Make each folder of ``dirs`` (absolute paths) with its missing
    parents; the folders made, each after its parent."""
    made = []
    for d in dirs:
        for m in _missing(d)[0]:
            os.mkdir(m)
            made.append(m)
    return made


def _can_make_folder(path: str) -> bool:
    """Whether ``path`` is a writable folder, or one can be made there (its
    nearest existing ancestor is a writable folder)."""
    p = _missing(os.path.abspath(path))[1]
    return os.path.isdir(p) and os.access(p, os.W_OK | os.X_OK)


def summary(rows: list[dict]) -> dict:
    """{method: {"n", "stable_fraction", "mean_iou"}}."""
    out = {}
    for m in sorted({r["method"] for r in rows}):
        rs = [r for r in rows if r["method"] == m]
        out[m] = {"n": len(rs), "stable_fraction": float(np.mean([r["stable"] for r in rs])),
                  "mean_iou": float(np.mean([r["iou"] for r in rs]))}
    return out


def run(checkpoint: str, out: str, split: str = "heldout", heuristic: bool = False, untrained: bool = False,
        refine: float | None = None, refine_solves: int | None = None, size_prior: float = 0.0,
        n_fresh: int | None = None, layouts_dir: str | None = None) -> int:
    """``stablelego evaluate``: score a checkpoint's decoded layouts with the
    exact solver, write the rows to ``out`` (and with ``layouts_dir`` the
    layouts, see the module docstring); exit status (2: missing or bad
    checkpoint, or an output that cannot be written; nothing written)."""
    if not os.path.isfile(checkpoint):
        print(f"error: {checkpoint}: checkpoint not found", file=sys.stderr)
        return 2
    if os.path.isdir(out) or not _can_make_folder(os.path.dirname(os.path.abspath(out))):
        print(f"error: {out}: cannot write the results there (a folder, or in a folder that cannot be made)",
              file=sys.stderr)
        return 2
    if layouts_dir and not _can_make_folder(layouts_dir):
        print(f"error: {layouts_dir}: cannot write layouts there (not a folder, or not writable)", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    kept: dict | None = {} if layouts_dir else None
    try:
        rows = evaluate(checkpoint, split, heuristic, untrained, refine, log=sys.stderr, refine_solves=refine_solves,
                        size_prior=size_prior, n_fresh=n_fresh, layouts=kept)
    except (OSError, ValueError, KeyError) as exc:
        print(f"error: {checkpoint}: cannot evaluate: {exc}", file=sys.stderr)
        return 2
    try:
        write_results(out, rows, layouts_dir, kept)
    except LayoutError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"error: {exc.filename or out}: cannot write: {exc.strerror or exc}", file=sys.stderr)
        return 2
    for m, s in summary(rows).items():
        print(f"{m}: {s['n']} {split} shapes, stable {s['stable_fraction']:.3f}, mean IoU {s['mean_iou']:.4f}")
    print(f"wrote {out} ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    return 0
