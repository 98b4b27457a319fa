"""Exact referee: the Eq. 9 problem as a linear programme solved by HiGHS,
and its canonical (least-norm) optimal force distribution.

Variables: forces f (m), drags D (one per NORMAL column), residual parts
r+ and r- (6 n each) and per-brick max drag t (n). Minimises
``sum |A f + g|_1 + alpha sum t + beta sum D`` subject to ``D >= -n``,
``D <= t`` for every contact of the brick, SIDE presses >= 0.

Eq. 9's optimum is often not unique (a statically indeterminate layout
carries its weight in many ways at the same cost), and each LP method
returns a different optimal vertex, hence different per-brick scores. The
*canonical* distribution (the default) is the least-norm optimum: among the
optimal solutions of Eq. 9, the one of least ``|f|^2`` (f: the forces, N).
It is unique (strictly convex in the forces, which fix every other
variable), symmetric for symmetric layouts and continuous in the loads.
Here it is computed in two stages: the LP's optimal cost c* (HiGHS), then
``min |f|^2 / 2`` over the constraints and ``cost <= c* + 1e-9 |c*| +
1e-12`` (the optimal set, to the LP solve's accuracy) by Clarabel, an
interior-point method (HiGHS' QP method is an active-set method that stalls
at ~100 bricks). The JAX interior point reaches the same point through
the minimiser of Eq. 9's cost plus ``ridge / (2 W) |f|^2`` (``Params.ridge``
= 1e-8, W the layout's total weight), which for a small enough ridge is
exactly the least-norm optimum (exact regularisation of linear programmes,
Mangasarian and Meyer 1979). A one-stage QP with that ridge is not solved
here: the ridge term is far below any solver's tolerance on the cost, so
the QP's answer drifts along the optimal set (up to 0.02 in a score on
measured layouts), where the second stage's objective is the norm itself.
"""
from __future__ import annotations

import numpy as np

from ..model import NORMAL, SIDE, ForceModel

# scipy.sparse and scipy.optimize are imported where they are used: importing
# them costs about half a second, which the JAX path of a short run never needs.

__all__ = ["solve_exact", "solve_lp_interior", "least_norm", "least_norm_optimum", "solve_qp", "ExactResult",
           "EXACT_METHODS", "equilibrium_matrix", "lp_arrays", "estimated_seconds"]


class ExactResult(dict):
    """``f`` (m_pad,) forces (N), ``objective`` (their Eq. 9 cost),
    ``status`` (the solver's message), ``success`` (a solution was found),
    ``canonical`` (it is the canonical distribution, not an LP vertex)."""

    __getattr__ = dict.__getitem__


def equilibrium_matrix(model: ForceModel):
    """Sparse (6 n, m) equilibrium matrix (``scipy.sparse.csr_matrix``) of the real rows and columns."""
    import scipy.sparse as sp

    m, n = model.m, model.n
    cb, coef = model.col_brick[:m], model.col_coef[:m]
    rows, cols, vals = [], [], []
    for s in range(2):
        real = cb[:, s] < n
        c = np.nonzero(real)[0]
        r = (6 * cb[c, s])[:, None] + np.arange(6)[None, :]
        rows.append(r.ravel())
        cols.append(np.repeat(c, 6))
        vals.append(coef[c, s, :].ravel())
    A = sp.coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(6 * n, m)
    )
    return A.tocsr()


def estimated_seconds(model: ForceModel) -> float:
    """Rough seconds :func:`solve_exact` (canonical, the default) takes on
    one core for ``model``, from its real column count m:
    ``9.94e-4 m^0.696 + 7.61e-9 m^2.211``. Fitted (least squares in log
    time) to 225 layouts of 2-779 bricks (every 5th of
    ``benchmarks/results/small500``, every 4th of ``shard500``; 2026-11-26,
    the 2-core CPU of BENCHMARKS.md, ``score --solver exact --jobs 1``,
    Clarabel on one thread): measured / model 0.70-1.43 (10th-90th
    percentile), 384.5 s measured against 396.4 s modelled in all. The
    second term is the large blobs (600-800 bricks, 24000-37000 columns),
    where the canonical stage takes 51-67 s. Used by ``solver="auto"`` to
    pick a solver."""
    m = float(model.m)
    return 9.94e-4 * m ** 0.696 + 7.61e-9 * m ** 2.211


