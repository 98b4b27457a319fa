"""How the library runs JAX without changing the user's JAX: float64 in a
scope, and a persistent cache of compiled solvers.

* :func:`x64` (a decorator) and :func:`float64` (a context manager) switch
  64-bit floats on for the library's own work only, with the scoped
  ``jax.enable_x64`` context of the installed JAX. After ``import
  stablelego_jax`` and any call, a user's ``jnp.zeros(3)`` is still float32
  (unless the user enabled x64 globally). Results handed back are numpy
  float64 arrays, or JAX arrays of the caller's precision for gradients.
* :func:`cache_dir` is where compiled solvers are kept between processes:
  ``$STABLELEGO_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/stablelego-jax``
  (``~/.cache/stablelego-jax``); ``STABLELEGO_CACHE=0`` turns the disk
  cache off. :func:`use_persistent_cache` points JAX's persistent
  compilation cache there unless the user configured one.
* :func:`compiler_options` are the XLA options the library compiles its
  solvers with (on a CPU: :data:`CPU_COMPILER_OPTIONS`), in
  :func:`stablelego_jax.solvers.compiled.compiled`; functions that may run
  inside a user's ``jax.jit`` (:func:`x64_differentiable`) cannot carry
  options and compile with XLA's defaults.
"""
from __future__ import annotations

import contextlib
import functools
import inspect
import os
import sys

import jax
import numpy as np

__all__ = ["x64", "x64_differentiable", "float64", "cache_dir", "use_persistent_cache", "compiler_options",
           "CPU_COMPILER_OPTIONS", "ONE_CORE_OPTIONS", "one_core_compiles", "quick_exit"]

#: XLA options for the library's programs on a CPU backend: XLA's LLVM IR
#: fusion emitters instead of its newer MLIR ones. On this project's
#: interior points they compile 20-48% faster (1.6-2.0 s against 2.0-3.4 s
#: a shape on a sample of the shard), with 16-17% fewer kernels and the same
#: solve time (``benchmarks/compile_shapes.py`` with and without
#: ``--xla-defaults``, BENCHMARKS.md, session 33).
CPU_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}

#: More CPU options for a process with one core to itself (:func:`one_core_compiles`):
#: XLA splits a module's code generation over threads, which on one core only costs.
ONE_CORE_OPTIONS = {"xla_cpu_parallel_codegen_split_count": 1}

_ONE_CORE: list = []


def one_core_compiles() -> None:
    """From now on this process compiles as one with one core to itself
    (a worker of a pool with a worker a core): :data:`ONE_CORE_OPTIONS`
    join :func:`compiler_options`. Pinned to one core, a dense interior
    point compiled in 1.15-1.19 s instead of 1.27-1.32 s; in ``score``'s
    pool of 2 on 2 cores the small set's first run took 8.3-8.6 s instead
    of 8.6-8.9 s, its solves 6.1-6.5 s summed instead of 6.6-6.9 s
    (BENCHMARKS.md, session 40). With two free cores the default split
    compiles sooner (0.7 s against 0.9 s), so a lone process keeps it."""
    _ONE_CORE[:] = [True]


@functools.lru_cache(maxsize=None)
def _accepted(backend: str, options: tuple) -> tuple:
    if backend != "cpu":
        return ()
    try:  # an XLA that no longer knows an option refuses to compile with it
        jax.jit(lambda v: v + 1).lower(np.zeros(1)).compile(compiler_options=dict(options))
    except Exception:  # noqa: BLE001 - jaxlib raises its own error types
        return ()
    return options


def compiler_options() -> dict:
    """XLA options for the library's compiles on the default backend:
    :data:`CPU_COMPILER_OPTIONS` on a CPU whose XLA accepts them (checked
    once per process with a one-line program), and
    :data:`ONE_CORE_OPTIONS` after :func:`one_core_compiles`; none
    elsewhere. Set
    ``STABLELEGO_XLA_DEFAULTS=1`` to compile with XLA's defaults."""
    if os.environ.get("STABLELEGO_XLA_DEFAULTS", "").strip().lower() in ("1", "yes", "true", "on"):
        return {}
    backend = jax.default_backend()
    if _ONE_CORE:  # an XLA that refuses these still gets the others
        more = _accepted(backend, tuple(sorted(dict(CPU_COMPILER_OPTIONS, **ONE_CORE_OPTIONS).items())))
        if more:
            return dict(more)
    return dict(_accepted(backend, tuple(sorted(CPU_COMPILER_OPTIONS.items()))))


