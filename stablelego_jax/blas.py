"""Threads of the CPU backend: one OpenBLAS thread for JAX's CPU linear
algebra, and XLA's CPU settings (made before JAX's backend starts).

JAX's CPU LAPACK kernels (Cholesky, LU, triangular solves) call SciPy's
bundled OpenBLAS. Its worker threads spin while they wait, and on a busy
machine they fight the other processes for the cores: a batch of the
interior-point solver took 83.4 s instead of 10.8 s next to two busy
processes on the 2-core box (``benchmarks/blas_threads.py``, BENCHMARKS.md);
the small dense LUs of the differentiable loss suffer the same way. On the
quiet machine one thread was faster too (5.5 s against 8.1 s). :func:`one_blas_thread`
sets the count to 1 for a block and restores it after; without SciPy's
OpenBLAS (another build) it does nothing.

:func:`xla_cpu_flags` configures XLA's CPU backend for this process
before JAX starts it: computations run inline on the calling thread
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

__all__ = ["one_blas_thread", "openblas_library", "xla_cpu_flags"]


def xla_cpu_flags(host_devices: int | None = None, eigen_threads: bool = True) -> str:
    """Configure XLA's CPU backend through the environment, before JAX's
    backend starts (a no-op after; it imports JAX): inline dispatch
    (``jax_cpu_enable_async_dispatch`` off, unless the environment sets
    ``JAX_CPU_ENABLE_ASYNC_DISPATCH=true``), ``--xla_cpu_multi_thread_eigen=false`` unless
    ``eigen_threads``, and ``--xla_force_host_platform_device_count`` =
    ``host_devices`` when given. Settings the user made win. Returns
    ``XLA_FLAGS``."""
    import os

    if os.environ.get("JAX_CPU_ENABLE_ASYNC_DISPATCH", "false").lower() in ("0", "false"):
        import jax

        jax.config.update("jax_cpu_enable_async_dispatch", False)
    flags = os.environ.get("XLA_FLAGS", "").split()
    have = {f.split("=")[0] for f in flags}
    if not eigen_threads and "--xla_cpu_multi_thread_eigen" not in have:
        flags.append("--xla_cpu_multi_thread_eigen=false")
    if host_devices and "--xla_force_host_platform_device_count" not in have:
        flags.append(f"--xla_force_host_platform_device_count={int(host_devices)}")
    os.environ["XLA_FLAGS"] = " ".join(flags)
    return os.environ["XLA_FLAGS"]


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
