"""Train the generator with shape fidelity + lambda * stability loss.

    stablelego train [--config CONFIG] [--out DIR] [--resume] [--seed S] [--lam L] [--steps N] [--jobs N]
                     [--init CHECKPOINT]

Loss per shape (B shapes per step, averaged; with ``sample`` "layers", B
one-layer samples of the layers net: see ``SAMPLES``):

* fidelity: ``fidelity`` (default 1; 0 drops the term) times the sum over target cells of (coverage - 1)^2, times
  ``under_weight`` where coverage < 1 (a cell left out costs more than a
  cell claimed twice on the way from one brick to another); coverage = the
  sum of the probabilities of the placements covering the cell; plus
  ``brick_weight`` * the sum of p over placements (a cost per brick, so
  fewer, larger bricks tile the shape more cheaply than 1x1s); plus ``bin_weight`` * the sum of p (1 - p) over placements
  (pushes probabilities to 0 or 1; its weight ramps up over the run);
  plus ``imitate`` * the cross-entropy against the merge heuristic's
  placements (0: none);
* stability: :func:`stablelego_jax.loss.stability_loss` of the soft layout
  over a subset of the placements, with existence weights = the generator's
  probabilities turned into shares of contested cells
  (:func:`stablelego_jax.train.net.existence_weights`): the placements decoded now plus the strongest competing
  ones (and a few random placements that reach from a supported cell over
  an overhang), chosen on the host each step (not
  differentiated) and compiled with :func:`stablelego_jax.soft.compile_placements`.
  ``stability_solves`` says how a batch's subsets are solved: ``"each"``
  (the default), one at a time, each padded to its own rung of the size
  ladder (:func:`~stablelego_jax.solvers.problem.plan_soft`: dense or
  layered, whichever factorises more cheaply), one compile per rung reused
  by every later step and run (the disk cache of
  :func:`~stablelego_jax.solvers.compiled.compiled`); or ``"batch"``, all
  padded to the config's one fixed size (``n_pad``, ``m_pad``, ``layers``
  x ``slots``, ...) and solved in one jit-compiled ``vmap``, one compile
  for the run. The same loss and gradient to rounding. On a CPU a
  ``vmap``-ed batch runs every problem at the padded size until the last
  has converged: at full scale (``configs/full_scale.json``) a step took
  122-152 s batched and 10-34 s one subset at a time, its executables on
  disk (BENCHMARKS.md, issue 19, session 55). With ``"each"``,
  ``solve_jobs`` subsets are solved at once in threads (default 0: one
  per core this process may run on; ``stablelego train --jobs N``), the
  largest first; the same numbers whatever the count.
  With ``lam`` 0 the term is not computed at all (no subsets, no solves:
  a step costs the network alone; its history logs ``stability`` and
  ``converged`` as null).

Checkpoints are plain ``.npz`` (params, optimizer state, step, numpy rng
state, config, history), written atomically to ``OUT/checkpoint.npz`` every
``checkpoint_every`` steps and at the end; ``--resume`` continues from it
exactly (same batches, same updates).
"""
from __future__ import annotations

import concurrent.futures
import functools
import json
import os
import sys
import time
from typing import NamedTuple

import numpy as np

from ..analysis import analyze_layout
from ..blas import check_batched_linalg, one_blas_thread, pool_threads
from ..files import atomic_write, atomic_write_text
from ..layout import brick_layout, cells_of
from ..runtime import x64
from ..soft import compile_placements
from ..solvers.compiled import compiled
from ..solvers.problem import cut_layers, layer_soft, pad_soft, plan_soft, soft_layer_plan, stack_soft
from .shapes import PROCEDURAL

DEFAULTS = {
    "grid": 20,
    "crop": [10, 10, 6],
    "data_seed": 0,
    "n_procedural": 240,
    "procedural": "small",
    "mesh_dir": "../shared/meshes",
    "mesh_extent": 6,
    "mesh_max_cells": 90,
    "heldout_frac": 0.2,
    "width": 16,
    "dilations": [1, 2, 4, 1],
    "out_bias": -2.0,
    "seed": 0,
    "steps": 400,
    "batch": 8,
    "lr": 0.01,
    "clip": 10.0,
    "lam": 0.0,
    "bin_weight": 0.1,
    "bin_weight_final": 1.0,
    "share_floor": 0.5,
    "share_power": 1.0,
    "under_weight": 1.0,
    "brick_weight": 0.0,
    "threshold": 0.5,
    "n_pad": 48,
    "m_pad": 2048,
    "p_pad": 64,
    "c_pad": 96,
    "layers": 0,
    "slots": 64,
    "chunk_pad": 512,
    "subset_base": "strict",
    "share_scope": "all",
    "val_count": 0,
    "grad_floor": 0.0,
    "logit_bound": 0.0,
    "lr_schedule": "constant",
    "lr_final_frac": 0.05,
    "competitors": 12,
    "random_competitors": 4,
    "random_pool": "span",
    "temperature": 0.02,
    "checkpoint_every": 50,
    "eval_every": 50,
    "eval_train": 32,
    "eval_heldout": True,
    "log_every": 10,
    "stability_solves": "each",
    "solve_jobs": 0,
    "absent_below": 0.0,
    "solver_iters": 30,
    "net": "volume",
    "imitate": 0.0,
    "fidelity": 1.0,
    "sample": "shapes",
    "init": "",
}

#: Config keys that change how the loss is computed, not its value: a
#: checkpoint resumes, and a stored run is reused, whatever they were.
HOW_KEYS = ("stability_solves", "solve_jobs")

#: Config keys read only by the stability term: runs with ``lam`` 0 do not
#: differ by them.
STABILITY_KEYS = ("absent_below", "solver_iters", "temperature", "competitors", "random_competitors",
                  "random_pool", "share_floor", "share_power", "share_scope", "subset_base", "n_pad", "m_pad", "p_pad",
                  "c_pad", "chunk_pad")


#: The generators (config key ``net``): "volume", the 3D conv net of
#: :mod:`.net`; "layers", the layer-by-layer net of :mod:`.layers`.
NETS = ("volume", "layers")

#: What a training batch draws (config key ``sample``): "shapes", ``batch``
#: whole shapes; "layers", ``batch`` non-empty layers of the training shapes,
#: each a one-layer sample whose layer below is the teacher's (net "layers",
#: lam 0 only: :meth:`Arrays.layer_samples`).
SAMPLES = ("shapes", "layers")


class ConfigError(ValueError):
    """A bad config file (the message names the file)."""


