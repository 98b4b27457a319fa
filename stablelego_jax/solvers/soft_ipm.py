"""The barrier interior point of soft problems and its implicit adjoint.

The point of the *central path* of the paper's Eq. 9 linear programme at
barrier parameter ``mu``, for a :class:`~stablelego_jax.soft.SoftProblem`
with existence weights and extra loads (see :mod:`stablelego_jax.loss` for
the problem, its units and what its gradient means). It is solved by an
infeasible primal-dual interior-point method (Mehrotra predictor-corrector,
then centring steps with a second-order corrector, their directions
refined once (:func:`_correction`); at most ``iters``
iterations of the loop both interior points share,
:func:`~stablelego_jax.solvers.interior.iterate`, stopping once the
iterate is centred at ``mu``) in which each Newton system is reduced, per
column and in closed form, to the changes of the residual rows' prices
(the bricks' drag maxima eliminated too). The matrix that remains, scaled
by the bricks' weights, is the symmetric positive definite reduced matrix
of the verdict LP (:mod:`~stablelego_jax.solvers.newton`), factorised by
the same block Cholesky (:mod:`~stablelego_jax.solvers.blocks`): one
dense (6 n x 6 n) block, or, for a problem placed layer by layer
(:func:`~stablelego_jax.solvers.problem.layer_soft`), a block-tridiagonal
one, ``O(L (6 B)^3)`` for L layers of B slots instead of ``O((6 n)^3)``. The optimality conditions are written per unit of
existence (divided by the weights), which keeps them regular at ``w = 0``.

:func:`central_path` has a custom VJP (implicit differentiation): one
transposed Newton system ``J^T lam = dL/dx`` at the solution (J: the
Jacobian of the barrier problem's optimality conditions R; factorised at
the solution, solved with one step of iterative refinement),
returning
``-(dR/dtheta)^T lam`` for theta = (weights, loads, the columns' wrenches
``prob.col_coef``; no other leaf of the problem is differentiated). Nothing is unrolled.
``jit`` and ``vmap`` work; float64 is switched on inside (forward and
backward), whatever the caller's JAX setting.
"""
from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..model import KNOB, NORMAL, Params
from ..runtime import x64
from ..score import bottom_sum, equilibrium, equilibrium_t
from ..soft import SoftProblem
from .blocks import block_cholesky, block_solve, layer_cuts
from .branch import cond_any
from .interior import boundary_step, centring, iterate
from .newton import reduced_matrix
from .problem import row_scale, scaled_wrenches

__all__ = [
    "BarrierOptions",
    "SoftContext",
    "soft_context",
    "column_force",
    "brick_residual",
    "central_path",
]


@dataclasses.dataclass(frozen=True)
class BarrierOptions:
    """Settings of the barrier interior point (hashable: a static jit argument).

    mu: barrier parameter at which forces are returned and differentiated
      (-> 0 gives Eq. 9's LP).
    iters: most interior-point iterations (a ``while_loop``, its last
      steps centring with a second-order corrector: it stops once
      mean(s z / w) <= 1.5 mu and every s z / w is within a factor
      ``centred`` of mu; under ``vmap`` when every problem has stopped).
    knob_cost: gamma, the cost (per T) of knob presses.
    compliance: eps, the compliance of the contacts of partly existing
      bricks (their cost ``eps (1 - w) / 2 (S^2 + D^2)`` per unit of
      existence); 0 at w = 1. It keeps the forces a faded-in brick carries
      proportional to its weight: with Eq. 9's linear costs alone, a brick
      of any positive weight standing on the baseplate could carry any load
      (the loss would jump at w = 0+).
    tol: convergence tolerance on the optimality conditions (inf-norm,
      scaled units) for ``converged``.
    params: physical parameters (T, alpha, beta, ...).
    """

    mu: float = 1e-5
    iters: int = 30
    centred: float = 0.01
    knob_cost: float = 1e-6
    compliance: float = 1e-2
    tol: float = 1e-5
    params: Params = Params()


class SoftContext(NamedTuple):
    """Weight-dependent constants of one problem (all JAX arrays)."""

    coef: jnp.ndarray  # (m, 2, 6) scaled wrench per unit force
    coef_t: jnp.ndarray  # (m, 2, 6) the same times the other-brick weight of each slot
    cb: jnp.ndarray  # (m, 2)
    g: jnp.ndarray  # (n, 6) scaled weight (with loads) per unit of existence
    om: jnp.ndarray  # (n,) brick weights (0 for padding)
    o0: jnp.ndarray  # (m,) weight of the slot-1 brick seen from slot 0 (1 within a unit)
    wcol: jnp.ndarray  # (m,) column weight
    real: jnp.ndarray  # (m,) bool real columns
    pair: jnp.ndarray  # (m,) bool real columns with two parts S - D (NORMAL, KNOB)
    normal: jnp.ndarray  # (m,) bool real NORMAL columns
    knob: jnp.ndarray  # (m,) bool real KNOB columns
    owner: jnp.ndarray  # (m,) brick whose bottom a NORMAL column is on (n: none)
    group: jnp.ndarray  # (n, P)
    cost: jnp.ndarray  # (n, 6) L1 weights of the scaled rows
    slot: jnp.ndarray | None = None  # (n,) place l B + s in the layered factorisation (None: dense)
    lay: jnp.ndarray | None = None  # (L, B): the layered factorisation's shape
    chunk: jnp.ndarray | None = None  # (C, W) columns grouped by brick pair (m: none)
    cut: jnp.ndarray | None = None  # (L,) each layer's used slots: factor each at its own size
    ws: jnp.ndarray | None = None  # (n,) row scale of each brick (its weight, >= 1e-30; 1 for padding)
    csym: jnp.ndarray | None = None  # (m,) column scale c_p: A~ = diag(1/ws) A diag(c)
    osym: jnp.ndarray | None = None  # (m,) o0 from the row scales (o0 where no weight is clamped)


