"""Batched scoring of many layouts: size buckets, ``vmap``, device sharding,
resumable JSON-lines results.

Flow per chunk of inputs: read and compile each layout (numpy), choose its
solver bucket (:func:`~stablelego_jax.solvers.problem.solve_plan`: a dense or a layer-by-layer shape for the
interior-point solver), group equal buckets, pad each group to its largest
column count, and solve each group in batches with one jit-compiled,
``vmap``-ed solver per (bucket shape, batch size), split over the local
devices with
``jax.shard_map`` (each device runs its own while-loop, so a device stops
as soon as its own layouts have converged). Compiled solvers are cached for
the whole run; compile time is measured apart from solve time.

Results: one JSON object per line, as ``stablelego analyze --json``; a bad
layout gets ``{"file", "error"}``. Lines are appended and flushed batch by
batch, so an interrupted run loses at most the batch in flight; a torn last
line is dropped on the next run, which skips every file already present.
"""
from __future__ import annotations

import atexit
import concurrent.futures
import contextlib
import dataclasses
import functools
import hashlib
import json
import multiprocessing
import os
import sys
import time
from typing import Iterable, Iterator, Sequence

import jax
import numpy as np

from .analysis import analyze_exact, error_message, make_analysis, pick_solver, resolve_unconverged
from .blas import batched_linalg_hangs, lapack_pool_deadlock, one_blas_thread
from .files import atomic_write, atomic_write_text, cut, read_text
from .formats.dataset import score_grid
from .formats import rows
from .formats.ldraw import unsupported_message
from .layout import LayoutError
from .model import Params, compile_layout, pack_models
from .progress import Progress
from .score import eq9_cost
from .solvers import ipm
from .solvers.compiled import STATS, available, cache_limit, compiled
from .solvers.exact import estimated_seconds
from .solvers.problem import (
    LOAD_S,
    MIN_BRICKS,
    MIN_CHUNKS,
    MIN_COLUMNS,
    MIN_SLOTS,
    Problem,
    Solution,
    batch_rung,
    chunk_rows,
    compile_seconds,
    layer_plan,
    merge_plans,
    plan_problem,
    plan_seconds,
    rung,
    solve_plan,
    stack_problems,
)

__all__ = ["find_layouts", "read_results", "ScoreStats", "iter_analyses", "analyze_many", "score_files",
           "batch_solver_fn", "batch_sizes", "plan_bytes", "parse_shard", "in_shard", "cpu_cores",
           "RESULT_PREFIX", "SolveUnit", "solve_units", "compiled_ready", "assign_units", "POOL_MIN",
           "auto_split", "ACCELERATOR_SPEEDUP", "ACCELERATOR_COMPILE_S", "CPU_CACHE_BYTES", "CPU_BUDGET_BYTES",
           "device_budget", "default_batch", "ACCELERATOR_BATCH", "accelerator_compile_s",
           "worker_order", "next_unit", "POOL_DEPTH", "Workers", "jax_pool_size", "exact_parts", "pack_items",
           "PACK_MOST", "column_runs", "solve_unit", "compile_ahead", "ahead_specs", "ahead_threads", "AHEAD_THREADS",
           "batch_specs"]

LAYOUT_EXTS = (".json", ".txt", ".ldr")
# files that sit beside StableLego layouts but are not layouts
NOT_LAYOUTS = {"lego_library.json", "labels.json", "config.json", "meta.json", "demo_examples.json",
               "few_shot_examples.json"}


def find_layouts(inputs: Sequence[str], id_column: str | None = None) -> list:
    """Expand ``inputs`` (files, folders of layout files, dataset folders with
    one object per sub-folder, row files) into layout sources, in a stable
    order: paths, and a :class:`~stablelego_jax.formats.rows.RowRef` per
    row of a JSON-lines or Parquet file (named by row or ``id_column``).

    A folder holding ``task_graph.json`` is one dataset object; any other
    folder is searched recursively for dataset objects, layout files and
    Parquet files (JSON-lines files are read only when named, since results
    files are JSON lines too). A missing input, or a row file that cannot be
    read, is kept as a path, so that it is reported as an error line.
    """
    out: list = []
    for inp in inputs:
        if not os.path.isdir(inp):
            out.extend(rows.expand(inp, id_column) if rows.is_row_file(inp) else [inp])
            continue
        n0 = len(out)
        # an unreadable folder is kept as a path, so that it gets an error line
        for d, subdirs, files in os.walk(inp, onerror=lambda exc: out.append(exc.filename)):
            subdirs[:] = sorted(s for s in subdirs if not s.startswith("."))
            if "task_graph.json" in files:
                out.append(d)
                subdirs[:] = []
                continue
            for f in sorted(files):
                if f.endswith(LAYOUT_EXTS) and f not in NOT_LAYOUTS and not f.startswith("."):
                    out.append(os.path.join(d, f))
                elif f.endswith(".parquet") and not f.startswith("."):
                    out.extend(rows.expand(os.path.join(d, f), id_column))
        if len(out) == n0:
            raise LayoutError(inp, "no layouts in this folder (no .json, .txt, .ldr or .parquet files, "
                                   "no dataset objects)")
    seen: set = set()
    return [p for p in out if not (str(p) in seen or seen.add(str(p)))]


#: fewest layouts worth a process pool (a spawned worker takes ~1 s to start)
POOL_MIN = 32


def cpu_cores() -> int:
    """Cores this process may run on (its CPU affinity; ``os.cpu_count()`` elsewhere)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def parse_shard(text: str) -> tuple[int, int]:
    """``"K/N"`` -> (K, N), 0 <= K < N (0-based, as cluster job arrays number tasks)."""
    try:
        k, n = (int(x) for x in str(text).split("/"))
    except ValueError:
        raise ValueError(f"--shard {text}: expected K/N, e.g. 0/4") from None
    if not (n >= 1 and 0 <= k < n):
        raise ValueError(f"--shard {text}: need 0 <= K < N")
    return k, n


def in_shard(source, k: int, n: int) -> bool:
    """Whether layout ``source`` (a path or row name, as :func:`find_layouts`
    gives it) belongs to shard ``k`` of ``n``: the SHA-1 of its name modulo
    ``n``. The same inputs named the same way give the same split on every
    host and every run, with no coordination; the shards are disjoint and
    cover every input."""
    h = hashlib.sha1(str(source).encode("utf-8", "surrogateescape")).digest()
    return int.from_bytes(h[:8], "big") % n == k


#: How every line of a results file of ours begins (``json.dumps`` of a dict whose first key is "file").
RESULT_PREFIX = '{"file": '


def read_results(out: str, key: str = "file") -> dict:
    """{record[key]: record} of a JSON-lines results file of ours.

    A torn last line (an interrupted write) is dropped and the file
    rewritten without it (atomically). Any other file is refused with a
    LayoutError naming it, never truncated: a file that is not UTF-8, not
    regular, or has a complete line that is not a result object."""
    done: dict = {}
    if not os.path.lexists(out):
        return done
    what = "results file"
    text = read_text(out, what)
    refuse = "exists and is not a results file of stablelego score ({}); refusing to write to it"
    lines = text.splitlines(keepends=True)
    good = []
    for no, line in enumerate(lines, start=1):
        if not line.strip():
            good.append(line)
            continue
        try:
            rec = json.loads(line)
            ok = isinstance(rec, dict) and key in rec and ("error" in rec or "scores" in rec or "stable" in rec)
        except ValueError:
            ok = False
        if ok and line.endswith("\n"):
            done[rec[key]] = rec
            good.append(line)
            continue
        torn = no == len(lines) and not line.endswith("\n") and (
            line.startswith(RESULT_PREFIX) or RESULT_PREFIX.startswith(line))
        if not torn:
            raise LayoutError(out, refuse.format(f"line {no}: {cut(line.strip())!r}"))
    if len(good) != len(lines):
        atomic_write_text(out, "".join(good))
    return done


def _on_cpu(cpu: bool | None = None) -> bool:
    """``cpu`` if given, else whether JAX's default backend is the CPU."""
    return jax.default_backend() == "cpu" if cpu is None else cpu


