"""Baselines of the paper's Sec. IV on the exact solver (HiGHS via scipy).

Both baselines make equilibrium (paper Eqs. 1-2) and the friction capacity
(every drag D <= T) *hard constraints*: a layout is **solvable** when some
force distribution satisfies them all, and a baseline calls a layout stable
exactly when it is solvable. There is no answer, no weakest brick, for an
unsolvable layout (floating bricks, overloaded cantilevers, ...): that is
the gap the paper's Eq. 9 (equilibrium in the objective) closes.

``"luo"``: Luo et al. 2015, *without* the paper's Eqs. 4-5. Eq. 5 (SPEC:
"equal-and-opposite pairs are one variable") is what ties the force a
connection applies to its upper brick to the force it applies to the lower
one. Without it every pair member is a variable of its own: a column of
:class:`~stablelego_jax.model.ForceModel` becomes one variable per brick it
touches (``f_split[c, s]`` on brick ``col_brick[c, s]``), each with the
column's bounds: a contact point gives its upper brick ``S - D`` and its
lower brick ``P - U`` (press down minus drag up), each at least ``-T``;
knob presses are free; side presses ``>= 0``. Without Eq. 4 (S*D = 0) S and
D of one point may coexist; because S is unbounded, the set of reachable
``S - D`` is ``[-T, inf)`` either way, so one merged variable per side is
exact for solvability. The problem then splits brick by brick: a brick is
unsolvable only if its own contacts cannot hold its own weight (no vertical
contact at all, or a heavy brick hooked on too few points); loads are not
passed on from brick to brick.

``"eb"``: the enhanced baseline, Luo plus Eqs. 4-5. Eq. 5 restores the
merged model (one variable per pair, as in our LP). Eq. 4 (S*D = 0,
U*P = 0 at each contact point) is non-convex; ``formulation="milp"`` states
it literally as a mixed-integer programme (S, D >= 0 separate, a binary
z per point, ``S <= M z``, ``D <= T (1 - z)``, with
``M = total weight + (number of points) * T``, a valid bound: the layers
above any interface weigh what its ``S - D`` carry, so no feasible S exceeds
it). ``formulation="lp"`` (the default) solves the exact LP reduction:
every feasible ``n = S - D >= -T`` splits into ``S = max(n, 0)``,
``D = max(-n, 0)``, which satisfies Eq. 4, and every point with Eq. 4
gives such an n, so both have the same solvability and, because D has
positive cost, the same optimal objective. ``tests/test_baselines.py``
checks that the two formulations agree.

Forces of a solvable layout: the distribution minimising the drag part of
Eq. 9 (``alpha * sum_b max drag on b's bottom + beta * sum D``) over the
feasible set, i.e. the least-friction equilibrium; with ``canonical`` (the
default, LP formulation) the canonical one among them, as for Eq. 9 (the
least-norm optimum, :func:`~stablelego_jax.solvers.exact.least_norm_optimum`,
solved by Clarabel once HiGHS has found the layout solvable and its optimal
cost), so that a stable layout gets the same scores from eb as from Eq. 9.
"""
from __future__ import annotations

import time

import numpy as np

from ..model import KNOB, NORMAL, SIDE, ForceModel, normal_groups
from ..score import largest_drag
from .exact import EXACT_METHODS, equilibrium_matrix, least_norm_optimum

# scipy.sparse and scipy.optimize are imported where they are used (see exact.py)

__all__ = [
    "METHODS",
    "BASELINES",
    "EB_FORMULATIONS",
    "BaselineResult",
    "solve_baseline",
    "residual_split",
]

#: analysis methods: ours (paper Eq. 9) and the two baselines of its Sec. IV
METHODS = ("ours", "luo", "eb")
BASELINES = ("luo", "eb")
EB_FORMULATIONS = ("lp", "milp")


