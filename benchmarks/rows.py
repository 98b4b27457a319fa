"""Resumable JSON-lines results of the benchmark scripts."""
import json
import os


def read_rows(path: str, key: str) -> dict:
    """{row[key]: row} of a JSON-lines file written a row at a time (later
    rows win); a torn last line (a killed run) is skipped. {} when the file
    does not exist."""
    out: dict = {}
    if not os.path.exists(path):
        return out
    with open(path) as fh:
        for line in fh:
            if not line.endswith("\n"):
                continue  # torn by a kill: that row is redone
            try:
                row = json.loads(line)
            except ValueError:
                continue
            out[row[key]] = row
    return out


class RowsError(Exception):
    """A finished results file that cannot be used; its text is one line
    naming the file and why."""


def all_rows(path: str) -> list[dict]:
    """Every row of a finished JSON-lines file (blank lines skipped), in
    order; a missing or malformed file raises :class:`RowsError`."""
    try:
        with open(path) as fh:
            return [json.loads(line) for line in fh if line.strip()]
    except OSError as e:
        raise RowsError(f"{path}: {e.strerror}") from None
    except ValueError as e:
        raise RowsError(f"{path}: not JSON lines ({e})") from None


def append_row(path: str, row: dict) -> None:
    """Append one row (one line) and flush it."""
    with open(path, "a") as fh:
        fh.write(json.dumps(row) + "\n")
