"""The command line: ``stablelego analyze`` (stablelego_jax.cli.main, run in-process)."""
import json
import os
import shutil

import pytest

from stablelego_jax import cli

HERE = os.path.dirname(__file__)
EXAMPLES = os.path.join(HERE, "..", "examples")
STABLELEGO = os.path.join(EXAMPLES, "stablelego")
BRICKGPT = os.path.join(EXAMPLES, "brickgpt")
from conftest import SHARED_REF  # noqa: E402

STAIR_19 = os.path.join(STABLELEGO, "stair_19.json")
STAIR_20 = os.path.join(STABLELEGO, "stair_20.json")
GUITAR = os.path.join(BRICKGPT, "guitar.txt")

JSON_KEYS = {"file", "stable", "weakest", "scores", "n_bricks", "solver", "converged", "time_s"}
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _example(name):
    """A reference layout: the bundled copy, else the shared one, else skip."""
    for d in (STABLELEGO, SHARED_REF):
        p = os.path.join(d, name)
        if os.path.isfile(p):
            return p
    pytest.skip(f"{name} not found in examples/ or shared/")


def _run(capsys, *args):
    rc = cli.main(["analyze", *args])
    out, err = capsys.readouterr()
    return rc, out, err


def _json_lines(out):
    lines = out.splitlines()
    assert all(ln.strip() for ln in lines)
    return [json.loads(ln) for ln in lines]


def _bad_json(tmp_path, name="bad.json"):
    p = tmp_path / name
    p.write_text('{"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},'
                 ' "2": {"x": 1, "y": 0, "z": 0, "brick_id": 2, "ori": 0}}')  # overlapping bricks
    return str(p)


def _is_png(path):
    with open(path, "rb") as fh:
        return fh.read(8) == PNG_MAGIC


def _pngs(d):
    return sorted(f for f in os.listdir(d) if f.endswith(".png"))


# ---------------------------------------------------------------------------
# readable output


def test_summary_output(capsys):
    rc, out, err = _run(capsys, STAIR_20, STAIR_19, "--solver", "exact")
    assert rc == 0  # an unstable layout is a result, not an error
    blocks = out.split(STAIR_19)
    assert len(blocks) == 2
    s20, s19 = blocks
    assert STAIR_20 in s20 and "UNSTABLE" in s20
    assert "20 bricks" in s20 and "solver exact" in s20 and "converged" in s20
    assert "weakest brick '2'" in s20
    assert "failing bricks (1): '2'" in s20
    assert "STABLE" in s19 and "UNSTABLE" not in s19 and "19 bricks" in s19
    assert "failing" not in s19
    assert "error" not in err


def test_summary_text_layout(capsys):
    rc, out, _ = _run(capsys, GUITAR, "--solver", "exact")
    assert rc == 0
    assert out.startswith(GUITAR + ": ")
    assert "weakest brick" in out


# ---------------------------------------------------------------------------
# --json


def test_json_lines(capsys):
    files = [STAIR_20, STAIR_19, GUITAR]
    rc, out, err = _run(capsys, *files, "--solver", "exact", "--json")
    assert rc == 0
    recs = _json_lines(out)
    assert len(recs) == len(files)
    for f, r in zip(files, recs):
        assert set(r) == JSON_KEYS
        assert r["file"] == f
        assert r["solver"] == "exact"
        assert r["converged"] is True
        assert isinstance(r["stable"], bool)
        assert isinstance(r["time_s"], float) and r["time_s"] >= 0
        assert isinstance(r["n_bricks"], int) and r["n_bricks"] == len(r["scores"])
        assert r["weakest"] in r["scores"]
        assert r["scores"][r["weakest"]] == max(r["scores"].values())
        assert r["stable"] == all(v < 1 for v in r["scores"].values())
    with open(STAIR_20) as fh:
        assert list(recs[0]["scores"]) == list(json.load(fh))  # the file's keys, in file order
    assert recs[0]["n_bricks"] == 20 and recs[1]["n_bricks"] == 19