def load_config(path: str, **overrides) -> dict:
    """DEFAULTS updated by the JSON object in ``path`` and ``overrides`` (None
    values ignored). Raises ConfigError naming the file on a missing file,
    bad JSON, an unknown key or a value of the wrong type."""
    if not os.path.isfile(path):
        raise ConfigError(f"{path}: config file not found")
    try:
        with open(path) as fh:
            user = json.load(fh)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: cannot read config: {exc}") from None
    if not isinstance(user, dict):
        raise ConfigError(f"{path}: config must be a JSON object")
    cfg = dict(DEFAULTS)
    for k, v in list(user.items()) + [(k, v) for k, v in overrides.items() if v is not None]:
        if k not in DEFAULTS:
            raise ConfigError(f"{path}: unknown config key {k!r} (known: {', '.join(sorted(DEFAULTS))})")
        d = DEFAULTS[k]
        ok = (v is None and k == "mesh_dir") or (
            isinstance(v, bool) if isinstance(d, bool) else
            isinstance(v, (int, float)) and not isinstance(v, bool) if isinstance(d, float) else
            isinstance(v, int) and not isinstance(v, bool) if isinstance(d, int) else
            isinstance(v, type(d)))
        if not ok:
            raise ConfigError(f"{path}: config key {k!r} must be {type(d).__name__}, got {v!r}")
        cfg[k] = float(v) if isinstance(d, float) else v
    if cfg["solve_jobs"] < 0:
        raise ConfigError(f"{path}: config key 'solve_jobs' must be >= 0 (0: every core), got {cfg['solve_jobs']}")
    for k in ("steps", "batch", "n_pad", "m_pad", "p_pad", "c_pad", "slots", "chunk_pad", "checkpoint_every",
              "eval_every", "log_every", "solver_iters"):
        if cfg[k] < 1:
            raise ConfigError(f"{path}: config key {k!r} must be >= 1, got {cfg[k]}")
    if not (isinstance(cfg["crop"], list) and len(cfg["crop"]) == 3 and all(
            isinstance(c, int) and 8 <= c <= cfg["grid"] for c in cfg["crop"][:2]) and 1 <= cfg["crop"][2] <= cfg["grid"]):
        raise ConfigError(f"{path}: crop must be [cx, cy, cz] with 8 <= cx, cy <= grid and 1 <= cz <= grid")
    if cfg["layers"] != 0 and cfg["layers"] < cfg["crop"][2]:
        raise ConfigError(f"{path}: config key 'layers' must be 0 (dense) or at least the crop's height, "
                          f"got {cfg['layers']} for crop {cfg['crop']}")
    for k, allowed in (("subset_base", ("strict", "filled")), ("share_scope", ("all", "subset")),
                       ("procedural", PROCEDURAL),
                       ("random_pool", ("span", "valid")),
                        ("lr_schedule", ("constant", "cosine")),
                       ("stability_solves", ("each", "batch")),
                       ("net", NETS),
                       ("sample", SAMPLES)):
        if cfg[k] not in allowed:
            raise ConfigError(f"{path}: config key {k!r} must be one of {', '.join(allowed)}, got {cfg[k]!r}")
    if cfg["lam"] < 0 or not 0 < cfg["threshold"] <= 1:
        raise ConfigError(f"{path}: need lam >= 0 and 0 < threshold <= 1")
    if cfg["imitate"] < 0 or cfg["fidelity"] < 0:
        raise ConfigError(f"{path}: need imitate >= 0 and fidelity >= 0, got {cfg['imitate']} and {cfg['fidelity']}")
    if cfg["sample"] == "layers" and (cfg["net"] != "layers" or cfg["lam"] > 0):
        raise ConfigError(f"{path}: sample 'layers' needs net 'layers' and lam 0 (the stability term "
                          f"judges whole shapes), got net {cfg['net']!r} and lam {cfg['lam']:g}")
    if not 0 < cfg["share_power"] <= 1:
        raise ConfigError(f"{path}: need 0 < share_power <= 1, got {cfg['share_power']}")
    if not 0 <= cfg["absent_below"] < 1:
        raise ConfigError(f"{path}: need 0 <= absent_below < 1, got {cfg['absent_below']}")
    if cfg["init"]:
        cfg["init"] = os.path.abspath(cfg["init"])
        if not os.path.isfile(cfg["init"]):
            raise ConfigError(f"{path}: init checkpoint {cfg['init']} not found")
    if cfg["mesh_dir"] is not None and not os.path.isabs(cfg["mesh_dir"]):
        cfg["mesh_dir"] = os.path.abspath(cfg["mesh_dir"])  # relative to the working folder
    if cfg["mesh_dir"] is not None and not os.path.isdir(cfg["mesh_dir"]):
        raise ConfigError(f"{path}: mesh_dir {cfg['mesh_dir']} is not a folder")
    return cfg


# --------------------------------------------------------------------------
# data


@functools.lru_cache(maxsize=4)
def _dataset(n_procedural, mesh_dir, seed, heldout_frac, grid, mesh_extent, mesh_max_cells, procedural):
    from .shapes import build_dataset

    return build_dataset(n_procedural, mesh_dir, seed, heldout_frac, grid, mesh_extent, mesh_max_cells,
                         procedural)


def dataset(cfg: dict, validation: bool = False):
    """(train, heldout) shapes of a config (deterministic in its data keys).

    ``validation``: (train, validation, heldout) instead, with ``val_count``
    training objects (chosen by ``data_seed``) moved out of the training
    shapes into a validation set for tuning; training always runs on the
    train part of this three-way split."""
    tr, he, _ = _dataset(cfg["n_procedural"], cfg["mesh_dir"], cfg["data_seed"], cfg["heldout_frac"],
                         cfg["grid"], cfg["mesh_extent"], cfg["mesh_max_cells"], cfg["procedural"])
    val_idx = set(np.random.default_rng(cfg["data_seed"] + 2).permutation(len(tr))[: cfg["val_count"]].tolist())
    train = [s for i, s in enumerate(tr) if i not in val_idx]
    val = [s for i, s in enumerate(tr) if i in val_idx]
    return (train, val, he) if validation else (train, he)


def config_diff(stored: dict, cfg: dict, ignore=()) -> list[str]:
    """The keys of ``cfg`` (sorted) whose value in ``stored`` differs, except
    ``ignore``, :data:`HOW_KEYS` and, when both have ``lam`` 0,
    :data:`STABILITY_KEYS`. A key ``stored`` lacks (a run from before the
    key existed) counts as its default, the old behaviour."""
    skip = set(ignore) | set(HOW_KEYS)
    if stored.get("lam") == 0 and cfg.get("lam") == 0:
        skip |= set(STABILITY_KEYS)
    return sorted(k for k in cfg if k not in skip and stored.get(k, DEFAULTS.get(k)) != cfg[k])


def split_shapes(cfg: dict, split: str, n_fresh: int | None = None):
    """The shapes of one split of :func:`dataset` (``validation=True``): one
    of :data:`~stablelego_jax.train.shapes.SPLITS`; "fresh": ``n_fresh``
    (None: :data:`~stablelego_jax.train.shapes.FRESH_COUNT`) procedural
    objects of the config's recipe that none of the others holds
    (:func:`~stablelego_jax.train.shapes.fresh_shapes`)."""
    if split == "fresh":
        from .shapes import FRESH_COUNT, fresh_shapes

        return fresh_shapes(FRESH_COUNT if n_fresh is None else n_fresh, cfg["n_procedural"], cfg["data_seed"],
                            cfg["grid"], cfg["procedural"])
    train, val, held = dataset(cfg, validation=True)
    return {"heldout": held, "val": val, "train": train}[split]