#: HiGHS methods of scipy.optimize.linprog that solve_exact accepts.
EXACT_METHODS = ("highs", "highs-ds", "highs-ipm")


def solve_exact(model: ForceModel, method: str = "highs", scale: bool = True, canonical: bool = True) -> ExactResult:
    """Solve Eq. 9 exactly: the canonical distribution (:func:`least_norm`:
    HiGHS' interior point for the optimal cost, whatever ``method``, then
    Clarabel) unless ``canonical`` is False or ``model.params.ridge`` is 0,
    else (and when a stage of it fails: ``status`` says so) the LP with HiGHS
    ``method`` ("highs": HiGHS chooses, in practice dual simplex;
    "highs-ds"; "highs-ipm": interior point with crossover, much faster on
    layouts of hundreds of bricks), an optimal vertex: on a degenerate LP
    different methods may return different optimal vertices (same
    objective, different per-brick scores).

    ``scale`` (default on): write the torque rows in N stud instead of N m (the same problem,
    better conditioned: in N m they are ~100x smaller than the force rows,
    near HiGHS' tolerances, and on layouts of hundreds of bricks HiGHS then
    stops with "Status 0: Not Set" or stalls).

    When the LP's first solve returns no solution, it is solved again scaled
    with "highs-ipm"; ``status`` then says so.
    """
    if method not in EXACT_METHODS:
        raise ValueError(f"method must be one of {EXACT_METHODS}, got {method!r}")
    f = np.zeros(model.m_pad)
    failed = ""
    if canonical and model.params.ridge > 0:
        x, msg, cost = least_norm(model, scale)
        if x is not None:
            f[:model.m] = x
            return ExactResult(f=f, objective=cost, status=f"canonical: {msg}", success=True, canonical=True)
        failed = f" (the canonical distribution failed: {msg}; an optimal LP vertex instead)"
    res = _solve_lp(model, method, scale)
    if res.status != 0 and (method, scale) != ("highs-ipm", True):
        first = res.message
        res = _solve_lp(model, "highs-ipm", True)
        res.message = f"{res.message} (scaled highs-ipm after {method}: {first})"
    if res.x is not None:
        f[:model.m] = res.x[:model.m]
    return ExactResult(f=f, objective=float(res.fun) if res.fun is not None else float("nan"),
                       status=res.message + failed, success=bool(res.status == 0), canonical=False)


def solve_lp_interior(model: ForceModel, scale: bool = True) -> ExactResult:
    """Eq. 9's LP by Clarabel's interior point (:func:`solve_qp` with no
    quadratic term, to 1e-10), no crossover: an optimal force distribution
    inside the optimal face, neither a vertex nor the canonical one. About
    4x faster than HiGHS' interior point with crossover on layouts of
    hundreds of bricks (a 327-brick blob, 8069 columns: 0.29 s against
    1.28 s, the same cost to 8 digits), for searches that judge many
    candidate layouts (:func:`~stablelego_jax.generate.stabilize.stabilize`).
    Where Clarabel fails, HiGHS' vertex (``status`` says so)."""
    c, A_eq, b_eq, A_ub, b_ub, bounds = lp_arrays(model, scale)
    x, status = solve_qp(c, A_eq, b_eq, A_ub, b_ub, bounds, np.zeros(len(c)), max_iter=400)
    if x is None:
        r = solve_exact(model, "highs-ipm", scale, canonical=False)
        r["status"] = f"{r.status} (after Clarabel: {status})"
        return r
    f = np.zeros(model.m_pad)
    f[:model.m] = x[:model.m]
    return ExactResult(f=f, objective=float(c @ x), status=f"Clarabel {status}", success=True, canonical=False)


