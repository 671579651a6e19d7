"""The stderr progress bar: quiet for short jobs, in place on a terminal, lines in logs."""

from __future__ import annotations

import io

from tiltrov_ros.progress import ProgressBar


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_job_shorter_than_the_delay_prints_nothing() -> None:
    clock, out = Clock(), Terminal()
    with ProgressBar('quick', stream=out, clock=clock) as bar:
        for k in range(1, 11):
            clock.now += 0.05
            bar(k / 10)
    assert out.getvalue() == '' and not bar.shown


def test_terminal_bar_redraws_in_place_and_ends_its_line() -> None:
    clock, out = Clock(), Terminal()
    with ProgressBar('pitch_hold pd', stream=out, clock=clock, width=10) as bar:
        clock.now += 1.5
        bar(0.5)
        clock.now += 0.01
        bar(0.55)                     # within 0.1 s of the last draw: skipped
        clock.now += 0.5
        bar(1.0)
    text = out.getvalue()
    assert text.count('\r') == 3      # 50 %, 100 %, and the final redraw on close
    assert '\rpitch_hold pd [#####     ]  50%  1.5 s' in text
    assert '[##########] 100%' in text and text.endswith('\n') and text.count('\n') == 1


def test_log_file_gets_one_line_per_quarter() -> None:
    clock, out = Clock(), io.StringIO()
    with ProgressBar('trajectory pid', stream=out, clock=clock) as bar:
        for k in range(1, 101):
            clock.now += 0.05
            bar(k / 100)
    lines = out.getvalue().splitlines()
    # The first second is quiet (the 25 % mark passed at 1.25 s: shown then).
    assert [line.split(':')[1].split()[0] for line in lines] == ['25%', '50%', '75%', '100%']
    assert lines[0].startswith('trajectory pid:') and '\r' not in out.getvalue()
