"""``tiltrov replay BAG --through allocator``: the recorded wrenches through the allocator
again, offline (no ROS), in both modes, against what was recorded.

::

    tiltrov replay runs/pd/bag --through allocator --out runs/pd/allocation

The bag's ``wrench_cmd`` messages, in stamp order, go through
:func:`tiltrov_ros.core.allocation.allocate_sequence` (``previous`` chained as
the ``thrust_allocator`` node does; a ``tilt_request`` of the switching
baseline with the tick's stamp, or else the latest one before it, holds the
tilts as the node holds them) for a ``paper`` and a ``robust``
:class:`~tiltrov_ros.core.allocation.ThrustAllocator`. The allocators get the
recorded robot limits and servo reach: ``max_thrust``, ``tilt_min``,
``tilt_max``, ``tilt_rate_limit``, ``control_period`` and ``max_tilt_step``
from the bag's ``run_info``, each falling back to the shipped
``config/robot.yaml`` and ``config/thrust_allocator.yaml`` (geometry and
weights always come from there). The recorded allocation is the bag's
``thrust_cmd`` and ``tilt_cmd`` with the same stamps; the wrench it produces is
eq. (4) of them.

Written into ``--out``:

* ``allocation.json``: the settings used (and where each came from) and, per
  allocation (``recorded``, ``paper``, ``robust``), the RMS and max weighted
  wrench error ``||W (achieved - wrench_cmd)||`` (W the allocator's
  ``weights``), the RMS unweighted error (as ``wrench_error_rms`` of
  metrics.json), the infeasible fraction (the allocator's own test), the
  saturation fraction, servo travel and the largest tilt step per servo
  (commanded tilts, rad); and ``reproduction``: how far the recorded answers
  are from the re-run of the recorded mode (0 for a lockstep bag);
* ``allocation.csv``: per tick, the wrench and each allocation's weighted
  error, tilts and thrusts;
* ``allocation.png``: the weighted error and both tilts of the three over time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from tiltrov_ros.analysis.runs import InputError, one_line
from tiltrov_ros.core.allocation import (
    AllocatorConfig,
    BatchResult,
    ThrustAllocator,
    allocate_sequence,
    infeasible_rows,
    load_allocator_config,
)
from tiltrov_ros.core.errors import BagError, TiltrovError
from tiltrov_ros.core.metrics import SATURATION_RTOL
from tiltrov_ros.core.names import (
    SERVOS,
    THRUST_CMD,
    TILT_CMD,
    TILT_REQUEST,
    WRENCH_CMD,
    WRENCH_DOFS,
    WRENCH_UNITS,
    join_namespace,
)
from tiltrov_ros.core.params import RobotParams, load_control_period, load_robot_params
from tiltrov_ros.core.runlog import FloatArray
from tiltrov_ros.core.timebase import seconds

#: The recorded allocation and the re-runs in both allocator modes, in table order.
ALLOCATIONS = ('recorded', 'paper', 'robust')
RERUNS = ALLOCATIONS[1:]
#: run_info keys that override the shipped robot parameters.
ROBOT_KEYS = ('max_thrust', 'tilt_min', 'tilt_max', 'tilt_rate_limit')
#: Recorded answers within this of the re-run (N, rad) reproduce it.
REPRODUCTION_TOL = 1e-9


@dataclass(frozen=True)
class AllocatorSettings:
    """The allocators of the re-run: the recorded limits over the shipped config."""

    robot: RobotParams
    control_period: float           # s
    max_tilt_step: float            # rad per control period
    weights: tuple[float, ...]
    sources: dict[str, str] = field(default_factory=dict)   # key -> 'run_info' | 'config'

    @classmethod
    def from_run_info(cls, run_info: Mapping[str, Any]) -> AllocatorSettings:
        """Settings from a bag's ``run_info``, each key falling back to the shipped files."""
        shipped = load_robot_params()
        values = shipped.as_dict()
        sources: dict[str, str] = {}
        for key in ROBOT_KEYS:
            recorded = _number(run_info.get(key))
            sources[key] = 'config' if recorded is None else 'run_info'
            if recorded is not None:
                values[key] = recorded
        robot = RobotParams.from_mapping(values, source='run_info')
        period = _number(run_info.get('control_period'))
        sources['control_period'] = 'config' if period is None else 'run_info'
        if period is None:
            period = load_control_period()
        config = load_allocator_config()
        step = _number(run_info.get('max_tilt_step'))
        sources['max_tilt_step'] = 'config' if step is None else 'run_info'
        if step is None:
            step = config.tilt_step(robot, period)
        return cls(robot, float(period), float(step), config.weights, sources)

    def build(self, mode: str) -> ThrustAllocator:
        return AllocatorConfig.from_mapping(
            {'mode': mode, 'max_tilt_step': self.max_tilt_step,
             'weights': list(self.weights)}).build(self.robot, self.control_period)

    def describe(self) -> dict[str, Any]:
        r = self.robot
        return {'length': r.length, 'width': r.width, 'max_thrust': r.max_thrust,
                'tilt_min': r.tilt_min, 'tilt_max': r.tilt_max,
                'tilt_rate_limit': r.tilt_rate_limit, 'control_period': self.control_period,
                'max_tilt_step': self.max_tilt_step, 'weights': list(self.weights),
                'sources': dict(self.sources)}


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(value) else None


