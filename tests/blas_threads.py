"""One BLAS thread for the dense factorisations of the differentiable solver.

JAX's CPU LAPACK calls go through SciPy's bundled OpenBLAS; on a busy 2-core
machine its worker threads spin and a 224 x 224 LU takes ~80 ms instead of
~0.5 ms. Test modules that solve many small systems import
:func:`one_blas_thread` as a module-scoped fixture (the thread count is
restored after), see :mod:`stablelego_jax.blas`.
"""
import pytest

from stablelego_jax.blas import one_blas_thread as _one


@pytest.fixture(autouse=True, scope="module")
def one_blas_thread():
    with _one():
        yield