def test_stairs_exact(capsys):
    rc, out, _ = _run(capsys, STAIR_20, STAIR_19, "--solver", "exact", "--json")
    assert rc == 0
    r20, r19 = _json_lines(out)
    assert r20["stable"] is False and r20["weakest"] == "2"
    assert r20["scores"]["2"] >= 1.0
    assert r19["stable"] is True
    assert max(r19["scores"].values()) < 1.0


def test_stairs_jax_solver_and_the_auto_default(capsys):
    """``--solver jax`` answers with the interior point; the default
    (``auto``) gives these small layouts to HiGHS, faster than a compile,
    with the same answers."""
    s20, s19 = _example("stair_20.json"), _example("stair_19.json")
    rc, out, _ = _run(capsys, s20, s19, "--json", "--solver", "jax")
    assert rc == 0
    r20, r19 = _json_lines(out)
    assert r20["solver"] == "jax" and r19["solver"] == "jax"
    assert r20["stable"] is False and r20["weakest"] == "2"
    assert r19["stable"] is True
    rc, out, _ = _run(capsys, s20, s19, "--json")
    assert rc == 0
    a20, a19 = _json_lines(out)
    assert a20["solver"] == "exact" and a19["solver"] == "exact"
    assert (a20["stable"], a20["weakest"], a19["stable"]) == (False, "2", True)
    for a, j in ((a20, r20), (a19, r19)):
        assert a["scores"] == pytest.approx(j["scores"], abs=1e-3)


def test_dataset_folder_keyed_by_argument(tmp_path, capsys):
    d = tmp_path / "object_0001"
    d.mkdir()
    shutil.copy(STAIR_19, d / "task_graph.json")
    rc, out, _ = _run(capsys, str(d), "--solver", "exact", "--json")
    assert rc == 0
    (r,) = _json_lines(out)
    assert r["file"] == str(d)
    assert r["stable"] is True and r["n_bricks"] == 19


def test_custom_library(tmp_path, capsys):
    lib = tmp_path / "lib.json"
    lib.write_text(json.dumps({"7": {"height": 1, "width": 2, "mass": 0.001}}))
    lay = tmp_path / "l.json"
    lay.write_text(json.dumps({"a": {"x": 0, "y": 0, "z": 0, "brick_id": 7, "ori": 1},
                               "b": {"x": 0, "y": 0, "z": 1, "brick_id": 7, "ori": 0}}))
    rc, out, _ = _run(capsys, str(lay), "--library", str(lib), "--solver", "exact", "--json")
    assert rc == 0
    (r,) = _json_lines(out)
    assert r["n_bricks"] == 2 and r["stable"] is True
    # without the library, id 7 is unknown
    rc, out, _ = _run(capsys, str(lay), "--solver", "exact", "--json")
    assert rc == 1
    (r,) = _json_lines(out)
    assert set(r) == {"file", "error"} and "brick_id" in r["error"]


# ---------------------------------------------------------------------------
# errors: reported per file, the others still run, non-zero exit


def _bad_files(tmp_path):
    garbled = tmp_path / "garbled.txt"
    garbled.write_text("2x2 (1.2.3,0,0)\n")
    dup = tmp_path / "dup.json"
    dup.write_text('{"1": {"x": 0, "y": 0, "z": 0, "brick_id": 2, "ori": 0},'
                   ' "1": {"x": 5, "y": 0, "z": 0, "brick_id": 2, "ori": 0}}')
    broken = tmp_path / "broken.json"
    broken.write_text('{"1": {"x": 0,')
    return [_bad_json(tmp_path), str(garbled), str(dup), str(broken), str(tmp_path / "missing.json")]


def test_bad_file_among_good_json(tmp_path, capsys):
    bad = _bad_json(tmp_path)
    rc, out, _ = _run(capsys, STAIR_19, bad, STAIR_20, "--solver", "exact", "--json")
    assert rc != 0
    recs = _json_lines(out)
    assert len(recs) == 3
    assert set(recs[1]) == {"file", "error"}
    assert recs[1]["file"] == bad
    assert bad in recs[1]["error"] and "overlap" in recs[1]["error"]
    assert set(recs[0]) == JSON_KEYS and recs[0]["stable"] is True
    assert set(recs[2]) == JSON_KEYS and recs[2]["weakest"] == "2"