@dataclass
class RecordedControl:
    """The control grid of a bag, as the allocator saw and answered it."""

    stamps: np.ndarray                  # (n,) int ns of the wrench_cmd messages
    wrench_cmd: FloatArray              # (n, 6)
    thrust_cmd: FloatArray              # (n, 4), NaN where the bag has none
    tilt_cmd: FloatArray                # (n, 2), NaN where the bag has none
    tilt_request: FloatArray | None     # (n, 2) or None (no tilt_request topic)
    run_info: dict[str, Any]
    namespace: str

    @property
    def t(self) -> FloatArray:
        return np.array([seconds(int(ns)) for ns in self.stamps], dtype=float)


def read_control(path: str | Path, *, namespace: str | None = None,
                 progress: bool | None = None) -> RecordedControl:
    """``wrench_cmd`` and the answers to it (``thrust_cmd``, ``tilt_cmd``, by stamp) and
    the tilt requests in force, from a bag; :class:`BagError` if it has no wrench_cmd."""
    from tiltrov_ros.bag.bagfile import bag_info
    from tiltrov_ros.bag.reader import (
        THRUSTS,
        TILT_POSITIONS,
        WRENCH,
        find_namespace,
        read_series,
        rows_as_of,
        rows_at,
    )

    info = bag_info(path)
    if namespace is None:
        namespace = find_namespace({n: t.msgtype for n, t in info.topics.items()},
                                   WRENCH_CMD, WRENCH.msgtype)
    names = {rel: join_namespace(namespace, rel)
             for rel in (WRENCH_CMD, THRUST_CMD, TILT_CMD, TILT_REQUEST)}
    decoders = {names[WRENCH_CMD]: WRENCH, names[THRUST_CMD]: THRUSTS,
                names[TILT_CMD]: TILT_POSITIONS, names[TILT_REQUEST]: TILT_POSITIONS}
    series = read_series(path, decoders, progress=progress)
    wrench = series.get(names[WRENCH_CMD])
    if wrench is None or not len(wrench):
        raise BagError(f'{path} has no {names[WRENCH_CMD]} messages')
    ticks = wrench.stamps
    thrust, _ = rows_at(ticks, series.get(names[THRUST_CMD]), 'thrust', 4)
    tilt, _ = rows_at(ticks, series.get(names[TILT_CMD]), 'tilt', 2)
    requests = series.get(names[TILT_REQUEST])
    request = rows_as_of(ticks, requests, 'tilt', 2)[0] if requests is not None else None
    return RecordedControl(ticks, wrench.columns['wrench'], thrust, tilt, request,
                           dict(info.run_info), namespace)


