"""Interior-point JAX solver for the Eq. 9 linear programme.

The same LP as the exact referee (``exact.py``), in scaled units (forces in
T, torque rows in T stud):

    min  beta sum_p D_p + alpha sum_b t_b + sum w (r+ + r-)
    s.t. A x - r+ + r- + g = 0                    (6 rows per brick)
         x_p + D_p >= 0, D_p >= 0, t_b - D_p >= 0  (NORMAL contact p of brick b)
         x_p >= 0 (SIDE), t_b >= 0, r+, r- >= 0

solved by a primal-dual Mehrotra predictor-corrector method (its step run by
the loop both interior points share, :func:`~stablelego_jax.solvers.interior.iterate`). Every Newton
system is reduced, in closed form, to the equality rows: the per-contact
variables (x, D) and each brick's max-drag variable t are eliminated by a
diagonal-plus-rank-one (per brick) inverse, which leaves

    M = A diag(e) A' + sum_b rho_b (A q_b)(A q_b)' + diag(1 / W_r),

a (6 n, 6 n) symmetric positive definite matrix. Every column joins bricks
of one layer or of adjacent layers, so with bricks ordered by layer
(``L`` layers of ``B`` slots, ``n = L B``) M is block tridiagonal with
(6 B, 6 B) blocks and is factorised by a block Cholesky ``lax.scan`` over
the layers: ``O(L (6 B)^3)`` instead of ``O((6 n)^3)``. ``L = 1`` is the
dense case. Wide, low layouts are numbered by vertical slabs instead
(:func:`~stablelego_jax.solvers.problem.slab_levels`; ``prob.supports``
set): a brick's supports may then lie in its own slab or either next one,
and its rank-one term is assembled brick by brick from its supports, as
it is in dense problems
(:func:`~stablelego_jax.solvers.problem.dense_supports`).
Iteration counts are 20-50 whatever the layout (no long first-order
tails), so a ``vmap``-ed batch finishes together.

Returns a :class:`~stablelego_jax.solvers.problem.Solution` (forces in N,
objective and dual bound in N-based units).
"""
from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp

from ..model import NORMAL, SIDE, Params
from ..runtime import x64
from ..score import bottom_sum
from .blocks import block_cholesky, block_solve, cut_cholesky
from .newton import reduced_matrix
from .problem import Problem, Solution, ladder, make_solution, operators
from .interior import boundary_step, centring, iterate

__all__ = ["IPMOptions", "solve", "below_ok", "options_for", "BELOW_MIN_SLOTS"]


@dataclasses.dataclass(frozen=True)
class IPMOptions:
    """Interior-point settings (scaled units: forces in T).

    max_iter: Newton iterations; eps_feas: primal and dual residual
    tolerance (inf-norm); eps_gap_abs, eps_gap_rel: gap tolerance
    ``tol = abs + rel |obj|``: converged when the complementarity gap
    sum(s lam) <= tol and obj - dual bound <= 100 tol (1e-10 abs keeps drags
    ~1e-7 T from optimal); polish_gap_abs, polish_gap_rel: the tolerance
    the iterations go on to once converged (the canonical term is far below
    the first tolerance: stopping there leaves the forces up to 0.02 T off
    the least-norm optimum along the optimal set; at 1e-13 + 1e-10 |obj| a
    flat face still left a failing set apart), stopping early, still
    converged, when the next iterate would lose the first tolerance, break
    down or pass ``max_iter``; delta: proximal regularisation of the forces in
    the Newton matrix (at least 1e-8 when ``Params.ridge`` is 0: free forces
    then have no curvature; with the canonical term a larger delta damps the
    steps along the optimal set and stalls the last iterations); step: fraction
    of the step to the boundary; init: scale of the starting interior point;
    reg_rel, reg_abs: static regularisation of the reduced matrix (relative
    to its diagonal, and times its largest diagonal entry); refine:
    iterative-refinement steps of each Newton solve (0: none; the
    infeasible method corrects a direction's error at the next iterate:
    on 98 layouts of 1-741 bricks, loads up to 10 kg, 0 and 2 steps gave
    the same iterations and the same distance to HiGHS, and 0 solves
    1.25-1.7x faster, BENCHMARKS.md). The cost includes the
    canonical term ``Params.ridge / (2 W) |x|^2`` (W: total weight), as the
    exact solver's (``exact.least_norm``). cut: a dense problem solved alone
    (not under ``vmap``) factors only its real bricks' rows, at the
    smallest size of the brick ladder from :data:`CUT_MIN` that holds them
    (:func:`~stablelego_jax.solvers.blocks.cut_cholesky`); the numbers are
    those of the full factor; with ``Problem.supports``, its bricks'
    rank-one terms are assembled from their supports (a batch, not cut,
    forms them as one product). below: a layered problem whose supports
    table holds every block coupling two levels (:func:`below_ok`; set by
    :func:`options_for`) forms each layer's ``C^-1 E'`` from its pivot
    block's inverse and E's blocks at the supports
    (:func:`~stablelego_jax.solvers.blocks.block_cholesky`'s ``below``):
    the same numbers to rounding; the unit cube's solve 0.84-0.99x the time.
    """

    max_iter: int = 80
    eps_feas: float = 1e-8
    eps_gap_abs: float = 1e-10
    eps_gap_rel: float = 1e-7
    polish_gap_abs: float = 1e-16
    polish_gap_rel: float = 1e-13
    delta: float = 1e-12
    reg_rel: float = 0.0
    reg_abs: float = 1e-16
    refine: int = 0
    step: float = 0.99
    init: float = 1e-2
    dtype: str = "float64"
    cut: bool = False
    below: bool = False