def soft_context(weights, loads, prob: SoftProblem, params: Params) -> SoftContext:
    dtype = jnp.float64
    n = prob.mass.shape[0]
    cost = jnp.asarray(row_scale(params)[1], dtype) * jnp.ones((n, 6), dtype)
    w_eff = jnp.asarray(weights, dtype)[prob.unit]
    om = jnp.where(prob.brick_mask, w_eff, 0.0)
    om_ext = jnp.concatenate([om, jnp.ones((1,), dtype)])
    unit_ext = jnp.concatenate([jnp.asarray(prob.unit, jnp.int32), jnp.full((1,), -1, jnp.int32)])
    cb = jnp.asarray(prob.col_brick)
    b0, b1 = cb[:, 0], cb[:, 1]
    same = unit_ext[b0] == unit_ext[b1]
    w0, w1 = om_ext[b0], om_ext[b1]
    o0 = jnp.where(same, 1.0, w1)
    o1 = jnp.where(same, 1.0, w0)
    real = jnp.asarray(prob.col_mask)
    coef = scaled_wrenches(jnp.asarray(prob.col_coef, dtype), params)
    coef_t = coef * jnp.stack([o0, o1], axis=1)[:, :, None]
    load = jnp.zeros((n,), dtype) if loads is None else jnp.asarray(loads, dtype)
    gz = -(jnp.asarray(prob.mass, dtype) + load) * params.g / params.T
    g = jnp.zeros((n, 6), dtype).at[:, 2].set(jnp.where(prob.brick_mask, gz, 0.0))
    kind = jnp.asarray(prob.col_kind)
    normal = (kind == NORMAL) & real
    knob = (kind == KNOB) & real
    # the symmetric form of the Newton matrix (see _factor): row scales ws,
    # A~ = diag(1/ws) A diag(csym) exactly while no weight is below 1e-30
    ws = jnp.where(jnp.asarray(prob.brick_mask), jnp.maximum(om, 1e-30), 1.0)
    ws_ext = jnp.concatenate([ws, jnp.ones((1,), dtype)])
    osym = jnp.where(same, 1.0, ws_ext[b1])
    return SoftContext(coef=coef, coef_t=coef_t, cb=cb, g=g, om=om, o0=o0, wcol=jnp.where(real, w0 * o0, 0.0),
                real=real, pair=normal | knob, normal=normal, knob=knob, owner=jnp.where(normal, b0, n),
                group=jnp.asarray(prob.group), cost=cost,
                slot=None if prob.slot is None else jnp.asarray(prob.slot), lay=prob.layers,
                chunk=None if prob.chunk is None else jnp.asarray(prob.chunk),
                cut=None if prob.cut is None else jnp.asarray(prob.cut, jnp.int32),
                ws=ws, csym=ws_ext[b0] * osym, osym=osym)


def _ext(v):
    return jnp.concatenate([v, jnp.zeros((1,), v.dtype)])


def column_force(x, ctx: SoftContext):
    S, D, _ = x
    return jnp.where(ctx.pair, S - D, S)


def brick_residual(ctx: SoftContext, phi):
    return equilibrium(ctx.coef_t, ctx.cb, phi, ctx.g.shape[0]) + ctx.g


# --------------------------------------------------------------------------
# inequalities: kinds 0: D >= 0 (pairs), 1: S >= 0 (real columns),
# 2: t_owner - o D >= 0 (NORMAL), 3: t >= 0 (bricks); then the residual
# rows' pairs a: r >= 0, b: r - rho >= 0 (r = r+, r - rho = r-)


def _masks(ctx: SoftContext):
    n = ctx.g.shape[0]
    ones = jnp.ones((n,), bool)
    rows = jnp.ones((n, 6), bool)
    return (ctx.pair, ctx.real, ctx.normal, ones, rows, rows)


def _weights(ctx: SoftContext, params: Params):
    """Barrier weight of each kind: the cost scale of its dual (alpha for the
    force parts and drag maxima, the row's cost c for the residual pairs),
    so that all complementarity products are of one size."""
    a = params.alpha
    return (a, a, a, a, ctx.cost, ctx.cost)


