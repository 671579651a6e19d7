"""``tiltrov bench`` finds the benchmarks of the checkout and rejects unknown names."""

from __future__ import annotations

from tiltrov_ros.cli import main


def test_bench_lists_the_checkout_benchmarks(capsys) -> None:
    assert main(['bench', '--list']) == 0
    out = capsys.readouterr().out
    assert 'allocation' in out and 'plant' in out


def test_bench_rejects_an_unknown_name(capsys) -> None:
    assert main(['bench', 'no_such_bench']) == 2
    assert "unknown benchmark 'no_such_bench'" in capsys.readouterr().err