#: Fewest bricks :attr:`IPMOptions.cut` factors: below, a smaller factor gained less than its
#: branch cost (dense 40 on the small set, session 40).
CUT_MIN = 40

#: Fewest slots a layer for :attr:`IPMOptions.below`. Measured at 104 slots (the unit
#: cube's solve 0.84-0.99x the time); the bound is where `benchmarks/layer_step.py`'s
#: gathers stopped paying in a step through the pivot's inverse (16-32 slots: 0.84-1.14x,
#: one core; BENCHMARKS.md, issue 17, session 48).
BELOW_MIN_SLOTS = 48


def below_ok(prob: Problem) -> bool:
    """Whether a (host, numpy) problem can be factored with
    :attr:`IPMOptions.below`: numbered by layers (``L > 1``) of at least
    :data:`BELOW_MIN_SLOTS` slots, with a supports table whose supports
    are all in the level below their brick's (a layered problem's, not
    slabs'), and no column between two levels other than a brick's with
    one of its supports, so that the table holds every block coupling two
    levels."""
    import numpy as np

    if prob.layers is None or prob.supports is None or len(prob.layers) < 2:
        return False
    n, L = prob.brick_mask.shape[0], len(prob.layers)
    B = n // L
    if B < BELOW_MIN_SLOTS:
        return False
    sup = np.asarray(prob.supports)
    level = np.arange(n) // B
    real = sup < n
    if (level[np.minimum(sup, n - 1)][real] != np.broadcast_to(level[:, None] - 1, sup.shape)[real]).any():
        return False
    cb = np.minimum(np.asarray(prob.col_brick), n)
    cb = cb[np.asarray(prob.col_mask) & (cb < n).all(1)]
    across = level[cb[:, 0]] != level[cb[:, 1]]
    upper = np.where(level[cb[:, 0]] > level[cb[:, 1]], cb[:, 0], cb[:, 1])[across]
    lower = np.where(level[cb[:, 0]] > level[cb[:, 1]], cb[:, 1], cb[:, 0])[across]
    return bool((sup[upper] == lower[:, None]).any(1).all())


def options_for(opts: "IPMOptions", prob: Problem) -> "IPMOptions":
    """``opts`` with :attr:`IPMOptions.below` set where :func:`below_ok`
    accepts a single (unbatched, host) problem."""
    return dataclasses.replace(opts, below=below_ok(prob)) if isinstance(opts, IPMOptions) else opts


# ----------------------------------------------------------------- solver