def _slacks(x, ctx: SoftContext):
    S, D, t = x
    return D, S, _ext(t)[ctx.owner] - ctx.o0 * D, t


def _msk(v, on, fill=0.0):
    return jnp.where(on, v, fill)


class _Pieces(NamedTuple):
    """Newton system pieces: diagonal curvatures, couplings, the residual rows'
    curvature ``ddpsi`` and the right-hand side."""

    hS: jnp.ndarray  # (m,)
    hD: jnp.ndarray  # (m,) h0 + o^2 h2 (pairs), 1 otherwise
    h0: jnp.ndarray  # (m,) curvature of D >= 0 alone (pairs)
    f: jnp.ndarray  # (m,) dR_D / dt_owner
    g: jnp.ndarray  # (m,) dR_t / dD
    h2o: jnp.ndarray  # (m,) o h2 (t's own curvature from column p)
    h3: jnp.ndarray  # (n,)
    ddpsi: jnp.ndarray  # (n, 6)


def _compliance(ctx: SoftContext, opts: BarrierOptions):
    """Per column: compliance * (1 - w_p), the curvature of the cost
    ``eps (1 - w_p) / 2 (S^2 + D^2)`` (per unit of existence) of the contacts
    of partly existing bricks; 0 for fully present ones (exact Eq. 9)."""
    return jnp.where(ctx.real, opts.compliance * (1.0 - ctx.wcol), 0.0)


def _system(x, ctx: SoftContext, dpsi, ddpsi, zeta, h, opts: BarrierOptions):
    """Right-hand side R (divided by the weights) and the Jacobian pieces.

    ``dpsi`` (n, 6): derivative of the residual rows' cost w.r.t. rho (their
    price); ``ddpsi``: its curvature; ``zeta``/``h`` per kind: the barrier
    multipliers and curvatures of kinds 0-3.

        R_S = A^T dpsi + gamma[knob] - zeta1 + e S
        R_D = -A^T dpsi + beta[normal] + gamma[knob] - zeta0 + o zeta2 + e D

    with e the compliance of partly existing bricks' contacts.
        R_t = alpha - zeta3 - sum_owner o zeta2
    """
    p = opts.params
    S, D, t = x
    z0, z1, z2, z3 = (_msk(v, on) for v, on in zip(zeta, _masks(ctx)[:4]))
    h0, h1, h2, h3 = (_msk(v, on) for v, on in zip(h, _masks(ctx)[:4]))
    o = ctx.o0
    atp = equilibrium_t(ctx.coef, ctx.cb, dpsi)
    kc = jnp.where(ctx.knob, opts.knob_cost, 0.0)
    ec = _compliance(ctx, opts)
    rS = jnp.where(ctx.real, atp + kc - z1 + ec * S, S)
    rD = jnp.where(ctx.pair, -atp + jnp.where(ctx.normal, p.beta, 0.0) + kc - z0 + o * z2 + ec * D, D)
    rt = p.alpha - z3 - bottom_sum(o * z2, ctx.group)
    pieces = _Pieces(
        hS=jnp.where(ctx.real, h1 + ec, 1.0),
        hD=jnp.where(ctx.pair, h0 + o * o * h2 + ec, 1.0),
        h0=h0 + ec,
        f=-o * h2,
        g=-o * o * h2,
        h2o=o * h2,
        h3=h3,
        ddpsi=ddpsi,
    )
    return (rS, rD, rt), pieces


# --------------------------------------------------------------------------
# linear algebra
#
# Unknowns of a Newton system: per column (S_p, D_p) (diagonal blocks), per
# brick t_b, and y = diag(ddpsi) A~ dphi (the change of the residual rows'
# prices). S and D are eliminated per column in closed form, and t per
# brick (its curvature ktt = h3 + sum g f / hD, written without
# cancellation, is diagonal), which leaves a (6 n) system in y:
#
#     M = diag(1/ddpsi) + A~ diag(theta) A^T + sum_b u_b v_b^T / ktt_b
#
# (theta = 1/hS + [pair]/hD; u_b = A~ f/hD and v_b = A g/hD over brick b's
# NORMAL columns; the transpose swaps f and g and A and A~). M is not
# symmetric when weights are below 1: A~ (the conditions per unit of
# existence) weighs each column's wrench on a brick by the other brick's
# weight. But A~ = diag(1/w) A diag(c) with c_p = w_b0 w_b1 (w within one
# unit) and g = o f, so W M (W: each brick's 6 rows times its weight) is
#
#     W M = W diag(1/ddpsi) + A diag(c theta) A^T + sum_b (w_b / ktt_b) v_b v_b^T
#
# with v_b = A (o f / hD) over b's NORMAL columns: symmetric positive
# definite, the form of the verdict LP's reduced matrix
# (:func:`~stablelego_jax.solvers.newton.reduced_matrix`), factorised by
# the same block Cholesky (one dense block, or block tridiagonal over the
# layers of ``ctx.slot``). M y = r is (W M) y = W r and M^T y = r is
# y = W (W M)^-1 r: one factorisation for both. Weights are taken as at
# least 1e-30 in W (a brick of weight 0 then perturbs M by 1e-30 relative).


