"""High-level analysis: layout -> compiled model -> solve -> Eq. 10 scores."""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from .blas import one_blas_thread
from .formats.reader import load_layout
from .layout import Layout, LayoutError, Library
from .model import ForceModel, Params, compile_layout
from .score import brick_scores, floating_bricks, residual, weakest_brick
from .solvers.baselines import METHODS, residual_split, solve_baseline
from .solvers.exact import solve_exact

# The JAX solvers are imported where they are used: importing JAX costs most
# of a second, which an exact-solver run never needs.

__all__ = ["Analysis", "analyze", "analyze_layout", "analyze_exact", "analyze_baseline", "make_analysis", "error_message",
           "solve_jax", "solver_fn", "resolve_unconverged", "LONGER_RUN", "auto_solver", "JAX_START_S",
           "SOLVERS", "REMOVED_SOLVERS", "SINGLE_NAME", "pick_solver"]

#: A JAX run stopped at its iteration cap is tried again with this many times the cap.
LONGER_RUN = 4

#: The solvers of :func:`analyze_layout` and of the batch engine: the JAX
#: interior point, HiGHS, and "auto" (whichever of the two is estimated
#: faster: :func:`auto_solver` for one layout, ``batch.auto_split`` per group
#: of layouts). Each returns the canonical force distribution (README,
#: "One answer per layout"); the first-order ADMM, which could not, was
#: removed in version 0.3.
SOLVERS = ("jax", "exact", "auto")

#: Solvers of earlier versions, each with what to use instead (the one-line error a caller gets).
REMOVED_SOLVERS = {"admm": "the first-order ADMM solver was removed in version 0.3 (it could not give the "
                           "canonical force distribution); use jax (the JAX interior point), exact or auto"}


def pick_solver(solver: str, method: str = "ours") -> str:
    """The solver that answers ``method`` when ``solver`` is asked for: a
    baseline method ("luo", "eb") runs on the exact solver only, so "auto"
    becomes "exact" there. ValueError (one line) for an unknown solver or
    method, or a baseline asked of a JAX solver."""
    if solver in REMOVED_SOLVERS:
        raise ValueError(f"solver {solver!r}: {REMOVED_SOLVERS[solver]}")
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r} (expected one of {', '.join(SOLVERS)})")
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r} (expected one of {', '.join(METHODS)})")
    if method == "ours":
        return solver
    if solver not in ("exact", "auto"):
        raise ValueError(f"method {method!r} runs on the exact solver only (solver 'exact' or 'auto'), not {solver!r}")
    return "exact"