def _system(prob: Problem, params: Params, opts: IPMOptions) -> dict:
    """The pieces of the interior-point method for one problem (closures).

    Every vector is flat, so one operation on all of them compiles to one
    kernel instead of one per part (XLA's compile time grows with the number
    of kernels): the primal variables ``z = [x, D, t, r+, r-]`` (lengths
    m, m, n, 6 n, 6 n; length ``2 m + 13 n``) and the slacks and their duals
    ``s = G(z) = [x + D, D, t_owner - D, x, t, r+, r-]`` (lengths m, m, m,
    m, n, 6 n, 6 n), with ``act`` (1: the inequality exists)."""
    dtype = jnp.dtype(opts.dtype)
    prob = prob._replace(col_coef=prob.col_coef.astype(dtype), gravity=prob.gravity.astype(dtype))
    A, At, coef, g, w = operators(prob, params)
    n, m = g.shape[0], prob.col_kind.shape[0]
    L = 1 if prob.layers is None else prob.layers.shape[0]
    k6 = 6 * (n // L)
    w = jnp.where(prob.brick_mask[:, None], w, 1.0).reshape(-1)  # padding rows: r = 0 at unit cost
    kind, cmask = prob.col_kind, prob.col_mask
    act_n = ((kind == NORMAL) & cmask).astype(dtype)
    act_s = ((kind == SIDE) & cmask).astype(dtype)
    zeros = functools.partial(jnp.zeros, dtype=dtype)
    # D exists on NORMAL contacts only (elsewhere it stays 0 and has no cost)
    act = jnp.concatenate([act_n, act_n, act_n, act_s, jnp.ones((13 * n,), dtype)])
    on = act > 0
    n_act = act.sum()
    group = prob.group
    owner = jnp.zeros((m + 1,), jnp.int32).at[group].set(
        jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32)[:, None], group.shape))[:m]

    def parts(v):  # slack-space vector -> its 7 parts (flat)
        return jnp.split(v, [m, 2 * m, 3 * m, 4 * m, 4 * m + n, 4 * m + 7 * n])

    def zparts(z):  # primal vector -> x, D, t, r+, r- (flat)
        return jnp.split(z, [m, 2 * m, 2 * m + n, 2 * m + 7 * n])

    alpha, beta = params.alpha, params.beta
    # the canonical term on the forces: ridge / (total weight, in T) (see Params), each
    # layout of a pack (Problem.member) by its own weight, (m,) a column by its brick's
    wsum = jax.ops.segment_sum(jnp.abs(g[:, 2]), prob.member, num_segments=n)
    reg = (params.ridge / jnp.maximum(wsum, 1e-30))[prob.member][jnp.minimum(prob.col_brick[:, 0], n - 1)]
    regz = jnp.concatenate([reg, zeros(m + 13 * n)])  # on z: the forces' entries

    # one dense block solved alone: factor only the leading rows of the real bricks
    # (padding bricks come last), at the smallest of the ladder's sizes that holds them
    # a dense problem solved alone assembles its bricks' rank-one terms from their supports
    # (problem.dense_supports: faster on a CPU); a batch of them (a GPU's) keeps the product
    supports, col_slot = (prob.supports, prob.col_slot) if L > 1 or opts.cut else (None, None)
    cut = opts.cut and L == 1 and n > CUT_MIN
    if cut:
        live = 6 * jnp.max(jnp.where(prob.brick_mask, jnp.arange(1, n + 1), 0))
        cuts = tuple(6 * r for r in ladder(n) if r >= CUT_MIN)  # ends with n

    below = None
    if opts.below and L > 1 and supports is not None:  # (L, B, K): each brick's supports as slots of the level below
        B = n // L
        sup = supports.reshape(L, B, -1)[1:] - (B * jnp.arange(L - 1))[:, None, None]
        sup = jnp.where((sup >= 0) & (sup < B), sup, B)
        below = jnp.concatenate([sup, jnp.full((1,) + sup.shape[1:], B, sup.dtype)])

    # the blocks of M for any weights (static scatter plan; :mod:`.newton`)
    assemble = reduced_matrix(prob.col_brick, coef, (kind == NORMAL) & cmask, n, L, prob.chunks,
                              supports, col_slot)

    def G(z):
        x, Dv, t, rp, rm = zparts(z)
        return jnp.concatenate([x + Dv, Dv, t[owner] - Dv, x, t, rp, rm])

    def Gt(v):
        v1, v2, v3, v4, v5, v6, v7 = parts(v * act)
        return jnp.concatenate([v1 + v4, v1 + v2 - v3, bottom_sum(v3, group) + v5, v6, v7])

    def Et(nu):
        nu = nu.reshape(-1)
        return jnp.concatenate([At(nu.reshape(n, 6)), zeros(m + n), -nu, nu])

    def Ez(z):
        x, _, _, rp, rm = zparts(z)
        return A(x) - (rp - rm).reshape(n, 6)

    cvec = jnp.concatenate([zeros(m), beta * act_n, jnp.full((n,), alpha, dtype), w, w])

    def dot(a, b):
        return (a * b).sum()

    def grad(z):  # gradient of the cost: c + (reg x, 0, ...)
        return cvec + regz * z

    def residuals(z, nu, lam):
        return grad(z) - Gt(lam) + Et(nu), Ez(z) + g

    def factor(z, lam):
        Wt = jnp.where(on, lam / G(z), 0.0)
        W1, W2, W3, W4, W5, W6, W7 = parts(Wt)
        # proximal term of the forces; the plain LP (ridge 0) gives them no curvature of their own
        d = opts.delta if params.ridge > 0 else max(opts.delta, 1e-8)
        hx = W1 + W4 + d + reg
        # a = hD - W1^2 / hx and gam = ht - sum W3^2 / a, written as sums of
        # nonnegative terms: no cancellation when the barrier weights reach 1e12+
        a = W2 + W3 + d + W1 * (W4 + d + reg) / hx
        gam = W5 + d + bottom_sum(W3 * (W2 + d + W1 * (W4 + d + reg) / hx) / a, group)
        e = (1.0 + W1 * W1 / (hx * a)) / hx
        q = W1 * W3 / (hx * a)
        dr = 1.0 / W6 + 1.0 / W7
        # static regularisation (relative to each pivot, plus a floor for rows no
        # column reaches, e.g. z torque of a 1x1 brick on one knob); its error in a
        # direction is corrected by the next iterate (or by opts.refine steps),
        # added on the diagonal in place (a full pass over a dense 720-row block was
        # a tenth of its iteration)
        i = jnp.arange(k6)
        if cut and supports is None:  # the rank-one terms as a factor for the cut
            Dm, Em, P = assemble(e, q, 1.0 / gam, dr, split=True)
            dg = Dm[:, i, i] + (P * P).sum(0)
        else:  # the whole matrix in D (the rank-one terms by :mod:`.newton`'s assemblies)
            P = None
            Dm, Em = assemble(e, q, 1.0 / gam, dr)
            dg = Dm[:, i, i]
        Dm = Dm.at[:, i, i].add(opts.reg_rel * dg + opts.reg_abs * (1.0 + dg.max()))
        C, Gf = cut_cholesky(Dm, P, live, cuts) if cut else block_cholesky(Dm, Em, below=below)
        return (Wt, hx, a, gam, C, Gf)

    def hinv(f, b):
        Wt, hx, a, gam, _, _ = f
        W1, _, W3, _, _, W6, W7 = parts(Wt)
        bx, bD, bt, brp, brm = zparts(b)
        bD2 = bD - W1 * bx / hx
        at = (bt + bottom_sum(W3 * bD2 / a, group)) / gam
        aD = act_n * (bD2 + W3 * at[owner]) / a
        ax = (bx - W1 * aD) / hx
        return jnp.concatenate([ax, aD, at, brp / W6, brm / W7])

    def newton(f, rhs1, rp_res):
        C, Gf = f[4], f[5]
        r = Ez(hinv(f, rhs1)) + rp_res

        def msolve(v):
            return block_solve(C, Gf, v.reshape(L, k6)).reshape(n, 6)

        # iterative refinement against the exact operator, unrolled: inside a
        # lax loop XLA copied the factor into LAPACK's column-major layout on
        # every pass (~20% of a small layout's iteration); unrolled, the solves
        # share one copy (1.2-1.6x faster per iteration, BENCHMARKS.md)
        dnu = msolve(r)
        for _ in range(opts.refine):
            dnu = dnu + msolve(r - Ez(hinv(f, Et(dnu))))
        return hinv(f, rhs1 - Et(dnu)), dnu

    def direction(f, z, lam, rd, rp_res, rc):
        s = G(z)
        rhs1 = -rd - Gt(jnp.where(on, rc / s, 0.0))
        dz, dnu = newton(f, rhs1, rp_res)
        ds = G(dz)
        dlam = jnp.where(on, -(rc + lam * ds) / s, 0.0)
        return dz, dnu, ds, dlam

    def max_step(v, dv):
        return jnp.minimum(1.0, boundary_step(v, dv, on))

    def measures(z, nu, lam):
        rd, rp_res = residuals(z, nu, lam)
        q = (regz * z * z).sum()
        obj = dot(cvec, z) + q / 2
        dual = (nu * g).sum() - q / 2  # the QP's (Wolfe) dual value
        pres = jnp.abs(rp_res).max()
        dres = jnp.abs(rd).max()
        # complementarity gap sum(s lam): the duality gap once residuals vanish (the
        # regularisation of free forces leaves ~delta |dx| in the dual residual, which
        # inflates obj - nu'g on statically indeterminate layouts without an error
        # in the forces)
        comp = dot(G(z), lam * act)

        def gap_ok(eps_abs, eps_rel):
            tol = eps_abs + eps_rel * jnp.abs(obj)
            return (comp <= tol) & (obj - dual <= 100 * tol)

        feas = (pres <= opts.eps_feas) & (dres <= opts.eps_feas)
        ok = feas & gap_ok(opts.eps_gap_abs, opts.eps_gap_rel)
        fine = ok & gap_ok(opts.polish_gap_abs, opts.polish_gap_rel)
        return (ok, fine), pres, dres, obj, dual, rd, rp_res

    def start():
        """Equality-feasible, strictly interior starting point (z, nu, lam)."""
        k0 = opts.init
        x0 = jnp.where(act_s > 0, k0, 0.0)
        r0 = (A(x0) + g).reshape(-1)
        rp0 = jnp.maximum(r0, 0.0) + k0
        z0 = jnp.concatenate([x0, k0 * act_n, jnp.full((n,), 2 * k0, dtype), rp0, rp0 - r0])
        # duals that zero the dual residual of r+-, D and t at nu = 0
        cnt = jnp.maximum(bottom_sum(act_n, group), 1.0)
        l3 = act_n * (params.alpha / 2) / cnt[owner]
        lam0 = jnp.concatenate([l3 / 2, params.beta + l3 / 2, l3, act_s * k0,
                                jnp.full((n,), params.alpha / 2, dtype), w, w])
        return z0, jnp.zeros((n, 6), dtype), jnp.where(on, lam0, 1.0)

    return dict(locals())


