"""Solvers of the paper's Eq. 9 problem, all on the arrays of one compiled model.

* :mod:`.problem`: the problem and solution pytrees, the one size ladder,
  padding and solve plans, the scaled equilibrium operators;
* :mod:`.ipm`: the JAX interior point (dense or layer by layer; the default);
* :mod:`.soft_ipm`: the barrier interior point of soft problems with its
  implicit adjoint (behind :mod:`stablelego_jax.loss`);
* :mod:`.exact`: the exact referee (HiGHS);
* :mod:`.baselines`: the paper's baselines (Luo et al., enhanced) on HiGHS;
* :mod:`.compiled`: the bounded, disk-backed cache of compiled solvers.
"""
