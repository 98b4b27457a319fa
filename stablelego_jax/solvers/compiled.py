"""Compiled solvers: the one place the library compiles JAX code for a shape.

:func:`compiled` returns an ahead-of-time compiled executable of a pure
function of flat arrays, for the shapes and dtypes of example arguments,
and keeps it in a bounded in-process cache (least recently used first out:
the number of executables a long run holds stays bounded, at most 32, and
so do the memory mappings of their machine code: XLA maps each compiled
kernel apart, 400-2000 mappings per solver executable, so the cache also
lets go of executables while the process holds more than half of the
kernel's ``vm.max_map_count``). Across
processes two disk caches under :func:`~stablelego_jax.runtime.cache_dir`
spare the work: the function traced and lowered once, stored with
``jax.export`` (``exported/``), and XLA's compiled code in JAX's persistent
compilation cache (``xla/``), so a second ``stablelego analyze`` of a small
layout neither traces nor compiles the solver again. Entries are keyed by
the function's name and static settings, the argument shapes and dtypes,
the JAX version, the backend and a digest of the library's source code, so
a changed solver never meets a stale entry.

:func:`compiled` may be called from several threads (``score`` on an
accelerator compiles its shapes ahead in threads while it solves): a key
being compiled by one thread is waited for by the others, never compiled
twice. Compiles are counted (:data:`STATS`) so batch runs report compile time
apart from solve time. After each compile that traced the function (not
read from disk) JAX's tracing and lowering caches are emptied
(:func:`drop_tracing_caches`; the executables stay), and after every
compile the C allocator hands the memory that compiling and evicting freed
back to the system (:func:`release_memory`). Without the latter, a run that keeps
compiling new shapes (ADMM over 448 small layouts: 68 compiles, 36
evictions) grew its resident memory by 430 MB after the cache was full,
with it by 19 MB when the shapes came from disk; without the former, a
first run that traces every shape (ADMM, 500 small layouts) still grew
124 MB over its second half, with it 37 MB (BENCHMARKS.md, "Robustness").
"""
from __future__ import annotations

import collections
import dataclasses
import functools
import hashlib
import os
import threading
import time
from typing import Callable, Hashable

import jax
import numpy as np

from ..files import atomic_write
from ..runtime import cache_dir, compiler_options, float64, use_persistent_cache

__all__ = ["CompileStats", "STATS", "compiled", "available", "clear", "set_limit", "cache_limit", "cache_size",
           "code_digest",
           "map_budget", "mappings", "release_memory", "drop_tracing_caches"]


@dataclasses.dataclass
class CompileStats:
    """Counters of this process: executables compiled (``compiles``, wall
    ``compile_s`` including tracing and disk loads), of those loaded from
    the export cache (``loaded``), in-process hits (``hits``) and
    executables dropped by the bound (``evicted``), calls that handed freed
    memory back to the system (``released``) and that emptied JAX's tracing
    caches (``dropped``)."""

    compiles: int = 0
    compile_s: float = 0.0
    loaded: int = 0
    hits: int = 0
    evicted: int = 0
    released: int = 0
    dropped: int = 0


STATS = CompileStats()
_CACHE: "collections.OrderedDict[tuple, Callable]" = collections.OrderedDict()
_LIMIT = {"n": 32}
_LOCK = threading.RLock()  # _CACHE, _FLIGHT and STATS
_FLIGHT: "dict[tuple, threading.Event]" = {}  # keys being compiled, set when done


def set_limit(n: int) -> None:
    """Keep at most ``n`` (>= 1) executables in this process."""
    if n < 1:
        raise ValueError(f"the executable cache needs room for at least 1, got {n}")
    with _LOCK:
        _LIMIT["n"] = int(n)
        _evict()


def cache_limit() -> int:
    """Most executables this process keeps (:func:`set_limit`)."""
    return _LIMIT["n"]


def cache_size() -> int:
    """Executables held in this process."""
    return len(_CACHE)


def clear() -> None:
    """Drop every executable of this process."""
    with _LOCK:
        _CACHE.clear()


@functools.lru_cache(maxsize=1)
def map_budget() -> int | None:
    """Memory mappings this process may hold before the cache lets go of
    executables: half of Linux's ``vm.max_map_count`` (None elsewhere)."""
    try:
        with open("/proc/sys/vm/max_map_count", "rb") as fh:
            return int(fh.read()) // 2
    except (OSError, ValueError):
        return None


@functools.lru_cache(maxsize=1)
def _malloc_trim():
    try:
        import ctypes

        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):  # not glibc
        return None