class _Lin(NamedTuple):
    """A factorised Newton matrix: the block Cholesky factors of W M."""

    pc: _Pieces
    C: jnp.ndarray  # (L, 6 B, 6 B) Cholesky factors of the pivot blocks
    G: jnp.ndarray  # (L, 6 B, 6 B) C[l]^-1 E[l]'
    ktt: jnp.ndarray  # (n,)


class _Plan(NamedTuple):
    """Where each brick's rows go: ``pos`` (n,) its slot (``L B``: none,
    padding bricks of a layered problem), L levels of B slots (one level of
    n slots: dense), the assembly of W M (:func:`_plan`), and, for a
    problem with ``cut`` (:class:`~stablelego_jax.soft.SoftProblem`), each
    level's live rows ((L,)) and the sizes its factor may be cut to (else
    None and ())."""

    pos: jnp.ndarray
    L: int
    B: int
    assemble: object
    live: jnp.ndarray | None = None
    cuts: tuple = ()


def _plan(ctx: SoftContext) -> _Plan:
    """The static structure of W M: dense (``ctx.slot`` None: brick b in
    slot b) or layered (``ctx.slot``, every brick's supports in the layer
    below: :func:`~stablelego_jax.solvers.problem.soft_levels`)."""
    n = ctx.g.shape[0]
    if ctx.slot is None:
        L, B, pos = 1, n, jnp.arange(n, dtype=jnp.int32)
    else:
        (L, B), pos = ctx.lay.shape, ctx.slot
    N = L * B
    pcb = jnp.concatenate([pos, jnp.full((1,), N, pos.dtype)])[ctx.cb]
    live, cuts = None, ()
    if ctx.cut is not None and L > 1:
        live, cuts = 6 * ctx.cut, layer_cuts(B)
    return _Plan(pos, L, B, reduced_matrix(pcb, ctx.coef, ctx.normal, N, L, ctx.chunk), live, cuts)


def _fg(pc: _Pieces, transpose: bool):
    return (pc.g, pc.f) if transpose else (pc.f, pc.g)


def _sides(ctx: SoftContext, transpose: bool):
    return (ctx.coef, ctx.coef_t) if transpose else (ctx.coef_t, ctx.coef)


def _ktt(ctx: SoftContext, pc: _Pieces):
    return pc.h3 + bottom_sum(jnp.where(ctx.normal, pc.h2o * pc.h0 / pc.hD, 0.0), ctx.group)


def _theta(ctx: SoftContext, pc: _Pieces):
    theta = 1.0 / pc.hS + jnp.where(ctx.pair, 1.0 / pc.hD, 0.0)
    return jnp.where(ctx.real, theta, 0.0)


def _factor(ctx: SoftContext, plan: _Plan, pc: _Pieces) -> _Lin:
    """Assemble W M (see above) and factor it (block Cholesky)."""
    N = plan.L * plan.B
    dtype = pc.hS.dtype
    theta = _theta(ctx, pc)
    ktt = _ktt(ctx, pc)
    q = jnp.where(ctx.normal, ctx.osym * pc.f / pc.hD, 0.0)
    rho = jnp.zeros((N + 1,), dtype).at[plan.pos].set(ctx.ws / ktt, mode="drop")[:N]
    dr = jnp.ones((N + 1, 6), dtype).at[plan.pos].set(ctx.ws[:, None] / pc.ddpsi, mode="drop")[:N]
    D, E = plan.assemble(ctx.csym * theta, q, rho, dr.reshape(-1))
    C, G = block_cholesky(D, E, plan.live, plan.cuts)
    return _Lin(pc=pc, C=C, G=G, ktt=ktt)


