"""Fuzz (issue 20, fast part): seeded random and malformed layout files
(tests/fuzz_cases.py) through the readers of analyze, export, score and
sequence, in-process. Each input gets a one-line error naming its file and
a non-zero exit, or a valid result; never a traceback, never a
half-written output. The long run is benchmarks/fuzz.py."""
import json
import os

import numpy as np
import pytest

from fuzz_cases import KINDS, classify_error, make_case
from stablelego_jax import cli
from stablelego_jax.batch import read_results
from stablelego_jax.formats.reader import load_layout

VALID = {"valid_json", "valid_text", "valid_far"}
N_CASES = 20 * len(KINDS)


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    rng = np.random.default_rng(20)
    return d, [make_case(rng, str(d), i, KINDS[i % len(KINDS)]) for i in range(N_CASES)]


def _check_result(rec, path):
    lay = load_layout(path)
    assert set(rec["scores"]) == set(lay.keys), path
    assert rec["stable"] == all(s < 1 for s in rec["scores"].values())
    assert rec["weakest"] in rec["scores"]


def test_analyze_fuzz(cases, capsys):
    d, cs = cases
    rc = cli.main(["analyze", *[p for p, _ in cs], "--solver", "exact", "--json"])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    recs = [json.loads(ln) for ln in out.splitlines()]
    assert [r["file"] for r in recs] == [p for p, _ in cs]  # one line per file, in order
    n_err = 0
    for (path, kind), rec in zip(cs, recs):
        if "error" in rec:
            n_err += 1
            assert kind not in VALID, rec
            assert classify_error(rec["error"], path) == "clear", rec["error"]
        else:
            _check_result(rec, path)
    assert rc == (1 if n_err else 0)
    assert 0 < n_err < len(cs)


def test_export_fuzz_all_or_nothing(cases, capsys, tmp_path):
    _, cs = cases
    for i, (path, kind) in enumerate(cs):
        js, txt = tmp_path / f"o{i}.json", tmp_path / f"o{i}.txt"
        rc = cli.main(["export", path, "--json", str(js), "--txt", str(txt)])
        out, err = capsys.readouterr()
        assert "Traceback" not in err
        if rc == 0:
            a, b, c = load_layout(path), load_layout(str(js)), load_layout(str(txt))
            for other in (b, c):
                assert sorted(map(tuple, other.pos.tolist())) == sorted(map(tuple, a.pos.tolist()))
        else:
            assert rc == 1 and kind not in VALID, (path, err)
            assert not js.exists() and not txt.exists(), path  # nothing half-written
            (line,) = err.splitlines()
            assert classify_error(line, path, str(txt)) == "clear", line  # e.g. a 10 kg brick has no text form
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".tmp")]


def test_score_fuzz_one_line_per_input(cases, capsys, tmp_path):
    d, cs = cases
    out = tmp_path / "r.jsonl"
    rc = cli.main(["score", str(d), "--out", str(out), "--solver", "exact", "--quiet"])
    _, err = capsys.readouterr()
    assert "Traceback" not in err and rc == 1  # some inputs are errors
    recs = read_results(str(out))
    assert set(recs) == {p for p, _ in cs}
    for path, kind in cs:
        rec = recs[path]
        if "error" in rec:
            assert kind not in VALID
            assert classify_error(rec["error"], path) == "clear", rec["error"]
        else:
            _check_result(rec, path)


def test_sequence_fuzz(cases, capsys):
    _, cs = cases
    for path, kind in cs[: 2 * len(KINDS)]:
        rc = cli.main(["sequence", path, "--solver", "exact"])
        out, err = capsys.readouterr()
        assert "Traceback" not in err
        if kind in VALID:
            assert rc in (0, 1) and out  # a plan, stable or not
        if rc != 0 and not out:
            (line,) = err.splitlines()
            assert classify_error(line, path) == "clear", line