def least_norm(model: ForceModel, scale: bool = True):
    """The canonical distribution of ``model``: the least-norm optimum of
    Eq. 9 (:func:`least_norm_optimum` over the variables of
    :func:`lp_arrays`). Returns ``(f, status, cost)``: f (m,) N or None when
    a stage failed, cost its Eq. 9 value (N-based units)."""
    c, A_eq, b_eq, A_ub, b_ub, bounds = lp_arrays(model, scale)
    x, status = least_norm_optimum(c, A_eq, b_eq, A_ub, b_ub, bounds, model.m)
    if x is None:
        return None, status, float("nan")
    return x[:model.m], status, float(c @ x)


def least_norm_optimum(c, A_eq, b_eq, A_ub, b_ub, bounds, k: int, cost: float | None = None):
    """Among the optimal solutions of the LP ``min c x`` (constraints as in
    :func:`solve_qp`), the one of least ``|x[:k]|^2`` (the forces). Two
    stages: the optimal cost (``cost`` when the caller has solved the LP
    with HiGHS, else HiGHS' interior point with crossover, whose vertex
    gives the cost to ~1e-10 relative: Clarabel's came out up to 1e-8 low),
    then ``min |x[:k]|^2 / 2`` by Clarabel subject to the constraints and
    ``c x <= cost + 1e-9 |cost| + 1e-12``. The slack is widened tenfold, up
    to ``1e-6 |cost|``, only while the cut leaves nothing feasible: the
    least-norm point of the cut moves with it (0.004 in a score from 1e-8
    to 1e-6 relative, on a measured layout). Returns ``(x, status)``: x
    None when a stage failed, status the solvers' words for both."""
    import scipy.sparse as sp

    N = len(c)
    first = ""
    if cost is None:
        res = _linprog((c, A_eq, b_eq, A_ub, b_ub, bounds), "highs-ipm")
        if res.status != 0:
            return None, f"optimal cost: {res.message}"
        cost, first = float(res.fun), "optimal cost HiGHS, "
    A2 = sp.vstack([A_ub, sp.csr_matrix(np.asarray(c, float)[None, :])]).tocsr()
    p = np.concatenate([np.ones(k), np.zeros(N - k)])
    for rel in (1e-9, 1e-8, 1e-7, 1e-6):
        x, st = solve_qp(np.zeros(N), A_eq, b_eq, A2, np.concatenate([b_ub, [cost + rel * abs(cost) + 1e-12]]),
                         bounds, p, max_iter=400)
        if x is not None:
            return x, f"{first}least norm Clarabel {st}" + (f" (cost slack {rel:g})" if rel > 1e-9 else "")
    return None, f"{first}least norm Clarabel {st}"


def solve_qp(c, A_eq, b_eq, A_ub, b_ub, bounds, p_diag, max_iter: int = 200):
    """``min c x + x diag(p_diag) x / 2`` subject to the constraints in
    :func:`scipy.optimize.linprog`'s form (sparse ``A_eq``, ``A_ub``;
    ``bounds`` (N, 2), +-inf where unbounded), by Clarabel to 1e-10 in at
    most ``max_iter`` iterations.
    Returns ``(x, status)``; x None unless Clarabel reports "Solved" or
    "AlmostSolved" (its reduced tolerances)."""
    import clarabel
    import scipy.sparse as sp

    N = len(c)
    lo, hi = bounds[:, 0], bounds[:, 1]
    fl, fh = np.nonzero(np.isfinite(lo))[0], np.nonzero(np.isfinite(hi))[0]
    A = sp.vstack([
        A_eq, A_ub,
        sp.csr_matrix((-np.ones(len(fl)), (np.arange(len(fl)), fl)), shape=(len(fl), N)),
        sp.csr_matrix((np.ones(len(fh)), (np.arange(len(fh)), fh)), shape=(len(fh), N)),
    ]).tocsc()
    b = np.concatenate([b_eq, b_ub, -lo[fl], hi[fh]])
    cones = [clarabel.ZeroConeT(A_eq.shape[0]), clarabel.NonnegativeConeT(A.shape[0] - A_eq.shape[0])]
    st = clarabel.DefaultSettings()
    st.verbose = False
    # one thread: Clarabel's default (one per core) left two worker threads
    # spinning in the kernel on large layouts (a 746-brick blob: 162-180 s,
    # 89-97 s of it system time; with one thread 65.5 s, 0.35 s system), and
    # in a pool of one worker per core they take the other workers' cores
    st.max_threads = 1
    st.tol_gap_abs = st.tol_gap_rel = st.tol_feas = 1e-10
    st.max_iter = int(max_iter)
    sol = clarabel.DefaultSolver(sp.diags(p_diag).tocsc(), np.asarray(c, float), A, b, cones, st).solve()
    if sol.status not in (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved):
        return None, str(sol.status)
    return np.asarray(sol.x), str(sol.status)