@dataclasses.dataclass
class Analysis:
    """Result of analysing one layout.

    scores: {key: Eq. 10 score}; stable: every score < 1; weakest: key of
    the highest score (ties within 1e-6: the larger drag, then input order; score.weakest_brick); forces: (m,) solved
    force per column (N, see model.ForceModel); max_drag: {key: N};
    residual: (n, 6) equilibrium residual (N, N m); converged/iters/gap:
    solver diagnostics (the exact solver reports HiGHS success).
    method: "ours" (paper Eq. 9) or a baseline ("luo", "eb"; see
    :mod:`~stablelego_jax.solvers.baselines`, where stable == solvable and an
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
    retried: tuple = ()

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
        if self.retried:  # the runs that did not converge before ``solver`` produced this answer
            out["retried"] = list(self.retried)
        return out


def error_message(path: str, exc: Exception) -> str:
    """One-line message for an input that failed, naming ``path`` once
    (layout and file errors as they are, anything else with its type)."""
    text = str(exc) if isinstance(exc, (LayoutError, OSError)) else f"{type(exc).__name__}: {exc}"
    if isinstance(exc, LayoutError) or (isinstance(exc, OSError) and exc.filename):
        return text  # names the file at fault (a library, an output), which may not be ``path``
    return text if path in text else f"{path}: {text}"


def solver_fn(params: Params, opts):
    """``fn(*problem arrays) -> tuple(Solution)`` of the JAX interior point
    with ``opts`` (:class:`~stablelego_jax.solvers.ipm.IPMOptions`), for
    :func:`~stablelego_jax.solvers.compiled.compiled`."""
    from .solvers import ipm
    from .solvers.problem import Problem

    def fn(*arrays):
        return tuple(ipm.solve(Problem(*arrays), params, opts))

    return fn


def solve_jax(model: ForceModel, opts=None):
    """Solve one model with a compiled JAX solver, padded to its bucket.

    opts: :class:`~stablelego_jax.solvers.ipm.IPMOptions` or None (interior point,
    dense or layer-by-layer as :func:`~stablelego_jax.solvers.problem.solve_plan`
    chooses, fitted to the layout when that saves more than a compile:
    :func:`~stablelego_jax.solvers.problem.fit_plan`).
    Returns (Solution of numpy arrays, model the forces belong to: padded,
    bricks in input order)."""
    import jax

    from .solvers import ipm
    from .solvers.compiled import compiled
    from .solvers.problem import Solution

    padded, arrays, opts = _single_problem(model, opts or ipm.IPMOptions())
    exe = compiled(SINGLE_NAME, solver_fn(model.params, opts), (model.params, opts), arrays)
    return Solution(*jax.device_get(exe(*arrays))), padded


def _single_plan(model: ForceModel) -> tuple:
    """(bucket, padded columns, padded contact slots) of :func:`solve_jax`."""
    from .solvers.problem import MIN_COLUMNS, MIN_SLOTS, fit_plan, rung, solve_plan

    m_pad, p_pad = rung(model.m, MIN_COLUMNS), rung(model.group.shape[1], MIN_SLOTS)
    return fit_plan(model, solve_plan(model), m_pad), m_pad, p_pad


#: Name of :func:`solve_jax`'s executables (:func:`~stablelego_jax.solvers.compiled.compiled`).
SINGLE_NAME = "ipm"


def _single_problem(model: ForceModel, opts, plan: tuple | None = None):
    """(padded model, problem arrays, options for it:
    :func:`~stablelego_jax.solvers.ipm.options_for`) of :func:`solve_jax`
    (``plan``: :func:`_single_plan`'s, if computed already)."""
    from .solvers import ipm
    from .solvers.problem import plan_problem

    padded, prob = plan_problem(model, *(plan or _single_plan(model)))
    return padded, tuple(a for a in prob if a is not None), ipm.options_for(opts, prob)


#: Seconds the JAX solver's first answer in a process costs beyond the
#: exact solver's, besides compiling or loading its executable: starting
#: JAX's backend. ``stablelego analyze examples/stablelego/stair_20.json``
#: with the executable on disk: 1.87-2.01 s with ``--solver jax``,
#: 1.85-1.87 s with ``--solver exact`` (2026-11-26, BENCHMARKS.md).
JAX_START_S = 0.2


def auto_solver(model: ForceModel) -> str:
    """"exact" or "jax": the solver of ``solver="auto"`` for one layout,
    whichever is estimated faster: HiGHS
    (:func:`~stablelego_jax.solvers.exact.estimated_seconds`) or the
    interior point: its solve (:func:`~stablelego_jax.solvers.problem.plan_seconds`)
    plus ``JAX_START_S`` plus loading its executable (``LOAD_S``) when it is
    in this process or on disk, else compiling it (``SINGLE_COMPILE_S``)."""
    import jax

    from .solvers import ipm
    from .solvers.compiled import available
    from .solvers.exact import estimated_seconds
    from .solvers.problem import LOAD_S, SINGLE_COMPILE_S, plan_seconds

    exact_s = estimated_seconds(model)
    plan = _single_plan(model)
    jax_s = JAX_START_S + plan_seconds(*plan[:2]) + LOAD_S
    if exact_s < jax_s:  # no need to pad the problem for the check below
        return "exact"
    _, arrays, opts = _single_problem(model, ipm.IPMOptions(), plan)
    specs = [jax.ShapeDtypeStruct(np.shape(a), np.result_type(a)) for a in arrays]
    if not available(SINGLE_NAME, (model.params, opts), specs):
        jax_s += SINGLE_COMPILE_S - LOAD_S
    return "exact" if exact_s < jax_s else "jax"


def resolve_unconverged(a: "Analysis", opts=None, params: Params | None = None) -> "Analysis":
    """The answer for a layout whose JAX run ``a`` did not converge, so that
    an unconverged result is never reported as a label: a longer run
    (:data:`LONGER_RUN` times the iteration cap; only when ``a`` stopped at
    its cap, since a run that stalled before it would stall again), then
    the exact solver (HiGHS). The Analysis returned has ``solver`` = the
    solver that produced it and ``retried`` = the runs that did not
    converge; ``converged`` is False only if HiGHS failed too."""
    from .solvers import ipm

    t0 = time.perf_counter() - a.time_s
    params = params or a.model.params
    opts = opts or ipm.IPMOptions()
    model = compile_layout(a.layout, params)
    tried = [f"{a.solver}: {a.iters} iterations, gap {a.gap:.1e}"]
    if a.iters >= opts.max_iter:
        longer = dataclasses.replace(opts, max_iter=opts.max_iter * LONGER_RUN)
        with one_blas_thread():
            sol, padded = solve_jax(model, longer)
        if bool(sol.converged):
            return make_analysis(a.layout, padded, np.asarray(sol.f), a.solver, True, t0, iters=int(sol.iters),
                                 gap=float(sol.gap), objective=float(sol.objective), retried=tuple(tried))
        tried.append(f"{a.solver} x{LONGER_RUN}: {int(sol.iters)} iterations, gap {float(sol.gap):.1e}")
    r = solve_exact(model, method="highs-ipm", scale=True)
    if not r.success:
        r = solve_exact(model, method="highs", scale=True)
    return make_analysis(a.layout, model, r.f, "exact", r.success, t0, objective=r.objective, retried=tuple(tried))


def make_analysis(layout, model, f, solver, converged, t0, **diag) -> Analysis:
    """The :class:`Analysis` of forces ``f`` ((m_pad,) N) solved on ``model``
    for ``layout`` by ``solver``; ``t0``: start time (perf_counter). Bricks
    with no chain of contacts to the ground fail (:func:`floating_bricks`)."""
    s, bad, dmax = (np.asarray(a)[: model.n] for a in brick_scores(model, f, floating=floating_bricks(model)))
    w = weakest_brick(s, dmax, model.params.T)
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
    fallback: bool = True,
) -> Analysis:
    """Analyse an in-memory layout with ``solver`` in {"jax", "exact", "auto"}.

    "jax": the batched-ready interior-point solver (:mod:`~stablelego_jax.solvers.ipm`;
    ``opts``: its IPMOptions, None for the defaults);
    "exact": HiGHS; "auto": "exact" or "jax", whichever :func:`auto_solver`
    estimates faster (the Analysis' ``solver`` says which).

    ``exact_method``, ``exact_scale``: HiGHS method and row scaling of the
    exact solver (see :func:`~stablelego_jax.solvers.exact.solve_exact`;
    "highs-ipm" with scaling is the fast, robust choice for layouts of
    hundreds of bricks). ``method``: "ours" (paper Eq. 9), or the baselines
    "luo" / "eb" (exact solver only; see :mod:`~stablelego_jax.solvers.baselines`).
    ``fallback``: a JAX run that did not converge is solved again
    (:func:`resolve_unconverged`); False returns it as it is."""
    solver = pick_solver(solver, method)
    t0 = time.perf_counter()
    model = compile_layout(layout, params)
    if solver == "auto":
        solver = auto_solver(model)
    if solver == "exact":
        return analyze_exact(layout, model, method, t0, exact_method, exact_scale)
    with one_blas_thread():  # JAX's CPU LAPACK goes through OpenBLAS (see blas.py)
        sol, padded = solve_jax(model, opts)
        f = np.asarray(sol.f)
    a = make_analysis(
        layout, padded, f, solver, bool(sol.converged), t0,
        iters=int(sol.iters), gap=float(sol.gap), objective=float(sol.objective),
    )
    if fallback and not a.converged:
        a = resolve_unconverged(a, opts, params)
    return a


