"""Runs as files: a headless run of a configuration (with a progress bar), a
RunLog's ``run.npz``, ``control.csv`` and ``metrics.json``, its summary line;
and :class:`InputError`, the bad input that commands report on one line.

``tiltrov sim`` writes these for a headless run, ``tiltrov analyze`` for a bag:
the same files from the same code.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from tiltrov_ros.core.campaign import load_hold
from tiltrov_ros.core.errors import TiltrovError
from tiltrov_ros.core.hold import HoldCriterion
from tiltrov_ros.core.metrics import compute_metrics, control_errors, write_metrics
from tiltrov_ros.core.names import (
    DOF_NAMES,
    DOF_UNITS,
    WRENCH_DOFS,
    WRENCH_UNITS,
)
from tiltrov_ros.core.params import robot_file
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.runner import StackConfig, run_scenario, stack_config
from tiltrov_ros.progress import ProgressBar


class InputError(Exception):
    """Bad user input: reported on one line, exit code 2."""


def one_line(exc: BaseException) -> str:
    """An exception's message on one line."""
    return ' '.join(str(exc).split()) or type(exc).__name__


def resolve(scenario: str, controller: str | None, allocator: str | None, *,
            controller_file: Path | None = None, allocator_file: Path | None = None,
            robot: str | None = None) -> StackConfig:
    """A StackConfig, or :class:`InputError` for anything wrong in the input files.
    ``robot``: a robot parameter file or the name of a shipped one (default: robot.yaml)."""
    try:
        return stack_config(scenario, controller, allocator_mode=allocator,
                            controller_file=controller_file, allocator_file=allocator_file,
                            robot_file=robot_file(robot) if robot else None)
    except (TiltrovError, yaml.YAMLError, OSError) as exc:
        raise InputError(one_line(exc)) from exc


def simulate(config: StackConfig, duration: float | None = None, *,
             label: str | None = None) -> RunLog:
    """Run one configuration with a progress bar on stderr (shown after 1 s)."""
    if duration is not None and not duration > 0:
        raise InputError(f'--duration must be > 0 s, got {duration}')
    name = label or f'{config.scenario.name} {config.controller.kind}'
    try:
        with ProgressBar(name) as bar:
            return run_scenario(config, duration=duration, progress=bar)
    except TiltrovError as exc:
        raise InputError(one_line(exc)) from exc


def write_control_csv(log: RunLog, path: str | Path) -> Path:
    """The control grid as CSV (SI units in the header), one row per tick with odometry.

    Columns: t, the setpoint eta_d, the pose eta (odometry at the tick), the
    error e = eta_d - eta (angles wrapped), wrench_cmd, wrench_achieved,
    thrust_cmd, tilt_cmd and the actual tilts at the tick.
    """
    err = control_errors(log)
    header = ['t [s]']
    header += [f'{n}_d [{u}]' for n, u in zip(DOF_NAMES, DOF_UNITS)]
    header += [f'{n} [{u}]' for n, u in zip(DOF_NAMES, DOF_UNITS)]
    header += [f'e_{n} [{u}]' for n, u in zip(DOF_NAMES, DOF_UNITS)]
    header += [f'{n}_cmd [{u}]' for n, u in zip(WRENCH_DOFS, WRENCH_UNITS)]
    header += [f'{n}_achieved [{u}]' for n, u in zip(WRENCH_DOFS, WRENCH_UNITS)]
    header += [f'thrust_{i}_cmd [N]' for i in range(1, 5)]
    header += ['tilt_front_cmd [rad]', 'tilt_rear_cmd [rad]', 'tilt_front [rad]',
               'tilt_rear [rad]']
    k = err.ticks
    table = np.hstack([err.t[:, None], err.eta_d, err.eta, err.e, log.wrench_cmd[k],
                       log.wrench_achieved[k], log.thrust_cmd[k], log.tilt_cmd[k],
                       log.tilt_position[err.rows]])
    target = Path(path)
    np.savetxt(target, table, delimiter=',', header=','.join(header), comments='',
               fmt='%.10g')
    return target


def hold_criterion(path: Path | None) -> HoldCriterion | None:
    """The hold criterion of a campaign or hold file (``--hold``; None: the shipped one),
    or :class:`InputError`."""
    if path is None:
        return None
    try:
        return load_hold(path)
    except TiltrovError as exc:
        raise InputError(one_line(exc)) from exc


def write_run(log: RunLog, out: Path, criterion: HoldCriterion | None = None
              ) -> tuple[list[Path], dict[str, Any]]:
    """run.npz, control.csv and metrics.json of one run into ``out``; paths and metrics
    (``hold`` judged by ``criterion``, default the shipped station-keeping one)."""
    out.mkdir(parents=True, exist_ok=True)
    log.save_npz(out / 'run.npz')
    metrics = compute_metrics(log, criterion=criterion)
    paths = [out / 'run.npz', write_control_csv(log, out / 'control.csv'),
             write_metrics(metrics, out / 'metrics.json')]
    return paths, metrics


def summary_line(metrics: dict[str, Any], label: str | None = None) -> str:
    """Final and RMS errors of one run, in mm and deg, for the terminal.

    ``label`` leads the line (default: the run's scenario and controller).
    """

    def fmt(values: dict[str, Any]) -> str:
        pos = ' '.join(f'{1e3 * (values[d] or 0.0):.2f}' for d in DOF_NAMES[:3])
        ang = ' '.join(f'{np.degrees(values[d] or 0.0):.3f}' for d in DOF_NAMES[3:])
        return f'{pos} mm, {ang} deg'

    run = metrics['run']
    if label is None:
        label = f"{run['scenario']} {run['controller']}"
    return (f'{label}: '
            f"final |e| (x y z, roll pitch yaw) {fmt(metrics['final_error'])}; "
            f"RMS {fmt(metrics['rms_error'])}")
