"""Differentiable stability loss of soft layouts (paper Eq. 9-10, smoothed by a barrier).

The problem
-----------
For a :class:`~stablelego_jax.soft.SoftProblem` with existence weights ``w``
and extra loads (kg per brick), the forces are the point of the *central
path* of the paper's Eq. 9 linear programme at barrier parameter ``mu``:
the minimiser of (scaled units: forces in units of the friction capacity T,
torques in T x stud pitch)

    sum_b w_b [ sum_i c_i (r+_bi + r-_bi) + alpha t_b ]       Eq. 9: |residual|, max drag
    + sum_p w_p [ beta D_p (NORMAL) + gamma (S_p + D_p) (KNOB)
                  + eps (1 - w_p) / 2 (S_p^2 + D_p^2) ]
    - mu * sum_k v_k log(slack_k)                              barrier

subject to ``r+_b - r-_b = rho_b`` (the residual of brick b), ``t_b >= o_p
D_p`` for the contacts p under b, and ``S, D, t, r+, r- >= 0``, where

* every force column p is split as in the paper into two non-negative
  parts, ``phi_p = S_p - D_p`` (support minus drag for contact points,
  +/- presses for knob presses; side presses have S only), given *per unit
  of existence*: the physical force is ``w_p phi_p`` (``w_p``: the product
  of the weights of the units the column joins, see
  :mod:`stablelego_jax.soft`), and ``o_p`` is the weight of the other brick
  of the column as seen from a brick;
* ``rho_b = sum_p o_p a_pb phi_p + g_b`` is brick b's residual per unit of
  its existence (g_b: its weight plus its extra load), ``c = (1, 1, 1, stud,
  stud, stud)`` (N and N m as in Eq. 9);
* ``gamma`` (``LossOptions.knob_cost``, 1e-6 like beta) is a tiny cost on
  knob presses that keeps each +/- pair bounded;
* ``eps`` (``LossOptions.compliance``) makes the contacts of *partly*
  existing bricks compliant; it vanishes at ``w = 1``, so for a plain
  layout everything but the barrier and gamma is Eq. 9;
* the barrier weight ``v_k`` of each inequality is the cost scale of its
  dual (alpha for the force parts and drag maxima, c for the residual
  pairs), so that all complementarity products have one size.

As ``mu -> 0`` the central path tends to an optimal solution of Eq. 9 (the
analytic centre of its optimal face). At the default ``mu = 1e-5`` the
largest drags of the paper's eight structures are within 5e-4 N of HiGHS'
(stair_20's brick '2': 0.98538 N vs 0.98537 N) and residuals are ~1e-7 N.
The central-path point is unique and a smooth function of weights and
loads. (Much below ``mu = 1e-6`` the reduced Newton systems are too
ill-conditioned for float64 on these near-degenerate LPs.)

Multiplying each brick's terms by its weight and using forces per unit of
existence makes ``w = 0`` exactly "absent" and keeps the first-order effect
of adding a brick finite and physical: the faded-in brick must balance its
own (scaled) weight through its contacts, so a candidate brick hanging in
the air cannot help, and one standing on the baseplate can.

It is solved by the barrier interior point of
:mod:`stablelego_jax.solvers.soft_ipm`. ``jit`` and ``vmap`` work; the
library's float64 is switched on inside every function here, forward and
backward pass (:func:`stablelego_jax.runtime.x64_differentiable`), so
callers may run JAX in float32 and take gradients with respect to
``weights`` and ``loads``.

Gradients
---------
Implicit differentiation (the solver's custom VJP, one transposed Newton
solve at the solution, refined once; nothing is unrolled). Central
differences agree to within 0.1% on the tests' layouts and 0.12% on the
20 layouts of ``benchmarks/loss_layered.py`` (session 49); losses and
gradients do not depend on the bricks' numbering, the factorisation
(dense or layered) or batching (losses to 1e-8 relative or float64's
rounding, gradients to ~3e-9 of their largest component).

The loss
--------
Per brick (``brick_loss``), at temperature ``tau`` (units of T):

    l_b = w_b [ tau softplus((t_b - 1) / tau) + E_b ]

with t_b the brick's largest drag in units of T (the Eq. 9 variable) and E_b
its equilibrium residual (sum of |force| + |torque| in T and T m). As
``tau`` and ``mu`` go to 0, ``l_b -> max(D_b/T - 1, 0) + E_b``: positive
exactly for the bricks Eq. 10 scores 1 (drag beyond T, or out of
equilibrium beyond the residual tolerance), zero otherwise. ``soft_scores``
gives the Eq. 10 scores and verdict of the smooth solution; ``fail_prob``,
``sigmoid((t_b - 1)/tau)``, is a smooth version of Eq. 10's indicator.

What the gradient means physically
----------------------------------
* ``d loss / d loads[b]`` (per kg): how much the total overload (drag beyond
  the capacity T, in units of T, plus any unbalanced force) grows per
  kilogram hung on brick b, with the forces redistributed as Eq. 9
  redistributes them.
* ``d loss / d weights[c]`` at ``w_c = 0`` for a candidate brick c: the
  rate at which the overload changes when c is faded in: its own weight is
  added, and its contacts start to carry forces (in proportion to w), chosen
  as Eq. 9 chooses them: pushing where the other bricks' equilibrium prices
  (the duals of their residual rows, i.e. the virtual displacements of the
  collapse) say it relieves them, while balancing c's own weight. Negative:
  adding c helps. For a base brick at ``w = 1``: positive means the layout
  would get better with less of that brick.
"""
from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .runtime import x64_differentiable
from .score import largest_drag, residual_bad, verdict
from .soft import ScenePositions, SoftProblem, shifted_wrenches
from .solvers.soft_ipm import BarrierOptions, SoftContext, brick_residual, central_path, column_force, soft_context