def analyze_exact(layout: Layout, model: ForceModel, method: str = "ours", t0: float | None = None,
                  exact_method: str = "highs", exact_scale: bool = True) -> Analysis:
    """The :class:`Analysis` of ``layout`` (compiled as ``model``) by HiGHS:
    paper Eq. 9 (``method`` "ours") or a baseline (:func:`analyze_baseline`);
    ``t0``: start time (perf_counter; None: now)."""
    t0 = time.perf_counter() if t0 is None else t0
    if method != "ours":
        return analyze_baseline(layout, model, method, t0, exact_method=exact_method, scale=exact_scale)
    r = solve_exact(model, method=exact_method, scale=exact_scale)
    return make_analysis(layout, model, r.f, "exact", r.success, t0, objective=r.objective)


def analyze(
    source,
    solver: str = "jax",
    library: Library | str | None = None,
    params: Params = Params(),
    opts=None,
    method: str = "ours",
    skip_unsupported: bool = False,
    report: dict | None = None,
    fallback: bool = True,
) -> Analysis:
    """Analyse a layout file / dataset folder path, or a Layout (``method``,
    ``fallback``: see :func:`analyze_layout`; ``skip_unsupported``,
    ``report``: LDraw parts that cannot be modelled, see
    :func:`~stablelego_jax.formats.reader.load_layout`)."""
    layout = source if isinstance(source, Layout) else load_layout(str(source), library, skip_unsupported, report)
    return analyze_layout(layout, solver=solver, params=params, opts=opts, method=method, fallback=fallback)


