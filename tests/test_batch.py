"""Batched scoring: discovery, results file, resume, errors, score grids, sharding."""
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from conftest import EXAMPLES, rerun_at_shipping_xla

from stablelego_jax.generate.objects import analyze_and_write
from stablelego_jax.generate.procedural import stairs, tower
from stablelego_jax import load_layout
from stablelego_jax.analysis import analyze
from stablelego_jax.batch import (CPU_CACHE_BYTES, POOL_MIN, ScoreStats, batch_sizes, exact_parts, find_layouts,
                                  jax_pool_size,
                                  piece_sizes, plan_bytes, read_results, score_files)
from stablelego_jax.cli import main
from stablelego_jax.solvers.problem import FULL_BATCH

REF = os.path.join(EXAMPLES, "stablelego")
SMALL = ["external_weight_good.json", "external_weight_fail.json", "stick_light.json"]
REQUIRED = {"file", "stable", "weakest", "scores", "n_bricks", "solver", "converged", "time_s"}


@pytest.fixture
def shard(tmp_path):
    """A folder of layout files plus a dataset folder with two objects."""
    d = tmp_path / "layouts"
    d.mkdir()
    for name in SMALL:
        shutil.copy(os.path.join(REF, name), d / name)
    shutil.copy(os.path.join(EXAMPLES, "labels_stablelego.json"), d / "labels.json")  # not a layout: skipped
    ds = tmp_path / "dataset"
    analyze_and_write(str(ds / "obj_a"), stairs(3), vis=False)
    analyze_and_write(str(ds / "obj_b"), tower(3), vis=False)
    return tmp_path


def _lines(path):
    with open(path) as fh:
        return [json.loads(line) for line in fh]


def test_find_layouts_expands_folders_and_dataset_objects(shard):
    found = find_layouts([str(shard / "layouts"), str(shard / "dataset")])
    names = [os.path.basename(p) for p in found]
    assert sorted(names[:3]) == sorted(SMALL)
    assert names[3:] == ["obj_a", "obj_b"]
    assert "labels.json" not in names


def test_scores_match_single_analysis_and_exact(shard, tmp_path):
    out = tmp_path / "r.jsonl"
    st = score_files([str(shard / "layouts"), str(shard / "dataset")], str(out), progress=False)
    assert (st.scored, st.errors, st.not_converged) == (5, 0, 0)
    recs = {r["file"]: r for r in _lines(out)}
    assert len(recs) == 5
    for path, r in recs.items():
        assert REQUIRED <= set(r)
        ex = analyze(path, solver="exact")
        assert r["stable"] == ex.stable, path
        assert r["weakest"] == ex.weakest, path
        assert set(r["scores"]) == set(ex.scores)
        assert max(r["scores"].values()) == pytest.approx(max(ex.scores.values()), abs=0.02)


