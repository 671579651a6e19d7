"""A one-line progress bar on stderr for long reads (no third-party dependency).

Shown only on a terminal and only for long jobs, unless forced; redrawn at
most every ``interval`` seconds so it never slows the loop it reports on.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """``with Progress(total, 'reading bag') as bar: ... bar.update()``.

    Args:
        total: number of steps (e.g. messages); 0 or less: unknown.
        label: text in front of the bar.
        enabled: True to always draw, False never; None: when ``stream`` is a
            terminal and ``total`` is at least ``min_total``.
        stream: where to draw (default ``sys.stderr``).

    """

    def __init__(self, total: int, label: str, *, enabled: bool | None = None,
                 stream: TextIO | None = None, min_total: int = 20_000,
                 interval: float = 0.2, width: int = 30) -> None:
        self.total = int(total)
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        if enabled is None:
            enabled = self.total >= min_total and self.stream.isatty()
        self.enabled = enabled
        self.count = 0
        self._interval = interval
        self._width = width
        self._start = time.monotonic()
        self._next_draw = 0.0

    def update(self, steps: int = 1) -> None:
        self.count += steps
        if self.enabled and time.monotonic() >= self._next_draw:
            self._draw()

    def _draw(self, end: str = '') -> None:
        now = time.monotonic()
        self._next_draw = now + self._interval
        elapsed = now - self._start
        if self.total > 0:
            fraction = min(1.0, self.count / self.total)
            filled = round(fraction * self._width)
            bar = '#' * filled + '-' * (self._width - filled)
            text = f'{self.label} [{bar}] {fraction:6.1%} {self.count}/{self.total}'
        else:
            text = f'{self.label} {self.count}'
        self.stream.write(f'\r{text} {elapsed:5.1f} s{end}')
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self._draw(end='\n')
            self.enabled = False

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
