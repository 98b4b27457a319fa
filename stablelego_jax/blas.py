"""Threads of the CPU backend: one OpenBLAS thread for JAX's CPU linear
algebra, and inline dispatch of JAX's CPU computations.

JAX's CPU LAPACK kernels (Cholesky, LU, triangular solves) call SciPy's
bundled OpenBLAS. Its worker threads spin while they wait, and on a busy
machine they fight the other processes for the cores: a batch of the
interior-point solver took 83.4 s instead of 10.8 s next to two busy
processes on the 2-core box (``benchmarks/blas_threads.py``, BENCHMARKS.md);
the small dense LUs of the differentiable loss suffer the same way. On the
quiet machine one thread was faster too (5.5 s against 8.1 s). :func:`one_blas_thread`
sets the count to 1 for a block and restores it after; without SciPy's
OpenBLAS (another build) it does nothing.

:func:`inline_cpu_dispatch`, called by the command line before JAX's
backend starts, runs CPU computations inline on the calling thread
(JAX's ``jax_cpu_enable_async_dispatch`` off). Batched ``score`` runs hung
three times on this machine (0 CPU, the main thread waiting forever in
``device_get`` for an asynchronously dispatched computation: twice with
XLA's Eigen thread pool on, once with it off, so the Eigen flag is not the
cause); inline dispatch removes the waiting step. It is a mitigation, not a
proven fix: the hang is rare and was not reproduced on demand.
"""
from __future__ import annotations

import contextlib
import functools

__all__ = ["one_blas_thread", "openblas_library", "inline_cpu_dispatch"]


def inline_cpu_dispatch() -> None:
    """Run JAX's CPU computations inline on the calling thread
    (``jax_cpu_enable_async_dispatch`` off) unless the environment sets
    ``JAX_CPU_ENABLE_ASYNC_DISPATCH=true``. Imports JAX; takes effect only
    before JAX's backend starts."""
    import os

    if os.environ.get("JAX_CPU_ENABLE_ASYNC_DISPATCH", "false").lower() in ("0", "false"):
        import jax

        jax.config.update("jax_cpu_enable_async_dispatch", False)


@contextlib.contextmanager
def one_blas_thread():
    """Context manager: one thread in SciPy's OpenBLAS inside, the previous
    count restored after."""
    lib = openblas_library()
    if lib is None:
        yield
        return
    old = lib.scipy_openblas_get_num_threads()
    lib.scipy_openblas_set_num_threads(1)
    try:
        yield
    finally:
        lib.scipy_openblas_set_num_threads(old)


@functools.lru_cache(maxsize=1)
def openblas_library():
    """ctypes handle of SciPy's bundled OpenBLAS (None when not found)."""
    import ctypes
    import glob
    import os

    import scipy

    pattern = os.path.join(os.path.dirname(os.path.dirname(scipy.__file__)), "scipy.libs", "libscipy_openblas*.so*")
    for path in glob.glob(pattern):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        if hasattr(lib, "scipy_openblas_set_num_threads") and hasattr(lib, "scipy_openblas_get_num_threads"):
            return lib
    return None
