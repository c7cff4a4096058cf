"""A small progress printer on stderr: counts, failures, reused rows, rate and ETA."""

from __future__ import annotations

import sys
import time
from typing import TextIO

__all__ = ["Progress", "format_seconds"]


def format_seconds(s: float) -> str:
    """``75.3`` -> ``'1m15s'``; hours shown when needed."""
    s = max(0, int(round(s)))
    h, rem = divmod(s, 3600)
    m, sec = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else (f"{m}m{sec:02d}s" if m else f"{sec}s")


class Progress:
    """``[#####.....] 12/40 rows (3 failed, 5 reused) 0.8/s ETA 35s`` redrawn in place on a
    terminal, or printed as a line at most every ``interval`` seconds otherwise."""

    def __init__(
        self,
        total: int,
        *,
        initial: int = 0,
        enabled: bool = True,
        stream: TextIO | None = None,
        interval: float = 5.0,
        width: int = 24,
    ):
        self.total, self.done, self.reused = total, initial, initial
        self.failed = 0
        self.enabled = enabled and total > 0
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval, self.width = interval, width
        self.t0 = time.perf_counter()
        self._last = 0.0
        if self.enabled:
            self._draw(force=True)

    def line(self) -> str:
        """The current status line."""
        frac = self.done / self.total if self.total else 1.0
        fill = int(round(frac * self.width))
        new = self.done - self.reused
        el = time.perf_counter() - self.t0
        rate = new / el if el > 0 and new else 0.0
        left = self.total - self.done
        eta = format_seconds(left / rate) if rate > 0 else "?"
        extra = f" ({self.failed} failed, {self.reused} reused)"
        return (
            f"[{'#' * fill}{'.' * (self.width - fill)}] {self.done}/{self.total} rows{extra} "
            f"{rate:.2f}/s elapsed {format_seconds(el)} ETA {eta if left else '0s'}"
        )

    def _draw(self, force: bool = False) -> None:
        now = time.perf_counter()
        if self.tty:
            self.stream.write("\r" + self.line() + " " * 4)
            self.stream.flush()
        elif force or now - self._last >= self.interval or self.done == self.total:
            self.stream.write(self.line() + "\n")
            self.stream.flush()
            self._last = now

    def update(self, n: int = 1, *, failed: bool = False) -> None:
        """Count ``n`` finished rows (``failed`` ones too)."""
        self.done += n
        self.failed += int(failed) * n
        if self.enabled:
            self._draw()

    def close(self) -> None:
        """Finish the line."""
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()