def lp_arrays(model: ForceModel, scale: bool = True):
    """The Eq. 9 LP that :func:`solve_exact` hands HiGHS, as arrays:
    ``(c, A_eq, b_eq, A_ub, b_ub, bounds)`` for
    ``min c x  s.t.  A_eq x = b_eq,  A_ub x <= b_ub,  bounds[:, 0] <= x <= bounds[:, 1]``
    (``A_eq``, ``A_ub`` ``scipy.sparse.csr_matrix``; ``bounds`` (N, 2),
    +-inf where unbounded). Variables: the m forces first (N, the columns of
    ``model``), then k drags, r+ (6 n), r- (6 n) and n max drags.

    ``scale``: torque rows in N stud instead of N m (see :func:`solve_exact`).
    For other LP solvers (benchmarks); HiGHS solves exactly these arrays.
    """
    import scipy.sparse as sp

    p = model.params
    m, n = model.m, model.n
    kind = model.col_kind[:m]
    # scale: torque rows in N stud instead of N m (row i times rs_i and its
    # residual cost divided by rs_i: the same LP, better conditioned)
    ts = 1.0 / p.stud if scale else 1.0
    rs = np.tile(np.array([1.0, 1.0, 1.0, ts, ts, ts]), n)
    A = sp.diags(rs) @ equilibrium_matrix(model)
    normal = np.nonzero(kind == NORMAL)[0]
    k = len(normal)
    owner = model.col_brick[normal, 0]
    g = model.gravity[:n].reshape(-1) * rs
    I6 = sp.identity(6 * n, format="csr")
    # equality: A f - r+ + r- = -g
    A_eq = sp.hstack([A, sp.csr_matrix((6 * n, k)), -I6, I6, sp.csr_matrix((6 * n, n))]).tocsr()
    b_eq = -g
    # -n_p - D_p <= 0 ; D_p - t_owner <= 0
    sel = sp.csr_matrix((np.ones(k), (np.arange(k), normal)), shape=(k, m))
    Ik = sp.identity(k, format="csr")
    own = sp.csr_matrix((np.ones(k), (np.arange(k), owner)), shape=(k, n))
    Z6 = sp.csr_matrix((k, 6 * n))
    A_ub = sp.vstack(
        [
            sp.hstack([-sel, -Ik, Z6, Z6, sp.csr_matrix((k, n))]),
            sp.hstack([sp.csr_matrix((k, m)), Ik, Z6, Z6, -own]),
        ]
    ).tocsr()
    b_ub = np.zeros(2 * k)
    c = np.concatenate([np.zeros(m), np.full(k, p.beta), np.tile(1.0 / rs, 2), np.full(n, p.alpha)])
    lo = np.where(kind == SIDE, 0.0, -np.inf)
    bounds = np.concatenate(
        [np.stack([lo, np.full(m, np.inf)], 1), np.tile([0.0, np.inf], (k + 12 * n + n, 1))]
    )
    return c, A_eq, b_eq, A_ub, b_ub, bounds


def _solve_lp(model: ForceModel, method: str, scale: bool):
    return _linprog(lp_arrays(model, scale), method)


def _linprog(arrays, method: str):
    """HiGHS (``scipy.optimize.linprog``, ``method``) on :func:`lp_arrays`-style arrays."""
    from scipy.optimize import linprog

    c, A_eq, b_eq, A_ub, b_ub, bounds = arrays
    return linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=b_eq, bounds=bounds, method=method)