def _solve(ctx: SoftContext, plan: _Plan, lin: _Lin, r, transpose: bool = False, ry_rhs=None):
    """Solve J d = r (J^T d = r with ``transpose``), r = (r_S, r_D, r_t).

    ``ry_rhs`` (n, 6), optional: a right-hand side of the residual-price rows
    too, ``A~ Phi d - y / ddpsi = ry_rhs`` (``A Phi`` with ``transpose``; Phi:
    the column forces of d), whose default 0 is the definition of y.

    Returns (d, y, d2): d = (dS, dD, dt), y the residual-price part, d2 =
    dt_owner - o dD (the change of the t - o D slack) computed without
    cancellation."""
    pc = lin.pc
    f, g = _fg(pc, transpose)
    rS, rD, rt = r
    n = rt.shape[0]
    left, right = _sides(ctx, transpose)
    u = jnp.where(ctx.real, rS / pc.hS, 0.0) - jnp.where(ctx.pair, rD / pc.hD, 0.0)
    ry = equilibrium(left, ctx.cb, u, n)
    rtt = rt - bottom_sum(jnp.where(ctx.pair, g * rD / pc.hD, 0.0), ctx.group)
    fq = jnp.where(ctx.normal, f / pc.hD, 0.0)
    gq = jnp.where(ctx.normal, g / pc.hD, 0.0)
    rhs = ry + equilibrium(left * fq[:, None, None], ctx.cb, _ext(rtt / lin.ktt)[ctx.owner], n)
    if ry_rhs is not None:
        rhs = rhs - ry_rhs
    N = plan.L * plan.B
    ws = ctx.ws[:, None]
    Y = jnp.zeros((N + 1, 6), rhs.dtype).at[plan.pos].add(rhs if transpose else ws * rhs, mode="drop")[:N]
    Y = block_solve(lin.C, lin.G, Y.reshape(plan.L, 6 * plan.B)).reshape(N, 6)
    Y = Y[jnp.minimum(plan.pos, N - 1)]
    y = jnp.where((plan.pos < N)[:, None], ws * Y if transpose else Y, rhs * pc.ddpsi)
    dt = (rtt - bottom_sum(gq * equilibrium_t(right, ctx.cb, y), ctx.group)) / lin.ktt
    aty = equilibrium_t(right, ctx.cb, y)
    dte = _ext(dt)[ctx.owner]
    dS = jnp.where(ctx.real, (rS - aty) / pc.hS, rS)
    qD = rD + aty
    dD = jnp.where(ctx.pair, (qD - f * dte) / pc.hD, rD)
    d2 = dte * pc.h0 / pc.hD - ctx.o0 * qD / pc.hD  # = dt_owner - o dD for NORMAL columns
    return (dS, dD, dt), y, d2


def _correction(ctx: SoftContext, plan: _Plan, lin: _Lin, r, sol, transpose: bool = False):
    """One step of iterative refinement of ``sol = _solve(..., r, transpose)``
    on the unreduced system, with the residual-price rows y as unknowns:
    ``J0 d + Phi^T A^T y = r`` and ``A~ Phi d - y / ddpsi = 0`` (J0: the
    Newton matrix with the price frozen, from ``lin.pc``; A and A~ swap with
    ``transpose``). The reduced solve leaves the second block off by ~1%
    where ddpsi is large (the cancellation in ``A~ Phi d``); one step brings
    both residuals to ~1e-12 (session 49). Returns the correction to add to
    (d, y, d2)."""
    pc = lin.pc
    f, g = _fg(pc, transpose)
    left, right = _sides(ctx, transpose)
    (dS, dD, dt), y, _ = sol
    aty = equilibrium_t(right, ctx.cb, y)
    jS = pc.hS * dS + jnp.where(ctx.real, aty, 0.0)
    jD = pc.hD * dD + jnp.where(ctx.pair, f * _ext(dt)[ctx.owner] - aty, 0.0)
    jt = (pc.h3 + bottom_sum(jnp.where(ctx.normal, pc.h2o, 0.0), ctx.group)) * dt \
        + bottom_sum(jnp.where(ctx.pair, g * dD, 0.0), ctx.group)
    res = (r[0] - jS, r[1] - jD, r[2] - jt)
    e = y / pc.ddpsi - equilibrium(left, ctx.cb, column_force(sol[0], ctx), dt.shape[0])
    return _solve(ctx, plan, lin, res, transpose, ry_rhs=e)


def _refine_with(plan: _Plan):
    """:func:`_correction` as a function of arrays only (for
    :func:`~.branch.cond_any`): the plan's brick slots and live rows
    passed in, its static sizes closed over."""
    def rare(ctx, pos, live, lin, r, sol):
        return _correction(ctx, plan._replace(pos=pos, live=live), lin, r, sol)
    return rare


def _unrefined(ctx, pos, live, lin, r, sol):
    return jax.tree_util.tree_map(jnp.zeros_like, sol)


def _refined(ctx: SoftContext, plan: _Plan, lin: _Lin, r, transpose: bool = False):
    """:func:`_solve` and one :func:`_correction`: (d, y, d2)."""
    sol = _solve(ctx, plan, lin, r, transpose)
    return _axpy(1.0, _correction(ctx, plan, lin, r, sol, transpose), sol)


# --------------------------------------------------------------------------
# the interior-point method


def _axpy(t, d, x):
    return jax.tree_util.tree_map(lambda a, b: a + t * b, x, d)


def _start(ctx: SoftContext, wts):
    n = ctx.g.shape[0]
    dtype = ctx.g.dtype
    S = jnp.where(ctx.real, 1.0, 0.0).astype(dtype)
    D = jnp.where(ctx.pair, 1.0, 0.0).astype(dtype)
    x = (S, D, jnp.full((n,), 2.0, dtype))
    rho = brick_residual(ctx, column_force(x, ctx))
    r = 1.0 + jnp.maximum(rho, 0.0)
    s = tuple(jnp.ones_like(v) for v in _slacks(x, ctx)) + (r, r - rho)
    z = tuple(jnp.ones_like(v) * w for v, w in zip(s, wts))
    return x, r, s, z