__all__ = [
    "LossOptions",
    "SoftSolution",
    "SoftReport",
    "solve_soft",
    "brick_loss",
    "stability_loss",
    "position_loss",
    "soft_scores",
    "fail_prob",
    "soft_report",
]


@dataclasses.dataclass(frozen=True)
class LossOptions(BarrierOptions):
    """Settings of the smooth solver and the loss (hashable: a static jit argument).

    The solver's fields (mu, iters, centred, knob_cost, compliance, tol,
    params) are those of :class:`~stablelego_jax.solvers.soft_ipm.BarrierOptions`;
    temperature: loss temperature tau (units of T) of the overload hinge;
    residual_smoothing: s of the smoothed |residual| in the loss (units of T).
    """

    temperature: float = 0.02
    residual_smoothing: float = 1e-6


class SoftSolution(NamedTuple):
    """Solution of the smooth problem.

    phi: (m,) force of each column per unit of existence, in units of T.
    max_drag: (n,) each brick's largest-drag variable t_b, in N (per unit of existence).
    force: (m,) physical force in N (``w_p phi_p T``).
    converged: optimality conditions within ``tol`` and iterate centred;
    opt_res: the optimality residual (inf-norm; 1 or more when not centred).
    """

    phi: jnp.ndarray
    max_drag: jnp.ndarray
    force: jnp.ndarray
    converged: jnp.ndarray
    opt_res: jnp.ndarray


def _terms(weights, loads, prob, opts):
    n = prob.mass.shape[0]
    weights = jnp.asarray(weights, jnp.float64)
    loads = jnp.zeros((n,), jnp.float64) if loads is None else jnp.asarray(loads, jnp.float64)
    x, aux = central_path(weights, loads, prob, opts)
    ctx = soft_context(weights, loads, prob, opts.params)
    return ctx, x, aux


@x64_differentiable("weights", "loads")
def solve_soft(weights, loads, prob: SoftProblem, opts: LossOptions = LossOptions()) -> SoftSolution:
    """Solve the smooth Eq. 9 problem of ``prob`` at ``weights`` (n,) and
    extra ``loads`` (n,) kg (None: no loads). Differentiable in weights and
    loads (implicit differentiation)."""
    ctx, x, aux = _terms(weights, loads, prob, opts)
    phi = column_force(x, ctx)
    res = jax.lax.stop_gradient(aux[2])
    return SoftSolution(phi=phi, max_drag=x[2] * opts.params.T, force=phi * ctx.wcol * opts.params.T,
                        converged=res <= opts.tol, opt_res=res)


def _brick_loss(ctx: SoftContext, x, rho, tau, opts: LossOptions):
    s = opts.residual_smoothing
    resid = (ctx.cost * (jnp.sqrt(rho * rho + s * s) - s)).sum(axis=1)
    hinge = tau * jax.nn.softplus((x[2] - 1.0) / tau)
    return ctx.om * (hinge + resid)


def _residual_bad(rho, opts: LossOptions):
    """Eq. 10's equilibrium test on the scaled residual ``rho`` (forces / T,
    torques / (T stud)), through :func:`stablelego_jax.score.residual_bad`."""
    p = opts.params
    unit = jnp.asarray([p.T, p.T, p.T, p.T * p.stud, p.T * p.stud, p.T * p.stud], rho.dtype)
    return residual_bad(rho * unit, p)


def _fail_prob(ctx: SoftContext, x, rho, tau, opts: LossOptions):
    p = jax.nn.sigmoid((x[2] - 1.0) / tau)
    return jnp.where(ctx.om > 0, jnp.where(_residual_bad(rho, opts), 1.0, p), 0.0)


def _scores(ctx: SoftContext, phi, rho, opts: LossOptions):
    d = jnp.where(ctx.normal, jnp.maximum(-phi, 0.0) * ctx.o0, 0.0)
    dm = largest_drag(d, ctx.group) * opts.params.T
    bad = _residual_bad(rho, opts)
    present = ctx.om > 0
    score = jnp.where(present, verdict(dm, bad, opts.params), 0.0)
    return score, dm, bad & present


