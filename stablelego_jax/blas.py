"""Threads of the CPU backend: one OpenBLAS thread for JAX's CPU linear
algebra, and XLA's CPU flags (no JAX import here, so the command line can
set them before JAX starts).

JAX's CPU LAPACK kernels (Cholesky, LU, triangular solves) call SciPy's
bundled OpenBLAS. Its worker threads spin while they wait, and on a busy
machine they fight the other processes for the cores: a batch of the
interior-point solver took 83.4 s instead of 10.8 s next to two busy
processes on the 2-core box (``benchmarks/blas_threads.py``, BENCHMARKS.md);
the small dense LUs of the differentiable loss suffer the same way. On the
quiet machine one thread was faster too (5.5 s against 8.1 s). :func:`one_blas_thread`
sets the count to 1 for a block and restores it after; without SciPy's
OpenBLAS (another build) it does nothing.

:func:`xla_cpu_flags` sets ``XLA_FLAGS`` for this process before JAX's
backend starts: XLA's CPU runtime can deadlock in a ``vmap``-ed solve that
runs its Eigen thread pool (seen twice in batched runs of ``score`` on this
machine: every pool thread idle, the main thread waiting in
``device_get``), so the command line runs XLA's Eigen kernels on the
calling thread, and uses the cores through host devices instead (one per
core, each its own share of a batch).
"""
from __future__ import annotations

import contextlib
import functools

__all__ = ["one_blas_thread", "openblas_library", "xla_cpu_flags"]


def xla_cpu_flags(host_devices: int | None = None, eigen_threads: bool = False) -> str:
    """Add XLA CPU flags to ``XLA_FLAGS`` in this process's environment and
    return the result: ``--xla_cpu_multi_thread_eigen=false`` unless
    ``eigen_threads``, and ``--xla_force_host_platform_device_count``
    = ``host_devices`` when given. Flags the user already set win. Takes
    effect only if JAX's backend has not started yet (call it before the
    first JAX computation)."""
    import os

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