class Arrays:
    """Per-shape network inputs on the crop around each shape: features
    x (S, cx, cy, cz, C) float32 (:func:`stablelego_jax.train.net.features`,
    or with ``net`` "layers" :func:`stablelego_jax.train.layers.features` with
    the merge's cover as the layer below), valid (S, cx, cy, cz, K) bool,
    target (S, cx, cy, cz) bool, offset (S, 3) of the crop in the
    (G, G, G) grid; with ``net`` "layers" or ``teach``, teacher
    (S, cx, cy, cz, K) bool: the merge's placements (else None)."""

    def __init__(self, shapes, crop_size, grid=20, net="volume", teach=False):
        from . import layers
        from .net import crop, features, spanning_placements, valid_placements

        crops = []
        for s in shapes:
            try:
                crops.append(crop(s.vox, crop_size))
            except ValueError as exc:
                raise ConfigError(f"shape {s.name}: {exc}") from None
        self.names = [s.name for s in shapes]
        self.grid = grid
        self.target = np.stack([c[0] for c in crops]) if crops else np.zeros((0, *crop_size), bool)
        self.offset = np.stack([c[1] for c in crops]) if crops else np.zeros((0, 3), np.int64)
        self.valid = np.stack([valid_placements(t) for t in self.target]) if crops else None
        self.span = np.stack([spanning_placements(t) for t in self.target]) if crops else None
        self.teacher = None
        if net == "layers" or teach:
            taught = [layers.teacher(t) for t in self.target]
            self.teacher = np.stack([t[1] for t in taught]) if crops else None
        if not crops:
            self.x = None
        elif net == "layers":
            self.x = np.stack([layers.features(t, ids, grid) for t, (ids, _) in zip(self.target, taught)])
        else:
            self.x = np.stack([features(t, grid) for t in self.target])

    def layer_samples(self) -> "Arrays":
        """The non-empty layers of these shapes as one-layer samples, for
        training with ``sample`` "layers" (net "layers": each layer's
        features already hold the layers around it and the teacher's layer
        below): x (N, cx, cy, 1, C), valid, span, target and teacher alike,
        names "SHAPE@zK", offset (N, 3) each layer's corner in the grid."""
        s, z = np.nonzero(self.target.any(axis=(1, 2)))  # (S, cz) -> the non-empty layers
        out = object.__new__(Arrays)
        out.names = [f"{self.names[i]}@z{k}" for i, k in zip(s, z)]
        out.grid = self.grid
        for k in ("target", "x", "valid", "span", "teacher"):
            a = getattr(self, k)
            setattr(out, k, None if a is None else a[s, :, :, z][:, :, :, None])
        out.offset = self.offset[s] + np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)
        return out

    def goal(self, b):
        """The loss's target of shapes ``b``: target[b], or with a teacher the pair
        (target[b], teacher[b])."""
        return self.target[b] if self.teacher is None else (self.target[b], self.teacher[b])


def shape_arrays(shapes, cfg: dict) -> Arrays:
    """:class:`Arrays` of ``shapes`` for ``cfg``'s crop, grid, net and imitation."""
    return Arrays(shapes, cfg["crop"], cfg["grid"], cfg["net"], cfg["imitate"] > 0)


# --------------------------------------------------------------------------
# the stability subset (host side)


class Subset(NamedTuple):
    """One shape's stability subset (or a batch of them, stacked):
    fi (n_pad,) flat placement indices into (X, Y, Z, K), mask (n_pad,) real
    slots, inc (c_pad, n_pad) float 0/1 cell incidence (which of the
    subset's cells each placement covers), prob the padded SoftProblem
    (stacked for a batch; with ``stability_solves`` "each", a shape's
    problem on its own rung of the ladder, and a tuple of them for a
    batch). The problem's first bricks are the subset's, in ``fi``'s
    order."""

    fi: np.ndarray
    mask: np.ndarray
    inc: np.ndarray
    prob: object


def select_subset(p: np.ndarray, valid: np.ndarray, cfg: dict, rng: np.random.Generator, span=None) -> Subset:
    """Placements of one shape for the stability term and their padded problem.

    p, valid, span: (X, Y, Z, K). The problem is dense, or with ``layers`` > 0
    numbered layer by layer for the block-tridiagonal factorisation
    (``layers`` x ``slots`` brick slots, ``chunk_pad`` column chunks:
    :func:`~stablelego_jax.solvers.problem.layer_soft`), whose cost grows
    with layers x slots^3 instead of bricks^3. Takes the decoded placements (lowest
    layers first; the strict decoding, or the filled one when
    ``subset_base`` is "filled", so every cell of the shape is in the
    problem), then the ``competitors`` most probable others, then
    ``random_competitors`` random ones among the ``span`` placements (those
    that reach from a supported cell into an overhang; all valid ones when
    None or when ``random_pool`` is "valid"), and drops from the end until the compiled problem fits
    (n_pad, m_pad, p_pad, c_pad; layered also layers, slots per layer and
    column chunks), keeping at least the competitors' share free. The
    problem is then padded to that fixed size, or with ``stability_solves``
    "each" planned on its own (:func:`~stablelego_jax.solvers.problem.plan_soft`).
    """
    from .net import MASS, TYPES, decode

    idx, _, _ = decode(p, cfg["threshold"], cfg["subset_base"] == "filled", valid)
    idx = idx[np.argsort(idx[:, 2], kind="stable")]
    dec = np.ravel_multi_index(tuple(idx.T), p.shape) if len(idx) else np.zeros(0, np.int64)
    n_comp = cfg["competitors"] + cfg["random_competitors"]
    dec = dec[: max(cfg["n_pad"] - n_comp, 1)]
    flat_p = p.ravel()
    vflat = np.nonzero(valid.ravel())[0]
    others = np.setdiff1d(vflat, dec)
    top = others[np.argsort(-flat_p[others], kind="stable")[: cfg["competitors"]]]
    pool = np.nonzero((valid if span is None or cfg["random_pool"] == "valid" else span).ravel())[0]
    rest = np.setdiff1d(pool, np.concatenate([dec, top]))
    rnd = rng.choice(rest, size=min(cfg["random_competitors"], len(rest)), replace=False) if len(rest) else rest
    chosen = np.concatenate([dec, top, rnd]).astype(np.int64)[: cfg["n_pad"]]
    while True:
        x, y, z, k = np.unravel_index(chosen, p.shape)
        size = np.asarray(TYPES, np.int64)[k]
        pos = np.stack([x, y, z], 1)
        cells, owner = cells_of(pos, size)
        ucells, cell_id = np.unique(cells, axis=0, return_inverse=True)
        prob = compile_placements(pos, size, MASS[k])
        if (prob.col_kind.shape[0] <= cfg["m_pad"] and prob.group.shape[1] <= cfg["p_pad"]
                and len(ucells) <= cfg["c_pad"]):
            fixed = _layered(prob, cfg) if cfg["layers"] else prob
            if fixed is not None:
                break
        chosen = chosen[: max(len(chosen) - 4, 1)]
    n = len(chosen)
    fi = np.zeros(cfg["n_pad"], np.int64)
    fi[:n] = chosen
    mask = np.zeros(cfg["n_pad"], bool)
    mask[:n] = True
    inc = np.zeros((cfg["c_pad"], cfg["n_pad"]))
    inc[np.ravel(cell_id), owner] = 1.0
    if cfg["stability_solves"] == "each":
        return Subset(fi, mask, inc, plan_soft(prob, shared=True))
    # chunk_pad pads a layered problem's column chunks (a dense one has none)
    return Subset(fi, mask, inc, pad_soft(fixed, cfg["n_pad"], cfg["m_pad"], cfg["p_pad"], c_pad=cfg["chunk_pad"]))