def summarize(allocator: ThrustAllocator, wrench_cmd: FloatArray, thrusts: FloatArray,
              tilts: FloatArray) -> tuple[dict[str, Any], FloatArray, FloatArray]:
    """Summary of one allocation of ``wrench_cmd`` (see the module docstring), the
    wrench it achieves (eq. (4)) and its weighted error per tick."""
    achieved = allocator.wrench(thrusts, tilts[:, 0], tilts[:, 1])
    weighted = allocator.weighted_error(wrench_cmd, achieved)
    known = np.all(np.isfinite(achieved), axis=1)
    steps = np.abs(np.diff(tilts, axis=0))
    n = int(known.sum())

    def stat(values: FloatArray, how: str) -> float | None:
        if not n:
            return None
        v = values[known]
        return float(np.sqrt(np.mean(v**2)) if how == 'rms' else np.max(v))

    at_limit = np.abs(thrusts[known]) >= allocator.max_thrust * (1.0 - SATURATION_RTOL)
    summary = {
        'ticks': n,
        'missing_ticks': int(len(known) - n),
        'rms_weighted_wrench_error': stat(weighted, 'rms'),
        'max_weighted_wrench_error': stat(weighted, 'max'),
        'wrench_error_rms': stat(np.linalg.norm(achieved - wrench_cmd, axis=1), 'rms'),
        'infeasible_fraction': (float(np.mean(infeasible_rows(
            wrench_cmd[known], achieved[known], allocator.max_thrust))) if n else None),
        'thrust_saturation_fraction': float(np.mean(np.any(at_limit, axis=1))) if n else None,
        'servo_travel': dict(zip(SERVOS, (float(v) for v in np.nansum(steps, axis=0)))),
        'max_tilt_step': dict(zip(SERVOS, (_max_finite(steps[:, j]) for j in range(2)))),
    }
    return summary, achieved, weighted


def _max_finite(values: FloatArray) -> float | None:
    finite = values[np.isfinite(values)]
    return float(finite.max()) if finite.size else None


@dataclass
class Comparison:
    """The recorded allocation and the re-runs, tick by tick, and their summaries."""

    control: RecordedControl
    settings: AllocatorSettings
    thrusts: dict[str, FloatArray]      # allocation -> (n, 4)
    tilts: dict[str, FloatArray]        # allocation -> (n, 2)
    weighted_error: dict[str, FloatArray]
    summary: dict[str, Any]


def compare(control: RecordedControl, settings: AllocatorSettings | None = None) -> Comparison:
    """Re-run the allocator in both modes on ``control.wrench_cmd``; compare to the recording."""
    settings = settings or AllocatorSettings.from_run_info(control.run_info)
    allocators = {mode: settings.build(mode) for mode in RERUNS}
    thrusts = {'recorded': control.thrust_cmd}
    tilts = {'recorded': control.tilt_cmd}
    for mode, allocator in allocators.items():
        batch = BatchResult.stack(allocate_sequence(allocator, control.wrench_cmd,
                                                    control.tilt_request))
        thrusts[mode], tilts[mode] = batch.thrusts, batch.tilts
    summaries: dict[str, Any] = {}
    weighted: dict[str, FloatArray] = {}
    for name in ALLOCATIONS:
        summaries[name], _, weighted[name] = summarize(allocators['robust'], control.wrench_cmd,
                                                       thrusts[name], tilts[name])
    recorded_mode = control.run_info.get('allocator_mode')
    reproduction: dict[str, Any] = {'mode': recorded_mode}
    if recorded_mode in RERUNS:
        known = np.all(np.isfinite(thrusts['recorded']), axis=1) & np.all(
            np.isfinite(tilts['recorded']), axis=1)
        d_thrust = np.abs(thrusts['recorded'][known] - thrusts[recorded_mode][known])
        d_tilt = np.abs(tilts['recorded'][known] - tilts[recorded_mode][known])
        worst_thrust = float(d_thrust.max()) if d_thrust.size else 0.0
        worst_tilt = float(d_tilt.max()) if d_tilt.size else 0.0
        reproduction.update(
            ticks=int(known.sum()), max_thrust_difference=worst_thrust,
            max_tilt_difference=worst_tilt,
            reproduced=worst_thrust <= REPRODUCTION_TOL and worst_tilt <= REPRODUCTION_TOL)
    summary = {
        'namespace': control.namespace,
        'ticks': len(control.stamps),
        'run': {key: control.run_info.get(key) for key in ('scenario', 'controller',
                                                            'allocator_mode')},
        'tilt_requests': control.tilt_request is not None,
        'allocator': settings.describe(),
        'allocations': summaries,
        'reproduction': reproduction,
    }
    return Comparison(control, settings, thrusts, tilts, weighted, summary)