def _ipm(ctx: SoftContext, opts: BarrierOptions):
    """Infeasible primal-dual interior point (Mehrotra predictor-corrector)
    with slack variables s and duals z per inequality (only s, z > 0 is
    kept: fraction 0.99 to the boundary, no line search).

    The barrier of inequality kind k is weighted by w_k (:func:`_weights`);
    each iteration targets ``tau = max(mu, sigma mean(s z / w))``. After
    the first step whose target is ``mu`` itself (a pure centring step)
    the steps are centring steps with a second-order corrector
    (``step_once``) towards the point of the central path at ``mu``, which
    is returned (with the residual rows' price and curvature there, for
    the backward pass, and the optimality residual)."""
    dtype = ctx.g.dtype
    n = ctx.g.shape[0]
    ons = _masks(ctx)
    wts = _weights(ctx, opts.params)
    n_pairs = sum(jnp.sum(o) for o in ons)
    cost = ctx.cost
    plan = _plan(ctx)

    def mean_gap(s, z):
        return sum(_msk(sv * zv / w, o).sum() for sv, zv, o, w in zip(s, z, ons, wts)) / n_pairs

    def pieces(x, r, s, z, target):
        rho = brick_residual(ctx, column_force(x, ctx))
        shat = tuple(_slacks(x, ctx)) + (r, r - rho)
        rp = tuple(_msk(sv - sh, o) for sv, sh, o in zip(s, shat, ons))  # primal residuals
        h = tuple(zv / sv for zv, sv in zip(z, s))
        zeta = tuple(tg / sv + hv * rv for sv, hv, rv, tg in zip(s, h, rp, target))
        # eliminate r: R_r = 2c - zeta_a - zeta_b, J_rr = h_a + h_b, J_r,rho = -h_b
        R_r = 2.0 * cost - zeta[4] - zeta[5]
        jrr = h[4] + h[5]
        dpsi = -cost + zeta[5] + h[5] * R_r / jrr
        ddpsi = h[4] * h[5] / jrr
        rr, pc = _system(x, ctx, dpsi, ddpsi, zeta[:4], h[:4], opts)
        return rp, h, R_r, dpsi, rr, pc

    def direction(x, r, s, z, target, lin, cap, refine):
        rp, h, _, dpsi, rr, _ = pieces(x, r, s, z, target)
        sol = _solve(ctx, plan, lin, rr)
        # centring steps refined (a branch: the predictor steps do not pay; under
        # vmap the batch pays only while one of its members centres)
        sol = _axpy(1.0, cond_any(refine, _refine_with(plan), _unrefined, ctx, plan.pos, plan.live, lin, rr, sol),
                    sol)
        (dS, dD, dt), y, d2 = sol
        dx = (-dS, -dD, -dt)
        # the residual rows' duals from y (the backward-stable part of the
        # solve): their dual equations hold to rounding, and the rounding
        # goes to the primal equation r - rho = s_b (absolute, tiny)
        dzb = (dpsi - y) + cost - z[5]
        dza = 2.0 * cost - z[4] - z[5] - dzb
        drho = -equilibrium(ctx.coef_t, ctx.cb, column_force((dS, dD, dt), ctx), n)
        comp = lambda k, dzk: (target[k] - s[k] * z[k] - s[k] * dzk) / z[k]  # noqa: E731
        zcomp = lambda k, dsk: (target[k] - s[k] * z[k] - z[k] * dsk) / s[k]  # noqa: E731
        # each pair's step goes through its active side(s) (h = z/s > 1): a
        # slack step from complementarity divides by z, exact only where z is
        # not tiny; the inactive side follows from the primal equations
        act_a, act_b = h[4] > 1.0, h[5] > 1.0
        dsa1, dsb1 = comp(4, dza), comp(5, dzb)
        dr_a = dsa1 + rp[4]  # through a
        dr_b = dsb1 + drho + rp[5]  # through b
        use_b = act_b & ~act_a
        dr = jnp.where(use_b, dr_b, dr_a)
        dsa = jnp.where(use_b, dr - rp[4], dsa1)
        dsb = jnp.where(act_b, dsb1, dr - drho - rp[5])
        dza = jnp.where(use_b, zcomp(4, dsa), dza)
        dzb = jnp.where(act_b, dzb, zcomp(5, dsb))
        dshat = (dx[1], dx[0], -d2, dx[2])
        ds = [_msk(dv - rv, o) for dv, rv, o in zip(dshat, rp[:4], ons[:4])]
        dz = [_msk(zcomp(k, ds[k]), ons[k]) for k in range(4)]
        ds = tuple(_msk(v, on) for v, on in zip(ds, ons[:4])) + (dsa, dsb)
        dz = tuple(_msk(v, on) for v, on in zip(dz, ons[:4])) + (dza, dzb)
        step = jnp.asarray(cap, dtype)
        for sv, dsv, zv, dzv, o in zip(s, ds, z, dz, ons):
            step = jnp.minimum(step, jnp.minimum(boundary_step(sv, dsv, o), boundary_step(zv, dzv, o)))
        return dx, dr, ds, dz, step

    def primal(state):
        x, r, s, _ = state
        shat = tuple(_slacks(x, ctx)) + (r, r - brick_residual(ctx, column_force(x, ctx)))
        return jnp.max(jnp.stack([jnp.abs(_msk(sv - sh, o)).max() for sv, sh, o in zip(s, shat, ons)]))

    def centrality(s, z, tau):
        return jnp.max(jnp.stack([jnp.abs(_msk(sv * zv / (w * tau) - 1.0, o)).max()
                                  for sv, zv, o, w in zip(s, z, ons, wts)]))

    def step(loop):
        state, centring_now = loop
        new, final = step_once(state, centring_now)
        # stop once centred on the final barrier parameter: further centring
        # steps only stir rounding errors around
        _, _, s, z = new
        ok = (mean_gap(s, z) <= 1.5 * opts.mu) & (centrality(s, z, opts.mu) <= opts.centred)
        # guard: near the end a step that loses primal feasibility (rounding
        # in a near-singular system) is refused and the iterate kept
        bad = (primal(new) > jnp.maximum(1e-6, 10.0 * primal(state))) & (mean_gap(*state[2:]) < 1e-3)
        return (new, centring_now | final), ok, bad

    def step_once(state, centring_now):
        """One factorisation, two directions. Predictor-corrector (the
        predictor: affine scaling, target 0; the corrector: centring towards
        tau plus the second-order term, pure centring once the target is
        mu itself, which returns ``final``) until a step has been final;
        then (``centring_now``) centring steps: the centring direction, then
        the same with the error of the complementarity products at its step
        taken off its target (a second-order corrector), kept where it goes
        at least as far, full steps allowed. One traced direction in a scan
        of length 2; the mode is a per-problem flag (selects, no branch:
        under ``vmap`` a batch runs one loop)."""
        x, r, s, z = state
        mu = mean_gap(s, z)
        # one factorisation per iteration (the matrix does not depend on the target)
        _, _, _, _, _, pc = pieces(x, r, s, z, wts)
        lin = _factor(ctx, plan, pc)
        cap = jnp.where(centring_now, 2.0, 1.0)

        def phase(target, _):
            out = direction(x, r, s, z, target, lin, cap, centring_now)
            _, _, ds1, dz1, st1 = out
            a = jnp.minimum(st1, 1.0)
            mu_a = mean_gap(_axpy(a, ds1, s), _axpy(a, dz1, z))
            tau = jnp.maximum(opts.mu, centring(mu_a, mu) * mu)
            final = tau <= opts.mu
            mehrotra = (tau * w - jnp.where(final, 0.0, _msk(dsv * dzv, o))
                        for w, dsv, dzv, o in zip(wts, ds1, dz1, ons))
            second = (t + _msk(opts.mu * w - (sv + a * dsv) * (zv + a * dzv), o)
                      for t, sv, dsv, zv, dzv, w, o in zip(target, s, ds1, z, dz1, wts, ons))
            nxt = tuple(jnp.where(centring_now, c, m) for c, m in zip(second, mehrotra))
            return nxt, (out, final)

        start = tuple(jnp.where(centring_now, _msk(opts.mu * w, o), 0.0) * jnp.ones_like(v)
                      for v, w, o in zip(s, wts, ons))
        _, (outs, final) = jax.lax.scan(phase, start, None, length=2)
        first, second = (jax.tree_util.tree_map(lambda v: v[i], outs) for i in (0, 1))
        # the corrector's direction; a centring step keeps the plain one where it goes further
        better = ~centring_now | (jnp.minimum(second[4], 1.0) >= jnp.minimum(first[4], 1.0))
        dx, dr, ds, dz, step = jax.tree_util.tree_map(lambda u, v: jnp.where(better, u, v), second, first)
        step = jnp.minimum(1.0, 0.99 * step)
        # safeguard: a step that multiplies the complementarity gap (rounding
        # in a near-singular system, e.g. contacts between absent bricks) is
        # shortened, by 4x at a time, until the gap at most doubles
        def grows(st):
            return mean_gap(_axpy(st, ds, s), _axpy(st, dz, z)) > 2.0 * jnp.maximum(mu, opts.mu)
        for _ in range(6):
            step = jnp.where(grows(step), 0.25 * step, step)
        # final[0]: the predictor's target is mu itself (this step centres)
        return (_axpy(step, dx, x), r + step * dr, _axpy(step, ds, s), _axpy(step, dz, z)), final[0]

    ((x, r, s, z), _), _ = iterate(step, (_start(ctx, wts), jnp.asarray(False)), opts.iters)
    # optimality residuals with the actual duals: stationarity (z in place of
    # the barrier multipliers), primal feasibility, centrality; and the
    # residual rows' price and curvature for the backward pass
    rp, h, _, _, _, pc = pieces(x, r, s, z, tuple(sv * zv for sv, zv in zip(s, z)))
    stat, _ = _system(x, ctx, -cost + z[5], pc.ddpsi, z[:4], h[:4], opts)
    stat = tuple(jnp.where(on, v, 0.0) for v, on in zip(stat, (ctx.real, ctx.pair, jnp.ones((n,), bool))))
    res = jnp.max(jnp.stack([jnp.abs(v).max() for v in stat] + [jnp.abs(v).max() for v in rp]
                            + [jnp.abs(2.0 * cost - z[4] - z[5]).max()]))
    res = jnp.where(centrality(s, z, opts.mu) <= 0.5, res, jnp.maximum(res, 1.0))
    return x, (-cost + z[5], pc.ddpsi, res)