def _layered(prob, cfg: dict):
    """A subset's problem numbered layer by layer in ``cfg``'s ``layers`` x
    ``slots`` (:func:`~stablelego_jax.solvers.problem.layer_soft`), or None
    where it needs more layers, slots per layer or column chunks than that."""
    L, B = soft_layer_plan(prob)
    if L > cfg["layers"] or B > cfg["slots"]:
        return None
    prob = layer_soft(prob, cfg["layers"], cfg["slots"])
    return prob if len(prob.chunk) <= cfg["chunk_pad"] else None


def batch_subsets(p: np.ndarray, valid: np.ndarray, cfg: dict, rng: np.random.Generator, span=None) -> Subset:
    """:func:`select_subset` of each shape of a batch (p, valid, span:
    (B, X, Y, Z, K)), stacked into one Subset of (B, ...) arrays; layered
    (``layers`` > 0), ``prob.cut`` is one (L,) array for the whole batch:
    each layer's most used slots over its shapes. With ``stability_solves``
    "each", ``prob`` is the tuple of the shapes' problems."""

    sub = [select_subset(p[j], valid[j], cfg, rng, None if span is None else span[j]) for j in range(len(p))]
    stacked = Subset(*(np.stack([getattr(s, f) for s in sub]) for f in ("fi", "mask", "inc")), None)
    if cfg["stability_solves"] == "each":
        return stacked._replace(prob=tuple(s.prob for s in sub))
    prob = stack_soft([s.prob for s in sub])
    if cfg["layers"]:
        # each layer factored at the most slots any shape of the batch uses there (one
        # (L,) cut for the batch, so one branch runs; a cut per shape would run every
        # branch under vmap): layers above every shape's height cost nothing
        prob = prob._replace(cut=np.max([cut_layers(s.prob).cut for s in sub], axis=0).astype(np.int32))
    return stacked._replace(prob=prob)


# --------------------------------------------------------------------------
# loss and step (jit)


def draw_batch(arrays: Arrays, cfg: dict, rng: np.random.Generator, params=None, probs_fn=None):
    """The next batch of a run, drawn with ``rng`` as :func:`train` draws
    it: (x, valid, target, p, sub) of ``cfg["batch"]`` shapes of
    ``arrays``; with ``probs_fn`` (and ``params``: the stability term) also
    the placements' probabilities ``p`` (B, X, Y, Z, K) and the subsets
    (:func:`batch_subsets`, which draws from ``rng`` too), else both None.
    Benchmarks replay a checkpoint's next batches with it."""
    b = rng.choice(len(arrays.names), size=cfg["batch"], replace=False)
    x, valid, target = arrays.x[b], arrays.valid[b], arrays.goal(b)
    if probs_fn is None:
        return x, valid, target, None, None
    p = np.asarray(probs_fn(params, x, valid))
    return x, valid, target, p, batch_subsets(p, valid, cfg, rng, arrays.span[b])


def bin_weight(cfg: dict, step: int) -> float:
    """Weight of the binarization term at ``step``: linear from ``bin_weight``
    to ``bin_weight_final`` over the run (probabilities settle to 0/1 late,
    after the stability term has had its say on which bricks)."""
    return cfg["bin_weight"] + (cfg["bin_weight_final"] - cfg["bin_weight"]) * step / max(cfg["steps"], 1)


# the config keys that shape the compiled graphs (the network and the loss);
# everything else, grad_floor and brick_weight included, enters as a value,
# so a sweep over those reuses one compilation
_GRAPH_KEYS = ("dilations", "logit_bound", "temperature", "under_weight", "share_scope", "share_floor",
               "share_power", "absent_below", "solver_iters", "net", "imitate", "fidelity")
_OPT_KEYS = ("lr", "lr_schedule", "steps", "lr_final_frac", "clip")


def solve_jobs(cfg: dict) -> int:
    """Subsets solved at once (:func:`solve_subsets`): the config's
    ``solve_jobs``, or with 0 the cores this process may run on."""
    from ..batch import cpu_cores

    return cfg["solve_jobs"] or cpu_cores()


def _graph(cfg: dict):
    """:func:`_model_fns` of ``cfg``'s graph keys (one per network and loss shape)."""
    # lam 0: a graph without the stability term (its soft solves cost nearly all of a step)
    return _model_fns(json.dumps(dict({k: cfg[k] for k in _GRAPH_KEYS}, stability=cfg["lam"] > 0,
                                      solves=cfg["stability_solves"]), sort_keys=True))


def batch_weights(cfg: dict, params, x, valid, sub: Subset) -> np.ndarray:
    """(B, n_pad) existence weights of a batch's subsets (``sub``, from
    :func:`draw_batch`) as the stability term of ``cfg`` sees them: the
    generator's probabilities as shares (``share_scope``), 0 on padding."""
    return np.asarray(_graph(cfg)[3](params, np.float64(cfg["grad_floor"]), x, valid, sub.fi, sub.mask, sub.inc))