class BaselineResult(dict):
    """Result of :func:`solve_baseline` (attribute access to the keys).

    solvable: True (a feasible force distribution exists), False (proved
    infeasible) or None (the solver gave no definite answer: time limit or
    numerical failure; ``success`` is then False). f: (m,) merged column
    forces (eb) or None. f_split: (m, 2) force of each column on the brick of
    each slot (luo: independent; eb: both slots equal; NaN for the
    baseplate slot), None when not solvable. max_drag: (n,) largest drag on
    each brick's bottom contacts (N; luo: the larger of the upper brick's D
    and the lower brick's U of each point), NaN when not solvable. pair_mismatch:
    largest |f_split[c, 0] - f_split[c, 1]| over real pairs (N): how far a
    Luo solution is from Newton's third law (0 for eb). objective, status
    (HiGHS message), method, formulation, time_s (solve only).
    """

    __getattr__ = dict.__getitem__


def _lp_columns(model: ForceModel, method: str):
    """Equilibrium matrix and per-variable data of a baseline.

    Returns (A (6 n, q) sparse, kind (q,), col (q,), slot (q,), owner (q,)):
    variable j is column ``col[j]`` acting on the brick of slot ``slot[j]``
    (-1: both slots, one merged variable); ``owner[j]`` is the upper brick of
    the connection whose friction it is (-1: not a contact point).
    """
    import scipy.sparse as sp

    m, n = model.m, model.n
    kind = model.col_kind[:m]
    cb = model.col_brick[:m]
    if method == "eb":
        col = np.arange(m)
        owner = np.where(kind == NORMAL, cb[:, 0], -1)
        return equilibrium_matrix(model), kind, col, np.full(m, -1), owner
    cols, slots = [], []
    for s in range(2):
        c = np.nonzero(cb[:, s] < n)[0]
        cols.append(c)
        slots.append(np.full(len(c), s))
    col, slot = np.concatenate(cols), np.concatenate(slots)
    q = len(col)
    brick = cb[col, slot]
    coef = model.col_coef[col, slot, :]  # (q, 6)
    rows = (6 * brick)[:, None] + np.arange(6)[None, :]
    A = sp.csr_matrix((coef.ravel(), (rows.ravel(), np.repeat(np.arange(q), 6))), shape=(6 * n, q))
    vk = kind[col]
    # both drags of a contact point (D on the upper brick, U on the lower one) are
    # friction of the upper brick's bottom connection, as in Eq. 10
    owner = np.where(vk == NORMAL, cb[col, 0], -1)
    return A, vk, col, slot, owner


def _build(model: ForceModel, method: str, scale: bool):
    """Shared pieces of the LP/MILP: scaled equality rows and variable data."""
    import scipy.sparse as sp

    p = model.params
    n = model.n
    A, kind, col, slot, owner = _lp_columns(model, method)
    ts = 1.0 / p.stud if scale else 1.0
    rs = np.tile(np.array([1.0, 1.0, 1.0, ts, ts, ts]), n)
    A = (sp.diags(rs) @ A).tocsr()
    g = model.gravity[:n].reshape(-1) * rs
    return A, -g, kind, col, slot, owner


