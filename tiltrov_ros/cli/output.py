"""What every ``tiltrov`` command reports alike: bad input on one line (exit code
2), a file that cannot be written on one line (exit code 1), and the list of
files written."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
import sys

from tiltrov_ros.analysis.runs import InputError, one_line

#: Exit codes of report_errors: bad input, and results that cannot be written.
EXIT_BAD_INPUT = 2
EXIT_IO = 1


def report_errors(prog: str, task: Callable[[], int]) -> int:
    """``task()``'s exit code; bad input (:class:`InputError`) one line on stderr and
    exit 2, a file that cannot be written one line and exit 1. ``tiltrov sim``,
    ``analyze`` and ``replay --through`` report alike with it."""
    try:
        return task()
    except InputError as exc:
        print(f'{prog}: error: {exc}', file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        print(f'{prog}: error: cannot write the results: {one_line(exc)}', file=sys.stderr)
        return EXIT_IO


def print_written(written: Sequence[Path], out: Path) -> None:
    """The files a command wrote, one per line."""
    print(f'wrote {len(written)} files into {out}:')
    for path in written:
        print(f'  {path}')