def make_fns(cfg: dict):
    """(probs_fn, step_fn, opt, terms, grad_fn): jit-compiled forward pass,
    training step ``step_fn(params, opt_state, lam, bw, x, valid, target,
    sub)``, the optimizer, the loss terms ``terms(params, x, valid, target,
    *sub)`` -> (fidelity, binarize, stability, converged fraction; the last
    two NaN, and ``sub``'s fields may be None, when ``cfg["lam"]`` is 0) and
    ``grad_fn(params, lam, bw, *batch)`` -> (loss, terms, grads). Compiled
    once per process for all configs that share the network and loss shape
    (``_GRAPH_KEYS``); ``grad_floor`` and ``brick_weight`` are passed as
    values. With ``stability_solves`` "each" (and ``lam`` > 0), ``terms``
    and ``grad_fn`` are Python functions around jitted pieces: the
    subsets' weights, each subset's solve (:func:`solve_subsets`) and the
    network's gradient through the weights."""
    opt, update_fn = _optimizer(json.dumps({k: cfg[k] for k in _OPT_KEYS}, sort_keys=True))
    probs_fn, terms_c, grad_c, _ = _graph(cfg)
    knobs = (np.float64(cfg["grad_floor"]), np.float64(cfg["brick_weight"]))
    # subsets solved one at a time (Python functions, not jitted): solve_jobs at once
    each = {"jobs": solve_jobs(cfg)} if cfg["stability_solves"] == "each" and cfg["lam"] > 0 else {}

    def terms(params, x, valid, target, fi, mask, inc, prob):
        return terms_c(params, *knobs, x, valid, target, fi, mask, inc, prob, **each)

    def grad_fn(params, lam, bw, *args):
        return grad_c(params, lam, bw, *knobs, *args, **each)

    def step_fn(params, opt_state, lam, bw, x, valid, target, sub: Subset):
        loss, aux, g = grad_fn(params, lam, bw, x, valid, target, *sub)
        params, opt_state = update_fn(params, opt_state, g)
        return params, opt_state, loss, aux

    return probs_fn, step_fn, opt, terms, grad_fn


def _optax():
    try:
        import optax
    except ImportError:
        raise ConfigError("training needs optax: pip install 'stablelego-jax[train]'") from None
    return optax


@functools.lru_cache(maxsize=8)
def _optimizer(key: str):
    """(optax optimizer, jitted update) for the optimizer keys in ``key``."""
    cfg = json.loads(key)
    import jax

    optax = _optax()
    lr = cfg["lr"] if cfg["lr_schedule"] == "constant" else optax.cosine_decay_schedule(
        cfg["lr"], max(cfg["steps"], 1), alpha=cfg["lr_final_frac"])
    opt = optax.chain(optax.clip_by_global_norm(cfg["clip"]), optax.adam(lr))

    @jax.jit
    def update_fn(params, opt_state, g):
        upd, opt_state = opt.update(g, opt_state, params)
        return optax.apply_updates(params, upd), opt_state

    return opt, update_fn


def loss_options(cfg: dict):
    """The stability term's :class:`~stablelego_jax.loss.LossOptions`:
    ``temperature`` and, as the interior point's most iterations,
    ``solver_iters`` (a subset that has not converged by then adds nothing;
    one that converges sooner stops sooner, with the same numbers)."""
    from ..loss import LossOptions

    return LossOptions(temperature=cfg["temperature"], iters=cfg["solver_iters"])


@functools.lru_cache(maxsize=8)
def _model_fns(key: str):
    """(probs_fn, terms, grad_fn, weights_fn) jitted for the graph keys in
    ``key``; terms and grad_fn take (grad_floor, brick_weight) after
    params / lam, bw; weights_fn (params, grad_floor, x, valid, fi, mask,
    inc) gives the subsets' existence weights (B, n_pad)."""
    cfg = json.loads(key)
    import jax
    import jax.numpy as jnp

    optax = _optax()  # ConfigError before anything is compiled or written
    from ..loss import soft_report
    from . import net

    dil = tuple(cfg["dilations"])
    opts = loss_options(cfg)
    model = generator(cfg)

    @jax.jit
    def probs_fn(params, x, valid):
        return model.probabilities(params, x, valid, dil, cfg["logit_bound"])

    def forward(params, floor, x, valid):
        """(p, p_g, coverage) of a batch: the placements' probabilities, the
        same values with d p / d logit = p (1 - p) + grad_floor (a saturated
        placement can still be moved), and the cells' coverage by p_g."""
        logits = model.logits(params, x, dil, cfg["logit_bound"])
        p = jnp.where(valid, jax.nn.sigmoid(logits), 0.0)  # = model.probabilities, sharing the logits
        p_g = p + floor * jnp.where(valid, logits - jax.lax.stop_gradient(logits), 0.0)
        return p, p_g, net.coverage(p_g), logits

    def shape_terms(params, floor, brick_weight, x, valid, target):
        """(fidelity, binarize, p_g, coverage) of a batch; ``target``: the
        shapes (B, X, Y, Z) bool, or with ``imitate`` > 0 the pair (shapes,
        the teacher's placements (B, X, Y, Z, K) bool)."""
        target, taught = target if cfg["imitate"] > 0 else (target, None)
        p, p_g, cov, lg = forward(params, floor, x, valid)
        B = p.shape[0]
        err = jnp.where(cov < 1.0, cfg["under_weight"], 1.0) * (cov - 1.0) ** 2
        fid = cfg["fidelity"] * jnp.where(target, err, 0.0).reshape(B, -1).sum(1).mean()
        # economy: each placement's probability costs brick_weight
        fid = fid + brick_weight * p_g.reshape(B, -1).sum(1).mean()
        if cfg["imitate"] > 0:  # cross-entropy against the teacher's placements, over the valid ones
            bce = jnp.where(valid, optax.sigmoid_binary_cross_entropy(lg, taught.astype(lg.dtype)), 0.0)
            fid = fid + cfg["imitate"] * bce.reshape(B, -1).sum(1).mean()
        binar = (p * (1.0 - p)).reshape(B, -1).sum(1).mean()
        return fid, binar, p_g, cov

    def subset_weights(p_g, cov, fi, mask, inc):
        """(B, n_pad) existence weights of the subsets' placements."""
        B = p_g.shape[0]
        if cfg["share_scope"] == "subset":
            ps = jnp.take_along_axis(p_g.reshape(B, -1), fi, axis=1) * mask
            return net.subset_shares(ps, inc, cfg["share_floor"], cfg["share_power"])
        wts = net.existence_weights(p_g, cov, cfg["share_floor"])
        return jnp.take_along_axis(wts.reshape(B, -1), fi, axis=1) * mask

    def terms(params, floor, brick_weight, x, valid, target, fi, mask, inc, prob):
        fid, binar, p_g, cov = shape_terms(params, floor, brick_weight, x, valid, target)
        if not cfg["stability"]:
            return fid, binar, jnp.full((), jnp.nan, fid.dtype), jnp.full((), jnp.nan, fid.dtype)
        w = subset_weights(p_g, cov, fi, mask, inc)
        # a layered batch's cut ((L,), :func:`batch_subsets`) is the batch's, not batched
        cut = prob.cut
        def report(wi, pi):
            wi, pi = present(wi, pi._replace(cut=cut), cfg["absent_below"])
            return soft_report(wi, None, pi, opts=opts)

        rep = jax.vmap(report)(w, prob._replace(cut=None))
        # a problem whose interior-point solve did not converge contributes nothing
        stab = jnp.where(rep.converged, rep.brick_loss.sum(1), 0.0).mean()
        return fid, binar, stab, rep.converged.mean()

    def total(params, lam, bw, floor, brick_weight, *args):
        fid, binar, stab, conv = terms(params, floor, brick_weight, *args)
        return fid + bw * binar + (lam * stab if cfg["stability"] else 0.0), (fid, binar, stab, conv)

    @jax.jit
    def grad_fn(params, lam, bw, floor, brick_weight, *args):
        (loss, aux), g = jax.value_and_grad(total, has_aux=True)(params, lam, bw, floor, brick_weight, *args)
        return loss, aux, g

    @jax.jit
    def weights_fn(params, floor, x, valid, fi, mask, inc):
        _, p_g, cov, _ = forward(params, floor, x, valid)
        return subset_weights(p_g, cov, fi, mask, inc)

    if cfg["solves"] == "batch" or not cfg["stability"]:
        return probs_fn, jax.jit(terms), grad_fn, weights_fn

    # one subset at a time: the stability term's value and its gradient with respect
    # to the weights from each shape's own compiled solve, then the network's
    # gradient through the weights as that of sum(w * cotangent)
    shape_fn = jax.jit(shape_terms)

    @jax.jit
    def linear_grad(params, bw, floor, brick_weight, x, valid, target, fi, mask, inc, w_ct):
        def f(params):
            fid, binar, p_g, cov = shape_terms(params, floor, brick_weight, x, valid, target)
            w = subset_weights(p_g, cov, fi, mask, inc)
            return fid + bw * binar + (w * w_ct).sum(), (fid, binar)
        return jax.value_and_grad(f, has_aux=True)(params)

    def stability(params, floor, x, valid, fi, mask, inc, probs, jobs):
        """(value (B,), converged (B,), d value / d w (B, n_pad)) of each subset."""
        w = np.asarray(weights_fn(params, floor, x, valid, fi, mask, inc))
        return solve_subsets(w, probs, opts, cfg["absent_below"], jobs)

    def terms_each(params, floor, brick_weight, x, valid, target, fi, mask, inc, probs, jobs=1):
        fid, binar, _, _ = shape_fn(params, floor, brick_weight, x, valid, target)
        val, conv, _ = stability(params, floor, x, valid, fi, mask, inc, probs, jobs)
        return fid, binar, np.float64(val.mean()), np.float64(conv.mean())

    def grad_each(params, lam, bw, floor, brick_weight, x, valid, target, fi, mask, inc, probs, jobs=1):
        val, conv, gw = stability(params, floor, x, valid, fi, mask, inc, probs, jobs)
        stab = float(val.mean())
        (_, (fid, binar)), g = linear_grad(params, bw, floor, brick_weight, x, valid, target, fi, mask, inc,
                                           np.float64(lam) * gw / len(probs))
        loss = fid + bw * binar + lam * stab
        return loss, (fid, binar, np.float64(stab), np.float64(conv.mean())), g

    return probs_fn, terms_each, grad_each, weights_fn


