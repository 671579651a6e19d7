"""A small progress bar on stderr for long jobs (no dependency).

Call it with the fraction done (0..1), as :func:`tiltrov_ros.core.runner.run`
does with its ``progress`` argument::

    with ProgressBar('pitch_hold pd') as bar:
        log = run_scenario(config, progress=bar)

A second argument, a short text (``'12/400 runs, 1 failed, ETA 3m05s'``), is
shown after the time. Nothing is shown for jobs that finish within ``delay``
seconds (1 s), so short runs and tests stay quiet. On a terminal the bar is
redrawn in place (``label [#########           ]  45%  2.1 s``, at most ten
times a second); when stderr is a file or a pipe, one plain line is written at
each quarter instead, so logs stay readable.
"""

from __future__ import annotations

from collections.abc import Callable
import sys
import time
from types import TracebackType
from typing import TextIO

_ERASE_LINE_END = '\x1b[K'     # ANSI: clear what a longer earlier text left on the line


class ProgressBar:
    """Callable progress reporter (see the module docstring).

    Parameters
    ----------
    label : str
        Shown before the bar.
    stream : text stream, optional
        Default ``sys.stderr``.
    delay : float
        Seconds of wall time before anything is shown.
    width : int
        Characters of the bar.
    clock : callable
        Wall clock in seconds (``time.monotonic``); injectable for tests.
    """

    def __init__(self, label: str, *, stream: TextIO | None = None, delay: float = 1.0,
                 width: int = 30, clock: Callable[[], float] = time.monotonic) -> None:
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.delay = delay
        self.width = width
        self._clock = clock
        self._start = clock()
        self._last_draw = -1.0
        self._fraction = 0.0
        self._detail = ''
        self._quarter = 0
        self.shown = False
        self._open_line = False
        isatty = getattr(self.stream, 'isatty', None)
        self.interactive = bool(isatty()) if callable(isatty) else False

    def __call__(self, fraction: float, detail: str = '') -> None:
        self._fraction = min(max(float(fraction), 0.0), 1.0)
        self._detail = f'  {detail}' if detail else ''
        now = self._clock()
        elapsed = now - self._start
        if elapsed < self.delay:
            return
        if self.interactive:
            if self._fraction >= 1.0 or now - self._last_draw >= 0.1:
                self._last_draw = now
                self._draw(elapsed)
        else:
            quarter = int(self._fraction * 4 + 1e-9)
            if quarter > self._quarter:
                self._quarter = quarter
                self.shown = True
                self.stream.write(f'{self.label}: {100 * self._fraction:3.0f}%  '
                                  f'{elapsed:.1f} s{self._detail}\n')
                self.stream.flush()

    def _draw(self, elapsed: float) -> None:
        filled = round(self.width * self._fraction)
        bar = '#' * filled + ' ' * (self.width - filled)
        erase = _ERASE_LINE_END if self._detail else ''
        self.stream.write(f'\r{self.label} [{bar}] {100 * self._fraction:3.0f}%  '
                          f'{elapsed:.1f} s{self._detail}{erase}')
        self.stream.flush()
        self.shown = True
        self._open_line = True

    def close(self) -> None:
        """End the bar's line (only if something was drawn)."""
        if self._open_line:
            self._draw(self._clock() - self._start)
            self.stream.write('\n')
            self.stream.flush()
            self._open_line = False

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