def release_memory() -> bool:
    """Hand the heap memory this process has freed back to the system
    (glibc's ``malloc_trim``; compiling a solver allocates and frees a few
    hundred MB that the allocator would otherwise keep). False where there
    is no glibc."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    with _LOCK:
        STATS.released += 1
    return True


def drop_tracing_caches() -> bool:
    """Empty JAX's tracing and lowering caches (its ``lu.cache``,
    ``util.cache`` and weak-reference LRU caches: the jaxprs of every shape
    traced, kept up to a few thousand entries each), leaving compiled code
    and the C++ dispatch caches of eager operations alone, unlike
    ``jax.clear_caches()``, which makes every eager operation compile again.
    Our executables need none of it once compiled. JAX has no public call
    for this part; False (nothing done) if its internals move."""
    try:
        from jax._src import util as jax_util

        jax_util.clear_all_caches()
    except (ImportError, AttributeError):
        return False
    with _LOCK:
        STATS.dropped += 1
    return True


def mappings() -> int | None:
    """Memory mappings this process holds now (Linux; None elsewhere)."""
    try:
        with open("/proc/self/maps", "rb") as fh:
            return fh.read().count(b"\n")
    except OSError:
        return None


def _evict() -> None:
    while len(_CACHE) > _LIMIT["n"]:
        _CACHE.popitem(last=False)
        STATS.evicted += 1
    budget = map_budget()
    while budget is not None and len(_CACHE) > 1 and (mappings() or 0) > budget:
        _CACHE.popitem(last=False)  # its code is unmapped as the executable is freed
        STATS.evicted += 1


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """sha256 of the library's Python sources (a changed solver changes it)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    h = hashlib.sha256()
    for d, subdirs, files in sorted(os.walk(root)):
        subdirs.sort()
        for f in sorted(files):
            if f.endswith(".py"):
                p = os.path.join(d, f)
                h.update(os.path.relpath(p, root).encode())
                with open(p, "rb") as fh:
                    h.update(fh.read())
    return h.hexdigest()


def _specs(args) -> tuple:
    return tuple(a if isinstance(a, jax.ShapeDtypeStruct) else jax.ShapeDtypeStruct(np.shape(a), np.result_type(a))
                 for a in args)


def _key(name: str, static: Hashable, specs: tuple) -> tuple:
    return (name, static, tuple((tuple(s.shape), str(s.dtype)) for s in specs))


def available(name: str, static: Hashable, specs, export: bool = True) -> bool:
    """Whether :func:`compiled` would find this executable ready (held in
    this process, or, with ``export``, its export on disk, written when it
    was first compiled, next to XLA's code for it) instead of tracing and
    compiling it. ``specs``: ``jax.ShapeDtypeStruct`` of the arguments."""
    key = _key(name, static, tuple(_specs(specs)))
    if key in _CACHE:
        return True
    path = _export_path(name, key) if export else None
    return path is not None and os.path.isfile(path)


def _export_path(name: str, key: tuple) -> str | None:
    d = cache_dir()
    if d is None:
        return None
    text = repr((key, jax.__version__, jax.default_backend(), code_digest()))
    return os.path.join(d, "exported", f"{name}-{hashlib.sha256(text.encode()).hexdigest()[:32]}.bin")


def _exported_call(name: str, fn: Callable, key: tuple, specs: tuple) -> tuple[Callable | None, bool]:
    """(``exp.call`` of the function exported once (read from disk, or
    traced, lowered and written there now), whether it was read from disk);
    (None, False) when the disk cache is off or export is unavailable."""
    path = _export_path(name, key)
    if path is None:
        return None, False
    try:
        from jax import export as jexport

        if os.path.isfile(path):
            try:
                with open(path, "rb") as fh:
                    exp = jexport.deserialize(bytearray(fh.read()))
                with _LOCK:
                    STATS.loaded += 1
                return exp.call, True
            except Exception:  # a torn or foreign entry: export again
                pass
        exp = jexport.export(jax.jit(fn))(*specs)
        blob = exp.serialize()
        os.makedirs(os.path.dirname(path), exist_ok=True)
        atomic_write(path, lambda fh: fh.write(blob), binary=True)
        return exp.call, False
    except (ImportError, OSError):
        return None, False


def compiled(name: str, fn: Callable, static: Hashable, args, export: bool = True) -> Callable:
    """An executable of ``fn`` (a pure function of the flat arrays ``args``,
    returning a tuple of arrays) compiled in float64 for their shapes and
    dtypes (``args`` may also be ``jax.ShapeDtypeStruct``), with the library's XLA options
    (:func:`~stablelego_jax.runtime.compiler_options`). ``name`` and
    ``static`` (hashable: everything ``fn`` closes
    over, e.g. parameters and options) identify it. ``export``: also use
    the disk export cache (functions on one device). Thread-safe: a call
    for a key another thread is compiling waits for that compile."""
    specs = _specs(args)
    key = _key(name, static, specs)
    with _LOCK:
        exe = _CACHE.get(key)
        if exe is not None:
            _CACHE.move_to_end(key)
            STATS.hits += 1
            return exe
        flight = _FLIGHT.get(key)
        if flight is None:
            _FLIGHT[key] = threading.Event()
    if flight is not None:  # another thread compiles it: wait, then take it (or compile it, had that failed)
        flight.wait()
        return compiled(name, fn, static, args, export)
    try:
        t0 = time.perf_counter()
        use_persistent_cache()
        with float64():
            call, from_disk = _exported_call(name, fn, key, specs) if export else (None, False)
            traced = not from_disk  # fn was traced here, not read from disk
            aot = jax.jit(call if call is not None else fn).lower(*specs).compile(compiler_options())

        def exe(*arrays):
            with float64():  # float64 inputs stay float64 whatever the caller's setting
                return aot(*arrays)

        with _LOCK:
            STATS.compiles += 1
            STATS.compile_s += time.perf_counter() - t0
            _CACHE[key] = exe
            _evict()
    finally:
        with _LOCK:
            _FLIGHT.pop(key).set()
            alone = not _FLIGHT
    # a load from disk leaves little behind, and emptying would cost a warm run seconds;
    # not while another thread traces
    if traced and alone:
        drop_tracing_caches()
    release_memory()
    return exe