def present(w, prob, below: float):
    """(w, prob) of a subset without its placements of weight at most
    ``below`` (0: all kept): they are dropped from the problem
    (:meth:`~stablelego_jax.soft.SoftProblem.keep_only`) and their weight
    set to 0, so the loss's gradient with respect to them is 0. w: (n,)
    traced weights; prob: its soft problem.

    Why: on a cluster of nearly absent bricks (weights like 1e-17 next to
    bricks of weight 1, as a generator's saturated probabilities give) the
    soft interior point often does not centre (BENCHMARKS.md, issue 19,
    session 56), and an unconverged subset contributes nothing. With
    ``grad_floor`` 0 and ``share_power`` 1 a placement's weight reaches
    the network's gradient scaled by that weight, so dropping those below
    ``below`` changes the gradient by at most that fraction of what they
    would have given."""
    import jax.numpy as jnp

    if below <= 0:
        return w, prob
    keep = (jnp.asarray(w)[prob.unit] > below) & prob.brick_mask
    return jnp.where(keep, w, 0.0), prob.keep_only(keep, xp=jnp)


def _subset_term(opts, fields: tuple, below: float):
    """``fn(w, *soft problem arrays) -> (value, converged, d value / d w)`` of
    one subset's stability term: the sum of its bricks' losses, 0 where the
    interior point did not converge; ``fields``: the names of the
    :class:`~stablelego_jax.soft.SoftProblem` fields the arrays are;
    ``below``: :func:`present`'s."""
    import jax
    import jax.numpy as jnp

    from ..loss import soft_report
    from ..soft import SoftProblem

    def term(w, prob):
        w, prob = present(w, prob, below)
        rep = soft_report(w, None, prob, opts=opts)
        return jnp.where(rep.converged, rep.brick_loss.sum(), 0.0), rep.converged

    vg = jax.value_and_grad(term, has_aux=True)

    def fn(w, *arrays):
        (v, c), g = vg(w, SoftProblem.from_flat(fields, arrays))
        return v, c, g

    return fn


def solve_subsets(w: np.ndarray, probs, opts, below: float = 0.0, jobs: int = 1):
    """The stability term of each subset of a batch, one solve per subset.

    w (B, n_pad): the subsets' existence weights (a problem's first bricks
    are its subset's); probs: B soft problems on their own rungs of the
    ladder (:func:`select_subset` with ``stability_solves`` "each"), each
    solved by an executable compiled once for its shape (kept in memory
    and on disk, :func:`~stablelego_jax.solvers.compiled.compiled`).
    ``below``: the weight at or below which a placement is dropped
    (:func:`present`). ``jobs``: solves run at once, each in a thread of
    its own (XLA runs a CPU computation on the thread that calls it), the
    largest problems first so that the threads finish together; every
    solve is the same computation whatever ``jobs`` is. Returns (value
    (B,), converged (B,) bool, d value / d w (B, n_pad)); value and
    gradient are 0 where a solve did not converge."""
    B, n_pad = w.shape
    val, conv, grad = np.zeros(B), np.zeros(B, bool), np.zeros((B, n_pad))

    def solve(j):
        prob = probs[j]
        n = prob.mass.shape[0]
        k = min(n, n_pad)
        wj = np.zeros(n)
        wj[:k] = w[j, :k]
        fields, arrays = prob.flat()
        arrays = (wj,) + arrays
        v, c, g = compiled("train-stability", _subset_term(opts, fields, below), (opts, fields, below), arrays)(*arrays)
        val[j], conv[j], grad[j, :k] = float(v), bool(c), np.asarray(g)[:k]

    if jobs <= 1 or len(probs) <= 1:
        for j in range(len(probs)):
            solve(j)
        return val, conv, grad
    size = [sum(np.size(a) for a in p.flat()[1]) for p in probs]
    order = sorted(range(len(probs)), key=lambda j: -size[j])
    with concurrent.futures.ThreadPoolExecutor(min(jobs, len(probs))) as pool:
        for f in [pool.submit(solve, j) for j in order]:
            f.result()  # a solve's error, raised here
    return val, conv, grad


# --------------------------------------------------------------------------
# checkpoints


@x64
def initial_params(cfg: dict, seed: int | None = None):
    """The generator's parameters at initialisation for ``cfg`` (its
    ``seed`` unless given)."""
    import jax

    key = jax.random.PRNGKey(cfg["seed"] if seed is None else seed)
    return generator(cfg).init_params(key, cfg["width"], tuple(cfg["dilations"]), cfg["out_bias"])


