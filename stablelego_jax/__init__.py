"""stablelego-jax: differentiable, batched stability analysis of Lego brick layouts.

The public API, by layer (each name lives in the module given; importing
the package imports none of them until first use, so ``stablelego --help``
and ``import stablelego_jax`` stay fast and do not touch JAX)::

    formats   load_layout, write_layout, parse_json_layout, parse_text_layout,
              read_ldr, write_ldr, read_object, write_object
    layout    Layout, LayoutError, Library, default_library, make_layout, brick_layout
    model     Params, ForceModel, compile_layout
    soft      SoftProblem, Candidate, candidate_brick, compile_soft, compile_placements, soft_problem
    solvers   IPMOptions, solve_exact, pad_soft
    score     brick_scores
    loss      LossOptions, stability_loss, brick_loss, fail_prob, soft_scores, soft_report, solve_soft
    analysis  Analysis, analyze, analyze_layout
    batch     score_files
    design    repair, greedy_repair, rollback_repair, RepairOptions
    render    render_heatmap

JAX runs in float64 inside the library only (:mod:`stablelego_jax.runtime`):
the caller's JAX configuration is never changed, with one exception: on
jaxlib 0.10 to 0.11.1, importing the package sets ``PJRT_NPROC=1`` (one
thread in XLA's CPU intra-op pool) unless ``PJRT_NPROC`` or ``NPROC`` is set,
because those versions' batched LAPACK kernels can deadlock a larger pool
(:func:`stablelego_jax.blas.one_xla_pool_thread`). Work that solves one
problem at a time may set it to its cores before the import; the library's
batched calls then stop with an error rather than hang
(:func:`stablelego_jax.blas.check_batched_linalg`).
"""
from __future__ import annotations

import importlib

from .blas import one_xla_pool_thread

__version__ = "0.3.0"

# before JAX's CPU backend starts: see stablelego_jax.blas
one_xla_pool_thread()

#: public name -> module that defines it
_EXPORTS = {
    "Layout": "layout",
    "LayoutError": "layout",
    "Library": "layout",
    "default_library": "layout",
    "make_layout": "layout",
    "brick_layout": "layout",
    "load_layout": "formats.reader",
    "write_layout": "formats.reader",
    "parse_json_layout": "formats.stablelego",
    "parse_text_layout": "formats.stablelego",
    "read_ldr": "formats.ldraw",
    "write_ldr": "formats.ldraw",
    "read_object": "formats.dataset",
    "write_object": "formats.dataset",
    "Params": "model",
    "ForceModel": "model",
    "compile_layout": "model",
    "SoftProblem": "soft",
    "Candidate": "soft",
    "candidate_brick": "soft",
    "compile_soft": "soft",
    "compile_placements": "soft",
    "soft_problem": "soft",
    "IPMOptions": "solvers.ipm",
    "solve_exact": "solvers.exact",
    "pad_soft": "solvers.problem",
    "brick_scores": "score",
    "LossOptions": "loss",
    "stability_loss": "loss",
    "brick_loss": "loss",
    "fail_prob": "loss",
    "soft_scores": "loss",
    "soft_report": "loss",
    "solve_soft": "loss",
    "Analysis": "analysis",
    "analyze": "analysis",
    "analyze_layout": "analysis",
    "score_files": "batch",
    "repair": "design.repair",
    "greedy_repair": "design.repair",
    "rollback_repair": "design.repair",
    "RepairOptions": "design.repair",
    "render_heatmap": "render",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'stablelego_jax' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{mod}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