def _solve_lp(model: ForceModel, method: str, lp_method: str, scale: bool, time_limit: float | None,
              canonical: bool = True):
    import scipy.sparse as sp
    from scipy.optimize import linprog

    p = model.params
    n = model.n
    A, b, kind, col, slot, owner = _build(model, method, scale)
    q = A.shape[1]
    normal = np.nonzero(kind == NORMAL)[0]
    k = len(normal)
    hasown = np.nonzero(owner[normal] >= 0)[0]
    k0 = len(hasown)
    # variables [x (q), D (k), t (n)]
    A_eq = sp.hstack([A, sp.csr_matrix((A.shape[0], k + n))]).tocsr()
    sel = sp.csr_matrix((np.ones(k), (np.arange(k), normal)), shape=(k, q))
    Ik = sp.identity(k, format="csr")
    pick = sp.csr_matrix((np.ones(k0), (np.arange(k0), hasown)), shape=(k0, k))
    own = sp.csr_matrix((np.ones(k0), (np.arange(k0), owner[normal][hasown])), shape=(k0, n))
    A_ub = sp.vstack(
        [
            sp.hstack([-sel, -Ik, sp.csr_matrix((k, n))]),  # -x_p - D_p <= 0  (D >= -x)
            sp.hstack([sp.csr_matrix((k0, q)), pick, -own]),  # D_p - t_owner <= 0
        ]
    ).tocsr()
    b_ub = np.zeros(k + k0)
    c = np.concatenate([np.zeros(q), np.full(k, p.beta), np.full(n, p.alpha)])
    lo = np.where(kind == SIDE, 0.0, np.where(kind == NORMAL, -p.T, -np.inf))
    bounds = np.concatenate(
        [
            np.stack([lo, np.full(q, np.inf)], 1),
            np.tile([0.0, p.T], (k, 1)),  # the friction capacity, hard
            np.tile([0.0, np.inf], (n, 1)),
        ]
    )
    opts = {} if time_limit is None else {"time_limit": float(time_limit)}
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=b, bounds=bounds, method=lp_method, options=opts)
    x = None if res.x is None else res.x[:q]
    msg, fun = res.message, res.fun
    if canonical and res.status == 0 and p.ridge > 0:
        z, st = least_norm_optimum(c, A_eq, b, A_ub, b_ub, bounds, q, cost=float(res.fun))
        if z is None:
            msg = f"{msg} (the canonical distribution failed: {st}; an optimal LP vertex instead)"
        else:
            x, fun, msg = z[:q], float(c @ z), f"{msg}; canonical distribution: Clarabel {st}"
    return res.status, msg, x, fun, (kind, col, slot, owner)


def _solve_milp(model: ForceModel, scale: bool, time_limit: float | None):
    """The enhanced baseline with Eq. 4 stated literally (see module doc)."""
    import scipy.sparse as sp
    from scipy.optimize import Bounds, LinearConstraint, milp

    p = model.params
    n = model.n
    A, b, kind, col, slot, owner = _build(model, "eb", scale)
    m = A.shape[1]
    normal = np.nonzero(kind == NORMAL)[0]
    k = len(normal)
    M = float(-model.gravity[:n, 2].sum()) + k * p.T  # largest possible S (module doc)
    # variables [x (m), S (k), D (k), z (k), t (n)]
    Z = lambda r, c_: sp.csr_matrix((r, c_))  # noqa: E731
    Ik = sp.identity(k, format="csr")
    sel = sp.csr_matrix((np.ones(k), (np.arange(k), normal)), shape=(k, m))
    own = sp.csr_matrix((np.ones(k), (np.arange(k), owner[normal])), shape=(k, n))
    rows = [
        (sp.hstack([A, Z(A.shape[0], 3 * k + n)]), b, b),  # equilibrium, hard
        (sp.hstack([sel, -Ik, Ik, Z(k, k + n)]), 0.0, 0.0),  # x_p = S_p - D_p
        (sp.hstack([Z(k, m), Ik, Z(k, k), -M * Ik, Z(k, n)]), -np.inf, 0.0),  # S_p <= M z_p
        (sp.hstack([Z(k, m + k), Ik, p.T * Ik, Z(k, n)]), -np.inf, p.T),  # D_p <= T (1 - z_p)
        (sp.hstack([Z(k, m + k), Ik, Z(k, k), -own]), -np.inf, 0.0),  # D_p <= t_owner
    ]
    cons = [LinearConstraint(r.tocsr(), lo, hi) for r, lo, hi in rows]
    lo = np.concatenate([np.where(kind == SIDE, 0.0, -np.inf), np.zeros(3 * k + n)])
    hi = np.concatenate([np.full(m, np.inf), np.full(k, M), np.full(k, p.T), np.ones(k), np.full(n, np.inf)])
    integ = np.concatenate([np.zeros(m + 2 * k), np.ones(k), np.zeros(n)])
    c = np.concatenate([np.zeros(m + k), np.full(k, p.beta), np.zeros(k), np.full(n, p.alpha)])
    opts = {"disp": False}
    if time_limit is not None:
        opts["time_limit"] = float(time_limit)
    res = milp(c, integrality=integ, bounds=Bounds(lo, hi), constraints=cons, options=opts)
    x = None if res.x is None else res.x[:m]
    return res.status, res.message, x, res.fun, (kind, col, slot, owner)


