"""Figures: names, units, legends, one panel per run, and byte-identical output."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tiltrov_ros.analysis.figures import (
    errors_figure,
    run_label,
    tilts_figure,
    tracking_figure,
    wrench_figure,
    write_figures,
)
from tiltrov_ros.core.metrics import control_errors
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.runner import run_scenario, stack_config


@pytest.fixture(scope='module')
def logs() -> list[RunLog]:
    return [run_scenario(stack_config('pitch_hold', kind), duration=1.0)
            for kind in ('pd', 'switching')]


def test_errors_figure_is_fig_5_in_mm_and_deg(logs: list[RunLog]) -> None:
    fig = errors_figure(logs)
    axes = fig.axes
    assert [ax.get_ylabel() for ax in axes] == [
        'x error [mm]', 'y error [mm]', 'z error [mm]',
        'roll error [deg]', 'pitch error [deg]', 'yaw error [deg]']
    assert axes[3].get_xlabel() == 'time [s]'
    # Each panel overlays both runs, scaled to the unit on its label.
    err = control_errors(logs[1])
    np.testing.assert_allclose(axes[2].lines[1].get_ydata(), err.e[:, 2] * 1e3)
    np.testing.assert_allclose(axes[4].lines[1].get_ydata(), err.e[:, 4] * 180 / math.pi)
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert legend == ['PD (16), proposed', 'selective switching [2]']


def test_tilts_figure_has_one_panel_per_run(logs: list[RunLog]) -> None:
    fig = tilts_figure(logs)
    assert len(fig.axes) == 2
    assert 'switching' in fig.axes[1].get_title(loc='left')
    np.testing.assert_allclose(fig.axes[0].lines[0].get_ydata(),
                               logs[0].tilt_position[:, 0] * 180 / math.pi)


def test_tracking_and_wrench_figures(logs: list[RunLog]) -> None:
    fig = tracking_figure(logs)
    assert [ax.get_xlabel() for ax in fig.axes] == ['x [m]', 'time [s]', 'time [s]']
    assert fig.axes[0].yaxis_inverted()                      # NED z down: up is up
    fig = wrench_figure(logs[0])
    assert [ax.get_ylabel() for ax in fig.axes] == ['X [N]', 'Y [N]', 'Z [N]', 'K [N m]',
                                                    'M [N m]', 'N [N m]']


def test_labels_name_the_controller_and_a_non_default_allocator(logs: list[RunLog]) -> None:
    log = logs[0]
    assert run_label(log) == 'PD (16), proposed'
    paper = RunLog(**{k: getattr(log, k) for k in log.__dataclass_fields__ if k != 'meta'},
                   meta={**log.meta, 'allocator_mode': 'paper', 'controller': 'lqr'})
    assert run_label(paper) == 'lqr, paper allocator'
    with pytest.raises(ValueError, match='1 labels for 2 runs'):
        errors_figure(logs, labels=['one'])


def test_write_figures_names_and_determinism(logs: list[RunLog], tmp_path: Path) -> None:
    runs = [logs[0], logs[1], logs[0]]
    first = write_figures(runs, tmp_path / 'a', prefix='pitch_hold_', dpi=30)
    assert [p.name for p in first] == [
        'pitch_hold_errors.png', 'pitch_hold_tilts.png', 'pitch_hold_tracking.png',
        'pitch_hold_overlay.png', 'pitch_hold_wrench_pd.png',
        'pitch_hold_wrench_switching.png', 'pitch_hold_wrench_pd_2.png']
    assert all(p.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' for p in first)
    # Same runs, same bytes (no time stamp or version in the file).
    again = write_figures(runs, tmp_path / 'b', prefix='pitch_hold_', which=['errors'], dpi=30)
    assert [p.name for p in again] == ['pitch_hold_errors.png']
    assert again[0].read_bytes() == first[0].read_bytes()
    with pytest.raises(ValueError, match='unknown figure'):
        write_figures(logs, tmp_path, which=['bode'])
    with pytest.raises(ValueError, match='no runs'):
        write_figures([], tmp_path)
