"""Ctrl-C that is answered at once, even during a long native call.

Python runs its SIGINT handler only between bytecodes. Ctrl-C during one
long XLA, HiGHS or Clarabel call (minutes on a large layout, or a long
compile) would wait for that call to end. :func:`prompt_interrupt` keeps
the usual path (KeyboardInterrupt, caught by the command, which prints one
line) and adds a watcher thread: the C-level signal handler writes the
signal number to a socket (``signal.set_wakeup_fd``) at once, and if the
main thread has not taken the interrupt within ``grace_s`` seconds, the
watcher ends the process itself: it flushes what was printed (complete
lines; a results file of ``score`` holds complete lines and drops a torn
last one when resumed), removes the temporary files of writers in progress
(:func:`stablelego_jax.files.remove_temporaries`, so nothing is
half-written), prints the same one line and exits with ``code``.
"""
from __future__ import annotations

import contextlib
import os
import signal
import socket
import sys
import threading

from ..files import remove_temporaries
from ..progress import end_bars

__all__ = ["prompt_interrupt", "end_process"]


def _flush_streams(timeout_s: float, first=None) -> None:
    """Flush stdout and stderr from a helper thread, giving up after
    ``timeout_s`` (a stream whose lock the stuck main thread holds);
    ``first()`` (if given) runs in that thread before the flush."""
    def flush():
        if first is not None:
            with contextlib.suppress(Exception):
                first()
        for s in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                s.flush()

    t = threading.Thread(target=flush, daemon=True)
    t.start()
    t.join(timeout_s)


def end_process(code: int, message: str | None = None) -> None:
    """End the process now with exit status ``code``: flush stdout and stderr
    (at most a second), remove writers' temporary files, print ``message``
    (if any) on stderr, and exit without unwinding or waiting for native
    work in flight (an interrupted XLA computation would otherwise hold the
    interpreter's shutdown until it ends: minutes on a large layout)."""
    _flush_streams(1.0, end_bars if message else None)
    remove_temporaries()
    if message:
        with contextlib.suppress(OSError):
            os.write(2, (message + "\n").encode("utf-8", "replace"))
    os._exit(code)


@contextlib.contextmanager
def prompt_interrupt(message: str, code: int = 130, grace_s: float = 1.0):
    """Within the block, Ctrl-C raises KeyboardInterrupt as usual; when the
    main thread is inside a native call and does not take it within
    ``grace_s`` seconds, the process prints ``message`` on stderr and exits
    with ``code`` (see the module docstring). Does nothing off the main
    thread, or where SIGINT is not at Python's default handler (ignored in
    a background job, or handled by the caller)."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield
        return
    taken = threading.Event()

    def handler(signum, frame):
        taken.set()
        raise KeyboardInterrupt

    r, w = socket.socketpair()
    w.setblocking(False)

    def watch():
        while True:
            try:
                data = r.recv(64)
            except OSError:
                return
            if not data:
                return
            if signal.SIGINT not in data:
                continue
            if taken.wait(grace_s):
                taken.clear()
                continue
            if not done.is_set():
                end_process(code, message)

    done = threading.Event()
    old_handler = signal.signal(signal.SIGINT, handler)
    try:
        old_fd = signal.set_wakeup_fd(w.fileno(), warn_on_full_buffer=False)
    except (ValueError, OSError):  # cannot watch: the usual KeyboardInterrupt only
        signal.signal(signal.SIGINT, old_handler)
        r.close()
        w.close()
        yield
        return
    watcher = threading.Thread(target=watch, name="stablelego-interrupt", daemon=True)
    watcher.start()
    try:
        yield
    finally:
        done.set()
        signal.set_wakeup_fd(old_fd)
        signal.signal(signal.SIGINT, old_handler)
        w.close()  # the watcher's recv returns b"" and it ends
        watcher.join(grace_s + 2.0)
        r.close()