def _brick_losses(weights, loads, prob, temperature, opts):
    tau = opts.temperature if temperature is None else temperature
    ctx, x, _ = _terms(weights, loads, prob, opts)
    return _brick_loss(ctx, x, brick_residual(ctx, column_force(x, ctx)), tau, opts)


@x64_differentiable("weights", "loads")
def brick_loss(weights, loads, prob: SoftProblem, temperature: float | None = None,
               opts: LossOptions = LossOptions()):
    """Per-brick loss (n,): ``w_b [tau softplus((t_b - 1)/tau) + E_b]`` with t_b
    the brick's largest drag and E_b its equilibrium residual, both in units
    of T (see the module docstring). ``temperature`` overrides
    ``opts.temperature``. Padding and absent bricks give 0."""
    return _brick_losses(weights, loads, prob, temperature, opts)


@x64_differentiable("weights", "loads")
def stability_loss(weights, loads, prob: SoftProblem, temperature: float | None = None,
                   opts: LossOptions = LossOptions()):
    """Scalar stability loss: the sum of :func:`brick_loss`."""
    return _brick_losses(weights, loads, prob, temperature, opts).sum()


@x64_differentiable("shift", "weights", "loads")
def position_loss(shift, weights, loads, prob: SoftProblem, geo: ScenePositions, temperature: float | None = None,
                  opts: LossOptions = LossOptions()):
    """:func:`stability_loss` of a scene whose plain blocks are moved
    horizontally by ``shift`` (n, 2) metres (``prob``:
    :func:`~stablelego_jax.soft.soft_problem` of the scene, ``geo``:
    :func:`~stablelego_jax.soft.scene_positions`). Differentiable in
    ``shift`` as well as weights and loads: ``d loss / d shift[b]`` is how the
    total overload changes per metre that block b slides, with the contact
    polygons following it (their vertices are affine in the moves while no
    contact appears or vanishes; at ``shift`` = 0 the loss equals
    :func:`stability_loss`, and away from 0 its contacts are those of the
    unmoved scene, linearised). At a kink (``geo.smooth`` False, e.g. two
    aligned edges) the gradient is the mean of the one-sided ones."""
    coef = shifted_wrenches(geo, shift, xp=jnp)
    return _brick_losses(weights, loads, prob._replace(col_coef=coef), temperature, opts).sum()


@x64_differentiable("weights", "loads")
def fail_prob(weights, loads, prob: SoftProblem, temperature: float | None = None,
              opts: LossOptions = LossOptions()):
    """Smooth Eq. 10 failure indicator per brick: ``sigmoid((t_b - 1)/tau)``
    (1 for bricks out of equilibrium); tends to Eq. 10's indicator as
    ``tau -> 0``. Absent and padding bricks give 0."""
    tau = opts.temperature if temperature is None else temperature
    ctx, x, _ = _terms(weights, loads, prob, opts)
    return _fail_prob(ctx, x, brick_residual(ctx, column_force(x, ctx)), tau, opts)


@x64_differentiable("weights", "loads")
def soft_scores(weights, loads, prob: SoftProblem, opts: LossOptions = LossOptions()):
    """Eq. 10 (:func:`stablelego_jax.score.verdict`) applied to the smooth
    solution (per unit of existence).

    Returns (scores (n,), max_drag (n,) N, residual_bad (n,) bool); scores
    are 1 for bricks out of equilibrium or with drag >= T, else drag / T,
    and 0 for padding and absent (w = 0) bricks.
    """
    ctx, x, _ = _terms(weights, loads, prob, opts)
    phi = column_force(x, ctx)
    return _scores(ctx, phi, brick_residual(ctx, phi), opts)


class SoftReport(NamedTuple):
    """Everything per brick from one solve (see :func:`soft_report`)."""

    brick_loss: jnp.ndarray  # (n,) as brick_loss
    fail_prob: jnp.ndarray  # (n,) as fail_prob
    scores: jnp.ndarray  # (n,) as soft_scores
    max_drag: jnp.ndarray  # (n,) N, as soft_scores
    residual_bad: jnp.ndarray  # (n,) bool
    converged: jnp.ndarray  # () bool


@x64_differentiable("weights", "loads")
def soft_report(weights, loads, prob: SoftProblem, temperature=None, opts: LossOptions = LossOptions()) -> SoftReport:
    """:func:`brick_loss`, :func:`fail_prob` and :func:`soft_scores` from one
    solve; ``temperature`` may be a traced value (it does not enter the solve)."""
    tau = opts.temperature if temperature is None else temperature
    ctx, x, aux = _terms(weights, loads, prob, opts)
    phi = column_force(x, ctx)
    rho = brick_residual(ctx, phi)
    score, max_drag, bad = _scores(ctx, phi, rho, opts)
    return SoftReport(brick_loss=_brick_loss(ctx, x, rho, tau, opts), fail_prob=_fail_prob(ctx, x, rho, tau, opts),
                      scores=score, max_drag=max_drag, residual_bad=bad,
                      converged=jax.lax.stop_gradient(aux[2]) <= opts.tol)