def quick_exit(code: int = 0) -> None:
    """End a process whose work is done with exit status ``code``: stdout
    and stderr flushed completely (a slow reader is waited for), then
    ``os._exit``, without the interpreter's teardown of JAX's backend (0.2
    s of every command, 0.5 s of a pool's workers; BENCHMARKS.md, session
    40). Every file the process wrote must be closed by then."""
    for s in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # a reader that went away (``| head``)
            s.flush()
    os._exit(code)


def float64():
    """Context manager: 64-bit JAX types inside, the caller's setting after."""
    return jax.enable_x64(True)


def x64(fn):
    """Decorator: run ``fn`` with 64-bit JAX types (see :func:`float64`)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with jax.enable_x64(True):
            return fn(*args, **kwargs)

    return wrapper


def _traced(value) -> bool:
    """Whether an argument is passed to a jitted function as traced arrays:
    None, or a pytree (e.g. a NamedTuple) whose leaves are all arrays or
    Python floats. Anything else (options, ints, strings) is static."""
    leaves = jax.tree_util.tree_leaves(value)
    return all(isinstance(v, (np.ndarray, np.generic, jax.Array, float)) and not isinstance(v, (bool, np.bool_))
               for v in leaves)


def x64_differentiable(*names: str):
    """Decorator: like :func:`x64`, jitted, and reverse-mode differentiable
    in the arguments ``names`` from a float32 program too.

    JAX runs a gradient's backward pass when the caller's ``jax.grad``
    does, outside the decorated call, where 64-bit types would be off; here
    forward and backward pass both run in float64 (a ``custom_vjp`` around
    the function's own VJP), and cotangents come back in the precision of
    the caller's arrays. Other arguments are not differentiated.

    The function runs under ``jax.jit``: array arguments (and pytrees of
    them, and floats) are traced, the others (options) are static and must
    be hashable. Called eagerly, it compiles once per argument shape and
    static value instead of on every call: a loss of a 21-brick soft
    problem took 6 s per eager call, every call, and now 15 ms after the
    first (BENCHMARKS.md). An unhashable static argument runs it unjitted."""

    def deco(fn):
        sig = inspect.signature(fn)
        jitted = {}

        def compiled_fn(static: tuple):
            if static not in jitted:
                jitted[static] = jax.jit(fn, static_argnames=static)
            return jitted[static]

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            bound = sig.bind(*args, **kwargs)
            bound.apply_defaults()
            diff = tuple(bound.arguments[k] for k in names)
            static = tuple(k for k, v in bound.arguments.items() if k not in names and not _traced(v))
            try:
                for k in static:
                    hash(bound.arguments[k])
                run = compiled_fn(static)
            except TypeError:  # an unhashable option: no jit
                run = fn

            def inner(*d):
                b = dict(bound.arguments, **dict(zip(names, d)))
                return run(**b)

            @jax.custom_vjp
            def call(*d):
                with jax.enable_x64(True):
                    return inner(*d)

            def call_fwd(*d):
                with jax.enable_x64(True):
                    return jax.vjp(inner, *d)

            def call_bwd(back, ct):
                with jax.enable_x64(True):
                    return back(ct)

            call.defvjp(call_fwd, call_bwd)
            with jax.enable_x64(True):
                return call(*diff)

        return wrapper

    return deco


def cache_dir() -> str | None:
    """The folder of the library's disk caches, or None when turned off."""
    if os.environ.get("STABLELEGO_CACHE", "1").strip().lower() in ("0", "off", "no", "false"):
        return None
    d = os.environ.get("STABLELEGO_CACHE_DIR")
    if not d:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        d = os.path.join(base, "stablelego-jax")
    return d


_STATE = {"configured": False}


def use_persistent_cache() -> str | None:
    """Point JAX's persistent compilation cache at ``cache_dir()/xla`` (once
    per process, before the library's first compile), unless the disk cache
    is off or the user set ``jax_compilation_cache_dir`` already (then the
    user's folder is used). Returns the folder in use, or None."""
    if _STATE["configured"]:
        return _STATE.get("dir")
    _STATE["configured"] = True
    user = jax.config.jax_compilation_cache_dir
    if user:
        _STATE["dir"] = user
        return user
    d = cache_dir()
    if d is None:
        return None
    xla = os.path.join(d, "xla")
    with contextlib.suppress(OSError):
        os.makedirs(xla, exist_ok=True)
    if not os.access(xla, os.W_OK):
        return None
    jax.config.update("jax_compilation_cache_dir", xla)
    # our solvers compile in seconds; cache every one of them
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    _STATE["dir"] = xla
    return xla