@pytest.mark.parametrize("which", range(5), ids=["overlap", "garbled-text", "duplicate-key", "broken-json",
                                                  "missing"])
def test_each_kind_of_bad_file(tmp_path, capsys, which):
    bad = _bad_files(tmp_path)[which]
    rc, out, _ = _run(capsys, bad, GUITAR, "--solver", "exact", "--json")
    assert rc == 1
    r_bad, r_good = _json_lines(out)
    assert r_bad == {"file": bad, "error": r_bad["error"]}
    assert bad in r_bad["error"]
    assert set(r_good) == JSON_KEYS


def test_bad_file_among_good_readable(tmp_path, capsys):
    bad = _bad_json(tmp_path)
    rc, out, err = _run(capsys, bad, STAIR_19, "--solver", "exact")
    assert rc == 1
    assert STAIR_19 in out and "STABLE" in out
    assert bad not in out
    assert err.startswith("error: ") and bad in err and "overlap" in err


def test_all_bad(tmp_path, capsys):
    bad = _bad_files(tmp_path)
    rc, out, _ = _run(capsys, *bad, "--solver", "exact", "--json")
    assert rc == 1
    recs = _json_lines(out)
    assert [r["file"] for r in recs] == bad
    assert all(set(r) == {"file", "error"} for r in recs)


def test_unexpected_exception_is_reported_per_file(tmp_path, capsys, monkeypatch):
    import stablelego_jax.analysis as api
    import stablelego_jax.batch as batch

    real = api.analyze_layout

    def flaky(layout, **kw):
        if layout.source == STAIR_20:
            raise RuntimeError("solver exploded")
        return real(layout, **kw)

    def batch_fails(*a, **kw):
        raise RuntimeError("solver exploded")

    # the batched call fails; analyze solves each file on its own, and only STAIR_20 fails
    monkeypatch.setattr(batch, "analyze_many", batch_fails)
    monkeypatch.setattr(api, "analyze_layout", flaky)
    rc, out, _ = _run(capsys, STAIR_20, STAIR_19, "--solver", "exact", "--json")
    assert rc == 1
    r_bad, r_good = _json_lines(out)
    assert r_bad["file"] == STAIR_20 and "RuntimeError" in r_bad["error"] and "solver exploded" in r_bad["error"]
    assert r_good["stable"] is True


def test_not_converged_warns_on_stderr(capsys, monkeypatch):
    import stablelego_jax.analysis as api

    real = api.analyze

    def unconverged(path, **kw):
        a = real(path, **kw)
        a.converged = False
        a.gap = 0.5
        return a

    monkeypatch.setattr(api, "analyze", unconverged)
    rc, out, err = _run(capsys, STAIR_19, "--solver", "exact", "--json")
    assert rc == 0
    (r,) = _json_lines(out)  # stdout stays one clean JSON line
    assert r["converged"] is False
    assert "warning" in err and STAIR_19 in err and "converge" in err


@pytest.mark.parametrize("argv", [[], ["analyze"], ["analyze", "x.json", "--solver", "cvx"], ["frobnicate"]])
def test_usage_errors(capsys, argv):
    with pytest.raises(SystemExit) as ei:
        cli.main(argv)
    assert ei.value.code == 2
    assert "usage" in capsys.readouterr().err


# ---------------------------------------------------------------------------
# --png


def test_png_one_file(tmp_path, capsys):
    png = str(tmp_path / "out.png")
    rc, out, _ = _run(capsys, STAIR_20, "--solver", "exact", "--png", png)
    assert rc == 0
    assert _is_png(png)
    assert os.listdir(tmp_path) == ["out.png"]  # no temporary files left
    assert png in out