def test_resume_skips_done_and_drops_torn_line(shard, tmp_path):
    out = tmp_path / "r.jsonl"
    inputs = [str(shard / "layouts")]
    score_files(inputs, str(out), progress=False)
    first = _lines(out)
    assert score_files(inputs, str(out), progress=False).scored == 0
    # simulate a kill in the middle of writing the last line
    text = out.read_text().splitlines(keepends=True)
    out.write_text("".join(text[:-1]) + text[-1][: len(text[-1]) // 2])
    assert len(read_results(str(out))) == 2
    st = score_files(inputs, str(out), progress=False)
    assert st.scored == 1 and st.skipped == 2
    again = _lines(out)
    assert sorted(r["file"] for r in again) == sorted(r["file"] for r in first)


def test_bad_layout_gets_error_line_and_run_continues(shard, tmp_path, capsys):
    bad = shard / "layouts" / "broken.json"
    bad.write_text("{not json")
    out = tmp_path / "r.jsonl"
    rc = main(["score", str(shard / "layouts"), "--out", str(out), "--quiet"])
    assert rc == 1
    recs = _lines(out)
    errs = [r for r in recs if "error" in r]
    assert len(errs) == 1 and errs[0]["file"] == str(bad) and "broken.json" in errs[0]["error"]
    assert sum("stable" in r for r in recs) == 3


def test_write_scores_beside_dataset_objects(shard, tmp_path):
    obj = shard / "dataset" / "obj_a"
    os.remove(obj / "stability_score.npy")
    out = tmp_path / "r.jsonl"
    score_files([str(shard / "dataset")], str(out), write_scores=True, progress=False)
    grid = np.load(obj / "stability_score.npy")
    vox = np.load(obj / "vox.npy")
    assert grid.shape == vox.shape
    assert ((grid > 0) <= vox).all()
    rec = {r["file"]: r for r in _lines(out)}[str(obj)]
    assert grid.max() == pytest.approx(max(rec["scores"].values()))


def test_exact_solver_path(shard, tmp_path):
    out = tmp_path / "r.jsonl"
    st = score_files([str(shard / "layouts")], str(out), solver="exact", progress=False)
    assert st.scored == 3
    assert all(r["solver"] == "exact" for r in _lines(out))


def test_batch_sizes_respect_memory_and_devices():
    small, big = plan_bytes(("dense", 8), 64), plan_bytes(("dense", 512), 4096)
    assert batch_sizes(small, 64, 1, cpu=False) == 64
    assert 1 <= batch_sizes(big, 64, 1, cpu=False) < 64
    assert batch_sizes(big, 64, 1, cpu=False) * big <= 2e9
    assert batch_sizes(small, 64, 4, cpu=False) % 4 == 0
    assert batch_sizes(10 * big, 64, 2, cpu=False) == 2
    # an accelerator batches a 20-layer member of 76 MB (64 of them: 12x one at a time on an H200)
    layered = plan_bytes(("layered", 20, 32), 2048)
    assert batch_sizes(layered, 64, 1, cpu=False, mem_budget=35e9) == 64
    assert batch_sizes(layered, 64, 1, cpu=False) == int(2e9 // layered)
    # the layer-by-layer plan of a 20-layer blob needs far less than its dense form
    assert plan_bytes(("layered", 20, 40), 8192) < plan_bytes(("dense", 800), 8192) / 10


def test_device_budget_is_a_quarter_of_the_device(monkeypatch):
    """An accelerator's batch budget: a quarter of what JAX may allocate on
    the first device, at least CPU_BUDGET_BYTES (also where it does not say)."""
    import jax

    from stablelego_jax import batch

    class Device:
        def __init__(self, stats):
            self.stats = stats

        def memory_stats(self):
            return self.stats

    for stats, want in (({"bytes_limit": 100e9}, 25e9), ({"bytes_limit": 1e9}, batch.CPU_BUDGET_BYTES),
                        (None, batch.CPU_BUDGET_BYTES), ({}, batch.CPU_BUDGET_BYTES)):
        monkeypatch.setattr(jax, "local_devices", lambda stats=stats: [Device(stats)])
        batch.device_budget.cache_clear()
        assert batch.device_budget() == want
    batch.device_budget.cache_clear()
    monkeypatch.setattr(jax, "local_devices", lambda: [Device({"bytes_limit": 100e9})])
    big = plan_bytes(("layered", 20, 32), 2048)
    assert batch_sizes(big, 64, 1, cpu=False) == 64  # 25 GB takes 64 members of 76 MB
    assert batch_sizes(big, 64, 1, cpu=True) == 1  # a CPU keeps its own rule
    batch.device_budget.cache_clear()


def test_default_batch_by_device():
    """No --batch: 64 on a CPU, where the cache rule holds every bucket below
    it anyway, and ACCELERATOR_BATCH on an accelerator."""
    from stablelego_jax.batch import ACCELERATOR_BATCH, default_batch

    assert default_batch(cpu=True) == 64
    assert default_batch(cpu=False) == ACCELERATOR_BATCH == 1024
    assert default_batch() == 64  # the tests run on a CPU
    tiny = plan_bytes(("dense", 8), 64)  # the smallest bucket's working set
    assert batch_sizes(tiny, ACCELERATOR_BATCH, 1, cpu=True) == batch_sizes(tiny, 64, 1, cpu=True) < 64


def test_accelerator_prices_a_compile_in_cpu_solve_seconds(monkeypatch):
    """On an accelerator, solve_units' bucket merge prices a compile (and a
    load) at accelerator_compile_s: padding is priced in a CPU core's solve
    seconds, and there a device solves ACCELERATOR_SPEEDUP times faster and
    compiles slower. A CPU keeps compile_seconds. A merge whose padding costs
    more than a CPU compile but less than an accelerator's happens on the
    accelerator only."""
    from stablelego_jax import batch
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.solvers.problem import DENSE_COMPILE_S, merge_plans, plan_seconds

    comp, load = batch.accelerator_compile_s()
    assert comp == batch.ACCELERATOR_COMPILE_S * batch.ACCELERATOR_SPEEDUP > DENSE_COMPILE_S
    assert load == batch.LOAD_S * batch.ACCELERATOR_SPEEDUP
    seen = []
    monkeypatch.setattr(batch, "merge_plans", lambda *a, **k: seen.append(k) or merge_plans(*a, **k))
    lays = [stairs(6)] * 3 + [stairs(14)] * 3
    loaded = [(i, lay, compile_layout(lay, Params())) for i, lay in enumerate(lays)]
    batch.solve_units(loaded, 64, 1, cpu=True)
    batch.solve_units(loaded, 64, 1, cpu=False)
    assert "compile_s" not in seen[0] and "load_s" not in seen[0]
    assert (seen[1]["compile_s"], seen[1]["load_s"]) == (comp, load)
    assert batch.solve_units(loaded, 64, 1) == batch.solve_units(loaded, 64, 1, cpu=True)
    # 2000 layouts of dense 16 padded to dense 32 cost more than a CPU compile, less than a device's
    sizes = {("dense", 16): [(16, 3, 6)] * 2000, ("dense", 32): [(32, 5, 8)] * 2000}
    pad = 2000 * (plan_seconds(("dense", 32)) - plan_seconds(("dense", 16)))
    assert DENSE_COMPILE_S < pad < comp
    assert merge_plans(sizes)[("dense", 16)] == ("dense", 16)
    assert merge_plans(sizes, compile_s=comp, load_s=load)[("dense", 16)] == ("dense", 32)


def test_cpu_batches_stay_within_a_cores_cache():
    """On a CPU each core's share of a batch fits CPU_CACHE_BYTES, at least
    one layout a device: a tiny bucket still batches, a 40-brick one does not."""
    tiny, mid = plan_bytes(("dense", 8), 300), plan_bytes(("dense", 40), 2184)
    assert tiny < CPU_CACHE_BYTES < mid
    b = batch_sizes(tiny, 64, 1, cpu=True)
    assert 2 <= b and b * tiny <= CPU_CACHE_BYTES and b & (b - 1) == 0
    assert batch_sizes(mid, 64, 1, cpu=True) == 1
    assert batch_sizes(mid, 64, 2, cpu=True) == 2  # one a device
    assert batch_sizes(tiny, 1, 1, cpu=True) == 1  # --batch still caps it


def test_jax_workers_only_on_a_cpu(monkeypatch):
    """JAX worker processes split a CPU's cores; on a GPU the one process
    that holds the device solves (workers would each claim its memory)."""
    import jax

    assert jax_pool_size(4, 1, POOL_MIN) == 4
    assert jax_pool_size(4, 1, POOL_MIN - 1) == 1  # too few layouts to pay for workers
    assert jax_pool_size(4, 2, 1000) == 1  # several devices: one process shards over them
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert jax_pool_size(16, 1, 1000) == 1


def test_exact_parts_give_the_large_layouts_out_first_and_alone():
    """45 large layouts (60 s each) among 955 small ones (0.1 s): each large
    one is a part of its own, first; no part holds more than 16 layouts or
    (but for a single large one) more than a quarter of a worker's share;
    every layout is in exactly one part."""
    costs = [0.1] * 955 + [60.0] * 45
    parts = exact_parts(costs, 16)
    assert sorted(k for p in parts for k in p) == list(range(1000))
    assert parts[:45] == [[k] for k in range(955, 1000)]
    cap = sum(costs) / (4 * 16)
    assert all(len(p) <= 16 for p in parts)
    assert all(len(p) == 1 or sum(costs[k] for k in p) <= cap for p in parts)
    # costs descend part by part: the pool's queue hands the long ones out first
    first = [costs[p[0]] for p in parts]
    assert first == sorted(first, reverse=True)
    assert exact_parts([], 4) == []


def test_piece_sizes_are_the_padded_batches_solved():
    """Full batches, then the rest padded to a power of two (times the
    devices); batches of at most FULL_BATCH are always padded to full."""
    key = ("dense", 8)
    assert piece_sizes(key, 64, 70, 64, 1, cpu=False) == [64, 8]
    assert piece_sizes(key, 64, 64, 64, 1, cpu=False) == [64]
    assert piece_sizes(key, 64, 5, 64, 2, cpu=False) == [8]
    assert piece_sizes(key, 64, 130, 32, 1, cpu=False) == [32, 32, 32, 32, 2]
    # 515 MB a member: three fit the 2 GB budget
    assert 2e9 // plan_bytes(("dense", 512), 4096) == 3
    assert piece_sizes(("dense", 512), 4096, 3, 64, 1, cpu=False) == [3]
    assert piece_sizes(("dense", 512), 4096, 7, 64, 1, cpu=False) == [3, 3, 3]
    assert piece_sizes(key, 64, 6, 4, 1, cpu=False) == [4, 4]  # not [4, 2]: one size compiled, not two
    assert FULL_BATCH >= 4
    assert piece_sizes(("dense", 40), 2184, 3, 64, 1, cpu=True) == [1, 1, 1]


def test_accelerator_compiles_ahead_in_threads_with_the_same_answers(monkeypatch):
    """On an accelerator, one process solves every unit: its shapes are
    compiled ahead in threads (compile_ahead) while it solves, each once,
    and the answers are those of the plain loop. Run here on the CPU with
    the accelerator's path forced."""
    from stablelego_jax import batch
    from stablelego_jax.batch import analyze_many
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.solvers import compiled as C
    from stablelego_jax.solvers import ipm

    lays = [stairs(3), stairs(6), stairs(14), tower(3), stairs(20)]
    plain = analyze_many(lays, solver="jax", jobs=1, merge=False)
    loaded = [(i, lay, compile_layout(lay, Params())) for i, lay in enumerate(lays)]
    units = batch.solve_units(loaded, 64, 1, merge=False, cpu=False)
    specs = batch.ahead_specs(units, 1)
    assert len(specs) == len({u.shape for u in units}) >= 2  # one batch size a bucket here
    monkeypatch.setenv("STABLELEGO_CACHE", "0")  # in-process only: every shape really compiles
    monkeypatch.setenv("STABLELEGO_COMPILE_AHEAD", "2")
    monkeypatch.setattr(batch, "_on_cpu", lambda cpu=None: False if cpu is None else cpu)
    C.clear()
    seen = []
    real = batch.compile_ahead
    monkeypatch.setattr(batch, "compile_ahead", lambda *a, **k: seen.append(real(*a, **k)) or seen[-1])
    st = ScoreStats()
    before = C.STATS.compiles
    ahead = analyze_many(lays, solver="jax", jobs=1, merge=False, stats=st)
    assert seen and seen[0] is not None  # the threads ran
    assert C.STATS.compiles - before == st.compiles == len(specs)  # each shape once, all counted
    for a, b in zip(ahead, plain):
        assert a.stable == b.stable and a.weakest == b.weakest
        assert a.scores.keys() == b.scores.keys()
        np.testing.assert_allclose([a.scores[k] for k in a.scores], [b.scores[k] for k in a.scores], atol=1e-12)
    monkeypatch.setenv("STABLELEGO_COMPILE_AHEAD", "0")
    assert batch.ahead_threads() == 0 and batch.compile_ahead(units, Params(), ipm.IPMOptions(), 1) is None
    monkeypatch.setenv("STABLELEGO_COMPILE_AHEAD", "many")
    with pytest.raises(ValueError, match="STABLELEGO_COMPILE_AHEAD"):
        batch.ahead_threads()
    C.clear()


def test_sharded_over_four_cpu_devices_matches(shard, tmp_path):
    """--devices 4 on forced host devices gives the same labels and scores,
    or, on a jaxlib whose LAPACK kernels deadlock several CPU devices, a
    clear refusal (exit 2) that points to --jobs."""
    from stablelego_jax.blas import lapack_pool_deadlock

    out1, out4 = tmp_path / "one.jsonl", tmp_path / "four.jsonl"
    inputs = [str(shard / "layouts")]
    score_files(inputs, str(out1), devices=1, progress=False)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4", JAX_PLATFORMS="cpu")
    root = os.path.join(os.path.dirname(__file__), "..")
    code = (
        "import sys; sys.path.insert(0, %r); import jax; assert jax.local_device_count() == 4;"
        "from stablelego_jax.cli import main; sys.exit(main(sys.argv[1:]))" % root
    )
    r = subprocess.run(
        [sys.executable, "-c", code, "score", *inputs, "--out", str(out4), "--devices", "4", "--batch", "4", "--quiet"],
        env=env, capture_output=True, text=True, timeout=600,
    )
    if lapack_pool_deadlock():
        assert r.returncode == 2, r.stderr
        assert "--devices 4: several CPU devices deadlock" in r.stderr and "--jobs" in r.stderr
        assert not out4.exists()
        return
    assert r.returncode == 0, r.stderr
    a = {x["file"]: x for x in _lines(out1)}
    b = {x["file"]: x for x in _lines(out4)}
    assert set(a) == set(b)
    for k in a:
        assert a[k]["stable"] == b[k]["stable"]
        for key, v in a[k]["scores"].items():
            assert b[k]["scores"][key] == pytest.approx(v, abs=1e-3)


def test_missing_input_is_an_error_line(tmp_path):
    out = tmp_path / "r.jsonl"
    st = score_files([str(tmp_path / "nope.json")], str(out), progress=False)
    assert st.errors == 1
    assert "nope.json" in _lines(out)[0]["error"]


def test_bad_device_count_is_refused(tmp_path):
    with pytest.raises(ValueError, match="local device"):
        score_files([os.path.join(REF, SMALL[0])], str(tmp_path / "r.jsonl"), devices=99, progress=False)


def test_compiled_buckets_are_not_merged_away(monkeypatch, tmp_path):
    """A bucket whose batched solver is compiled already (here: in this
    process) is solved in its own shape, not padded into a larger bucket;
    a bucket with nothing compiled merges as before."""
    from stablelego_jax import batch
    from stablelego_jax.batch import analyze_many, compiled_ready, solve_units
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.solvers import compiled, ipm
    from stablelego_jax.solvers.problem import solve_plan

    # 96 small layouts (moving them costs more than a load, less than a compile), four larger
    lays = [stairs(3)] * 96 + [tower(k) for k in range(20, 24)]
    loaded = [(i, lay, compile_layout(lay, Params())) for i, lay in enumerate(lays)]
    small = solve_plan(loaded[0][2])
    assert all(solve_plan(it[2]) != small for it in loaded[96:])
    ready = compiled_ready(Params(), ipm.IPMOptions(), 1)
    monkeypatch.setenv("STABLELEGO_CACHE_DIR", str(tmp_path))  # nothing on disk yet
    compiled.clear()
    units = solve_units(loaded, 64, 1, ready=ready)
    assert len({u.key for u in units}) == 1 and units[0].key != small  # merged: one compile instead of two
    analyze_many(lays[:96], "jax", merge=False)  # compiles the small bucket's solver
    ready = compiled_ready(Params(), ipm.IPMOptions(), 1)  # a new planning pass
    units = solve_units(loaded, 64, 1, ready=ready)
    keys = {u.key for u in units}
    assert small in keys and len(keys) == 2
    # within one pass a bucket is looked up once (solve_units, then auto_split)
    calls = []
    real = batch.available
    monkeypatch.setattr(batch, "available", lambda *a, **k: calls.append(a[0]) or real(*a, **k))
    again = solve_units(loaded, 64, 1, ready=ready)
    assert [(u.key, u.m_pad, len(u.items)) for u in again] == [(u.key, u.m_pad, len(u.items)) for u in units]
    assert calls == []
    compiled.clear()


def test_analyze_many_in_input_order_with_errors_in_place():
    """The in-memory batch engine behind score (and anything that scores many
    layouts at once): one answer per layout, in input order; a layout that
    cannot be compiled gets its exception, the others their Analysis."""
    import dataclasses

    from stablelego_jax.analysis import analyze_layout
    from stablelego_jax.batch import analyze_many
    from stablelego_jax.layout import LayoutError

    good = [stairs(3), tower(4), stairs(5)]
    s2 = stairs(2)
    broken = dataclasses.replace(s2, pos=np.zeros_like(s2.pos))  # overlapping bricks: compile fails
    res = analyze_many([good[0], broken, good[1], good[2]], "jax", batch=2)
    assert isinstance(res[1], LayoutError) and "overlaps" in str(res[1])
    for a, lay in zip([res[0], res[2], res[3]], good):
        ref = analyze_layout(lay, solver="exact")
        assert a.stable == ref.stable and a.weakest == ref.weakest and a.converged
        assert max(abs(a.scores[k] - ref.scores[k]) for k in ref.scores) < 1e-3
    ex = analyze_many(good, "exact")
    assert [a.stable for a in ex] == [a.stable for a in (res[0], res[2], res[3])]


def test_shards_are_disjoint_cover_everything_and_stable():
    from stablelego_jax.batch import in_shard, parse_shard

    names = [f"data/obj_{i:04d}.json" for i in range(300)] + [f"rows.jsonl#{i}" for i in range(100)]
    parts = [[p for p in names if in_shard(p, k, 3)] for k in range(3)]
    assert sorted(sum(parts, [])) == sorted(names)  # disjoint and complete
    assert all(60 < len(p) < 200 for p in parts)  # a hash, not a range
    assert parts[1] == [p for p in names if in_shard(p, *parse_shard("1/3"))]
    for bad in ("3/3", "-1/2", "1", "a/b", "0/0"):
        with pytest.raises(ValueError, match="--shard"):
            parse_shard(bad)


def test_exact_pool_gives_the_same_answers(tmp_path):
    from stablelego_jax.batch import POOL_MIN, analyze_many

    lays = [stairs(k) for k in range(1, 17)] + [tower(k) for k in range(1, 17)]
    assert len(lays) >= POOL_MIN
    one = analyze_many(lays, "exact", jobs=1)
    two = analyze_many(lays, "exact", jobs=2)
    for a, b in zip(one, two):
        assert (a.stable, a.weakest) == (b.stable, b.weakest)
        assert a.scores == b.scores


def test_two_shard_processes_split_a_folder(shard, tmp_path):
    """Two processes on one machine, each ``--shard K/2`` with its own
    results file: together every layout once, as one unsharded run."""
    inputs = [str(shard / "layouts"), str(shard / "dataset")]
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    outs = [tmp_path / f"part{k}.jsonl" for k in range(2)]
    procs = [subprocess.Popen([sys.executable, "-m", "stablelego_jax", "score", *inputs, "--out", str(o),
                               "--solver", "exact", "--quiet", "--shard", f"{k}/2"], env=env)
             for k, o in enumerate(outs)]
    assert [p.wait(timeout=300) for p in procs] == [0, 0]
    parts = [{r["file"]: r for r in _lines(o)} for o in outs]
    assert not set(parts[0]) & set(parts[1])
    whole = tmp_path / "whole.jsonl"
    assert main(["score", *inputs, "--out", str(whole), "--solver", "exact", "--quiet", "--jobs", "1"]) == 0
    ref = {r["file"]: r for r in _lines(whole)}
    assert {**parts[0], **parts[1]}.keys() == ref.keys()
    for f, r in {**parts[0], **parts[1]}.items():
        assert (r["stable"], r["weakest"], r["scores"]) == (ref[f]["stable"], ref[f]["weakest"], ref[f]["scores"])


def test_bad_shard_and_jobs_are_refused(tmp_path, capsys):
    for extra in (["--shard", "2/2"], ["--jobs", "0"]):
        assert main(["score", str(tmp_path), "--out", str(tmp_path / "r.jsonl"), *extra]) == 2
        assert "error: --" in capsys.readouterr().err
    assert not (tmp_path / "r.jsonl").exists()


def test_assign_units_keeps_a_bucket_together_unless_splitting_pays():
    from stablelego_jax.batch import SolveUnit, assign_units

    small = [SolveUnit(("dense", 8), 64, 8, 64, [None] * 64) for _ in range(4)]  # ~0.04 s each
    large = [SolveUnit(("layered", 20, 32), 512, 8, 16, [None] * 64) for _ in range(4)]  # ~28 s each
    assert all(u.seconds() < 1.0 for u in small) and all(u.seconds() > 8.0 for u in large)
    # the cheap bucket's pieces all go to the worker that is free (one compile);
    # compiling it on the busy worker too would not finish sooner
    assert assign_units(large[:1] + small, 2) == [0, 1, 1, 1, 1]
    assert sorted(assign_units(large, 2)) == [0, 0, 1, 1]  # splitting the costly bucket pays
    assert assign_units(small, 1) == [0, 0, 0, 0]


def test_next_unit_evens_out_the_end_of_a_run():
    """A worker whose queue is empty takes another worker's last unit: first
    of a shape it holds, then of a shape compiled elsewhere when enough is
    left to pay a load; never a shape nobody compiled, never the other's
    next unit, and its own queue first."""
    from stablelego_jax.batch import next_unit

    a, b, c = ("dense", 24), ("dense", 120), ("layered", 16, 16)
    shape = [a, b, b, a, c]  # units 0-4, with their estimated seconds
    secs = [1.0, 1.0, 1.0, 1.0, 3.0]
    q = [[], [0, 1, 2, 3]]
    assert next_unit(q, 0, shape, secs, {shape[1]}, {shape[1]}) == 2  # the last unit of a shape it holds
    assert q == [[], [0, 1, 3]]
    assert next_unit(q, 0, shape, secs, set(), set()) is None  # nothing compiled: nothing to take
    assert next_unit(q, 0, shape, secs, set(), {shape[0]}, load_s=1.0) is None  # 3 s left: not four loads
    assert next_unit(q, 0, shape, secs, set(), {shape[0]}) == 3  # loads of 0.15 s: one pays
    q = [[], [0, 4, 4, 3]]
    assert next_unit(q, 0, shape, secs, set(), {shape[0]}, load_s=1.0) == 3  # 8 s left: a load pays
    assert next_unit(q, 0, shape, secs, set(), {shape[0]}) is None  # the rest: shape c, compiled nowhere
    assert next_unit([[4], [0, 3]], 0, shape, secs, {shape[0]}, {shape[0]}) == 4  # its own queue first
    assert next_unit([[], [3]], 0, shape, secs, {shape[0]}, {shape[0]}) is None  # the other's next unit stays


def test_assign_units_charges_a_load_for_a_shape_on_disk():
    """A shape whose executable is on disk, or that another worker compiles
    first, costs a worker a load, not a compile: a cheap bucket's pieces
    spread once a worker falls behind; each worker solves its share of a
    shape compiled elsewhere after its own shapes."""
    from stablelego_jax.batch import SolveUnit, assign_units, worker_order

    class Timed(SolveUnit):  # bsz stands for the unit's seconds
        def seconds(self):
            return float(self.bsz)

    big = Timed(("layered", 16, 16), 512, 8, 11, [(0, None, None)])
    pieces = [Timed(("dense", 8), 64, 8, 2, [(k, None, None)]) for k in range(1, 8)]
    # a compile priced at 8 s: worker 1 compiles the pieces' shape and solves 6 of them (20 s);
    # worker 0 (11 s of solve, 8 s of compile) takes the 7th from disk: 11 + 8 + 2 + 0.15 < 20 + 2
    cold = assign_units([big] + pieces, 2, compile_s=8.0)
    assert cold == [0] + [1] * 6 + [0]
    asked = []
    warm = assign_units([big] + pieces, 2, compile_s=8.0, ready=lambda *a: asked.append(a[:4]) or True)
    assert warm == [0] + [1] * 6 + [0]
    assert asked[0] == (("layered", 16, 16), 512, 8, None)
    # worker 0 solves the big unit first, then the piece worker 1 compiled
    units = pieces + [big]  # given order: the 7th piece before the big unit
    where = assign_units(units, 2, compile_s=8.0)
    order = worker_order(units, where)
    assert sorted(order) == list(range(len(units)))
    on0 = [units[u] for u in order if where[u] == 0]
    assert on0[0] is big and all(u.key == ("dense", 8) for u in on0[1:]) and len(on0) == 2


def test_jax_pool_gives_the_same_answers(request):
    """``jobs=2``: the same batches solved in two worker processes give the
    same numbers as one process, bit for bit (in the shipped build: run at
    XLA's default optimisation)."""
    if rerun_at_shipping_xla(request):
        return
    from stablelego_jax.batch import POOL_MIN, analyze_many

    lays = [stairs(k) for k in range(1, 17)] + [tower(k) for k in range(1, 17)]
    assert len(lays) >= POOL_MIN
    one = analyze_many(lays, "jax", jobs=1)
    two = analyze_many(lays, "jax", jobs=2)
    for a, b in zip(one, two):
        assert (a.stable, a.weakest, a.converged, a.solver) == (b.stable, b.weakest, b.converged, b.solver)
        assert a.scores == b.scores
    # workers started ahead (as score starts them before reading): the pool
    # solves on them, the same answers, and leaves them running for the caller
    from stablelego_jax.batch import Workers

    with Workers(2) as workers:
        pids = {w.submit(os.getpid).result() for w in workers.pools}
        three = analyze_many(lays, "jax", jobs=2, workers=workers)
        assert {w.submit(os.getpid).result() for w in workers.pools} == pids
    assert len(pids) == 2 and os.getpid() not in pids
    assert [a.scores for a in three] == [a.scores for a in one]


def test_worker_counts_add_up_and_parent_counts_stay():
    """A worker's solver counters are added; the parent's file counts are its own."""
    st = ScoreStats(total=5, scored=4, solve_s=1.0, compiles=2)
    st.add_solver_counts(ScoreStats(total=99, scored=99, solve_s=0.5, compile_s=2.0, compiles=3,
                                    not_converged=1, retried=1))
    assert (st.total, st.scored) == (5, 4)
    assert (st.solve_s, st.compile_s, st.compiles, st.not_converged, st.retried) == (1.5, 2.0, 5, 1, 1)


def test_auto_split_gives_each_group_to_the_faster_solver(monkeypatch):
    """``solver="auto"``: a group of layouts that would share one compiled
    solver goes to HiGHS when its estimated time is below the interior
    point's (a compile included unless the executables are ready)."""
    from stablelego_jax import batch
    from stablelego_jax.batch import auto_split, solve_units
    from stablelego_jax.model import Params, compile_layout

    lays = [stairs(3)] * 8
    loaded = [(i, lay, compile_layout(lay, Params())) for i, lay in enumerate(lays)]
    units = solve_units(loaded, 64, 1, merge=False)
    assert len(units) == 1
    # a few small layouts: HiGHS' estimate is below even a warm interior point's (a load)
    few = solve_units(loaded[:4], 64, 1, merge=False)
    assert sum(batch.estimated_seconds(it[2]) for it in loaded[:4]) < few[0].seconds() + batch.LOAD_S
    for ready in (lambda *a: False, lambda *a: True):
        ex, jx = auto_split(few, ready)
        assert [it[0] for it in ex] == list(range(4)) and jx == []
    # HiGHS estimated at 2 s a layout: the interior point, compile included
    monkeypatch.setattr(batch, "estimated_seconds", lambda model: 2.0)
    ex, jx = auto_split(units, lambda *a: False, compile_s=8.0)
    assert ex == [] and jx == units
    # ... unless the compile costs more than HiGHS' 16 s
    ex, jx = auto_split(units, lambda *a: False, compile_s=60.0)
    assert len(ex) == 8 and jx == []
    assert auto_split(units, lambda *a: True, compile_s=60.0)[1] == units  # compiled: no compile to pay
    # on an accelerator the interior point's estimate is divided by the measured speedup:
    # HiGHS 8 x 1 s against the interior point's 10 s (CPU) or 10 s / 8 (GPU), compiled
    monkeypatch.setattr(batch, "estimated_seconds", lambda model: 1.0)
    monkeypatch.setattr(batch.SolveUnit, "seconds", lambda self: 10.0)
    assert auto_split(units, lambda *a: True)[1] == []
    monkeypatch.setattr(batch.jax, "default_backend", lambda: "gpu")
    assert batch.ACCELERATOR_SPEEDUP > 10.0 / (8.0 - batch.LOAD_S)
    assert auto_split(units, lambda *a: True)[1] == units
    assert auto_split(units, lambda *a: True, speedup=1.0)[1] == []
    # not compiled: an accelerator's compile (ACCELERATOR_COMPILE_S) is paid
    ex, jx = auto_split(units, lambda *a: False)
    assert (jx == units) == (10.0 / batch.ACCELERATOR_SPEEDUP + batch.ACCELERATOR_COMPILE_S < 8.0)


def test_auto_scores_small_layouts_with_highs_and_says_so(shard, tmp_path, capsys):
    """``score --solver auto`` on a few small layouts: HiGHS answers every
    one (no compile), each line says so, and the answers are the exact
    solver's."""
    out = tmp_path / "auto.jsonl"
    assert main(["score", str(shard / "layouts"), "--out", str(out), "--solver", "auto", "--quiet",
                 "--jobs", "1"]) == 0
    err = capsys.readouterr().err
    assert "compile 0.0 s (0 shapes)" in err and f"({len(SMALL)} given to HiGHS by --solver auto)" in err
    lines = _lines(out)
    assert len(lines) == len(SMALL) and all(r["solver"] == "exact" and "iters" not in r for r in lines)
    for r in lines:
        ex = analyze(r["file"], solver="exact")
        assert (r["stable"], r["weakest"]) == (ex.stable, ex.weakest)
        assert r["scores"] == pytest.approx(ex.scores, abs=1e-6)


def test_exact_solver_yields_each_layout_as_it_is_solved():
    """One process, the exact solver: a results line per layout as soon as
    it is solved (an interrupted run keeps what was done; the progress bar
    moves), not one list at the end of the chunk."""
    from stablelego_jax.batch import iter_analyses

    lays = [stairs(k) for k in range(1, 5)]
    it = iter_analyses(lays, "exact", jobs=1)
    first = next(it)
    assert [i for i, _ in first] == [0] and first[0][1].solver == "exact"
    assert [[i for i, _ in part] for part in it] == [[1], [2], [3]]


def test_pack_items_fill_the_bucket_and_cover_every_layout_once():
    from types import SimpleNamespace

    from stablelego_jax.batch import PACK_MOST, pack_items

    rng = np.random.default_rng(0)
    items = [(i, None, SimpleNamespace(n=int(rng.integers(1, 13)), m=int(rng.integers(5, 200))))
             for i in range(60)] + [(60 + i, None, SimpleNamespace(n=1, m=1)) for i in range(40)]
    crows = {it[0]: int(rng.integers(1, 20)) for it in items}
    packs = pack_items(items, 24, 1000, 120, crows)
    assert sorted(it[0] for p in packs for it in p) == list(range(100))
    for p in packs:
        assert 1 <= len(p) <= PACK_MOST
        assert sum(it[2].n for it in p) <= 24
        assert sum(it[2].m for it in p) <= 1000
        assert sum(crows[it[0]] for it in p) <= 120
    assert len(packs) < 40  # the 1-brick layouts share packs


def test_pack_items_is_first_fit_most_bricks_first():
    """The packs are those of a plain first fit over every pack opened (full packs skipped, not moved)."""
    from types import SimpleNamespace

    from stablelego_jax.batch import PACK_MOST, pack_items

    def first_fit(items, n, m_pad, c_pad, crows):
        packs = []
        for it in sorted(items, key=lambda it: -it[2].n):
            for p in packs:
                if (len(p) < PACK_MOST and sum(x[2].n for x in p) + it[2].n <= n
                        and sum(x[2].m for x in p) + it[2].m <= m_pad
                        and sum(crows[x[0]] for x in p) + crows[it[0]] <= c_pad):
                    p.append(it)
                    break
            else:
                packs.append([it])
        return packs

    for seed in range(20):
        rng = np.random.default_rng(seed)
        k = int(rng.integers(1, 300))
        items = [(i, None, SimpleNamespace(n=int(rng.integers(1, 25)), m=int(rng.integers(3, 400)))) for i in range(k)]
        crows = {it[0]: int(rng.integers(1, 40)) for it in items}
        n, m_pad, c_pad = int(rng.choice([16, 24, 40])), int(rng.integers(400, 2000)), int(rng.integers(40, 200))
        got = [[it[0] for it in p] for p in pack_items(items, n, m_pad, c_pad, crows)]
        assert got == [[it[0] for it in p] for p in first_fit(items, n, m_pad, c_pad, crows)], seed
    assert pack_items([], 24, 1000, 120, {}) == []


def _column_items(counts, seed=0):
    """Fake compiled layouts of a dense 16 bucket: ``counts`` {most columns: how many}."""
    from types import SimpleNamespace

    rng = np.random.default_rng(seed)
    items = []
    for top, k in counts.items():
        for _ in range(k):
            m = int(rng.integers(top // 2 + 1, top + 1))
            items.append((len(items), None, SimpleNamespace(n=int(rng.integers(9, 17)), m=m, group=np.zeros((16, 8)))))
    order = rng.permutation(len(items))
    return [items[i] for i in order], {it[0]: 2 + it[2].m // 40 for it in items}


def test_column_runs_cut_a_large_bucket_by_columns_and_keep_a_small_one_whole():
    """Every iteration passes over every padded column, so a bucket of many
    narrow layouts and a few wide ones is cut into runs padded to their own
    columns when the estimated solve time saved pays for the second
    compile; a short run is left whole (one compile), in its own order."""
    from stablelego_jax.batch import column_runs
    from stablelego_jax.solvers.problem import MIN_COLUMNS, rung

    key = ("dense", 16)
    items, crows = _column_items({200: 3000, 1000: 20})
    runs = column_runs(items, key, 64, 1, crows, cpu=True)
    assert len(runs) >= 2
    assert sorted(it[0] for r in runs for it in r) == sorted(it[0] for it in items)
    tops = [max(rung(it[2].m, MIN_COLUMNS) for it in r) for r in runs]
    lows = [min(rung(it[2].m, MIN_COLUMNS) for it in r) for r in runs]
    assert tops == sorted(tops) and all(hi < lo for hi, lo in zip(tops, lows[1:]))  # consecutive rungs
    assert tops[0] <= rung(200, MIN_COLUMNS) < tops[-1]
    few, crows_few = _column_items({200: 12, 1000: 2})
    assert column_runs(few, key, 64, 1, crows_few, cpu=True) == [few]


def test_column_runs_take_a_compiled_shape_where_it_costs_only_a_load():
    """A narrow shape compiled already (this process or the disk cache)
    costs a load, not a compile: a bucket too short to pay for a compile
    is still cut where its narrow layouts' shape is ready."""
    from stablelego_jax.batch import column_runs

    key = ("dense", 16)
    items, crows = _column_items({200: 200, 1000: 2})
    assert len(column_runs(items, key, 64, 1, crows, cpu=True)) == 1
    runs = column_runs(items, key, 64, 1, crows, ready=lambda k, m_pad, *a: m_pad <= 224, cpu=True)
    assert [len(r) for r in runs] == [200, 2]


def test_packed_small_layouts_get_the_answers_they_get_alone(monkeypatch):
    """Small layouts of a dense bucket are solved several to a problem
    (block diagonal); each gets the scores it gets solved alone."""
    import stablelego_jax.batch as batch
    from stablelego_jax.batch import analyze_many, solve_units
    from stablelego_jax.model import compile_layout

    # two larger stairs join the small layouts' bucket to dense 24, solved one problem at a time
    lays = [stairs(k) for k in range(1, 7)] + [tower(k) for k in range(1, 7)] + [stairs(18), stairs(22)]
    loaded = [(i, lay, compile_layout(lay)) for i, lay in enumerate(lays)]
    units = solve_units(loaded, 64, 1)
    assert any(u.pack for u in units)
    assert sorted(it[0] for u in units for it in u.items) == list(range(len(lays)))
    packed = analyze_many(lays, "jax", jobs=1)
    monkeypatch.setattr(batch, "PACK_MOST", 1)
    assert not any(u.pack for u in solve_units(loaded, 64, 1))
    alone = analyze_many(lays, "jax", jobs=1)
    for a, b in zip(packed, alone):
        assert (a.stable, a.weakest, a.converged, a.solver) == (b.stable, b.weakest, b.converged, b.solver)
        assert a.scores.keys() == b.scores.keys()
        assert max(abs(a.scores[k] - b.scores[k]) for k in a.scores) < 1e-6
        assert a.forces.shape == b.forces.shape
        assert a.objective == pytest.approx(b.objective, rel=1e-5, abs=1e-12)


def test_packed_layouts_of_very_different_weights_get_their_lone_answers():
    """Four extension layouts (pallets, a stack, a knob under a heavy load)
    packed into one problem: each layout's canonical term is normalised by
    its own weight (``member``), so each gets the answer it gets alone.
    Normalised by the pack's total weight, the light layouts' terms were
    ~1000x weaker and the pack stalled."""
    from stablelego_jax.analysis import analyze_layout
    from stablelego_jax.batch import SolveUnit, solve_unit
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.solvers import ipm

    names = ["pallet_stands.json", "pallet_top_moved.json", "stack8_moved.json", "lego_single_knob_load.json"]
    lays = [load_layout(os.path.join(EXAMPLES, "extensions", f)) for f in names]
    items = [(i, lay, compile_layout(lay)) for i, lay in enumerate(lays)]

    def run(unit):
        return dict(x for part in solve_unit(unit, Params(), ipm.IPMOptions(), 1, False, ScoreStats())
                    for x in part)

    packed = run(SolveUnit(("dense", 40), 1024, 40, 1, items, 128, pack=True))
    assert sorted(packed) == [0, 1, 2, 3]
    for it in items:
        a, alone = packed[it[0]], run(SolveUnit(("dense", 40), 1024, 40, 1, [it], 128))[it[0]]
        ex = analyze_layout(it[1], solver="exact")
        assert (a.solver, a.converged, alone.converged) == ("jax", True, True)
        assert max(abs(a.scores[k] - alone.scores[k]) for k in a.scores) < 1e-6
        assert (a.stable, a.weakest) == (ex.stable, ex.weakest)


def test_a_pack_that_does_not_converge_is_solved_layout_by_layout():
    """A pack left unconverged (here: at an iteration cap of 4) is solved
    again layout by layout, with the same compiled shape: each layout gets
    the answer of its lone solve."""
    from stablelego_jax.batch import SolveUnit, solve_unit
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.solvers import ipm

    lays = [stairs(3), tower(4), stairs(5)]
    items = [(i, lay, compile_layout(lay)) for i, lay in enumerate(lays)]
    opts = ipm.IPMOptions(max_iter=4)

    def run(unit):
        return dict(x for part in solve_unit(unit, Params(), opts, 1, False, ScoreStats()) for x in part)

    packed = run(SolveUnit(("dense", 24), 512, 40, 1, items, 64, pack=True))
    for it in items:
        a, alone = packed[it[0]], run(SolveUnit(("dense", 24), 512, 40, 1, [it], 64))[it[0]]
        assert not a.converged and a.iters == alone.iters == 4
        np.testing.assert_array_equal(a.forces, alone.forces)
        assert a.time_s > 0


@pytest.mark.usefixtures("x64")
def test_a_batch_of_dense_problems_solves_them_as_they_are_solved_alone():
    """batch_solver_fn: dense problems (planned with support tables) in a
    batch of two (the product of the rank-one terms) and one at a time (cut,
    the supports' pieces) give the same forces and objectives."""
    import jax

    from stablelego_jax.batch import batch_solver_fn
    from stablelego_jax.model import Params, compile_layout
    from stablelego_jax.solvers import ipm
    from stablelego_jax.solvers.problem import plan_problem, stack_problems

    probs = [plan_problem(compile_layout(lay), ("dense", 48), 1024, 32, 64)[1] for lay in (stairs(6), tower(5))]
    assert all(p.supports is not None for p in probs)
    fn = jax.jit(batch_solver_fn(Params(), ipm.IPMOptions(), 1))
    both = fn(*[a for a in stack_problems(probs) if a is not None])
    for i, p in enumerate(probs):
        one = fn(*[a[None] for a in p if a is not None])
        np.testing.assert_allclose(np.asarray(both[0][i]), np.asarray(one[0][0]), rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(float(both[5][i]), float(one[5][0]), rtol=1e-9, atol=1e-12)


def test_a_pool_that_would_hang_gets_batches_of_one_and_the_same_answers(monkeypatch):
    """On a jaxlib whose batched LAPACK calls deadlock a larger XLA pool
    (stablelego_jax.blas), a CPU solves one layout a call (tiny layouts
    batch 8 otherwise), with the answers of the batched solve; a batch of two
    on such a pool is an error, not a hang."""
    from stablelego_jax import batch
    from stablelego_jax.batch import analyze_many
    from stablelego_jax.blas import check_batched_linalg

    lays = [stairs(2), stairs(3), tower(2), tower(3)] * 2
    tiny = plan_bytes(("dense", 8), 80)
    assert batch_sizes(tiny, 64, 1, cpu=True) >= 2
    plain = analyze_many(lays, solver="jax", jobs=1, merge=False)
    monkeypatch.setattr(batch, "batched_linalg_hangs", lambda *a, **k: True)
    assert batch_sizes(tiny, 64, 1, cpu=True) == 1
    assert batch_sizes(tiny, 64, 1, cpu=False) >= 2  # an accelerator has no such kernels
    single = analyze_many(lays, solver="jax", jobs=1, merge=False)
    for a, b in zip(single, plain):
        assert a.stable == b.stable and a.weakest == b.weakest
        np.testing.assert_allclose([a.scores[k] for k in a.scores], [b.scores[k] for k in a.scores], atol=1e-9)
    with pytest.raises(RuntimeError, match="deadlock such a pool on a batch of 2"):
        check_batched_linalg(2, {"PJRT_NPROC": "2"}, "0.10.2")