def plan_bytes(key: tuple, m_pad: int) -> int:
    """Working memory of one layout in a batch (float64 bytes): the reduced
    matrix blocks, their factors and the per-column assembly buffers."""
    L, B = (1, key[1]) if key[0] == "dense" else key[1:3]
    k6 = 6 * B
    # blocks, factors and work copies; per-layer products; the per-column 12 x 12
    # outer products, their scatter indices and the weighted copy of each assembly
    return 8 * (6 * L * k6 * k6 + 4 * L * B * k6) + m_pad * 144 * (8 + 4 + 8) + 8 * 40 * m_pad


def batch_sizes(per_layout: int, batch: int, n_dev: int, mem_budget: float | None = None,
                cpu: bool | None = None) -> int:
    """Largest batch: at most ``batch``, within ``mem_budget`` bytes a device
    (default :func:`device_budget`) for ``per_layout`` bytes of each member,
    and a multiple of ``n_dev``.

    On a CPU (``cpu``; default: JAX's default backend) each core's share of
    a batch is also held within :data:`CPU_CACHE_BYTES` (a power of two, at
    least one member a device): there ``vmap`` gains nothing (a batch's
    members run one after the other anyway) and loses twice, running every
    member for its slowest member's iterations and passing over Newton
    matrices that no longer fit in the core's cache (BENCHMARKS.md, session
    32: batches of 1-4 solve 1.3-4.8x faster per layout than 32-64). On an
    accelerator only the memory budget holds a batch back: there a batch of
    64 solved 12x more layouts a second than one at a time even for a
    20-layer bucket of 76 MB a member, 16x for a 40-brick dense bucket (54x
    at 1024) (an H200, ``benchmarks/batch_rate.py``, BENCHMARKS.md session
    44). A CPU whose jaxlib deadlocks batched LAPACK calls on its XLA pool
    (:func:`~stablelego_jax.blas.batched_linalg_hangs`: ``PJRT_NPROC`` set
    above 1 on jaxlib 0.10-0.11.1) gets one layout a device."""
    cpu = _on_cpu(cpu)
    if cpu and batched_linalg_hangs():
        return n_dev  # one layout a device: a batch of one matrix never splits over the pool (blas)
    if mem_budget is None:
        mem_budget = CPU_BUDGET_BYTES if cpu else device_budget()
    cap = mem_budget * n_dev // max(per_layout, 1)
    if cpu:
        fit = max(int(CPU_CACHE_BYTES // max(per_layout, 1)), 1)
        cap = min(cap, n_dev * (1 << (fit.bit_length() - 1)))  # a power of two a device, as batch_rung pads
    b = int(max(1, min(batch, cap)))
    return max(n_dev, (b // n_dev) * n_dev)


def default_batch(cpu: bool | None = None) -> int:
    """Most layouts per solver call when none is asked for: 64 on a CPU
    (where :func:`batch_sizes` holds batches far lower anyway),
    :data:`ACCELERATOR_BATCH` on an accelerator (``cpu``; default: JAX's
    default backend)."""
    return 64 if _on_cpu(cpu) else ACCELERATOR_BATCH


#: Most layouts per solver call on an accelerator, memory permitting: on an H200 a batch of
#: 1024 solved 3.3-5.4x as many small layouts a second as one of 64 (BENCHMARKS.md, session 44).
ACCELERATOR_BATCH = 1024
#: Working set (bytes) of one CPU core's share of a batch (this machine's L2 holds 4 MiB a core).
CPU_CACHE_BYTES = 4e6
#: Memory (bytes) a batch may take on a CPU device, and at least on an accelerator.
CPU_BUDGET_BYTES = 2e9


@functools.lru_cache(maxsize=None)
def device_budget() -> float:
    """Memory (bytes) one batch may take on the first local device: a quarter
    of what JAX may allocate there (``memory_stats()['bytes_limit']``), at
    least :data:`CPU_BUDGET_BYTES` (also where the device does not say)."""
    try:
        limit = (jax.local_devices()[0].memory_stats() or {}).get("bytes_limit", 0)
    except Exception:  # a backend without memory statistics
        limit = 0
    return max(CPU_BUDGET_BYTES, float(limit) / 4)


def batch_solver_fn(params: Params, opts, n_dev: int):
    """``fn(*stacked problem arrays) -> tuple(Solution)``: ``vmap`` of the JAX
    interior point with ``opts`` (:class:`~stablelego_jax.solvers.ipm.IPMOptions`),
    split over the first ``n_dev`` local devices with ``shard_map``
    (each device runs its own while-loop, so it stops as soon as its own
    layouts have converged). The interior point of one dense problem (on each device) runs without ``vmap``: the
    same numbers from a smaller program, compiled in 25-45% less time on
    this CPU at the same solve time, which factors only its real bricks'
    rows (:attr:`~stablelego_jax.solvers.ipm.IPMOptions.cut`); layered problems stay batched
    (unbatched, their block solves ran 10-25% slower; BENCHMARKS.md,
    session 33)."""

    def f(*arrays):
        layers = Problem(*arrays).layers  # (batch, L) or None
        if arrays[0].shape[0] == 1 and (layers is None or layers.shape[-1] == 1):
            one = dataclasses.replace(opts, cut=True)  # alone: factor only the real bricks' rows
            return tuple(x[None] for x in ipm.solve(Problem(*(a[0] for a in arrays)), params, one))
        return tuple(jax.vmap(lambda *a: ipm.solve(Problem(*a), params, opts))(*arrays))

    if n_dev <= 1:
        return f
    from jax.sharding import Mesh, PartitionSpec as P

    mesh = Mesh(np.array(jax.devices()[:n_dev]), ("batch",))
    # every value is per-device (no collectives), so skip the varying-axis type check
    return jax.shard_map(f, mesh=mesh, in_specs=P("batch"), out_specs=P("batch"), check_vma=False)


@dataclasses.dataclass
class ScoreStats:
    """Totals of one :func:`score_files` run (times in s)."""

    total: int = 0
    skipped: int = 0
    scored: int = 0
    errors: int = 0
    not_converged: int = 0
    retried: int = 0
    left_out: int = 0
    compile_s: float = 0.0
    solve_s: float = 0.0
    load_s: float = 0.0
    wall_s: float = 0.0
    compiles: int = 0
    auto_exact: int = 0  # ``--solver auto``: layouts given to the exact solver

    def to_json(self) -> dict:
        return dataclasses.asdict(self)

    def add_solver_counts(self, other: "ScoreStats") -> None:
        """Add the counters a solver worker keeps (solve and compile time,
        compiles, unconverged and retried layouts) of ``other`` to these."""
        for f in ("solve_s", "compile_s", "compiles", "not_converged", "retried"):
            setattr(self, f, getattr(self, f) + getattr(other, f))


def _write_score_grid(path: str, layout, scores) -> None:
    """stability_score.npy beside a dataset object (grid shape of its vox.npy)."""
    shape = None
    vox = os.path.join(path, "vox.npy")
    if os.path.exists(vox):
        shape = np.load(vox, mmap_mode="r").shape
    grid = score_grid(layout, [scores[k] for k in layout.keys], shape)
    atomic_write(os.path.join(path, "stability_score.npy"), lambda fh: np.save(fh, grid), binary=True)


def _device_count(devices) -> int:
    """Local devices to shard a batch over: ``devices`` ("all" or a count).
    On CPU with a jaxlib whose LAPACK kernels deadlock several devices
    (:func:`~stablelego_jax.blas.lapack_pool_deadlock`), "all" is one
    device and a larger count is refused: worker processes (``jobs``) use
    the other cores instead."""
    n_dev = jax.local_device_count() if devices in ("all", None) else int(devices)
    if not 1 <= n_dev <= jax.local_device_count():
        raise ValueError(f"--devices {devices}: this machine has {jax.local_device_count()} local device(s)")
    if n_dev > 1 and _on_cpu() and lapack_pool_deadlock():
        if devices in ("all", None):
            return 1
        raise ValueError(f"--devices {devices}: several CPU devices deadlock this jaxlib's LAPACK kernels "
                         "(see stablelego_jax.blas); use --jobs N (worker processes) for the cores")
    return n_dev


def iter_analyses(
    layouts: Sequence,
    solver: str = "jax",
    params: Params = Params(),
    opts=None,
    batch: int | None = None,
    devices: str | int = 1,
    exact_method: str = "highs",
    exact_scale: bool = True,
    method: str = "ours",
    stats: ScoreStats | None = None,
    jobs: int = 1,
    merge: bool = True,
    fallback: bool = True,
    jax_jobs: int | None = None,
    workers: "Workers | None" = None,
) -> Iterator[list[tuple[int, object]]]:
    """Analyse many in-memory layouts, batched: yields, per solver call, the
    list of ``(i, Analysis)`` for the ``layouts[i]`` it solved (batches do
    not come in input order), and first one list of ``(i, exception)`` for
    the layouts that cannot be compiled.

    solver "jax": layouts are grouped by solver bucket
    (:func:`~stablelego_jax.solvers.problem.solve_plan`), padded to the
    group's largest column count and solved ``batch`` (None:
    :func:`default_batch`) at a time by one compiled, ``vmap``-ed solver
    per (bucket, batch size), split over ``devices`` local devices
    (:func:`solve_units`); "exact": HiGHS one at
    a time (``method``: "ours" or a baseline); "auto": the interior point's
    groups that HiGHS is estimated to solve faster (compile included) go to
    HiGHS, first, the rest to the interior point (:func:`auto_split`; a
    baseline ``method``: HiGHS). With ``jobs`` > 1
    (:func:`cpu_cores` for every core) and at least ``POOL_MIN`` layouts,
    every solver spreads them over ``jobs`` spawned worker processes
    (JAX on one device: each worker solves whole batches, a bucket's
    batches kept on one worker unless splitting it pays for a second
    compile, :func:`assign_units`). ``merge`` (JAX): a bucket with few layouts is
    solved in a larger bucket of the same call when that lowers the
    estimated time, padded batches and compiles counted
    (:func:`~stablelego_jax.solvers.problem.merge_plans`). ``stats`` (a :class:`ScoreStats`) accumulates solve and
    compile time, compiles and non-converged counts. An Analysis of a JAX
    solver has ``time_s`` = its share of its batch(es) and ``iters``.
    ``jax_jobs``: worker processes of the JAX solvers (None: ``jobs``;
    :func:`jax_pool_size`: on a GPU, none; there the interior point's shapes
    are compiled ahead in threads while it solves, :func:`compile_ahead`).
    ``fallback``: a layout the JAX solver leaves unconverged is solved
    again, alone (:func:`~stablelego_jax.analysis.resolve_unconverged`: a
    longer run, then the exact solver; its ``solver`` says which answered,
    ``retried`` what did not converge); False yields it as it is.
    ``workers``: started :class:`Workers` the JAX pool uses (and leaves
    running) instead of spawning its own.
    """
    solver = pick_solver(solver, method)
    batch = batch or default_batch()
    st = stats if stats is not None else ScoreStats()
    loaded, bad = [], []
    for i, lay in enumerate(layouts):
        try:
            loaded.append((i, lay, compile_layout(lay, params)))
        except Exception as exc:  # a bad layout is reported, the others go on
            bad.append((i, exc))
    if bad:
        yield bad
    if solver == "exact":
        yield from _exact_parts(loaded, jobs, method, exact_method, exact_scale, st)
        return
    opts = opts or ipm.IPMOptions()
    n_dev = _device_count(devices)
    ready = compiled_ready(params, opts, n_dev)
    units = solve_units(loaded, batch, n_dev, merge, ready=ready)
    if solver == "auto":
        to_exact, units = auto_split(units, ready, n_dev)
        st.auto_exact += len(to_exact)
        yield from _exact_parts(to_exact, jobs, method, exact_method, exact_scale, st)
    n_jax = sum(len(u.items) for u in units)
    jobs = min(jax_pool_size(jobs if jax_jobs is None else jax_jobs, n_dev, n_jax), max(len(units), 1))
    if jobs > 1:
        yield from _jax_pool(units, jobs, params, opts, fallback, st, ready, workers)
        return
    ahead = None if _on_cpu() else compile_ahead(units, params, opts, n_dev)  # the interior point only
    c0, s0 = (STATS.compiles, STATS.compile_s), (st.compiles, st.compile_s)
    done = False
    try:
        for unit in units:
            yield from solve_unit(unit, params, opts, n_dev, fallback, st)
        done = True
    finally:
        if ahead is not None:
            # interrupted: no waiting for a compile nobody needs now
            ahead.shutdown(wait=done, cancel_futures=True)
            # every compile of the run, the threads' included (a solve saw only those it waited for)
            st.compiles, st.compile_s = s0[0] + STATS.compiles - c0[0], s0[1] + STATS.compile_s - c0[1]


#: Most threads compiling ahead on an accelerator (:func:`compile_ahead`); the
#: environment variable ``STABLELEGO_COMPILE_AHEAD`` sets another count (0: none).
AHEAD_THREADS = 8


def ahead_threads() -> int:
    """Threads :func:`compile_ahead` may use: ``STABLELEGO_COMPILE_AHEAD``
    when set (a count; 0 turns it off), else :data:`AHEAD_THREADS`, at most
    one less than the cores (the main thread solves meanwhile)."""
    text = os.environ.get("STABLELEGO_COMPILE_AHEAD", "").strip()
    if text:
        try:
            return max(0, int(text))
        except ValueError:
            raise ValueError(f"STABLELEGO_COMPILE_AHEAD={text!r}: expected a number of threads (0: off)") from None
    return max(0, min(AHEAD_THREADS, cpu_cores() - 1))


def ahead_specs(units: Sequence[SolveUnit], n_dev: int) -> list:
    """The argument shapes (``jax.ShapeDtypeStruct``) of each distinct
    batched interior-point executable that solving ``units`` in order asks
    for (:func:`solve_unit`'s first pass: each unit's pieces, padded to
    their batch sizes), first asked first. Packed units are left out."""
    out, seen = [], set()
    for u in units:
        sizes = [z for z in dict.fromkeys(_rungs(u.bsz, len(u.items), n_dev)) if (u.shape, z) not in seen]
        if u.pack or not sizes:
            continue
        seen.update((u.shape, z) for z in sizes)
        out += batch_specs(u.items[0][2], u.key, u.m_pad, u.p_pad, u.c_pad, sizes)
    return out


def compile_ahead(units: Sequence[SolveUnit], params: Params, opts, n_dev: int,
                  threads: int | None = None) -> "concurrent.futures.ThreadPoolExecutor | None":
    """Compile (or load from disk) the batched interior point's executables
    that solving ``units`` in order will ask for (:func:`ahead_specs`; at
    most half the in-process executable cache), in ``threads`` background
    threads (default :func:`ahead_threads`), first needed first, so that a
    process solving on an accelerator compiles its next shapes on the
    host's cores while the device solves the current one, instead of one
    after the other. :func:`~stablelego_jax.solvers.compiled.compiled` is
    thread-safe: a solve that needs a shape still compiling waits for it.
    Returns the executor (shut it down when done), or None when there is
    nothing to overlap (at most one shape, or no threads)."""
    threads = ahead_threads() if threads is None else threads
    specs = ahead_specs(units, n_dev)[: max(1, cache_limit() // 2)] if threads > 0 else []
    if len(specs) < 2:
        return None
    fn = batch_solver_fn(params, opts, n_dev)
    ex = concurrent.futures.ThreadPoolExecutor(min(threads, len(specs)), thread_name_prefix="compile-ahead")
    for sp in specs:
        ex.submit(_compile_quietly, BATCH_NAME, fn, (params, opts, n_dev), sp, n_dev == 1)
    return ex


def _compile_quietly(name, fn, static, specs, export) -> None:
    """A background compile: an error is left to the solve that needs the
    shape (it compiles it again and raises there)."""
    with contextlib.suppress(Exception):
        compiled(name, fn, static, specs, export=export)


def jax_pool_size(jobs: int, n_dev: int, n_layouts: int) -> int:
    """Worker processes for the JAX solvers of ``n_layouts`` layouts:
    ``jobs`` on a CPU backend solving on one device (``n_dev``) with at
    least ``POOL_MIN`` layouts, else 1. On an accelerator (a GPU) JAX runs
    in this process: one process holds the device, and workers would each
    claim its memory."""
    if n_dev == 1 and n_layouts >= POOL_MIN and _on_cpu():
        return max(1, int(jobs))
    return 1


def _exact_parts(loaded, jobs, method, exact_method, exact_scale, st) -> Iterator[list]:
    """Lists of (i, Analysis) of compiled layouts ``loaded`` ((i, layout,
    model)) solved by HiGHS: one layout a list, as each is solved, or with
    ``jobs`` > 1 and at least ``POOL_MIN`` layouts a few a list from
    :func:`_exact_pool`; ``st`` accumulates solve time and non-converged counts."""
    jobs = min(max(1, int(jobs)), len(loaded))
    if jobs <= 1 or len(loaded) < POOL_MIN:
        parts = (_exact_items([item], method, exact_method, exact_scale) for item in loaded)
    else:
        parts = _exact_pool(loaded, jobs, method, exact_method, exact_scale)
    for part in parts:
        for _, a in part:
            st.solve_s += a.time_s
            st.not_converged += not a.converged
        yield part


#: On an accelerator (``--solver auto``): how many times faster the interior point solves than
#: :meth:`SolveUnit.seconds` estimates (a CPU core), and a compile's seconds. Measured on one
#: NVIDIA H200 against this project's 2-core CPU (BENCHMARKS.md, session 37): summed solve
#: time 8.3x lower on the 1000-layout shard, 9.7x on the 500 small layouts; 3.7-4.3 s a shape.
ACCELERATOR_SPEEDUP = 8.0
ACCELERATOR_COMPILE_S = 4.0


def accelerator_compile_s() -> tuple[float, float]:
    """(compile, load) of one shape on an accelerator, in the unit
    :func:`~stablelego_jax.solvers.problem.merge_plans` prices padding in (a
    CPU core's solve seconds): :data:`ACCELERATOR_COMPILE_S` and
    :data:`~stablelego_jax.solvers.problem.LOAD_S` times
    :data:`ACCELERATOR_SPEEDUP`. Priced at a CPU's compile seconds, an
    H200's first run of the 1000-layout shard compiled 13 shapes (65 s of
    its 92 s), each saving padding worth about 1 s of device time
    (BENCHMARKS.md, session 45)."""
    return ACCELERATOR_COMPILE_S * ACCELERATOR_SPEEDUP, LOAD_S * ACCELERATOR_SPEEDUP


def auto_split(units: Sequence["SolveUnit"], ready=None, n_dev: int = 1,
               compile_s: float | None = None, speedup: float | None = None) -> tuple[list, list]:
    """(items for the exact solver, units for the interior point) of
    ``--solver auto``: each group of units that would share one compiled
    solver (bucket, padded columns, slots and chunks) goes to whichever
    solver is estimated faster: the interior point's solve time
    (:meth:`SolveUnit.seconds` / ``speedup``) plus ``compile_s`` when
    ``ready`` (see :func:`solve_units`) says its executables are not
    compiled yet (else a load from disk, ``LOAD_S``), against the sum of
    HiGHS' estimated times
    (:func:`~stablelego_jax.solvers.exact.estimated_seconds`). ``compile_s``
    and ``speedup`` default to the bucket kind's
    :func:`~stablelego_jax.solvers.problem.compile_seconds` and 1 on a CPU
    backend, to :data:`ACCELERATOR_COMPILE_S` and :data:`ACCELERATOR_SPEEDUP` elsewhere."""
    cpu = _on_cpu()
    if speedup is None:
        speedup = 1.0 if cpu else ACCELERATOR_SPEEDUP
    groups: dict = {}
    for u in units:
        groups.setdefault(u.shape, []).append(u)
    to_exact, to_jax = [], []
    for (key, m_pad, p_pad, c_pad), us in groups.items():
        sizes = {batch_rung(len(u.items), n_dev, u.bsz) for u in us}
        warm = ready is not None and ready(key, m_pad, p_pad, c_pad, sizes, us[0].items[0][2])
        c = compile_s if compile_s is not None else compile_seconds(key) if cpu else ACCELERATOR_COMPILE_S
        jax_s = sum(u.seconds() for u in us) / speedup + (LOAD_S if warm else c)
        exact_s = sum(estimated_seconds(it[2]) for u in us for it in u.items)
        if exact_s < jax_s:
            to_exact += [it for u in us for it in u.items]
        else:
            to_jax += us
    return sorted(to_exact, key=lambda it: it[0]), to_jax


@dataclasses.dataclass
class SolveUnit:
    """One batch-sized piece of a solver bucket: ``items`` ((i, layout,
    ForceModel)) padded to ``key`` (:func:`~stablelego_jax.solvers.problem.solve_plan`),
    ``m_pad`` columns, ``p_pad`` contact slots and ``c_pad`` column chunks
    (None: each layout its own ladder rung), solved ``bsz`` at a time. The
    pieces of one bucket share these, so they share compiled solvers."""

    key: tuple
    m_pad: int
    p_pad: int
    bsz: int
    items: list
    c_pad: int | None = None
    pack: bool = False  # the items are one problem (:func:`~stablelego_jax.model.pack_models`), solved once

    @property
    def shape(self) -> tuple:
        """(key, m_pad, p_pad, c_pad): what the compiled solvers of the unit's bucket share."""
        return self.key, self.m_pad, self.p_pad, self.c_pad

    def seconds(self) -> float:
        """Rough solve time (s) of the interior point (:func:`~stablelego_jax.solvers.problem.plan_seconds`)."""
        return (1 if self.pack else len(self.items)) * plan_seconds(self.key, self.m_pad)


def _longest_first(units: Sequence[SolveUnit]) -> list:
    """Indices of ``units``, longest estimated solve first (stable)."""
    return sorted(range(len(units)), key=lambda k: -units[k].seconds())


def piece_sizes(key: tuple, m_pad: int, count: int, batch: int, n_dev: int, cpu: bool | None = None) -> list:
    """Padded batch size of each piece when ``count`` layouts of bucket
    ``key`` with ``m_pad`` columns are solved at most ``batch`` at a time on
    ``n_dev`` devices (:func:`batch_sizes`, :func:`~stablelego_jax.solvers.problem.batch_rung`)."""
    return _rungs(batch_sizes(plan_bytes(key, m_pad), batch, n_dev, cpu=cpu), count, n_dev)


def _rungs(bsz: int, count: int, n_dev: int) -> list:
    """Padded size of each piece of ``count`` layouts cut ``bsz`` at a time."""
    return [batch_rung(min(bsz, count - b0), n_dev, bsz) for b0 in range(0, count, bsz)]


def _pieces(items: list, key: tuple, batch: int, n_dev: int, crows: dict, cpu: bool | None = None) -> tuple:
    """(m_pad, p_pad, c_pad, bsz, padded batch sizes) of one bucket's ``items``
    (``crows``: each item's column chunks, by index; ``cpu``: see :func:`batch_sizes`)."""
    m_pad = rung(max(it[2].m for it in items), MIN_COLUMNS)
    p_pad = rung(max(it[2].group.shape[1] for it in items), MIN_SLOTS)
    c_pad = rung(max(crows[it[0]] for it in items), MIN_CHUNKS)
    bsz = batch_sizes(plan_bytes(key, m_pad), batch, n_dev, cpu=cpu)
    return m_pad, p_pad, c_pad, bsz, set(_rungs(bsz, len(items), n_dev))


def solve_units(loaded, batch: int, n_dev: int, merge: bool = True, ready=None,
                cpu: bool | None = None) -> list:
    """The :class:`SolveUnit` list of compiled layouts ``loaded`` ((i, layout,
    ForceModel)): grouped by solver bucket (dense or layered shape), small
    buckets merged into larger ones (``merge``) when that lowers the estimated time, padded batches and compiles counted:
    :func:`~stablelego_jax.solvers.problem.merge_plans`), each group padded to its largest column and
    slot counts and cut into pieces of at most one batch. ``ready(key,
    m_pad, p_pad, c_pad, sizes, model) -> bool`` (optional): whether a bucket's
    batched solvers are compiled already (this process or the disk cache);
    such a bucket costs no compile, so it is not merged away.

    The merge prices padding in a CPU core's solve seconds
    (:func:`~stablelego_jax.solvers.problem.plan_seconds`). On an
    accelerator (``cpu`` False; default: JAX's default backend) a compile
    and a load are priced in the same unit, :func:`accelerator_compile_s`:
    there solving is about :data:`ACCELERATOR_SPEEDUP` times faster than
    the estimate and compiling slower than on a CPU, so fewer shapes pay."""
    cpu = _on_cpu(cpu)
    groups: dict = {}
    for item in loaded:
        groups.setdefault(solve_plan(item[2]), []).append(item)
    crows = {it[0]: chunk_rows(it[2]) for it in loaded}
    if merge:
        # small buckets join a larger one when that saves more than it costs
        done, m_pads = set(), {}
        for k, v in groups.items():
            m_pads[k], p_pad, c_pad, _, sizes = _pieces(v, k, batch, n_dev, crows, cpu)
            if ready is not None and ready(k, m_pads[k], p_pad, c_pad, sizes, v[0][2]):
                done.add(k)
        priced = {} if cpu else dict(zip(("compile_s", "load_s"), accelerator_compile_s()))
        into = merge_plans({k: [(rung(it[2].n, MIN_BRICKS), *layer_plan(it[2])) for it in v]
                            for k, v in groups.items()}, ready=done, m_pads=m_pads,
                           pieces=lambda k, m, c: piece_sizes(k, m, c, batch, n_dev, cpu=cpu), **priced)
        merged: dict = {}
        for k, v in groups.items():
            merged.setdefault(into[k], []).extend(v)
        groups = merged
    units = []
    for key in sorted(groups):
        runs = [groups[key]]
        if cpu:
            runs = column_runs(groups[key], key, batch, n_dev, crows, ready, cpu)
        for items in runs:
            m_pad, p_pad, c_pad, bsz, _ = _pieces(items, key, batch, n_dev, crows, cpu)
            if _packs(key, bsz):
                units += [SolveUnit(key, m_pad, p_pad, 1, p, c_pad, pack=len(p) > 1)
                          for p in pack_items(items, key[1], m_pad, c_pad, crows)]
                continue
            units += [SolveUnit(key, m_pad, p_pad, bsz, items[b0: b0 + bsz], c_pad)
                      for b0 in range(0, len(items), bsz)]
    return units


def _packs(key: tuple, bsz: int) -> bool:
    """Whether a bucket's layouts are packed several to a problem
    (:func:`pack_items`): the interior point's dense buckets of at most
    :data:`~stablelego_jax.solvers.ipm.CUT_MIN` bricks, solved one problem at a time."""
    return bsz == 1 and key[0] == "dense" and key[1] <= ipm.CUT_MIN


def column_runs(items: list, key: tuple, batch: int, n_dev: int, crows: dict, ready=None,
                cpu: bool | None = None) -> list[list]:
    """``items`` ((i, layout, ForceModel)) of one interior-point bucket
    ``key``, cut into runs of consecutive column rungs (:func:`~stablelego_jax.solvers.problem.rung`
    of each layout's columns), each run padded to its own largest column
    count, where that lowers the estimated time; one run (the whole bucket
    padded to its largest layout, as before) otherwise. The cut with the
    least estimated seconds, by dynamic programming over the rungs: a run's
    solves (layouts, or packs where the bucket packs them, :func:`_packs`)
    times :func:`~stablelego_jax.solvers.problem.plan_seconds` at its
    padding, plus a compile per batch size
    (:func:`~stablelego_jax.solvers.problem.compile_seconds`), or a load
    (:data:`~stablelego_jax.solvers.problem.LOAD_S`) where ``ready`` (as
    :func:`solve_units`) says that shape is compiled already. Every
    iteration of the interior point passes over every padded column: on
    the small set, 107 layouts of at most 224 columns in dense 16 solved
    in 3.0-3.2 ms each at 224 columns and 5.7-6.4 ms at the bucket's 872
    (BENCHMARKS.md, issue 17, session 52), so a run large enough to pay
    for a second compile is cut; a short run is not."""
    by_rung: dict = {}
    for it in items:
        by_rung.setdefault(rung(it[2].m, MIN_COLUMNS), []).append(it)
    rungs = sorted(by_rung)
    if len(rungs) < 2:
        return [list(items)]
    cache: dict = {}

    def cost(i: int, j: int) -> float:
        """Estimated seconds of the run of rungs i..j-1."""
        if (i, j) not in cache:
            run = [it for r in rungs[i:j] for it in by_rung[r]]
            m_pad, p_pad, c_pad, bsz, sizes = _pieces(run, key, batch, n_dev, crows, cpu)
            if _packs(key, bsz):
                solves = len(pack_items(run, key[1], m_pad, c_pad, crows))
            else:
                solves = sum(_rungs(bsz, len(run), n_dev))
            have = ready is not None and ready(key, m_pad, p_pad, c_pad, sizes, run[0][2])
            cache[i, j] = solves * plan_seconds(key, m_pad) + len(sizes) * (LOAD_S if have else compile_seconds(key))
        return cache[i, j]

    best, start = [0.0], []
    for j in range(1, len(rungs) + 1):
        v, i = min((best[i] + cost(i, j), i) for i in range(j))  # ties: the longer run
        best.append(v)
        start.append(i)
    runs, j = [], len(rungs)
    while j > 0:
        i = start[j - 1]
        runs.append([it for r in rungs[i:j] for it in by_rung[r]])
        j = i
    if len(runs) == 1:
        return [list(items)]  # the bucket's own order
    return runs[::-1]


#: Most layouts in one pack (:func:`pack_items`).
PACK_MOST = 16


def pack_items(items: list, n: int, m_pad: int, c_pad: int, crows: dict) -> list[list]:
    """``items`` ((i, layout, ForceModel)) of one dense bucket of ``n`` bricks,
    ``m_pad`` columns and ``c_pad`` column chunks, in packs that each fit
    the bucket (first fit, most bricks first; at most :data:`PACK_MOST` a
    pack). A small layout solved alone in a joined bucket pays the whole
    bucket's work; packed with others (one block-diagonal problem,
    :func:`~stablelego_jax.model.pack_models`) it shares it. Measured on the
    277 layouts of 2-16 bricks of the 1000-layout shard, in dense 24 with
    1376 columns: 1.8x faster, 17.5 iterations a pack against 15.4 a layout
    (BENCHMARKS.md, issue 17). Only buckets solved one problem at a time
    whose factor is not cut (:attr:`~stablelego_jax.solvers.ipm.IPMOptions.cut`):
    there a pack's factor grows with its bricks."""
    if not items:
        return []
    # a pack that no layout of the bucket fits any more leaves the list first fit scans (the packs
    # come out the same; column_runs on a 2048-layout chunk of small layouts: 1.21 -> 0.29 s)
    least = (min(it[2].n for it in items), min(it[2].m for it in items), min(crows[it[0]] for it in items))
    packs: list = []  # [members, bricks, columns, chunks], in the order they were opened
    open_: list = []  # the packs some layout may still join, in the same order
    for it in sorted(items, key=lambda it: -it[2].n):
        fm, c = it[2], crows[it[0]]
        for k, p in enumerate(open_):
            if p[1] + fm.n <= n and p[2] + fm.m <= m_pad and p[3] + c <= c_pad:
                p[0].append(it)
                p[1] += fm.n
                p[2] += fm.m
                p[3] += c
                break
        else:
            p, k = [[it], fm.n, fm.m, c], len(open_)
            packs.append(p)
            open_.append(p)
        if (len(p[0]) >= PACK_MOST or p[1] + least[0] > n or p[2] + least[1] > m_pad
                or p[3] + least[2] > c_pad):
            del open_[k]
    return [p[0] for p in packs]


#: Name of the batched interior point's executables (:func:`~stablelego_jax.solvers.compiled.compiled`).
BATCH_NAME = "batch-ipm"


def batch_specs(model, key: tuple, m_pad: int, p_pad: int, c_pad: int | None, sizes) -> list:
    """The argument shapes (``jax.ShapeDtypeStruct``) of the batched interior
    point for layouts like ``model`` padded to ``key``, ``m_pad``, ``p_pad``
    and ``c_pad``, at each batch size of ``sizes``: one tuple a size, as
    :func:`solve_unit` passes its arrays."""
    arrays = [a for a in plan_problem(model, key, m_pad, p_pad, c_pad)[1] if a is not None]
    return [tuple(jax.ShapeDtypeStruct((size,) + np.shape(a), np.result_type(a)) for a in arrays)
            for size in sizes]


def compiled_ready(params: Params, opts, n_dev: int):
    """The ``ready`` test of :func:`solve_units` for the batched solver of
    ``opts`` on ``n_dev`` devices: every batch size of the bucket has its
    executable in this process or on disk (:func:`~stablelego_jax.solvers.compiled.available`).
    Each answer is kept (one planning pass asks for a bucket in
    :func:`solve_units` and again in :func:`auto_split`; ``model`` only
    gives the arrays' dtypes and trailing shapes, set by the padding)."""
    seen: dict = {}

    def look(key, m_pad, p_pad, c_pad, sizes, model) -> bool:
        return all(available(BATCH_NAME, (params, opts, n_dev), specs, export=n_dev == 1)
                   for specs in batch_specs(model, key, m_pad, p_pad, c_pad, sizes))

    def ready(key, m_pad, p_pad, c_pad, sizes, model) -> bool:
        tag = (key, m_pad, p_pad, c_pad, frozenset(sizes))
        if tag not in seen:
            seen[tag] = look(key, m_pad, p_pad, c_pad, sizes, model)
        return seen[tag]

    return ready


def solve_unit(unit: SolveUnit, params: Params, opts, n_dev: int, fallback: bool,
               st: "ScoreStats") -> Iterator[list]:
    """Solve one :class:`SolveUnit` with the interior point's ``opts``
    (``fallback``, ``st``: as :func:`iter_analyses`' ``fallback`` and ``stats``);
    yields lists of (i, Analysis) (see :func:`iter_analyses`). A packed unit
    is one problem; where it does not converge, each of its layouts is
    solved alone, with the same compiled shape."""

    def solve_batch(probs, bsz):
        """Solve one batch of problems; returns (solution, seconds)."""
        size = batch_rung(len(probs), n_dev, bsz)
        probs = probs + [probs[-1]] * (size - len(probs))
        arrays = tuple(a for a in stack_problems(probs) if a is not None)
        n0, t0c = STATS.compiles, STATS.compile_s
        exe = compiled(BATCH_NAME, batch_solver_fn(params, opts, n_dev), (params, opts, n_dev), arrays,
                       export=n_dev == 1)
        st.compiles += STATS.compiles - n0
        st.compile_s += STATS.compile_s - t0c
        t1 = time.perf_counter()
        sol = Solution(*jax.device_get(exe(*arrays)))
        dt = time.perf_counter() - t1
        st.solve_s += dt
        return sol, dt

    if unit.pack:
        done, dt = _solve_pack(unit, solve_batch)
        if done is not None:
            yield [(i, _settled(a, opts, params, fallback, st)) for i, a in done]
            return
        # a pack that did not converge: each layout alone (the same compiled shape), its
        # time counting its share of the pack's
        for it in unit.items:
            for part in solve_unit(dataclasses.replace(unit, items=[it], pack=False), params, opts,
                                   n_dev, fallback, st):
                for _, a in part:
                    a.time_s += dt / len(unit.items)
                yield part
        return
    prepared = []
    for it in unit.items:
        fm, prob = plan_problem(it[2], unit.key, unit.m_pad, unit.p_pad, unit.c_pad)
        prepared.append((it, fm, prob))
    bsz = unit.bsz
    for b0 in range(0, len(prepared), bsz):
        sub = prepared[b0: b0 + bsz]
        sol, dt = solve_batch([pr for _, _, pr in sub], bsz)
        done = []
        for j, ((i, lay, model), fm, _) in enumerate(sub):
            a = make_analysis(lay, fm, np.asarray(sol.f[j]), "jax", bool(sol.converged[j]),
                              time.perf_counter(), iters=int(sol.iters[j]), gap=float(sol.gap[j]),
                              objective=float(sol.objective[j]))
            a.time_s = dt / len(sub)  # amortised share of its batch
            done.append((i, _settled(a, opts, params, fallback, st)))
        yield done


def _solve_pack(unit: SolveUnit, solve_batch) -> tuple:
    """Solve a packed :class:`SolveUnit` (the interior point) as one problem:
    ``([(i, Analysis)], seconds)``, each layout answered from its own
    columns (the forces of a block-diagonal problem are its members' own
    optima; iterations, gap and convergence are the pack's, the time its
    share), or ``(None, seconds)`` when the pack did not converge (its
    layouts share one step length and one stopping test, so one layout that
    stalls holds the others)."""
    pack, cols = pack_models([it[2] for it in unit.items])
    _, prob = plan_problem(pack, unit.key, unit.m_pad, unit.p_pad, unit.c_pad)
    sol, dt = solve_batch([prob], 1)
    if not bool(sol.converged[0]):
        return None, dt
    f = np.asarray(sol.f[0])
    done = []
    for j, (i, lay, model) in enumerate(unit.items):
        fj = f[cols[j]: cols[j + 1]]
        a = make_analysis(lay, model, fj, "jax", True, time.perf_counter(), iters=int(sol.iters[0]),
                          gap=float(sol.gap[0]), objective=float(eq9_cost(model, fj)))
        a.time_s = dt / len(unit.items)
        done.append((i, a))
    return done, dt


def _settled(a, opts, params: Params, fallback: bool, st: "ScoreStats"):
    """``a``, or with ``fallback`` where it did not converge its answer by a
    longer run, then the exact solver (:func:`~stablelego_jax.analysis.resolve_unconverged`);
    counted in ``st``."""
    if fallback and not a.converged:
        t1 = time.perf_counter()
        with one_blas_thread():
            a = resolve_unconverged(a, opts, params)
        st.solve_s += time.perf_counter() - t1
        st.retried += 1
    st.not_converged += not a.converged
    return a


def _unit_results(unit: SolveUnit, params, opts, fallback) -> tuple:
    """In a worker process: ([(i, Analysis)] of ``unit`` on one device, the
    worker's :class:`ScoreStats` of it)."""
    st = ScoreStats()
    with one_blas_thread():
        out = [x for part in solve_unit(unit, params, opts, 1, fallback, st) for x in part]
    return out, st


def assign_units(units: Sequence[SolveUnit], jobs: int, compile_s: float | None = None, ready=None) -> list:
    """Worker index of each unit: longest first, each to the worker that
    would finish it soonest. The first worker to take a unit of a shape
    pays ``compile_s`` for it (None: its kind's
    :func:`~stablelego_jax.solvers.problem.compile_seconds`), or ``LOAD_S`` where ``ready`` (see
    :func:`solve_units`; one device per worker) says its executable is
    compiled already, on disk; any other worker that takes a unit of that
    shape pays ``LOAD_S``: it solves such units after its own shapes
    (:func:`worker_order`), by when the first has compiled the shape and
    written it to the disk cache."""
    load = [0.0] * jobs
    shapes: list = [set() for _ in range(jobs)]
    out = [0] * len(units)
    for u in _longest_first(units):
        un = units[u]
        key = un.shape
        new = compile_seconds(un.key) if compile_s is None else compile_s
        if any(key in sh for sh in shapes) or (ready is not None and ready(
                *key, {batch_rung(len(un.items), 1, un.bsz)}, un.items[0][2])):
            new = LOAD_S
        cost = [load[w] + un.seconds() + (0.0 if key in shapes[w] else new) for w in range(jobs)]
        w = min(range(jobs), key=cost.__getitem__)
        load[w] = cost[w]
        shapes[w].add(key)
        out[u] = w
    return out


def worker_order(units: Sequence[SolveUnit], where: Sequence[int]) -> list:
    """Indices of ``units`` in the order their workers (``where``, from
    :func:`assign_units`) solve them: each worker first the units of the
    shapes it compiles itself (those whose longest unit it took: it is
    that shape's first taker), in the given order, then its share of
    shapes another worker compiles, read from the disk cache."""
    owner: dict = {}
    for u in _longest_first(units):  # assign_units' order: a shape's first unit there is its first taker
        owner.setdefault(units[u].shape, where[u])
    return sorted(range(len(units)), key=lambda u: (owner[units[u].shape] != where[u], u))


class Workers:
    """``jobs`` spawned worker processes (one single-process pool each, so a
    unit goes to the worker :func:`assign_units` chose), started at once and
    each made ready in the background (JAX imported, its backend and the
    compilation cache set up, :func:`_ready_worker`), so that their start
    overlaps the parent's reading and planning. A context manager: leaving
    it shuts the workers down. Ctrl-C is the parent's to handle."""

    def __init__(self, jobs: int):
        ctx = multiprocessing.get_context("spawn")
        self.pools = [concurrent.futures.ProcessPoolExecutor(1, mp_context=ctx, initializer=_ignore_sigint)
                      for _ in range(jobs)]
        for pool in self.pools:
            pool.submit(_ready_worker, jobs >= cpu_cores())

    def close(self) -> None:
        for pool in self.pools:
            pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> "Workers":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _ready_worker(one_core: bool = False) -> None:
    """What a worker's first solve would otherwise wait for: JAX's CPU
    backend, the persistent compilation cache and the compiler-options check
    (``one_core``: the pool has a worker a core, :func:`~stablelego_jax.runtime.one_core_compiles`)."""
    from .runtime import compiler_options, one_core_compiles, quick_exit, use_persistent_cache

    jax.devices()
    use_persistent_cache()
    if one_core:
        one_core_compiles()
    compiler_options()
    # a worker's last act, once its pool has let it go (results sent, the disk cache written
    # as each compile ended); registered after JAX's own hooks, so it runs first
    atexit.register(quick_exit)


def _jax_pool(units, jobs, params, opts, fallback, st, ready=None, workers=None) -> Iterator[list]:
    """The units over ``jobs`` worker processes, one device (and one XLA
    pool thread) each: ``workers`` (:class:`Workers`, at least ``jobs``;
    left running) or spawned here; every worker solves the units
    :func:`assign_units` gives it (``ready``: which shapes are on disk), in
    :func:`worker_order`, so each shape is compiled once, by one worker.
    Yields each unit's results as it finishes."""
    where = assign_units(units, jobs, ready=ready)
    own = Workers(jobs) if workers is None or len(workers.pools) < jobs else None
    pools = (own or workers).pools[:jobs]
    order = worker_order(units, where)
    queues = [[u for u in order if where[u] == w] for w in range(jobs)]
    shapes, secs = [un.shape for un in units], [un.seconds() for un in units]
    have: list = [set() for _ in range(jobs)]  # shapes each worker holds
    on_disk: set = set()  # shapes some worker has compiled (and written to the disk cache)
    flying: dict = {}  # future -> (worker, unit)

    def feed() -> None:
        for w in range(jobs):
            while sum(1 for v, _ in flying.values() if v == w) < POOL_DEPTH:
                u = next_unit(queues, w, shapes, secs, have[w], on_disk)
                if u is None:
                    break
                fut = pools[w].submit(_unit_results, units[u], params, opts, fallback)
                flying[fut] = (w, u)

    try:
        feed()
        while flying:
            done, _ = concurrent.futures.wait(list(flying), return_when=concurrent.futures.FIRST_COMPLETED)
            for fut in done:
                w, u = flying.pop(fut)
                out, wst = fut.result()
                have[w].add(shapes[u])
                on_disk.add(shapes[u])
                st.add_solver_counts(wst)
                feed()  # before the parent writes: no worker waits on it
                if out:
                    yield out
    finally:
        for fut in flying:
            fut.cancel()
        if own is not None:
            own.close()


#: Units handed to a pool worker ahead of time (one running, one queued in its pool).
POOL_DEPTH = 2


def next_unit(queues: list, w: int, shapes: Sequence, seconds: Sequence[float], have: set, on_disk: set,
              load_s: float = LOAD_S) -> int | None:
    """The next unit for worker ``w`` (popped from ``queues``, each
    worker's units in :func:`worker_order`; ``shapes`` and ``seconds``:
    each unit's :attr:`SolveUnit.shape` and :meth:`SolveUnit.seconds`,
    worked out once for the run): its own next one; once its
    queue is empty, the last unit of the worker with the most estimated
    seconds left among those of a shape ``w``
    holds (``have``), else of a shape compiled already (``on_disk``: a load,
    ``load_s``) where that worker has more than four loads' worth left.
    Never a shape nobody has compiled: that is its first taker's
    to compile. The static plan (:func:`assign_units`) ends with one worker
    busy while another waits when its estimates miss (on the small set,
    2.2 s of a 10 s first run); this evens the end out."""
    if queues[w]:
        return queues[w].pop(0)
    left = {v: sum(seconds[u] for u in q) for v, q in enumerate(queues) if q and v != w}
    for v in sorted(left, key=lambda v: -left[v]):
        q = queues[v]
        for ok in (lambda u: shapes[u] in have,
                   lambda u: shapes[u] in on_disk and left[v] > 4 * load_s):
            for j in range(len(q) - 1, 0, -1):  # never the victim's very next unit
                if ok(q[j]):
                    return q.pop(j)
    return None


def _exact_items(items, method, exact_method, exact_scale) -> list:
    """[(i, Analysis)] of compiled ``items`` ((i, layout, model)) solved by
    HiGHS one at a time (``method``: ours or a baseline)."""
    return [(i, analyze_exact(lay, model, method, None, exact_method, exact_scale)) for i, lay, model in items]


def _ignore_sigint() -> None:
    """Worker initialiser: Ctrl-C is the parent's to handle (one line, no
    traceback per worker); the parent shuts the pool down."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _exact_worker() -> None:
    """Initialiser of a HiGHS worker: :func:`_ignore_sigint`, and JAX (used
    for nothing there) kept on the CPU, so that workers on a machine with
    an accelerator never claim its memory."""
    _ignore_sigint()
    jax.config.update("jax_platforms", "cpu")


def exact_parts(costs: Sequence[float], jobs: int, most: int = 16) -> list[list[int]]:
    """Parts (lists of indices into ``costs``, estimated seconds a layout)
    for ``jobs`` HiGHS workers, longest first: each part at most ``most``
    layouts and about a quarter of a worker's share of the total, a layout
    costlier than that alone. A pool that takes the parts in this order
    gives the long layouts out first and ends with short parts (longest
    processing time first), so no worker is left with a run of the
    largest layouts while the others wait."""
    order = sorted(range(len(costs)), key=lambda k: -costs[k])
    cap = sum(costs) / (4 * max(1, jobs))
    parts: list[list[int]] = []
    cur: list[int] = []
    spent = 0.0
    for k in order:
        if cur and (len(cur) >= most or spent + costs[k] > cap):
            parts.append(cur)
            cur, spent = [], 0.0
        cur.append(k)
        spent += costs[k]
    if cur:
        parts.append(cur)
    return parts


def _exact_pool(items, jobs, method, exact_method, exact_scale) -> Iterator[list]:
    """:func:`_exact_items` over ``jobs`` spawned worker processes (spawned,
    not forked: the parent may hold JAX's threads), in the parts of
    :func:`exact_parts` (by :func:`~stablelego_jax.solvers.exact.estimated_seconds`),
    yielded as they finish. Each worker runs HiGHS on one core."""
    plan = exact_parts([estimated_seconds(model) for _, _, model in items], jobs)
    parts = [[items[k] for k in part] for part in plan]
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=ctx, initializer=_exact_worker) as pool:
        futs = [pool.submit(_exact_items, part, method, exact_method, exact_scale) for part in parts]
        try:
            for fut in concurrent.futures.as_completed(futs):
                yield fut.result()
        finally:
            for fut in futs:
                fut.cancel()


def analyze_many(layouts: Sequence, solver: str = "jax", **kwargs) -> list:
    """:func:`iter_analyses` collected in input order: one Analysis (or the
    exception of a layout that cannot be compiled) per layout."""
    out: list = [None] * len(layouts)
    for part in iter_analyses(layouts, solver, **kwargs):
        for i, a in part:
            out[i] = a
    return out


def _score_files(
    inputs: Sequence[str],
    out: str,
    solver: str = "jax",
    batch: int | None = None,
    devices: str | int = "all",
    write_scores: bool = False,
    library=None,
    params: Params = Params(),
    opts=None,
    chunk: int = 2048,
    progress: bool = True,
    exact_method: str = "highs",
    exact_scale: bool = True,
    stream=None,
    method: str = "ours",
    column: str | None = None,
    id_column: str | None = None,
    jobs: int = 1,
    shard: tuple[int, int] | None = None,
    skip_unsupported: bool = False,
) -> ScoreStats:
    """Score every layout of ``inputs`` into the JSON-lines file ``out``
    (``score_files`` runs this with one OpenBLAS thread: :mod:`~stablelego_jax.blas`).

    solver: "jax" (batched interior point, :mod:`~stablelego_jax.solvers.ipm`),
    "auto" (each group of layouts by whichever of "jax" and "exact" is
    estimated faster, :func:`auto_split`; each line's ``solver`` says which) or
    "exact" (HiGHS ``exact_method``, one layout at a time; ``exact_scale``:
    torque rows in N stud, the same LP, which HiGHS solves reliably on
    layouts of hundreds of bricks); opts: options of the JAX solver
    (IPMOptions; None: defaults); method: "ours" or a
    baseline ("luo", "eb"; exact solver only, see :mod:`~stablelego_jax.solvers.baselines`);
    batch: most layouts per solver call (None: :func:`default_batch`); devices: "all" or a count of local
    devices to shard each batch over; chunk: layouts read and grouped at a
    time (bounds host memory); column / id_column: the layout and id columns
    of JSON-lines and Parquet inputs (:mod:`~stablelego_jax.formats.rows`;
    each row is one result line, ``file`` = ``FILE#ROW`` or ``FILE#ID``, with
    ``row`` and ``id``); jobs: worker processes of the exact solver and the
    baselines (:func:`iter_analyses`); shard: (K, N) scores only the inputs of
    shard K of N (:func:`in_shard`), so N processes or hosts split a dataset
    with no coordination (each its own ``out``); skip_unsupported: LDraw
    files are scored without the parts that cannot be modelled (their line
    gets ``left_out`` {part: count}, stderr a warning; ``left_out`` in the
    totals counts such files), instead of an error line. Returns run totals; files already in ``out``
    are skipped. The solving is :func:`iter_analyses`; lines are appended and
    flushed per solver call.
    """
    solver = pick_solver(solver, method)
    t_run = time.perf_counter()
    # refuse a bad device count before reading anything
    n_dev = _device_count(devices) if solver != "exact" else None
    paths = find_layouts(inputs, id_column)
    if not paths:
        raise LayoutError(", ".join(map(str, inputs)), "no layouts to score")
    if shard is not None:
        paths = [p for p in paths if in_shard(p, *shard)]
    done = read_results(out)
    todo = [p for p in paths if str(p) not in done]
    st = ScoreStats(total=len(paths), skipped=len(paths) - len(todo))
    bar = Progress(len(todo), stream=stream, enabled=progress, unit="layouts")
    d = os.path.dirname(os.path.abspath(out))
    os.makedirs(d, exist_ok=True)
    # the JAX pool's workers start now, while this process reads and plans ("auto" may give
    # HiGHS every layout: its workers start when it knows)
    pool_jobs = jax_pool_size(jobs, n_dev, len(todo)) if solver == "jax" else 1
    with open(out, "a", encoding="utf-8") as fh, (Workers(pool_jobs) if pool_jobs > 1 else contextlib.nullcontext()) \
            as workers:

        def emit(recs: Iterable[dict]) -> None:
            lines = "".join(json.dumps(r) + "\n" for r in recs)
            fh.write(lines)
            fh.flush()
            os.fsync(fh.fileno())

        for c0 in range(0, len(todo), chunk):
            part = todo[c0: c0 + chunk]
            t0 = time.perf_counter()
            loaded, errs = [], []
            for p in part:
                report: dict = {}  # LDraw parts left out (skip_unsupported)
                try:
                    lay = rows.load_source(p, library, column, id_column, skip_unsupported, report)
                except Exception as exc:  # a bad layout is reported, the run goes on
                    errs.append(dict(rows.result_fields(p), error=error_message(str(p), exc)))
                    continue
                loaded.append((p, lay, report))
                if report:
                    bar.write(f"warning: {p}: left out, {unsupported_message(report)}", sys.stderr)
            st.load_s += time.perf_counter() - t0
            if errs:
                emit(errs)
                st.errors += len(errs)
                bar.advance(len(errs))
            for part_done in iter_analyses([lay for _, lay, _ in loaded], solver, params, opts, batch, devices,
                                           exact_method, exact_scale, method, stats=st, jobs=jobs,
                                           workers=workers):
                recs = []
                for i, a in part_done:
                    p, lay, report = loaded[i]
                    if isinstance(a, Exception):
                        recs.append(dict(rows.result_fields(p), error=error_message(str(p), a)))
                        st.errors += 1
                        continue
                    if write_scores and isinstance(p, str) and os.path.isdir(p) and a.scores:
                        _write_score_grid(p, lay, a.scores)
                    rec = dict(a.to_json(), **rows.result_fields(p))
                    if report:
                        rec["left_out"] = {k: c for k, (c, _) in report.items()}
                        st.left_out += 1
                    if (a.solver if solver == "auto" else solver) != "exact":
                        rec["iters"] = a.iters
                    recs.append(rec)
                    st.scored += 1
                emit(recs)
                bar.advance(len(recs))
    bar.close()
    st.wall_s = time.perf_counter() - t_run
    return st


@functools.wraps(_score_files)
def score_files(*args, **kwargs) -> ScoreStats:
    with one_blas_thread():
        return _score_files(*args, **kwargs)