def analyze_baseline(layout: Layout, model: ForceModel, method: str, t0: float | None = None, **kw) -> Analysis:
    """An :class:`Analysis` of ``layout`` (compiled as ``model``) under
    baseline ``method``; ``kw`` go to
    :func:`~stablelego_jax.solvers.baselines.solve_baseline`.

    ``solvable`` and ``stable`` (= solvable) are the baseline's answer;
    ``scores`` are each brick's capacity use, largest bottom drag / T (at
    most 1 by the constraint; the paper's Eq. 10 without its equilibrium
    test, which is a constraint here); ``weakest`` the brick using most.
    An unsolvable layout has no forces: empty ``scores``/``max_drag``,
    ``weakest``, ``forces`` and ``residual`` None. ``converged`` says the
    solver reached a definite answer (optimal or proved infeasible).
    """
    t0 = time.perf_counter() if t0 is None else t0
    r = solve_baseline(model, method, **kw)
    keys = list(layout.keys)
    scores, dmax, weakest, res = {}, {}, None, None
    if r.solvable:
        T = model.params.T
        s = np.minimum(r.max_drag / T, 1.0)
        scores = dict(zip(keys, s.tolist()))
        dmax = dict(zip(keys, r.max_drag.tolist()))
        weakest = keys[weakest_brick(s, r.max_drag, T)]
        res = residual_split(model, r.f_split)
    forces = r.f[: model.m] if r.f is not None else r.f_split
    return Analysis(
        file=layout.source, layout=layout, model=model, solver="exact", scores=scores,
        stable=bool(r.solvable), weakest=weakest, forces=forces, max_drag=dmax, residual=res,
        converged=r.success, time_s=time.perf_counter() - t0,
        objective=r.objective, method=method, solvable=r.solvable,
    )
