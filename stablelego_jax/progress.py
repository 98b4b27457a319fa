"""Progress on stderr, drawn by tqdm.

:class:`Progress` is the small interface the commands use (``start`` /
``done`` per item, or ``advance`` for many small items); the bar itself,
its rate, ETA and terminal handling are tqdm's. Off a terminal (logs,
pipes) the bar is redrawn at most every 10 s, and each finished item's
message is a line of its own either way.
"""
from __future__ import annotations

import sys
import time
import weakref

from tqdm import tqdm

__all__ = ["Progress", "end_bars"]

# bars on screen, for :func:`end_bars`
_LIVE: "weakref.WeakSet[Progress]" = weakref.WeakSet()


class Progress:
    """``start(label)`` before an item, ``done(message)`` after it; or, for
    many small items, ``advance(k)`` (no line per item). ``close()`` ends
    the bar with a ``done: k/n in t s`` line."""

    def __init__(self, total: int, stream=None, enabled: bool = True, unit: str = "items"):
        self.total = max(int(total), 0)
        self.stream = sys.stderr if stream is None else stream
        self.enabled = bool(enabled)
        self.count = 0
        self.t0 = time.perf_counter()
        try:
            tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):
            tty = False
        self.tty = tty
        if self.enabled:
            _LIVE.add(self)
        self.bar = tqdm(total=self.total, file=self.stream, unit=f" {unit}", disable=not self.enabled,
                        mininterval=0.5 if tty else 10.0, ascii=not tty, dynamic_ncols=tty, leave=False)

    def start(self, label: str) -> None:
        self.bar.set_description_str(label)

    def done(self, message: str) -> None:
        self.count += 1
        if self.enabled:
            self.bar.write(f"[{self.count}/{self.total}] {message}", file=self.stream)
        self.bar.update(1)

    def write(self, line: str, stream=None) -> None:
        """Print ``line`` (to ``stream``, default the bar's) without
        breaking the bar; shown even when the bar is disabled (warnings)."""
        self.bar.write(line, file=self.stream if stream is None else stream)

    def advance(self, k: int = 1) -> None:
        self.count += int(k)
        self.bar.update(int(k))

    def close(self) -> None:
        _LIVE.discard(self)
        self.bar.close()
        if self.enabled:
            self.stream.write(f"done: {self.count}/{self.total} in {time.perf_counter() - self.t0:.1f} s\n")
            self.stream.flush()


def end_bars() -> None:
    """End the line of every bar on screen, so that a message printed next
    (the commands' Ctrl-C line) starts a line of its own: on a terminal
    the bar is cleared, elsewhere (a log) its last drawing is ended with a
    newline. Takes no lock (it may run while the main thread is stopped
    anywhere); the bars stay open."""
    for p in list(_LIVE):
        try:
            if p.tty:
                p.bar.clear(nolock=True)
            else:
                p.stream.write("\n")
            p.stream.flush()
        except (OSError, ValueError):  # a closed stream: nothing to end
            pass
        _LIVE.discard(p)