def test_png_one_file_json_names_it(tmp_path, capsys):
    png = str(tmp_path / "g.png")
    rc, out, _ = _run(capsys, GUITAR, "--solver", "exact", "--png", png, "--json")
    assert rc == 0
    (r,) = _json_lines(out)
    assert JSON_KEYS <= set(r) and r["png"] == png
    assert _is_png(png)


def test_png_one_file_into_existing_folder(tmp_path, capsys):
    rc, _, _ = _run(capsys, STAIR_19, "--solver", "exact", "--png", str(tmp_path))
    assert rc == 0
    assert _pngs(tmp_path) == ["stair_19.png"]
    assert _is_png(tmp_path / "stair_19.png")


def test_png_folder_for_several_files(tmp_path, capsys):
    d = tmp_path / "maps"  # created on demand
    rc, out, _ = _run(capsys, STAIR_20, STAIR_19, GUITAR, "--solver", "exact", "--png", str(d), "--json")
    assert rc == 0
    assert _pngs(d) == ["guitar.png", "stair_19.png", "stair_20.png"]
    assert sorted(os.listdir(d)) == _pngs(d)
    for name in _pngs(d):
        assert _is_png(d / name)
    assert [r["png"] for r in _json_lines(out)] == [str(d / n) for n in ("stair_20.png", "stair_19.png",
                                                                         "guitar.png")]


def test_png_same_stem_does_not_overwrite(tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    shutil.copy(STAIR_19, a / "s.json")
    shutil.copy(STAIR_20, b / "s.json")
    d = tmp_path / "maps"
    rc, out, _ = _run(capsys, str(a / "s.json"), str(b / "s.json"), "--solver", "exact", "--png", str(d), "--json")
    assert rc == 0
    assert _pngs(d) == ["s-2.png", "s.png"]
    assert [r["png"] for r in _json_lines(out)] == [str(d / "s.png"), str(d / "s-2.png")]


def test_failing_file_leaves_no_png(tmp_path, capsys):
    bad = _bad_json(tmp_path, "broken_layout.json")
    d = tmp_path / "maps"
    rc, out, _ = _run(capsys, bad, STAIR_19, "--solver", "exact", "--png", str(d), "--json")
    assert rc == 1
    assert _pngs(d) == ["stair_19.png"]
    assert os.listdir(d) == ["stair_19.png"]
    r_bad, r_good = _json_lines(out)
    assert "png" not in r_bad and r_good["png"] == str(d / "stair_19.png")


def test_failing_single_file_leaves_no_png(tmp_path, capsys):
    bad = _bad_json(tmp_path)
    png = tmp_path / "out.png"
    rc, _, err = _run(capsys, bad, "--solver", "exact", "--png", str(png))
    assert rc == 1
    assert not png.exists()
    assert os.listdir(tmp_path) == ["bad.json"]
    assert bad in err


def test_a_removed_solver_is_a_usage_error_saying_what_replaces_it(capsys):
    """``--solver admm`` (removed in version 0.3) is refused before anything
    is read, with one line naming what to use instead."""
    for cmd in (["analyze", STAIR_20], ["score", STAIR_20, "--out", "never-written.jsonl"], ["sequence", STAIR_20]):
        with pytest.raises(SystemExit) as e:
            cli.main([*cmd, "--solver", "admm"])
        assert e.value.code == 2
        err = capsys.readouterr().err
        assert "removed in version 0.3" in err and "use jax" in err
    assert not os.path.exists("never-written.jsonl")


def test_help_and_usage_errors_import_no_jax():
    """``stablelego --help``, a command's ``--help`` and a usage error end
    before anything imports JAX (the package's promise: help stays fast)."""
    import subprocess
    import sys

    code = ("import sys\n"
            "from stablelego_jax.cli import main\n"
            "for argv in (['--help'], ['analyze', '--help'], ['score', '--no-such-option']):\n"
            "    try:\n"
            "        main(argv)\n"
            "    except SystemExit:\n"
            "        pass\n"
            "print('jax' in sys.modules)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=os.path.join(os.path.dirname(__file__), ".."))
    assert r.returncode == 0 and r.stdout.strip().splitlines()[-1] == "False", r.stderr[-2000:]