def write_csv(comparison: Comparison, path: Path) -> Path:
    """One row per tick: t, wrench_cmd, then per allocation its weighted error, tilts, thrusts."""
    c = comparison
    header = ['t [s]'] + [f'{n}_cmd [{u}]' for n, u in zip(WRENCH_DOFS, WRENCH_UNITS)]
    columns = [c.control.t[:, None], c.control.wrench_cmd]
    for name in ALLOCATIONS:
        header += [f'{name}_weighted_error', f'{name}_tilt_front [rad]',
                   f'{name}_tilt_rear [rad]'] + [f'{name}_thrust_{i} [N]' for i in range(1, 5)]
        columns += [c.weighted_error[name][:, None], c.tilts[name], c.thrusts[name]]
    np.savetxt(path, np.hstack(columns), delimiter=',', header=','.join(header), comments='',
               fmt='%.10g')
    return path


def reallocate(bag: str | Path, out: Path, *, namespace: str | None = None,
               figure: bool = True, dpi: int = 100) -> tuple[Comparison, list[Path]]:
    """Read, re-run, compare and write (module docstring); :class:`InputError` on bad input."""
    try:
        control = read_control(bag, namespace=namespace)
        comparison = compare(control)
    except (TiltrovError, OSError) as exc:
        raise InputError(one_line(exc)) from exc
    out.mkdir(parents=True, exist_ok=True)
    summary_path = out / 'allocation.json'
    summary_path.write_text(json.dumps({'bag': str(bag), **comparison.summary}, indent=2,
                                       allow_nan=False) + '\n', encoding='utf-8')
    written = [summary_path, write_csv(comparison, out / 'allocation.csv')]
    if figure:
        from tiltrov_ros.analysis.figures import allocation_figure, save

        title = ' '.join(str(v) for v in comparison.summary['run'].values() if v) or Path(bag).name
        written.append(save(allocation_figure(control.t, comparison.weighted_error,
                                              comparison.tilts, title), out / 'allocation.png',
                            dpi=dpi))
    return comparison, written


def summary_lines(comparison: Comparison) -> list[str]:
    """A small table for the terminal."""
    lines = [f'{"allocation":10s} {"RMS weighted error":>19s} {"infeasible":>11s} '
             f'{"servo travel f/r [deg]":>23s} {"max step f/r [deg]":>19s}']
    for name, s in comparison.summary['allocations'].items():
        rms = s['rms_weighted_wrench_error']
        infeasible = s['infeasible_fraction']
        travel = '/'.join(f'{math.degrees(v):.1f}' for v in s['servo_travel'].values())
        step = '/'.join('-' if v is None else f'{math.degrees(v):.2f}'
                        for v in s['max_tilt_step'].values())
        lines.append(f'{name:10s} {"-" if rms is None else f"{rms:.4g}":>19s} '
                     f'{"-" if infeasible is None else f"{100 * infeasible:.2f} %":>11s} '
                     f'{travel:>23s} {step:>19s}')
    rep = comparison.summary['reproduction']
    if 'reproduced' in rep:
        lines.append(f"recorded vs {rep['mode']} re-run: max |thrust difference| "
                     f"{rep['max_thrust_difference']:.3g} N, max |tilt difference| "
                     f"{rep['max_tilt_difference']:.3g} rad "
                     f"({'reproduced' if rep['reproduced'] else 'NOT reproduced'})")
    return lines


def check_options(through: str | None, given: Sequence[str]) -> None:
    """--through runs offline: the live-replay options named in ``given`` do not apply."""
    if through is not None and given:
        raise InputError(f'--through {through} replays offline; {", ".join(given)} do not apply')