@x64
def solve(prob: Problem, params: Params = Params(), opts: IPMOptions = IPMOptions()) -> Solution:
    """Solve one compiled problem to optimality (jit/vmap friendly).

    ``prob.layers`` (shape (L,)) selects the block-tridiagonal factorisation
    over L layers of ``n / L`` brick slots (bricks numbered layer by layer,
    see :func:`~stablelego_jax.solvers.problem.to_layered`); None or L = 1: dense.
    """
    K = _system(prob, params, opts)
    act, dot, n_act, m = K["act"], K["dot"], K["n_act"], K["m"]
    measures, G, factor, direction, max_step = K["measures"], K["G"], K["factor"], K["direction"], K["max_step"]
    z0, nu0, lam0 = K["start"]()

    def step(c):
        # the residuals at the iterate come from the previous iteration's measures
        z, nu, lam, rd, rp_res = c["z"], c["nu"], c["lam"], c["rd"], c["rp"]
        s = G(z)
        mu = dot(s, lam * act) / n_act
        f = factor(z, lam)

        def phase(rc, _):
            # the predictor (rc: the complementarity products), then the corrector (rc: Mehrotra's,
            # from the predictor's step): one traced direction in a scan of two, a smaller program;
            # the corrector's own step and next target are computed too and dropped (a few passes
            # over the slacks, no solve)
            d = direction(f, z, lam, rd, rp_res, rc)
            _, _, ds, dlam = d
            ap, ad = max_step(s, ds), max_step(lam, dlam)
            mu_aff = dot(s + ap * ds, (lam + ad * dlam) * act) / n_act
            sigma = centring(mu_aff, mu)
            return (s * lam + ds * dlam - sigma * mu) * act, d

        _, dirs = jax.lax.scan(phase, s * lam * act, None, length=2)
        dz, dnu, ds, dlam = (v[1] for v in dirs)
        ap = opts.step * max_step(s, ds)
        ad = opts.step * max_step(lam, dlam)
        z = z + ap * dz
        lam = lam + ad * dlam
        nu = nu + ad * dnu
        (ok, fine), pres, dres, obj, dual, rd, rp_res = measures(z, nu, lam)
        new = dict(z=z, nu=nu, lam=lam, rd=rd, rp=rp_res, ok=ok, pres=pres, dres=dres, obj=obj, dual=dual)
        # numerical breakdown (factor lost definiteness near the end), or a polishing step that
        # lost convergence: keep the last iterate and stop
        bad = ~(jnp.isfinite(obj) & jnp.isfinite(dual) & jnp.isfinite(pres) & jnp.isfinite(dres)) | (c["ok"] & ~ok)
        return new, fine, bad

    big = jnp.asarray(jnp.inf, K["dtype"])
    rd0, rp0 = K["residuals"](z0, nu0, lam0)
    c0 = dict(z=z0, nu=nu0, lam=lam0, rd=rd0, rp=rp0, ok=jnp.asarray(False), pres=big, dres=big, obj=big, dual=-big)
    c, it = iterate(step, c0, opts.max_iter)
    gap = (c["obj"] - c["dual"]) / jnp.maximum(jnp.abs(c["obj"]), 1e-12)
    cost = dot(K["cvec"], c["z"])  # the Eq. 9 value, without the least-norm term
    return make_solution(prob, params, c["z"][:m], it, c["ok"], c["pres"], c["dres"], cost, c["dual"], gap)