def solve_baseline(
    model: ForceModel,
    method: str,
    exact_method: str = "highs",
    scale: bool = True,
    formulation: str = "lp",
    time_limit: float | None = None,
    canonical: bool = True,
) -> BaselineResult:
    """Solve baseline ``method`` ("luo" or "eb", see the module doc) on a compiled model.

    exact_method: HiGHS LP method (as :func:`~stablelego_jax.solvers.exact.solve_exact`);
    scale: torque rows in N stud (the same constraints, better conditioned);
    formulation: "lp" or, for eb only, "milp" (Eq. 4 with binaries);
    time_limit: seconds per solve (None: none); a solve stopped without a
    feasible point gives ``solvable=None``; canonical: the canonical
    distribution of a solvable layout (LP formulation; see the module doc).
    """
    if method not in BASELINES:
        raise ValueError(f"baseline method must be one of {BASELINES}, got {method!r}")
    if exact_method not in EXACT_METHODS:
        raise ValueError(f"exact_method must be one of {EXACT_METHODS}, got {exact_method!r}")
    if formulation not in EB_FORMULATIONS:
        raise ValueError(f"formulation must be one of {EB_FORMULATIONS}, got {formulation!r}")
    if formulation == "milp" and method != "eb":
        raise ValueError("formulation='milp' is for the enhanced baseline (eb) only: luo has no Eq. 4")
    t0 = time.perf_counter()
    if formulation == "milp":
        status, msg, x, fun, info = _solve_milp(model, scale, time_limit)
    else:
        status, msg, x, fun, info = _solve_lp(model, method, exact_method, scale, time_limit, canonical)
        if status == 4 and (exact_method, scale) != ("highs-ipm", True):  # numerical trouble: retry
            first = msg
            status, msg, x, fun, info = _solve_lp(model, method, "highs-ipm", True, time_limit, canonical)
            msg = f"{msg} (scaled highs-ipm after {exact_method}: {first})"
    dt = time.perf_counter() - t0
    kind, col, slot, owner = info
    # status: 0 optimal, 2 infeasible (the objective is bounded below by 0, so
    # never unbounded); 1 limit reached (solvable if a feasible point came back)
    if status == 0 or (status == 1 and x is not None):
        solvable = True
    elif status == 2:
        solvable = False
    else:
        solvable = None
    out = BaselineResult(
        solvable=solvable, success=solvable is not None, status=str(msg), method=method,
        formulation=formulation, objective=float(fun) if solvable and fun is not None else float("nan"),
        f=None, f_split=None, max_drag=np.full(model.n, np.nan), pair_mismatch=float("nan"), time_s=dt,
    )
    if not solvable or x is None:
        return out
    m, n = model.m, model.n
    cb = model.col_brick[:m]
    fs = np.full((m, 2), np.nan)
    if method == "eb":
        out["f"] = np.zeros(model.m_pad)
        out["f"][:m] = x
        fs[:] = x[:, None]
        fs[cb >= n] = np.nan
    else:
        fs[col, slot] = x
    out["f_split"] = fs
    both = (cb < n).all(axis=1)
    out["pair_mismatch"] = float(np.abs(fs[both, 0] - fs[both, 1]).max()) if both.any() else 0.0
    # largest drag max(-(S - D), 0) on each brick's own bottom contacts (luo: D or U)
    sel = (kind == NORMAL) & (owner >= 0)
    group = normal_groups(np.stack([np.where(sel, owner, n), np.full(len(x), n)], axis=1),
                          np.where(sel, NORMAL, KNOB), n)
    out["max_drag"] = largest_drag(np.where(sel, np.maximum(-x, 0.0), 0.0), group)
    return out


def residual_split(model: ForceModel, fs: np.ndarray) -> np.ndarray:
    """(n, 6) equilibrium residual of per-slot forces ``fs`` (m, 2)."""
    n, m = model.n, model.m
    out = np.zeros((n + 1, 6))
    for s in range(2):
        b = np.where(model.col_brick[:m, s] < n, model.col_brick[:m, s], n)
        np.add.at(out, b, model.col_coef[:m, s, :] * np.nan_to_num(fs[:, s])[:, None])
    return out[:n] + model.gravity[:n]
