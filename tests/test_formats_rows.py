"""Datasets as rows: JSON-lines and Parquet files in the schema BrickGPT reads
(a ``bricks`` text layout and ``captions`` per row), named by row or id column,
and ``score`` over them (resumable, bad rows as error lines)."""
import json
import os

import pytest
from conftest import EXAMPLES

from stablelego_jax.batch import find_layouts, score_files
from stablelego_jax.formats.reader import load_layout
from stablelego_jax.formats.rows import RowRef, load_row, parse_row, read_rows, row_refs
from stablelego_jax.formats.stablelego import layout_to_json_dict
from stablelego_jax.layout import LayoutError

BRICKGPT = os.path.join(EXAMPLES, "brickgpt")
CAR = open(os.path.join(BRICKGPT, "car.txt")).read()
CHAIR = open(os.path.join(BRICKGPT, "chair.txt")).read()


def _rows():
    """Three rows in StableText2Brick's columns (the ones BrickGPT's prepare step reads: captions, bricks)."""
    return [
        {"structure_id": "s-car", "object_id": "o1", "category_id": "car", "captions": ["a small car"], "bricks": CAR},
        {"structure_id": "s-chair", "object_id": "o2", "category_id": "chair", "captions": ["a chair"],
         "bricks": CHAIR},
        {"structure_id": "s-one", "object_id": "o3", "category_id": "misc", "captions": ["one brick"],
         "bricks": "2x4 (0,0,0)\n"},
    ]


@pytest.fixture
def jsonl(tmp_path):
    p = tmp_path / "stable_text2brick.jsonl"
    p.write_text("".join(json.dumps(r) + "\n" for r in _rows()))
    return str(p)


@pytest.fixture
def parquet(tmp_path):
    pa = pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    p = tmp_path / "train-00000-of-00001.parquet"
    pq.write_table(pa.Table.from_pylist(_rows()), str(p))
    return str(p)


def test_jsonl_rows_are_the_text_layouts(jsonl):
    refs = row_refs(jsonl)
    assert [r.name for r in refs] == [f"{jsonl}#0", f"{jsonl}#1", f"{jsonl}#2"]
    lay = load_row(refs[0])
    ref = load_layout(os.path.join(BRICKGPT, "car.txt"))
    assert lay.source == f"{jsonl}#0" and lay.keys == ref.keys
    assert (lay.pos == ref.pos).all() and (lay.size == ref.size).all()


def test_parquet_rows_match_jsonl_and_id_column_names_them(parquet, jsonl):
    refs = row_refs(parquet, id_column="structure_id")
    assert [r.id for r in refs] == ["s-car", "s-chair", "s-one"]
    assert refs[1].name == f"{parquet}#s-chair"
    a, b = load_row(refs[1]), load_row(row_refs(jsonl)[1])
    assert (a.pos == b.pos).all() and a.n == b.n


def test_stablelego_json_cells_object_or_string():
    d = layout_to_json_dict(load_layout(os.path.join(EXAMPLES, "stablelego", "stick_light.json")))
    assert parse_row(d, None, "x#0").n == parse_row(json.dumps(d), None, "x#1").n == len(d)


def test_bad_rows_name_file_and_line(tmp_path):
    p = tmp_path / "bad.jsonl"
    p.write_text('{"bricks": "2x4 (0,0,0)"}\n{not json\n')
    with pytest.raises(LayoutError, match=r"bad.jsonl: line 2: not valid JSON"):
        read_rows(str(p))
    p.write_text('{"text": "2x4 (0,0,0)"}\n')
    with pytest.raises(LayoutError, match=r"no layout column .*columns: text"):
        load_row(RowRef(str(p), 0, f"{p}#0"))
    p.write_text('{"id": 1, "bricks": "2x4 (0,0,0)"}\n{"id": 1, "bricks": "2x2 (0,0,0)"}\n')
    with pytest.raises(LayoutError, match=r"row 1: id '1' of column 'id' repeats"):
        row_refs(str(p), id_column="id")
    p.write_text('{"bricks": "2x3 (0,0,0)"}\n')
    with pytest.raises(LayoutError, match=r"bad.jsonl#0: .*2x3 is not a library brick"):
        load_row(row_refs(str(p))[0])


def test_score_rows_resumable_with_error_lines(jsonl, tmp_path):
    bad = tmp_path / "more.jsonl"
    bad.write_text('{"bricks": "2x4 (0,0,0)"}\n{"bricks": "9x9 (0,0,0)"}\n')
    out = tmp_path / "r.jsonl"
    assert [str(s) for s in find_layouts([jsonl, str(bad)])][-1] == f"{bad}#1"
    st = score_files([jsonl, str(bad)], str(out), solver="exact", progress=False, id_column=None)
    assert (st.scored, st.errors) == (4, 1)
    recs = {r["file"]: r for r in map(json.loads, open(out))}
    assert recs[f"{jsonl}#2"]["stable"] is True and recs[f"{jsonl}#2"]["row"] == 2
    assert "9x9" in recs[f"{bad}#1"]["error"] and recs[f"{bad}#1"]["row"] == 1
    st = score_files([jsonl, str(bad)], str(out), solver="exact", progress=False)
    assert (st.skipped, st.scored) == (5, 0)


def test_score_rows_by_id_column(parquet, tmp_path):
    out = tmp_path / "r.jsonl"
    st = score_files([str(tmp_path)], str(out), solver="exact", progress=False, id_column="structure_id")
    assert st.scored == 3
    recs = [json.loads(x) for x in open(out)]
    assert {r["id"] for r in recs} == {"s-car", "s-chair", "s-one"}
    assert all(r["file"] == f"{parquet}#{r['id']}" for r in recs)


def test_unreadable_row_file_is_one_error_line(tmp_path):
    p = tmp_path / "broken.parquet"
    p.write_bytes(b"not parquet")
    out = tmp_path / "r.jsonl"
    st = score_files([str(p)], str(out), solver="exact", progress=False)
    assert st.errors == 1
    (rec,) = [json.loads(x) for x in open(out)]
    assert rec["file"] == str(p) and "broken.parquet" in rec["error"]
