"""A plain-stderr progress bar (no dependency): redrawn in place on a terminal, silent otherwise."""
from __future__ import annotations

import sys
import time


class ProgressBar:
    def __init__(self, label: str, total: int | None = None, stream=None, enabled: bool | None = None,
                 width: int = 30, min_interval_s: float = 0.1):
        self.label = label
        self.total = total
        self.stream = stream if stream is not None else sys.stderr
        isatty = getattr(self.stream, "isatty", lambda: False)
        self.enabled = bool(isatty()) if enabled is None else enabled
        self.width = width
        self.min_interval_s = min_interval_s
        self._last = 0.0
        self._start = time.monotonic()
        self._drawn = False

    def update(self, done: int, total: int | None = None) -> None:
        if total is not None:
            self.total = total
        if not self.enabled:
            return
        now = time.monotonic()
        final = self.total is not None and done >= self.total
        if not final and now - self._last < self.min_interval_s:
            return
        self._last = now
        elapsed = now - self._start
        if self.total:
            frac = min(max(done / self.total, 0.0), 1.0)
            filled = int(round(frac * self.width))
            bar = "#" * filled + "." * (self.width - filled)
            text = f"\r{self.label} [{bar}] {done}/{self.total} {elapsed:5.1f}s"
        else:
            text = f"\r{self.label} {done} {elapsed:5.1f}s"
        self.stream.write(text)
        self.stream.flush()
        self._drawn = True

    __call__ = update

    def close(self) -> None:
        if self.enabled and self._drawn:
            self.stream.write("\n")
            self.stream.flush()
            self._drawn = False

    def __enter__(self) -> "ProgressBar":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