#: Config keys that give the network's parameters their shapes: a run
#: started from another's parameters (``init``) must share them.
NET_KEYS = ("net", "width", "dilations")


def params_from(path: str, cfg: dict):
    """The parameters of checkpoint ``path``, to start a run of ``cfg`` from
    (config key ``init``: fine-tuning, say with ``lam`` > 0 from a run with
    ``lam`` 0; a fresh optimizer state, step 0). Raises ConfigError naming
    the file when it cannot be read or its network differs (``NET_KEYS``)."""
    try:
        params, _, _, _, stored, _ = load_checkpoint(path)
    except (OSError, ValueError, KeyError) as exc:
        raise ConfigError(f"{path}: cannot read the init checkpoint: {exc}") from None
    diff = [f"{k} {stored[k]!r} (run: {cfg[k]!r})" for k in NET_KEYS if stored[k] != cfg[k]]
    if diff:
        raise ConfigError(f"{path}: init checkpoint has another network: {', '.join(diff)}")
    return params


def generator(cfg: dict):
    """The module of ``cfg``'s network: :mod:`.net` ("volume") or :mod:`.layers`
    ("layers"); both give ``init_params``, ``logits`` and ``probabilities``."""
    from . import layers, net

    return layers if cfg["net"] == "layers" else net


def _leaves(tree):
    import jax

    return [np.asarray(a) for a in jax.tree_util.tree_leaves(tree)]


def save_checkpoint(path: str, params, opt_state, step: int, rng: np.random.Generator, cfg: dict,
                    history: list) -> None:
    """Write ``path`` atomically (temp file, then rename): plain npz arrays."""
    arrs = {f"param_{i}": a for i, a in enumerate(_leaves(params))}
    arrs.update({f"opt_{i}": a for i, a in enumerate(_leaves(opt_state))})
    arrs["step"] = np.asarray(step)
    arrs["rng_state"] = np.asarray(json.dumps(rng.bit_generator.state))
    arrs["config"] = np.asarray(json.dumps(cfg))
    arrs["history"] = np.asarray(json.dumps(history))
    atomic_write(path, lambda fh: np.savez(fh, **arrs), binary=True)


@x64
def load_checkpoint(path: str, cfg: dict | None = None):
    """(params, opt_state, step, rng, cfg, history) from ``path`` (cfg: the
    stored config unless given)."""
    import jax
    import jax.numpy as jnp

    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    stored = dict(DEFAULTS, **json.loads(str(data["config"])))
    cfg = stored if cfg is None else cfg
    params0 = initial_params(cfg, 0)  # only the tree structure is used
    opt = make_fns(cfg)[2]
    opt0 = opt.init(params0)
    tdef_p = jax.tree_util.tree_structure(params0)
    tdef_o = jax.tree_util.tree_structure(opt0)
    np_ = tdef_p.num_leaves
    params = jax.tree_util.tree_unflatten(tdef_p, [jnp.asarray(data[f"param_{i}"]) for i in range(np_)])
    opt_state = jax.tree_util.tree_unflatten(
        tdef_o, [jnp.asarray(data[f"opt_{i}"]) for i in range(tdef_o.num_leaves)])
    rng = np.random.default_rng()
    rng.bit_generator.state = json.loads(str(data["rng_state"]))
    return params, opt_state, int(data["step"]), rng, stored, json.loads(str(data["history"]))


class Replay(NamedTuple):
    """A run as its checkpoint left it (:func:`replay`)."""

    params: object
    step: int
    rng: np.random.Generator
    cfg: dict
    arrays: Arrays  # its training shapes, from which draw_batch draws


def replay(checkpoint: str, cfg: dict | None = None) -> Replay:
    """The run of ``checkpoint`` where it stopped: ``draw_batch(r.arrays,
    r.cfg, r.rng, r.params, probs_fn)`` draws the batches it would draw
    next (the parameters held). cfg: the stored config unless given.
    Benchmarks replay a run's solves with it."""
    params, _, step, rng, stored, _ = load_checkpoint(checkpoint, cfg)
    cfg = stored if cfg is None else cfg
    return Replay(params, step, rng, cfg, shape_arrays(dataset(cfg, validation=True)[0], cfg))


# --------------------------------------------------------------------------
# exact evaluation (also used by stablelego_jax.train.evaluate)


def layout_of(pos, size, source="<generated>"):
    """A Layout of decoded bricks with Table I masses (None when empty)."""
    if len(pos) == 0:
        return None
    return brick_layout(pos, size, source=source)


def score_layout(layout) -> bool:
    """Exact (HiGHS) verdict; an empty layout (nothing built) counts as not stable."""
    if layout is None:
        return False
    return bool(analyze_layout(layout, solver="exact").stable)


@x64
def decoded_layouts(params, arrays: Arrays, cfg: dict, probs_fn, chunk: int = 8, fill: bool = False,
                    size_prior: float = 0.0):
    """Per shape: (layout in the (G, G, G) grid or None when empty, iou) of
    the network's decoding (``fill``, ``size_prior``: see
    :func:`stablelego_jax.train.net.decode`; net "layers": bottom up,
    :func:`stablelego_jax.train.layers.decode`)."""
    from . import layers
    from .net import decode, decoded_iou

    def chunks():
        """(pos, size) of each shape's decoding, in the crop, a chunk of shapes at a time."""
        for s in range(0, len(arrays.names), chunk):
            if cfg["net"] == "layers":  # bottom up, each layer on the bricks decoded below it
                yield from layers.decode(probs_fn, params, arrays.target[s:s + chunk], arrays.valid[s:s + chunk],
                                         arrays.grid, cfg["threshold"], fill, size_prior)
                continue
            p = np.asarray(probs_fn(params, arrays.x[s:s + chunk], arrays.valid[s:s + chunk]))
            for j in range(len(p)):
                yield decode(p[j], cfg["threshold"], fill, arrays.valid[s + j], size_prior)[1:]

    out = []
    for i, (pos, size) in enumerate(chunks()):
        iou = decoded_iou(arrays.target[i], pos, size)
        out.append((layout_of(pos + arrays.offset[i], size), iou))  # back into the (G, G, G) grid
    return out


def score_decoded(decoded) -> list:
    """Per shape: (stable, iou, n_bricks) of :func:`decoded_layouts`'s
    layouts, judged by the exact solver."""
    return [(score_layout(lay), iou, 0 if lay is None else lay.n) for lay, iou in decoded]


def decode_and_score(params, arrays: Arrays, cfg: dict, probs_fn, chunk: int = 8, fill: bool = False):
    """:func:`score_decoded` of :func:`decoded_layouts`."""
    return score_decoded(decoded_layouts(params, arrays, cfg, probs_fn, chunk, fill))


# --------------------------------------------------------------------------
# the loop


