"""``stablelego generate`` and ``stablelego export`` (run in-process)."""
import json
import os

import numpy as np
import pytest
import trimesh

from stablelego_jax.formats.dataset import read_object
from stablelego_jax import cli, load_layout
from stablelego_jax.formats.ldraw import read_ldr

HERE = os.path.dirname(os.path.abspath(__file__))
GUITAR = os.path.join(HERE, "..", "examples", "brickgpt", "guitar.txt")


def _meshes(tmp_path):
    a = tmp_path / "meshes" / "block.stl"
    b = tmp_path / "meshes" / "tall.obj"
    c = tmp_path / "other" / "block.ply"  # same stem as a
    for p in (a, b, c):
        p.parent.mkdir(exist_ok=True)
    trimesh.creation.box(extents=(2.0, 1.0, 1.0)).export(a)
    trimesh.creation.box(extents=(1.0, 3.0, 1.0)).export(b)  # tall along y
    trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(c)
    return str(a), str(b), str(c)


def test_generate_shard_then_score_it(tmp_path, capsys):
    a, b, c = _meshes(tmp_path)
    bad = tmp_path / "meshes" / "broken.stl"
    bad.write_bytes(b"\x00garbage")
    out = tmp_path / "shard"
    rc = cli.main(["generate", a, b, str(bad), c, "--out", str(out), "--grid", "6", "--up", "y",
                   "--no-vis", "--bricks", "basic", "--seed", "3"])
    o, e = capsys.readouterr()
    assert rc == 1  # one mesh failed, the others were written
    assert sorted(os.listdir(out)) == ["block", "block-2", "tall"]
    assert f"error: {bad}: " in e and ("cannot read mesh" in e or "no triangles" in e)
    assert "4/4" in e  # progress bar on stderr
    assert o.count("bricks") == 3 and "broken" not in o
    obj = read_object(str(out / "tall"))
    assert obj.vox.shape == (6, 6, 6)
    assert obj.meta["up"] == "y" and obj.meta["seed"] == 3
    assert np.nonzero(obj.vox.any(axis=(0, 1)))[0].max() == 5  # y-up: the tall side stands up
    assert not os.path.exists(out / "vis.png") and "vis.png" not in os.listdir(out / "tall")
    # the shard goes straight into batch scoring
    results = tmp_path / "scores.jsonl"
    rc = cli.main(["score", str(out), "--out", str(results), "--solver", "exact", "--quiet"])
    capsys.readouterr()
    assert rc == 0
    recs = [json.loads(ln) for ln in results.read_text().splitlines()]
    assert len(recs) == 3 and all(r["stable"] for r in recs)
    assert {os.path.basename(os.path.normpath(r["file"])) for r in recs} == {"block", "block-2", "tall"}
    # and a dataset object exports to LDraw under its folder's name
    ldr = tmp_path / "tall.ldr"
    assert cli.main(["export", str(out / "tall"), "--ldr", str(ldr)]) == 0
    capsys.readouterr()
    assert ldr.read_text().splitlines()[0] == "0 tall"
    back = read_ldr(str(ldr))
    assert np.array_equal(back.pos, obj.layout.pos) and np.array_equal(back.size, obj.layout.size)


def test_generate_json_overwrite_and_argument_errors(tmp_path, capsys):
    a, _, _ = _meshes(tmp_path)
    out = tmp_path / "shard"
    args = ["generate", a, "--out", str(out), "--grid", "5", "--json", "--quiet"]
    assert cli.main(args) == 0
    o, e = capsys.readouterr()
    rec = json.loads(o)
    assert rec["name"] == "block" and rec["stable"] is True and rec["solver"] == "exact"
    assert e == ""  # --quiet: no progress bar
    assert "vis.png" in os.listdir(out / "block")
    assert cli.main(args) == 1  # exists
    o, e = capsys.readouterr()
    assert "already exists" in e and json.loads(o)["error"]
    assert cli.main(args + ["--overwrite", "--no-vis"]) == 0
    capsys.readouterr()
    assert "vis.png" not in os.listdir(out / "block")
    assert cli.main(["generate", a, "--out", str(out), "--bricks", "2x4"]) == 2
    assert "1x1" in capsys.readouterr().err
    assert cli.main(["generate", a, "--out", str(out), "--grid", "1"]) == 2
    capsys.readouterr()
    with pytest.raises(SystemExit):
        cli.main(["generate", a])  # --out is required


def test_export_ldr_json_txt(tmp_path, capsys):
    ldr = tmp_path / "guitar.ldr"
    js = tmp_path / "guitar.json"
    rc = cli.main(["export", GUITAR, "--ldr", str(ldr), "--json", str(js)])
    o, _ = capsys.readouterr()
    assert rc == 0 and "28 bricks" in o
    g = load_layout(GUITAR)
    back = read_ldr(str(ldr))
    assert np.array_equal(back.pos, g.pos) and np.array_equal(back.size, g.size)
    assert np.array_equal(load_layout(str(js)).pos, g.pos)
    # and from the .ldr to text again
    txt = tmp_path / "again.txt"
    assert cli.main(["export", str(ldr), "--txt", str(txt), "--step", "brick"]) == 0
    assert txt.read_text() == open(GUITAR).read()
    capsys.readouterr()


def test_export_errors(tmp_path, capsys):
    assert cli.main(["export", GUITAR]) == 2
    assert "--ldr" in capsys.readouterr().err
    missing = str(tmp_path / "nope.json")
    assert cli.main(["export", missing, "--ldr", str(tmp_path / "x.ldr")]) == 1
    assert missing in capsys.readouterr().err
    bad = tmp_path / "slope.ldr"
    bad.write_text("1 4 0 0 0 1 0 0 0 1 0 0 0 1 3040.dat\n")
    assert cli.main(["export", str(bad), "--json", str(tmp_path / "x.json")]) == 1
    err = capsys.readouterr().err
    assert str(bad) in err and "3040" in err
    assert not (tmp_path / "x.json").exists() and not (tmp_path / "x.ldr").exists()
