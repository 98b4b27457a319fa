"""File plumbing shared by every writer: atomic writes and checked reads.

Nothing a user asked us to write is ever left half-written: every file goes
to a temporary sibling first and is renamed into place.
"""
from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile

from .layout import LayoutError, cut

__all__ = ["atomic_write", "atomic_write_text", "read_text", "read_bytes", "check_regular", "check_output",
           "staged_outputs", "current_umask", "remove_temporaries", "cut"]

#: temporary siblings being written now (removed by :func:`remove_temporaries` on a forced exit)
_LIVE: set = set()


def _temporary(path: str) -> str:
    """A new empty temporary sibling of ``path`` (same folder, its name as
    suffix), recorded as live; OSError names ``path``, not the temporary."""
    try:
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(path)), prefix=".tmp-",
                                   suffix=os.path.basename(path))
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, path) from None
    _LIVE.add(tmp)
    os.close(fd)
    return tmp


def _settle(tmp: str, path: str | None) -> None:
    """Rename the temporary ``tmp`` onto ``path`` (None: remove it)."""
    try:
        if path is None:
            if os.path.exists(tmp):
                os.unlink(tmp)
        else:
            os.replace(tmp, path)
    finally:
        _LIVE.discard(tmp)


def remove_temporaries() -> int:
    """Remove every temporary file a writer of this module has open now (for
    a process about to end without unwinding, e.g. a forced Ctrl-C exit);
    returns how many were removed."""
    n = 0
    for tmp in list(_LIVE):
        with contextlib.suppress(OSError):
            os.unlink(tmp)
            n += 1
        _LIVE.discard(tmp)
    return n


def atomic_write(path: str, write, binary: bool = False) -> None:
    """Write a file via a temporary sibling and rename: never half-written.

    ``write(fh)`` fills the open temporary file (UTF-8 text, or bytes when
    ``binary``). The file gets the permissions of a plainly created one
    (0o666 & ~umask), not the 0600 of the temporary file.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise OSError(errno.EISDIR, "is a folder, not a file", path)
    tmp = _temporary(path)  # names the user's path on failure, not the temporary file
    try:
        with open(tmp, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8"})) as fh:
            write(fh)
        os.chmod(tmp, 0o666 & ~current_umask())
        _settle(tmp, path)
    except BaseException as exc:
        _settle(tmp, None)
        if isinstance(exc, OSError) and exc.filename in (tmp, None) and exc.errno is not None:
            raise OSError(exc.errno, exc.strerror, path) from None
        raise


def atomic_write_text(path: str, text: str) -> None:
    """Write a UTF-8 text file atomically (see :func:`atomic_write`)."""
    atomic_write(path, lambda fh: fh.write(text))


def current_umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def check_regular(path: str, what: str = "file") -> None:
    """LayoutError naming ``path`` unless it is a regular file (a named pipe,
    a device or a socket would block or never end; a folder is no file)."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise LayoutError(path, f"cannot read {what}: {exc.strerror}") from None
    if stat.S_ISDIR(st.st_mode):
        raise LayoutError(path, f"{what} is a folder, not a file")
    if not stat.S_ISREG(st.st_mode):
        kind = "a named pipe" if stat.S_ISFIFO(st.st_mode) else "a device or socket"
        raise LayoutError(path, f"{what} is {kind}, not a regular file")


def read_bytes(path: str, what: str = "file") -> bytes:
    """The bytes of the regular file ``path``; LayoutError naming it otherwise."""
    check_regular(path, what)
    try:
        with open(path, "rb") as fh:
            return fh.read()
    except OSError as exc:
        raise LayoutError(path, f"cannot read {what}: {exc.strerror}") from None


def read_text(path: str, what: str = "file") -> str:
    """The UTF-8 text of the regular file ``path``; LayoutError naming the file otherwise."""
    data = read_bytes(path, what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise LayoutError(path, f"{what} is not UTF-8 text" if what != "file" else "file is not UTF-8 text") from None


def check_output(path: str) -> None:
    """LayoutError naming ``path`` when it cannot be written: its folder is
    missing or not writable, or it is a folder or a non-regular file. Run on
    every output of a command before writing any (all or nothing)."""
    path = os.fspath(path)
    d = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(d):
        raise LayoutError(path, f"cannot write: folder {os.path.dirname(path) or d!r} does not exist")
    if not os.access(d, os.W_OK | os.X_OK):
        raise LayoutError(path, f"cannot write: folder {os.path.dirname(path) or d!r} is not writable")
    if os.path.isdir(path):
        raise LayoutError(path, "cannot write: is a folder")
    if os.path.lexists(path) and not os.path.isfile(path):
        raise LayoutError(path, "cannot write: not a regular file")


@contextlib.contextmanager
def staged_outputs(paths):
    """All-or-nothing writing of several files: checks every path first
    (:func:`check_output`), then yields ``stage(path)``, which gives a
    temporary sibling of ``path`` (same folder, same extension) for a
    writer to write. When the block ends without an exception, every staged
    file is renamed into place; otherwise they are all removed, and an
    error that names a temporary file is re-raised naming the user's path.
    Paths never staged are not written."""
    paths = [os.fspath(p) for p in paths if p]
    for p in paths:
        check_output(p)
    tmps: dict = {}

    def stage(p: str) -> str:
        p = os.fspath(p)
        if p not in tmps:
            tmps[p] = _temporary(p)
        return tmps[p]

    try:
        try:
            yield stage
        except OSError as exc:
            user = {t: p for p, t in tmps.items()}
            if exc.filename in user and exc.errno is not None:
                raise OSError(exc.errno, exc.strerror, user[exc.filename]) from None
            raise
        except LayoutError as exc:
            user = {t: p for p, t in tmps.items()}
            if exc.source in user:
                raise LayoutError(user[exc.source], exc.message, exc.key, exc.what) from None
            raise
        mask = 0o666 & ~current_umask()
        for p, tmp in list(tmps.items()):
            os.chmod(tmp, mask)
            _settle(tmp, p)
            del tmps[p]
    finally:
        for tmp in tmps.values():
            _settle(tmp, None)
