"""Datasets as rows: JSON-lines and Parquet files whose rows hold a layout.

LLM brick datasets (StableText2Brick, the training data of BrickGPT) ship
as table rows: a ``bricks`` column with a text layout (``HxW (x,y,z)`` a
line) beside captions and ids. A row may instead hold StableLego JSON (an
object, or a string holding one). Each row is one layout, named
``FILE#ROW`` (0-based row number) or ``FILE#ID`` with an id column.

* :func:`is_row_file`: ``.jsonl`` / ``.ndjson`` / ``.parquet``;
* :func:`row_refs`: the rows of a file as :class:`RowRef` (its name, file, row);
* :func:`load_row`: the Layout of one row (the file's rows are read once and
  kept while its rows are loaded in turn).

Parquet needs pyarrow (``pip install 'stablelego-jax[rows]'``).
"""
from __future__ import annotations

import dataclasses
import json
import os
from typing import Mapping

from ..files import read_text
from ..layout import Layout, LayoutError, Library
from .reader import load_layout
from .stablelego import as_library, parse_json_layout, parse_text_layout

__all__ = ["ROW_EXTS", "DEFAULT_COLUMNS", "RowRef", "is_row_file", "read_rows", "row_refs", "load_row",
           "parse_row", "expand", "load_source", "result_fields"]

ROW_EXTS = (".jsonl", ".ndjson", ".parquet")
#: Layout columns tried in turn when none is named: BrickGPT's ``bricks``, then ``layout``.
DEFAULT_COLUMNS = ("bricks", "layout")


@dataclasses.dataclass(frozen=True)
class RowRef:
    """One row of a row file: ``name`` is ``path#row`` or ``path#id``."""

    path: str
    row: int
    name: str
    id: str | None = None

    def __str__(self) -> str:
        return self.name


def is_row_file(path: str) -> bool:
    return os.fspath(path).lower().endswith(ROW_EXTS)


_CACHE: dict = {}


def read_rows(path: str) -> list:
    """Every row of ``path`` as a dict (the last file read is kept in
    memory, keyed by its size and modification time). LayoutError naming
    the file (and line) on a read or parse failure."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise LayoutError(path, f"cannot read: {exc.strerror}") from None
    key = (os.path.abspath(path), st.st_size, st.st_mtime_ns)
    if key in _CACHE:
        return _CACHE[key]
    rows = _read_parquet(path) if path.lower().endswith(".parquet") else _read_jsonl(path)
    _CACHE.clear()
    _CACHE[key] = rows
    return rows


def _read_jsonl(path: str) -> list:
    rows = []
    for lineno, line in enumerate(read_text(path).splitlines(), start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as exc:
            raise LayoutError(path, f"line {lineno}: not valid JSON ({exc.msg})") from None
        if not isinstance(rec, dict):
            raise LayoutError(path, f"line {lineno}: a row must be a JSON object")
        rows.append(rec)
    return rows


def _read_parquet(path: str) -> list:
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise LayoutError(path, "reading Parquet needs pyarrow: pip install 'stablelego-jax[rows]'") from None
    try:
        return pq.read_table(path).to_pylist()
    except Exception as exc:  # pyarrow raises its own error types for bad files
        raise LayoutError(path, f"cannot read Parquet: {exc}") from None


def _column(rows: list, column: str | None, path: str) -> str:
    if column:
        if rows and column not in rows[0]:
            raise LayoutError(path, f"no column {column!r} (columns: {', '.join(map(str, rows[0]))})")
        return column
    for c in DEFAULT_COLUMNS:
        if rows and c in rows[0]:
            return c
    have = ", ".join(map(str, rows[0])) if rows else "none"
    raise LayoutError(path, f"no layout column ({' or '.join(DEFAULT_COLUMNS)}; columns: {have}); name one")


def row_refs(path: str, id_column: str | None = None) -> list:
    """The rows of ``path`` as :class:`RowRef`, named by row number or by
    ``id_column`` (LayoutError on a missing column or a repeated id)."""
    rows = read_rows(path)
    out, seen = [], set()
    for i, r in enumerate(rows):
        if id_column is None:
            out.append(RowRef(path, i, f"{path}#{i}"))
            continue
        if id_column not in r or r[id_column] is None:
            raise LayoutError(path, f"row {i}: no id in column {id_column!r}")
        rid = str(r[id_column])
        if rid in seen:
            raise LayoutError(path, f"row {i}: id {rid!r} of column {id_column!r} repeats")
        seen.add(rid)
        out.append(RowRef(path, i, f"{path}#{rid}", rid))
    return out


def parse_row(value, library: Library | None, source: str) -> Layout:
    """The layout of one cell: StableLego JSON (an object, or a string
    holding one) or a text layout."""
    if isinstance(value, Mapping):
        return parse_json_layout(value, library, source=source)
    if not isinstance(value, str):
        raise LayoutError(source, f"layout cell is {type(value).__name__}, not text or a JSON object")
    if value.lstrip().startswith("{"):
        try:
            raw = json.loads(value)
        except json.JSONDecodeError as exc:
            raise LayoutError(source, f"layout cell is not valid JSON ({exc.msg})") from None
        return parse_json_layout(raw, library, source=source)
    return parse_text_layout(value, source=source)


def load_row(ref: RowRef, library: Library | str | None = None, column: str | None = None) -> Layout:
    """The Layout of row ``ref`` (source ``ref.name``)."""
    rows = read_rows(ref.path)
    if not 0 <= ref.row < len(rows):
        raise LayoutError(ref.name, f"no row {ref.row} ({len(rows)} rows)")
    col = _column(rows, column, ref.path)
    if col not in rows[ref.row]:
        raise LayoutError(ref.name, f"row has no column {col!r}")
    return parse_row(rows[ref.row][col], as_library(library), ref.name)


def expand(path: str, id_column: str | None = None) -> list:
    """The rows of a row file as RowRefs; ``[path]`` when it cannot be read
    (so that :func:`load_source` reports why, as an error line)."""
    try:
        return row_refs(path, id_column)
    except LayoutError:
        return [path]


def load_source(source, library=None, column: str | None = None, id_column: str | None = None,
                skip_unsupported: bool = False, report: dict | None = None) -> Layout:
    """The Layout of a layout source: a RowRef, or a path for
    :func:`~stablelego_jax.formats.reader.load_layout` (a row file that
    could not be expanded raises its reason; ``skip_unsupported``,
    ``report``: LDraw parts that cannot be modelled, as there)."""
    if isinstance(source, RowRef):
        return load_row(source, library, column)
    if is_row_file(source):
        row_refs(source, id_column)
    return load_layout(source, library, skip_unsupported, report)


def result_fields(source) -> dict:
    """Naming fields of a result line: ``file`` (``FILE#ROW`` / ``FILE#ID``
    for a row, with ``row`` and ``id``)."""
    if isinstance(source, RowRef):
        return {"file": source.name, "row": source.row, **({"id": source.id} if source.id is not None else {})}
    return {"file": source}
