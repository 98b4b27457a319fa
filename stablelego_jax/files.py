"""File plumbing shared by every writer: atomic writes and checked reads.

Nothing a user asked us to write is ever left half-written: every file goes
to a temporary sibling first and is renamed into place.
"""
from __future__ import annotations

import os
import tempfile

from .layout import LayoutError

__all__ = ["atomic_write", "atomic_write_text", "read_text", "current_umask", "cut"]


def atomic_write(path: str, write, binary: bool = False) -> None:
    """Write a file via a temporary sibling and rename: never half-written.

    ``write(fh)`` fills the open temporary file (UTF-8 text, or bytes when
    ``binary``). The file gets the permissions of a plainly created one
    (0o666 & ~umask), not the 0600 of the temporary file.
    """
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(dir=d, prefix=".tmp-", suffix=os.path.basename(path))
    try:
        with (os.fdopen(fd, "wb") if binary else os.fdopen(fd, "w", encoding="utf-8")) as fh:
            write(fh)
        os.chmod(tmp, 0o666 & ~current_umask())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str, text: str) -> None:
    """Write a UTF-8 text file atomically (see :func:`atomic_write`)."""
    atomic_write(path, lambda fh: fh.write(text))


def current_umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def read_text(path: str) -> str:
    """The UTF-8 text of ``path``; LayoutError naming the file otherwise."""
    try:
        with open(path, encoding="utf-8") as fh:
            return fh.read()
    except UnicodeDecodeError:
        raise LayoutError(path, "file is not UTF-8 text") from None
    except OSError as exc:
        raise LayoutError(path, f"cannot read: {exc.strerror}") from None


def cut(s: str, limit: int = 40) -> str:
    """``s`` cut to ``limit`` characters (keeps error messages readable)."""
    return s if len(s) <= limit else s[: limit - 3] + "..."
