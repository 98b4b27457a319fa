"""Issue 20: errors name the file at fault, nothing a user wrote is lost,
Ctrl-C ends cleanly, multi-output commands are all or nothing, limits come
before allocations, and an unconverged JAX run is never reported as a label."""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from stablelego_jax import cli
from stablelego_jax.batch import read_results

HERE = os.path.dirname(__file__)
ROOT = os.path.join(HERE, "..")
STABLELEGO = os.path.join(ROOT, "examples", "stablelego")
STAIR_19 = os.path.join(STABLELEGO, "stair_19.json")
ONE = {"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0}}


def _write(path, obj):
    path.write_text(json.dumps(obj))
    return str(path)


def _run(capsys, *argv):
    rc = cli.main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def _one_line(err):
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


# ------------------------------------------------------------------ library files


@pytest.mark.parametrize("cmd", ["analyze", "export", "score"])
@pytest.mark.parametrize("kind", ["binary", "huge"])
def test_bad_library_is_named_not_the_layout(tmp_path, capsys, cmd, kind):
    lay = _write(tmp_path / "lay.json", ONE)
    lib = tmp_path / "lib.json"
    if kind == "binary":
        lib.write_bytes(bytes(range(256)) * 4)
    else:
        lib.write_text(json.dumps({"2": {"height": 100000, "width": 2, "mass": 0.001}}))
    argv = {"analyze": ["analyze", lay, "--solver", "exact"],
            "export": ["export", lay, "--json", str(tmp_path / "o.json")],
            "score": ["score", lay, "--out", str(tmp_path / "r.jsonl"), "--solver", "exact", "--quiet"]}[cmd]
    rc, out, err = _run(capsys, *argv, "--library", str(lib))
    line = _one_line(err)
    assert rc == 2 and out == ""
    assert line.startswith(f"error: {lib}: ") and "lay.json" not in line
    assert ("UTF-8" in line) if kind == "binary" else ("100000" in line and "too large" in line)
    assert not (tmp_path / "o.json").exists() and not (tmp_path / "r.jsonl").exists()


# ------------------------------------------------------------------ score inputs and results file


@pytest.mark.parametrize("content", [None, "README.md"])
def test_score_folder_without_layouts_is_an_error(tmp_path, capsys, content):
    d = tmp_path / "in"
    d.mkdir()
    if content:
        (d / content).write_text("# not a layout\n")
    rc, out, err = _run(capsys, "score", str(d), "--out", str(tmp_path / "r.jsonl"), "--solver", "exact", "--quiet")
    line = _one_line(err)
    assert rc == 2 and str(d) in line and "no layouts" in line
    assert not (tmp_path / "r.jsonl").exists()


def test_score_unreadable_folder_gets_an_error_line_and_exit_1(tmp_path, capsys, monkeypatch):
    d = tmp_path / "in"
    (d / "ok").mkdir(parents=True)
    (d / "locked").mkdir()
    _write(d / "ok" / "a.json", ONE)
    real_walk = os.walk

    def walk(top, onerror=None, **kw):  # root reads every folder: simulate the permission error
        for root, dirs, files in real_walk(top, onerror=onerror, **kw):
            if root.endswith("locked"):
                onerror(PermissionError(13, "Permission denied", root))
                dirs[:] = []
                continue
            yield root, dirs, files

    real_listdir = os.listdir
    monkeypatch.setattr(os, "walk", walk)
    monkeypatch.setattr(os, "listdir", lambda p=".": (_ for _ in ()).throw(PermissionError(13, "Permission denied", p))
                        if str(p).endswith("locked") else real_listdir(p))
    out = tmp_path / "r.jsonl"
    rc, _, err = _run(capsys, "score", str(d), "--out", str(out), "--solver", "exact", "--quiet")
    assert rc == 1
    recs = read_results(str(out))
    assert set(recs) == {str(d / "locked"), str(d / "ok" / "a.json")}
    assert "cannot read folder" in recs[str(d / "locked")]["error"]
    assert "1 errors" in err


def test_score_refuses_out_that_is_not_ours(tmp_path, capsys):
    lay = _write(tmp_path / "lay.json", ONE)
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\nline two\n")
    rc, _, err = _run(capsys, "score", lay, "--out", str(notes), "--solver", "exact", "--quiet")
    line = _one_line(err)
    assert rc == 2 and str(notes) in line and "not a results file" in line
    assert notes.read_text() == "my notes\nline two\n"  # untouched
    # a single line without a newline is not taken for a torn result line either
    notes.write_text("my notes")
    assert _run(capsys, "score", lay, "--out", str(notes), "--solver", "exact", "--quiet")[0] == 2
    assert notes.read_text() == "my notes"
    binary = tmp_path / "bin.jsonl"
    binary.write_bytes(b"\xff\xfe\x00junk" * 10)
    rc, _, err = _run(capsys, "score", lay, "--out", str(binary), "--solver", "exact", "--quiet")
    assert rc == 2 and str(binary) in _one_line(err)
    assert binary.read_bytes() == b"\xff\xfe\x00junk" * 10
    # ours is recognised and appended to
    ours = tmp_path / "r.jsonl"
    assert _run(capsys, "score", lay, "--out", str(ours), "--solver", "exact", "--quiet")[0] == 0
    lay2 = _write(tmp_path / "lay2.json", ONE)
    assert _run(capsys, "score", lay, lay2, "--out", str(ours), "--solver", "exact", "--quiet")[0] == 0
    assert set(read_results(str(ours))) == {lay, lay2}


def test_ctrl_c_during_score_one_line_exit_130_resumable(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    for i in range(300):
        _write(d / f"l{i:03d}.json", {"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},
                                      "2": {"x": i % 3, "y": 0, "z": 1, "brick_id": 2, "ori": 0}})
    out = tmp_path / "r.jsonl"
    env = dict(os.environ, PYTHONPATH=os.path.abspath(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    argv = [sys.executable, "-m", "stablelego_jax", "score", str(d), "--out", str(out), "--solver", "exact",
            "--quiet"]
    # SIGINT at its default in the child, as in a terminal (a shell's background job starts
    # with it ignored, and Python then never raises KeyboardInterrupt)
    p = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    t_end = time.time() + 120
    while time.time() < t_end and p.poll() is None and (not out.exists() or out.stat().st_size < 2000):
        time.sleep(0.05)
    assert p.poll() is None, "finished before it could be interrupted"
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130
    assert _one_line(err) == "stablelego score: interrupted (rerun the same command to resume)"
    n_done = len(read_results(str(out)))  # every complete line is a result; a torn one is dropped
    assert 0 < n_done < 300
    assert cli.main(argv[3:]) == 0
    lines = [json.loads(ln) for ln in out.read_text().splitlines()]
    assert sorted(r["file"] for r in lines) == sorted(str(d / f"l{i:03d}.json") for i in range(300))


# ------------------------------------------------------------------ all-or-nothing outputs


def test_export_writes_nothing_when_one_output_cannot_be_written(tmp_path, capsys):
    a, b = tmp_path / "a.ldr", tmp_path / "missing" / "x.json"
    rc, out, err = _run(capsys, "export", STAIR_19, "--ldr", str(a), "--json", str(b))
    line = _one_line(err)
    assert rc == 1 and out == "" and str(b) in line and ".tmp" not in line
    assert sorted(os.listdir(tmp_path)) == []


def test_export_failing_writer_leaves_nothing_and_names_the_users_path(tmp_path, capsys):
    lay = _write(tmp_path / "load.json", {"1": {"x": 0, "y": 0, "z": 0, "brick_id": 1, "ori": 0}})
    a, t = tmp_path / "a.ldr", tmp_path / "b.txt"
    rc, _, err = _run(capsys, "export", lay, "--ldr", str(a), "--txt", str(t))  # the load block has no text form
    line = _one_line(err)
    assert rc == 1 and str(t) in line and ".tmp" not in line
    assert sorted(os.listdir(tmp_path)) == ["load.json"]


def test_repair_png_into_missing_folder_writes_nothing(tmp_path, capsys):
    out = tmp_path / "r.json"
    png = tmp_path / "missing" / "dir" / "x.png"
    rc, _, err = _run(capsys, "repair", os.path.join(STABLELEGO, "stair_20.json"), "--out", str(out),
                      "--png", str(png))
    line = _one_line(err)
    assert rc == 1 and str(png) in line and "does not exist" in line
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------------ inputs


def test_named_pipe_is_refused(tmp_path, capsys):
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    rc, _, err = _run(capsys, "analyze", str(fifo), "--solver", "exact")
    line = _one_line(err)
    assert rc == 1 and str(fifo) in line and "named pipe" in line
    lib = tmp_path / "lib.json"
    os.mkfifo(lib)
    rc, _, err = _run(capsys, "analyze", STAIR_19, "--solver", "exact", "--library", str(lib))
    assert rc == 2 and "named pipe" in _one_line(err)


def test_far_apart_bricks_within_limits_are_accepted(tmp_path, capsys):
    from stablelego_jax.layout import MAX_COORD

    lay = _write(tmp_path / "far.json", {
        "a": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},
        "b": {"x": MAX_COORD, "y": MAX_COORD, "z": 0, "brick_id": 2, "ori": 0},
        "c": {"x": MAX_COORD, "y": MAX_COORD, "z": 1, "brick_id": 2, "ori": 0}})
    rc, out, err = _run(capsys, "analyze", lay, "--solver", "exact", "--json")
    assert rc == 0, err
    rec = json.loads(out)
    assert rec["stable"] and set(rec["scores"]) == {"a", "b", "c"}


def test_sparse_model_matches_the_near_layout():
    """The far layout's force model is the near one's, shifted: same columns and coefficients."""
    import dataclasses

    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.model import compile_layout

    near = load_layout(STAIR_19)
    far = dataclasses.replace(near, pos=near.pos + [60000, 50000, 0])
    a, b = compile_layout(near), compile_layout(far)
    assert a.m == b.m
    np.testing.assert_array_equal(a.col_brick, b.col_brick)
    np.testing.assert_allclose(a.col_coef[:, :, :3], b.col_coef[:, :, :3])
    np.testing.assert_allclose(b.col_coef[:, :, 3:], a.col_coef[:, :, 3:], atol=1e-12)


def test_generate_grid_limit_before_allocating(tmp_path, capsys):
    from stablelego_jax.generate.mesh import MAX_GRID

    rc, _, err = _run(capsys, "generate", "x.stl", "--out", str(tmp_path / "o"), "--grid", "100000")
    assert rc == 2 and str(MAX_GRID) in _one_line(err)
    assert not (tmp_path / "o").exists()


def test_junk_stl_clear_error_without_optional_packages(tmp_path, monkeypatch):
    from stablelego_jax.generate.mesh import MeshError, load_mesh

    monkeypatch.setitem(sys.modules, "charset_normalizer", None)  # as on an install without it
    junk = tmp_path / "junk.stl"
    junk.write_bytes(b"solid x\n" + bytes(range(128, 256)) * 8)
    with pytest.raises(MeshError) as e:
        load_mesh(str(junk))
    assert str(e.value).startswith(str(junk)) and "charset" not in str(e.value)
    # a binary STL whose free-text header is not UTF-8 is read
    tri = np.array([[0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0]], "<f4").tobytes() + b"\0\0"
    ok = tmp_path / "hdr.stl"
    ok.write_bytes(bytes([0xFF, 0xFE]) * 40 + (1).to_bytes(4, "little") + tri)
    assert len(load_mesh(str(ok)).faces) == 1


def test_ply_triangle_strips_are_read(tmp_path):
    from stablelego_jax.generate.mesh import load_mesh, voxelize

    verts = "\n".join(f"{x} {y} {z}" for z in (0, 1) for y in (0, 1) for x in (0, 1))
    ply = tmp_path / "cube.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\n"
                   "property float z\nelement tristrips 1\nproperty list int int vertex_indices\nend_header\n"
                   f"{verts}\n14 0 1 2 3 7 1 5 0 4 2 6 7 4 5\n")
    mesh = load_mesh(str(ply))
    assert len(mesh.faces) == 12 and mesh.is_watertight
    assert voxelize(str(ply), grid=4).vox.all()  # a solid cube


# ------------------------------------------------------------------ unconverged JAX runs


def test_unconverged_jax_run_is_solved_again_and_says_by_whom(tmp_path, capsys):
    """A 100 kg load on brick '6' of stick_heavy stops the interior point
    unconverged (it stalls before its cap; 10 kg did so until the proximal
    term shrank): the answer comes from the exact solver and the line says so."""
    from stablelego_jax.analysis import analyze

    raw = json.load(open(os.path.join(STABLELEGO, "stick_heavy.json")))
    raw["6"]["mass"] = 100.0
    lay = _write(tmp_path / "heavy.json", raw)
    raw_jax = analyze(lay, solver="jax", fallback=False)
    assert not raw_jax.converged  # the case this test is about
    exact = analyze(lay, solver="exact")
    rc, out, err = _run(capsys, "analyze", lay, "--json", "--solver", "jax")
    rec = json.loads(out)
    assert rc == 0 and rec["converged"] is True and rec["solver"] == "exact"
    assert rec["retried"] and rec["retried"][0].startswith("jax")
    assert rec["stable"] == exact.stable and rec["weakest"] == exact.weakest
    assert "not converge" not in err
    res = tmp_path / "r.jsonl"
    rc, _, err = _run(capsys, "score", lay, "--out", str(res), "--quiet", "--solver", "jax")
    (line,) = read_results(str(res)).values()
    assert rc == 0 and line["solver"] == "exact" and line["retried"] and line["converged"]
    assert "0 not converged (1 solved again)" in err