# --------------------------------------------------------------------------
# implicit differentiation


@functools.partial(jax.custom_vjp, nondiff_argnums=(3,))
@x64
def central_path(weights, loads, prob, opts):
    """(x, aux): the solution x = (S, D, t) (S, D: (m,) the two parts of each
    column's force per unit of existence, in T; t: (n,) each brick's
    largest-drag variable, in T) and, not differentiable, aux = (dpsi,
    ddpsi, res) (residual rows' price and curvature, optimality residual)."""
    return _ipm(soft_context(weights, loads, prob, opts.params), opts)


@x64
def _x_fwd(weights, loads, prob, opts):
    out = central_path(weights, loads, prob, opts)
    return out, (out, weights, loads, prob)


def _barrier_system(x, ctx: SoftContext, ctx0: SoftContext, dpsi, ddpsi, opts: BarrierOptions):
    """Optimality conditions R of the barrier problem at ``opts.mu`` (all
    barrier multipliers ``mu w / slack``), with the residual rows' price
    linearised around the solution: exact value and first derivatives at the
    solution (where ``ctx == ctx0``; ``ctx0=None``: the price frozen). (Their
    closed form, sqrt-type in rho, is too sensitive to rounding at small mu
    to evaluate directly.)"""
    mu = opts.mu
    wts = _weights(ctx, opts.params)[:4]
    sl = [_msk(v, on, 1.0) for v, on in zip(_slacks(x, ctx), _masks(ctx)[:4])]
    dp = dpsi if ctx0 is None else dpsi + ddpsi * (brick_residual(ctx, column_force(x, ctx)) - brick_residual(ctx0, column_force(x, ctx0)))
    return _system(x, ctx, dp, ddpsi, [mu * w / v for v, w in zip(sl, wts)],
                   [mu * w / (v * v) for v, w in zip(sl, wts)], opts)


