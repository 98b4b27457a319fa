"""Interior-point JAX solver for the Eq. 9 linear programme.

The same LP as the exact referee (``exact.py``), in scaled units (forces in
T, torque rows in T stud):

    min  beta sum_p D_p + alpha sum_b t_b + sum w (r+ + r-)
    s.t. A x - r+ + r- + g = 0                    (6 rows per brick)
         x_p + D_p >= 0, D_p >= 0, t_b - D_p >= 0  (NORMAL contact p of brick b)
         x_p >= 0 (SIDE), t_b >= 0, r+, r- >= 0

solved by a primal-dual Mehrotra predictor-corrector method. Every Newton
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
and its rank-one term is assembled brick by brick from its supports.
Iteration counts are 20-50 whatever the layout (no long first-order
tails), so a ``vmap``-ed batch finishes together.

Returns the same :class:`~stablelego_jax.solvers.problem.Solution` as the ADMM
solver (forces in N, objective and dual bound in N-based units).
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from ..model import NORMAL, SIDE, Params
from ..runtime import x64
from .blocks import block_cholesky, block_solve
from .newton import reduced_matrix
from .problem import Problem, Solution, make_solution, operators

__all__ = ["IPMOptions", "solve"]


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
    exact solver's (``exact.least_norm``).
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


# ----------------------------------------------------------------- solver


def _system(prob: Problem, params: Params, opts: IPMOptions) -> dict:
    """The pieces of the interior-point method for one problem (closures)."""
    dtype = jnp.dtype(opts.dtype)
    prob = prob._replace(col_coef=prob.col_coef.astype(dtype), gravity=prob.gravity.astype(dtype))
    A, At, coef, g, w = operators(prob, params)
    n, m = g.shape[0], prob.col_kind.shape[0]
    L = 1 if prob.layers is None else prob.layers.shape[0]
    k6 = 6 * (n // L)
    w = jnp.where(prob.brick_mask[:, None], w, 1.0)  # padding rows: r = 0 at unit cost
    kind, cmask = prob.col_kind, prob.col_mask
    act_n = ((kind == NORMAL) & cmask).astype(dtype)
    act_s = ((kind == SIDE) & cmask).astype(dtype)
    # D exists on NORMAL contacts only (elsewhere it stays 0 and has no cost)
    act = (act_n, act_n, act_n, act_s, jnp.ones((n,), dtype),
           jnp.ones((n, 6), dtype), jnp.ones((n, 6), dtype))
    n_act = sum(a.sum() for a in act)
    group = prob.group
    owner = jnp.zeros((m + 1,), jnp.int32).at[group].set(
        jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32)[:, None], group.shape))[:m]

    def segsum(v):  # (m,) per-contact -> (n,) per owning brick
        return jnp.concatenate([v, jnp.zeros((1,), v.dtype)])[group].sum(axis=1)

    alpha, beta = params.alpha, params.beta
    # the canonical term on the forces: ridge / (total weight, in T) (see Params)
    reg = params.ridge / jnp.maximum(jnp.abs(g[:, 2]).sum(), 1e-30)

    # the blocks of M for any weights (static scatter plan; :mod:`.newton`)
    assemble = reduced_matrix(prob.col_brick, coef, (kind == NORMAL) & cmask, n, L, prob.chunks,
                              prob.supports, prob.col_slot)

    def G(z):
        x, Dv, t, rp, rm = z
        return (x + Dv, Dv, t[owner] - Dv, x, t, rp, rm)

    def Gt(v):
        v = tuple(a * b for a, b in zip(v, act))
        return (v[0] + v[3], v[0] + v[1] - v[2], segsum(v[2]) + v[4], v[5], v[6])

    def Et(nu):
        return (At(nu), jnp.zeros((m,), dtype), jnp.zeros((n,), dtype), -nu, nu)

    def Ez(z):
        return A(z[0]) - z[3] + z[4]

    def cost():
        return (jnp.zeros((m,), dtype), beta * act_n, jnp.full((n,), alpha, dtype), w, w)

    cvec = cost()

    def dot(a, b):
        return sum((x * y).sum() for x, y in zip(a, b))

    def grad(z):  # gradient of the cost: c + (reg x, 0, ...)
        return (cvec[0] + reg * z[0],) + cvec[1:]

    def residuals(z, nu, lam):
        rd = jax.tree_util.tree_map(lambda c, gl, e: c - gl + e, grad(z), Gt(lam), Et(nu))
        rp = Ez(z) + g
        return rd, rp

    def factor(z, lam):
        s = G(z)
        Wt = tuple(jnp.where(a > 0, l_ / s_, 0.0) for l_, s_, a in zip(lam, s, act))
        W1, W2, W3, W4, W5, W6, W7 = Wt
        # proximal term of the forces; the plain LP (ridge 0) gives them no curvature of their own
        d = opts.delta if params.ridge > 0 else max(opts.delta, 1e-8)
        hx = W1 + W4 + d + reg
        # a = hD - W1^2 / hx and gam = ht - sum W3^2 / a, written as sums of
        # nonnegative terms: no cancellation when the barrier weights reach 1e12+
        a = W2 + W3 + d + W1 * (W4 + d + reg) / hx
        gam = W5 + d + segsum(W3 * (W2 + d + W1 * (W4 + d + reg) / hx) / a)
        e = (1.0 + W1 * W1 / (hx * a)) / hx
        q = W1 * W3 / (hx * a)
        dr = 1.0 / W6 + 1.0 / W7
        Dm, Em = assemble(e, q, 1.0 / gam, dr)
        # static regularisation (relative to each pivot, plus a floor for rows no
        # column reaches, e.g. z torque of a 1x1 brick on one knob); its error in a
        # direction is corrected by the next iterate (or by opts.refine steps)
        dg = jax.vmap(jnp.diagonal)(Dm)
        Dm = Dm + jax.vmap(jnp.diag)(opts.reg_rel * dg + opts.reg_abs * (1.0 + dg.max()))
        C, Gf = block_cholesky(Dm, Em)
        return (Wt, hx, a, gam, C, Gf)

    def hinv(f, b):
        Wt, hx, a, gam, _, _ = f
        W1, W3, W6, W7 = Wt[0], Wt[2], Wt[5], Wt[6]
        bx, bD, bt, brp, brm = b
        bD2 = bD - W1 * bx / hx
        at = (bt + segsum(W3 * bD2 / a)) / gam
        aD = act_n * (bD2 + W3 * at[owner]) / a
        ax = (bx - W1 * aD) / hx
        return (ax, aD, at, brp / W6, brm / W7)

    def newton(f, rhs1, rp_res):
        C, Gf = f[4], f[5]
        h = hinv(f, rhs1)
        r = Ez(h) + rp_res

        def msolve(v):
            return block_solve(C, Gf, v.reshape(L, k6)).reshape(n, 6)

        # iterative refinement against the exact operator, unrolled: inside a
        # lax loop XLA copied the factor into LAPACK's column-major layout on
        # every pass (~20% of a small layout's iteration); unrolled, the solves
        # share one copy (1.2-1.6x faster per iteration, BENCHMARKS.md)
        dnu = msolve(r)
        for _ in range(opts.refine):
            dnu = dnu + msolve(r - Ez(hinv(f, Et(dnu))))
        dz = hinv(f, jax.tree_util.tree_map(lambda a, b: a - b, rhs1, Et(dnu)))
        return dz, dnu

    def direction(f, z, lam, rd, rp_res, rc):
        s = G(z)
        rcs = tuple(jnp.where(ac > 0, r_ / s_, 0.0) for r_, s_, ac in zip(rc, s, act))
        rhs1 = jax.tree_util.tree_map(lambda a, b: -a - b, rd, Gt(rcs))
        dz, dnu = newton(f, rhs1, rp_res)
        ds = G(dz)
        dlam = tuple(jnp.where(ac > 0, -(r_ + l_ * d_) / s_, 0.0)
                     for r_, l_, d_, s_, ac in zip(rc, lam, ds, s, act))
        return dz, dnu, ds, dlam

    def max_step(v, dv):
        ratios = [jnp.where((ac > 0) & (b < 0), -a / jnp.where(b < 0, b, -1.0), jnp.inf)
                  for a, b, ac in zip(v, dv, act)]
        return jnp.minimum(1.0, jnp.stack([r.min() for r in ratios]).min())

    def measures(z, nu, lam):
        rd, rp_res = residuals(z, nu, lam)
        q = reg * (z[0] * z[0]).sum()
        obj = dot(cvec, z) + q / 2
        dual = (nu * g).sum() - q / 2  # the QP's (Wolfe) dual value
        pres = jnp.abs(rp_res).max()
        dres = jnp.stack([jnp.abs(r).max() for r in rd]).max()
        # complementarity gap sum(s lam): the duality gap once residuals vanish (the
        # regularisation of free forces leaves ~delta |dx| in the dual residual, which
        # inflates obj - nu'g on statically indeterminate layouts without an error
        # in the forces)
        comp = dot(G(z), tuple(l_ * a for l_, a in zip(lam, act)))

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
        r0 = A(x0) + g
        rp0 = jnp.maximum(r0, 0.0) + k0
        z0 = (x0, k0 * act_n, jnp.full((n,), 2 * k0, dtype), rp0, rp0 - r0)
        # duals that zero the dual residual of r+-, D and t at nu = 0
        cnt = jnp.maximum(segsum(act[0]), 1.0)
        l3 = act[0] * (params.alpha / 2) / cnt[owner]
        lam0 = (l3 / 2, params.beta + l3 / 2, l3, act_s * k0, jnp.full((n,), params.alpha / 2, dtype), w, w)
        lam0 = tuple(jnp.where(a > 0, l_, 1.0) for l_, a in zip(lam0, act))
        nu0 = jnp.zeros((n, 6), dtype)
        return z0, nu0, lam0

    return dict(locals())


@x64
def solve(prob: Problem, params: Params = Params(), opts: IPMOptions = IPMOptions()) -> Solution:
    """Solve one compiled problem to optimality (jit/vmap friendly).

    ``prob.layers`` (shape (L,)) selects the block-tridiagonal factorisation
    over L layers of ``n / L`` brick slots (bricks numbered layer by layer,
    see :func:`~stablelego_jax.solvers.problem.to_layered`); None or L = 1: dense.
    """
    K = _system(prob, params, opts)
    act, dtype, dot, n_act = K["act"], K["dtype"], K["dot"], K["n_act"]
    measures, G, factor, direction, max_step = K["measures"], K["G"], K["factor"], K["direction"], K["max_step"]
    z0, nu0, lam0 = K["start"]()

    def body(c):
        # the residuals at the iterate come from the previous iteration's measures
        z, nu, lam, rd, rp_res = c["z"], c["nu"], c["lam"], c["rd"], c["rp"]
        s = G(z)
        mu = dot(s, tuple(l_ * a for l_, a in zip(lam, act))) / n_act
        f = factor(z, lam)
        # predictor
        rc = tuple(s_ * l_ * a for s_, l_, a in zip(s, lam, act))
        dz, dnu, ds, dlam = direction(f, z, lam, rd, rp_res, rc)
        ap, ad = max_step(s, ds), max_step(lam, dlam)
        mu_aff = dot(tuple(s_ + ap * d_ for s_, d_ in zip(s, ds)),
                     tuple((l_ + ad * d_) * a for l_, d_, a in zip(lam, dlam, act))) / n_act
        sigma = jnp.clip((mu_aff / mu) ** 3, 0.0, 1.0)
        # corrector
        rc = tuple((s_ * l_ + d1 * d2 - sigma * mu) * a
                   for s_, l_, d1, d2, a in zip(s, lam, ds, dlam, act))
        dz, dnu, ds, dlam = direction(f, z, lam, rd, rp_res, rc)
        ap = opts.step * max_step(s, ds)
        ad = opts.step * max_step(lam, dlam)
        z = jax.tree_util.tree_map(lambda a, b: a + ap * b, z, dz)
        lam = tuple(l_ + ad * d_ for l_, d_ in zip(lam, dlam))
        nu = nu + ad * dnu
        (ok, fine), pres, dres, obj, dual, rd, rp_res = measures(z, nu, lam)
        new = dict(z=z, nu=nu, lam=lam, rd=rd, rp=rp_res, it=c["it"] + 1, done=fine, ok=ok, pres=pres, dres=dres,
                   obj=obj, dual=dual)
        # numerical breakdown (factor lost definiteness near the end), or a polishing step that
        # lost convergence: keep the last iterate and stop
        bad = ~(jnp.isfinite(obj) & jnp.isfinite(dual) & jnp.isfinite(pres) & jnp.isfinite(dres)) | (c["ok"] & ~ok)
        old = dict(c, it=c["it"] + 1, done=True)
        return jax.tree_util.tree_map(lambda u, v: jnp.where(bad, u, v), old, new)

    big = jnp.asarray(jnp.inf, dtype)
    rd0, rp0 = K["residuals"](z0, nu0, lam0)
    c0 = dict(z=z0, nu=nu0, lam=lam0, rd=rd0, rp=rp0, it=jnp.asarray(0), done=jnp.asarray(False),
              ok=jnp.asarray(False), pres=big, dres=big, obj=big, dual=-big)
    c = jax.lax.while_loop(lambda c: (~c["done"]) & (c["it"] < opts.max_iter), body, c0)
    gap = (c["obj"] - c["dual"]) / jnp.maximum(jnp.abs(c["obj"]), 1e-12)
    cost = dot(K["cvec"], c["z"])  # the Eq. 9 value, without the least-norm term
    return make_solution(prob, params, c["z"][0], c["it"], c["ok"], c["pres"], c["dres"], cost, c["dual"], gap)
