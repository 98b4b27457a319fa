"""A plain-text progress bar on stderr (no dependency).

On a terminal the bar line is redrawn in place while an item runs, and each
finished item leaves one line; elsewhere (logs, pipes) only the finished
lines are written, so a log file stays readable.
"""
from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """``start(label)`` before an item, ``done(message)`` after it; or, for
    many small items, ``advance(k)`` (no line per item)."""

    def __init__(self, total: int, stream=None, width: int = 24, enabled: bool = True, unit: str = "items"):
        self.total = max(int(total), 0)
        self.stream = sys.stderr if stream is None else stream
        self.width = int(width)
        self.enabled = bool(enabled)
        self.unit = unit
        self.count = 0
        self.t0 = time.perf_counter()
        self._last = 0.0
        try:
            self.tty = bool(self.stream.isatty())
        except (AttributeError, ValueError):
            self.tty = False

    def _bar(self, k: int) -> str:
        n = self.total or 1
        fill = int(round(self.width * min(k, n) / n))
        w = len(str(self.total))
        return f"[{'#' * fill}{'.' * (self.width - fill)}] {k:>{w}}/{self.total}"

    def _eta(self) -> str:
        if not self.count or self.count >= self.total:
            return ""
        el = time.perf_counter() - self.t0
        return f" eta {el / self.count * (self.total - self.count):.0f}s"

    def start(self, label: str) -> None:
        if self.enabled and self.tty:
            self.stream.write(f"\r\033[K{self._bar(self.count)} {label} ...{self._eta()}")
            self.stream.flush()

    def done(self, message: str) -> None:
        self.count += 1
        if not self.enabled:
            return
        prefix = "\r\033[K" if self.tty else ""
        self.stream.write(f"{prefix}{self._bar(self.count)} {message}\n")
        self.stream.flush()

    def advance(self, k: int = 1) -> None:
        """Count ``k`` finished items; the bar with items/s and ETA is redrawn
        in place on a terminal (at most every 0.5 s), else written as a line
        at most every 10 s and at the end."""
        self.count += int(k)
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self._last < (0.5 if self.tty else 10.0) and self.count < self.total:
            return
        self._last = now
        el = now - self.t0
        line = f"{self._bar(self.count)} {self.count / el if el > 0 else 0.0:.1f} {self.unit}/s{self._eta()}"
        self.stream.write(f"\r\033[K{line}" if self.tty else line + "\n")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            el = time.perf_counter() - self.t0
            prefix = "\r\033[K" if self.tty else ""
            self.stream.write(f"{prefix}done: {self.count}/{self.total} in {el:.1f} s\n")
            self.stream.flush()