@x64
def _x_bwd(opts, res, ct):
    """R(x*(theta), theta) = 0, so theta_bar = -(dR/dtheta)^T J^-T x_bar.

    R depends on theta through the residual rows (rho) and through the
    other-brick weights in the drag-maximum constraints. The rho part of
    lam^T dR/dtheta is ``y^T drho/dtheta`` with ``y = ddpsi A lam_phi`` taken
    from the backward-stable part of the transposed solve (forming it from
    lam_phi would amplify rounding by the huge curvatures of a near-LP)."""
    (x, (dpsi, ddpsi, _)), weights, loads, prob = res
    ctx0 = soft_context(weights, loads, prob, opts.params)
    _, pc = _barrier_system(x, ctx0, ctx0, dpsi, ddpsi, opts)
    plan0 = _plan(ctx0)
    # refined: without, gradients moved by up to 7e-6 relative between two
    # numberings of one problem (session 49)
    lam, y, _ = _refined(ctx0, plan0, _factor(ctx0, plan0, pc), ct[0], transpose=True)

    def rfun(w, l, cc):  # R with the residual rows' price frozen
        return _barrier_system(x, soft_context(w, l, prob._replace(col_coef=cc), opts.params), None, dpsi, ddpsi,
                               opts)[0]

    def rhofun(w, l, cc):
        ctx = soft_context(w, l, prob._replace(col_coef=cc), opts.params)
        return brick_residual(ctx, column_force(x, ctx))

    cc = jnp.asarray(prob.col_coef, jnp.float64)
    _, vjp = jax.vjp(rfun, weights, loads, cc)
    gw, gl, gc = vjp(jax.tree_util.tree_map(jnp.negative, lam))
    _, vjp_rho = jax.vjp(rhofun, weights, loads, cc)
    gw2, gl2, gc2 = vjp_rho(-y)
    # the problem's only differentiable leaf: the columns' wrenches (moving bodies, :mod:`stablelego_jax.loss`)
    prob_ct = jax.tree_util.tree_map(lambda _: None, prob)._replace(
        col_coef=(gc + gc2).astype(jnp.result_type(prob.col_coef)))
    return gw + gw2, gl + gl2, prob_ct


central_path.defvjp(_x_fwd, _x_bwd)
