"""High-level analysis: layout -> compiled model -> solve -> Eq. 10 scores."""
from __future__ import annotations

import dataclasses
import functools
import time

import jax
import numpy as np

from .blas import one_blas_thread
from .exact import solve_exact
from .io import load_layout
from .layout import Layout, LayoutError, Library
from .model import ForceModel, Params, bucket_size, compile_layout
from .score import brick_scores, residual
from . import ipm
from .solver import SolverOptions, solve, to_problem

jax.config.update("jax_enable_x64", True)

__all__ = ["Analysis", "analyze", "analyze_layout", "error_message", "pad_to_bucket", "solve_jax"]


@dataclasses.dataclass
class Analysis:
    """Result of analysing one layout.

    scores: {key: Eq. 10 score}; stable: every score < 1; weakest: key of
    the highest score (ties broken by the larger drag); forces: (m,) solved
    force per column (N, see model.ForceModel); max_drag: {key: N};
    residual: (n, 6) equilibrium residual (N, N m); converged/iters/gap:
    solver diagnostics (the exact solver reports HiGHS success).
    method: "ours" (paper Eq. 9) or a baseline ("luo", "eb"; see
    :mod:`~stablelego_jax.baselines`, where stable == solvable and an
    unsolvable layout has no scores, weakest or forces); solvable: always
    True for ours.
    """

    file: str
    layout: Layout
    model: ForceModel
    solver: str
    scores: dict
    stable: bool
    weakest: str
    forces: np.ndarray
    max_drag: dict
    residual: np.ndarray
    converged: bool
    time_s: float
    iters: int = 0
    gap: float = 0.0
    objective: float = float("nan")
    method: str = "ours"
    solvable: bool | None = True

    def to_json(self) -> dict:
        out = {
            "file": self.file,
            "stable": self.stable,
            "weakest": self.weakest,
            "scores": {k: round(float(v), 6) for k, v in self.scores.items()},
            "n_bricks": self.layout.n,
            "solver": self.solver,
            "converged": self.converged,
            "time_s": round(self.time_s, 6),
        }
        if self.method != "ours":  # baselines (see baselines.py): "unsolvable" is an answer
            out.update(method=self.method, solvable=self.solvable)
        return out


def error_message(path: str, exc: Exception) -> str:
    """One-line message for an input that failed, naming ``path`` once
    (layout and file errors as they are, anything else with its type)."""
    text = str(exc) if isinstance(exc, (LayoutError, OSError)) else f"{type(exc).__name__}: {exc}"
    return text if path in text else f"{path}: {text}"


def pad_to_bucket(model: ForceModel) -> ForceModel:
    """Pad a model to the bucket ladder so similar sizes share one compile."""
    return model.pad(bucket_size(model.n), bucket_size(model.m, base=64), bucket_size(model.group.shape[1], base=4))


@functools.lru_cache(maxsize=None)
def _jitted(params: Params, opts):
    fn = solve if isinstance(opts, SolverOptions) else ipm.solve
    return jax.jit(functools.partial(fn, params=params, opts=opts))


def solve_jax(model: ForceModel, opts=None):
    """Solve one model with a jit-compiled JAX solver, padded to its bucket.

    opts: :class:`~stablelego_jax.ipm.IPMOptions` or None (interior point,
    dense or layer-by-layer as :func:`~stablelego_jax.ipm.solve_plan`
    chooses) or :class:`~stablelego_jax.solver.SolverOptions` (ADMM).
    Returns (Solution, model the forces belong to: padded, bricks in input
    order)."""
    if isinstance(opts, SolverOptions):
        padded = pad_to_bucket(model)
        return jax.device_get(_jitted(model.params, opts)(to_problem(padded))), padded
    opts = opts or ipm.IPMOptions()
    m_pad, p_pad = bucket_size(model.m, base=64), bucket_size(model.group.shape[1], base=4)
    padded, prob = ipm.plan_problem(model, ipm.solve_plan(model), m_pad, p_pad)
    return jax.device_get(_jitted(model.params, opts)(prob)), padded


def _finish(layout, model, f, solver, converged, t0, **diag) -> Analysis:
    s, bad, dmax = (np.asarray(a)[: model.n] for a in brick_scores(model, f))
    order = np.lexsort((dmax, s))  # by score, then drag
    w = int(order[-1])
    return Analysis(
        file=layout.source,
        layout=layout,
        model=model,
        solver=solver,
        scores=dict(zip(layout.keys, s.tolist())),
        stable=bool((s < 1.0).all()),
        weakest=layout.keys[w],
        forces=np.asarray(f)[: model.m],
        max_drag=dict(zip(layout.keys, dmax.tolist())),
        residual=np.asarray(residual(model, f))[: model.n],
        converged=bool(converged),
        time_s=time.perf_counter() - t0,
        **diag,
    )


def analyze_layout(
    layout: Layout,
    solver: str = "jax",
    params: Params = Params(),
    opts=None,
    exact_method: str = "highs",
    exact_scale: bool = True,
    method: str = "ours",
) -> Analysis:
    """Analyse an in-memory layout with ``solver`` in {"jax", "admm", "exact"}.

    "jax": the batched-ready interior-point solver (:mod:`~stablelego_jax.ipm`;
    ``opts`` an IPMOptions, or a SolverOptions to run ADMM instead);
    "admm": the first-order solver (:mod:`~stablelego_jax.solver`);
    "exact": HiGHS.

    ``exact_method``, ``exact_scale``: HiGHS method and row scaling of the
    exact solver (see :func:`~stablelego_jax.exact.solve_exact`;
    "highs-ipm" with scaling is the fast, robust choice for layouts of
    hundreds of bricks). ``method``: "ours" (paper Eq. 9), or the baselines
    "luo" / "eb" (exact solver only; see :mod:`~stablelego_jax.baselines`)."""
    from .baselines import METHODS, analyze_baseline

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r} (expected one of {', '.join(METHODS)})")
    if method != "ours" and solver != "exact":
        raise ValueError(f"method {method!r} runs on the exact solver only (solver='exact'), not {solver!r}")
    t0 = time.perf_counter()
    model = compile_layout(layout, params)
    if method != "ours":
        return analyze_baseline(layout, model, method, t0, exact_method=exact_method, scale=exact_scale)
    if solver == "exact":
        r = solve_exact(model, method=exact_method, scale=exact_scale)
        return _finish(layout, model, r.f, "exact", r.success, t0, objective=r.objective)
    if solver not in ("jax", "admm"):
        raise ValueError(f"unknown solver {solver!r} (expected 'jax', 'admm' or 'exact')")
    if solver == "admm" and not isinstance(opts, SolverOptions):
        opts = SolverOptions()
    with one_blas_thread():  # JAX's CPU LAPACK goes through OpenBLAS (see blas.py)
        sol, padded = solve_jax(model, opts)
        f = np.asarray(sol.f)
    return _finish(
        layout, padded, f, solver, bool(sol.converged), t0,
        iters=int(sol.iters), gap=float(sol.gap), objective=float(sol.objective),
    )


def analyze(
    source,
    solver: str = "jax",
    library: Library | str | None = None,
    params: Params = Params(),
    opts=None,
    method: str = "ours",
) -> Analysis:
    """Analyse a layout file / dataset folder path, or a Layout (``method``:
    see :func:`analyze_layout`)."""
    layout = source if isinstance(source, Layout) else load_layout(str(source), library)
    return analyze_layout(layout, solver=solver, params=params, opts=opts, method=method)