def _line(step, total, loss, aux, rate, eta):
    fill = int(24 * step / max(total, 1))
    stab = "stab off" if aux[2] is None else f"stab {aux[2]:.5f} conv {aux[3]:.2f}"
    return (f"[{'#' * fill}{'.' * (24 - fill)}] {step}/{total} loss {loss:.4f} fid {aux[0]:.4f} "
            f"bin {aux[1]:.4f} {stab} | {rate:.2f} steps/s eta {eta:.0f}s")


@x64
def train(cfg: dict, out: str, resume: bool = False, log=sys.stderr, max_steps: int | None = None):
    """Train per ``cfg``; checkpoints in ``out``. Returns (params, history).
    ``max_steps``: stop (with a checkpoint) after this many steps of this
    call, for tests of resuming. Runs in float64 (the library's scope)."""
    probs_fn, step_fn, opt = make_fns(cfg)[:3]  # ConfigError (e.g. no optax) before anything is written
    if cfg["stability_solves"] == "batch":
        try:
            check_batched_linalg(cfg["batch"])  # the batch's soft problems are solved under vmap
        except RuntimeError as exc:
            raise ConfigError(str(exc)) from None
    ckpt = os.path.join(out, "checkpoint.npz")
    resuming = resume and os.path.exists(ckpt)
    # init's parameters (a ConfigError before anything is written), unless the run resumes past them
    start = params_from(cfg["init"], cfg) if cfg["init"] and not resuming else None
    os.makedirs(out, exist_ok=True)
    if resuming:
        params, opt_state, step, rng, stored, history = load_checkpoint(ckpt, cfg)
        diff = config_diff(stored, cfg, ignore=("steps",))
        if diff:
            raise ConfigError(f"{ckpt}: checkpoint was trained with a different config ({', '.join(diff)})")
        print(f"resuming from {ckpt} at step {step}", file=log)
    else:
        params = initial_params(cfg) if start is None else start
        opt_state = opt.init(params)
        step, rng, history = 0, np.random.default_rng(cfg["seed"]), []
    train_shapes, val, held = dataset(cfg, validation=True)
    tr = shape_arrays(train_shapes, cfg)
    if cfg["sample"] == "layers":
        tr = tr.layer_samples()
    ev_val = shape_arrays(val, cfg)
    ev_idx = np.random.default_rng(cfg["data_seed"] + 1).permutation(len(train_shapes))[: cfg["eval_train"]]
    ev_tr = shape_arrays([train_shapes[i] for i in sorted(ev_idx)], cfg)
    ev_he = shape_arrays(held, cfg) if cfg["eval_heldout"] else None
    lam = np.float64(cfg["lam"])
    stability = cfg["lam"] > 0
    how = ("; lam 0: no stability term" if not stability else
           f"; subsets solved {solve_jobs(cfg)} at a time, XLA's CPU pool {pool_threads()} threads"
           if cfg["stability_solves"] == "each" else "")
    print(f"{len(train_shapes)} training shapes ({len(val)} validation, {len(held)} held out), from step {step} "
          f"of {cfg['steps']}; the first step compiles{how}", file=log, flush=True)
    t0, s0 = time.perf_counter(), step
    done = 0
    with one_blas_thread():
        while step < cfg["steps"] and (max_steps is None or done < max_steps):
            x, valid, target, _, sub = draw_batch(tr, cfg, rng, params, probs_fn if stability else None)
            if sub is None:  # no stability term: no subsets
                sub = Subset(None, None, None, None)
            bw = np.float64(bin_weight(cfg, step))
            params, opt_state, loss, aux = step_fn(params, opt_state, lam, bw, x, valid, target, sub)
            step += 1
            done += 1
            aux = [float(a) for a in aux[:2]] + ([float(a) for a in aux[2:]] if stability else [None, None])
            el = time.perf_counter() - t0
            rate = (step - s0) / el
            if step % cfg["log_every"] == 0 or step == cfg["steps"]:
                history.append({"step": step, "loss": float(loss), "fidelity": aux[0], "binarize": aux[1],
                                "stability": aux[2], "converged": aux[3], "time_s": round(el, 2)})
                print(_line(step, cfg["steps"], float(loss), aux, rate, (cfg["steps"] - step) / rate), file=log,
                      flush=True)
            if step % cfg["eval_every"] == 0 or step == cfg["steps"]:
                rec = {"step": step, "eval": True}
                print(f"  evaluating at step {step} (decoded layouts judged by the exact solver)", file=log, flush=True)
                for name, arr in (("train", ev_tr), ("val", ev_val), ("heldout", ev_he)):
                    if arr is None or not arr.names:
                        continue
                    r = decode_and_score(params, arr, cfg, probs_fn)
                    rec[f"{name}_stable"] = float(np.mean([a[0] for a in r]))
                    rec[f"{name}_iou"] = float(np.mean([a[1] for a in r]))
                    r = decode_and_score(params, arr, cfg, probs_fn, fill=True)
                    rec[f"{name}_stable_filled"] = float(np.mean([a[0] for a in r]))
                history.append(rec)
                print(f"  eval at step {step}: " + ", ".join(f"{k} {v:.3f}" for k, v in rec.items()
                                                          if k not in ("step", "eval")), file=log, flush=True)
            if step % cfg["checkpoint_every"] == 0 or step == cfg["steps"] or (
                    max_steps is not None and done == max_steps):
                save_checkpoint(ckpt, params, opt_state, step, rng, cfg, history)
    return params, history


def run(config: str, out: str | None = None, resume: bool = False, seed: int | None = None,
        lam: float | None = None, steps: int | None = None, jobs: int | None = None,
        widen_pool: bool = False, init: str | None = None) -> int:
    """``stablelego train``: load ``config``, train, write OUT/checkpoint.npz
    and OUT/history.json; exit status (2: bad config, nothing written).
    ``seed``, ``lam``, ``steps``, ``jobs`` (``solve_jobs``), ``init``: overrides.
    ``widen_pool`` (the program, before JAX's backend starts): with
    subsets solved one per call, XLA's CPU pool gets every core
    (:func:`~stablelego_jax.blas.widen_xla_pool`): each solve's products
    run on all of them, and ``solve_jobs`` solves run at once (with the
    one-thread pool they queue for its thread)."""
    try:
        cfg = load_config(config, seed=seed, lam=lam, steps=steps, solve_jobs=jobs, init=init)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if widen_pool and cfg["stability_solves"] == "each" and cfg["lam"] > 0:
        from ..batch import cpu_cores
        from ..blas import widen_xla_pool

        widen_xla_pool(cpu_cores())
    out = out or os.path.join("out", f"train_lam{cfg['lam']:g}_seed{cfg['seed']}")
    t0 = time.perf_counter()
    try:
        _, history = train(cfg, out, resume)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    atomic_write_text(os.path.join(out, "history.json"),
                      json.dumps({"config": cfg, "history": history, "wall_s": time.perf_counter() - t0}, indent=1))
    print(f"done: {out}/checkpoint.npz ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    return 0
