"""Random station keeping: a seeded scenario sampler and the hold criterion.

The paper's two scenarios are hand-picked. This module draws the runs a user
meets every day and says, with reasons, whether the robot held in each:

* :func:`sample_cases` ``(n, seed)`` -> ``n`` :class:`StationKeepingCase`: the
  robot starts at rest at the origin in a constant ocean current; at
  ``step_at`` the setpoint steps in a random subset of x, y, z, pitch and yaw
  (:data:`STEP_RANGES`); the current is horizontal, up to
  :data:`MAX_CURRENT` from any direction; the center-of-mass error is up to
  :data:`MAX_COM_ERROR` in any direction; the servo rate is between
  :data:`SERVO_RATES`. The same ``(n, seed)`` always gives the same cases,
  and case ``i`` does not depend on ``n``.
* :func:`hold_verdict` ``(metrics, controller)`` -> :class:`Verdict`: held or
  not, with one reason per criterion missed (:class:`HoldCriterion`).
* :func:`run_case` runs one case headless (:func:`~tiltrov_ros.core.runner.run_scenario`)
  and returns its metrics and verdict.

Everything is plain data in, plain data out, so a campaign runner (a loop, a
process pool, a cluster) can build on it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
import math
from typing import Any

import numpy as np

from tiltrov_ros.core.metrics import compute_metrics
from tiltrov_ros.core.names import DOF_NAMES
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.runner import run, stack_config
from tiltrov_ros.core.scenarios import Scenario

DEG = math.pi / 180.0
#: s, length of every run.
DURATION = 60.0
#: s, time of the setpoint step (the robot first holds the origin in the current).
STEP_AT = 10.0
#: Setpoint step per DOF: (DOF, half-range of the uniform draw); m for x, y, z,
#: rad for pitch and yaw. Each DOF steps with probability 1/2 (at least one does).
STEP_RANGES: tuple[tuple[str, float], ...] = (
    ('x', 1.0), ('y', 1.0), ('z', 0.5), ('pitch', 30.0 * DEG), ('yaw', 90.0 * DEG))
#: m/s, largest ocean current (horizontal, uniform direction, uniform speed).
MAX_CURRENT = 0.3
#: m, largest center-of-mass error (uniform direction, uniform size).
MAX_COM_ERROR = 0.01
#: rad/s, servo rate range (uniform).
SERVO_RATES = (60.0 * DEG, 150.0 * DEG)
#: The controllers a campaign runs on every case.
CONTROLLERS = ('pd', 'pid')


@dataclass(frozen=True)
class StationKeepingCase:
    """One random station-keeping run (SI units, rad).

    index : position in the campaign; seed : the campaign's seed
    setpoint : (x, y, z, roll, pitch, yaw) from ``step_at`` on (roll always 0)
    current : (3,) constant ocean current in NED, m/s
    com_error : (3,) true minus nominal center of gravity, body frame, m
    tilt_rate_limit : servo rate, rad/s
    """

    index: int
    seed: int
    setpoint: tuple[float, ...]
    current: tuple[float, ...]
    com_error: tuple[float, ...]
    tilt_rate_limit: float
    step_at: float = STEP_AT
    duration: float = DURATION

    @property
    def name(self) -> str:
        return f'station_keeping_{self.seed}_{self.index}'

    def scenario(self) -> Scenario:
        """The case as a :class:`Scenario` (what a scenario file would hold)."""
        reference = {dof: [{'type': 'step', 'value': value, 'at': self.step_at}]
                     for dof, value in zip(DOF_NAMES, self.setpoint) if value != 0.0}
        return Scenario.from_mapping({
            'name': self.name, 'duration': self.duration, 'angle_unit': 'rad',
            'description': self.describe(), 'reference': reference,
            'disturbances': {'com_error': list(self.com_error),
                             'current': list(self.current)},
            'robot': {'tilt_rate_limit': self.tilt_rate_limit}})

    def describe(self) -> str:
        steps = ', '.join(
            f'{dof} {value * (1 / DEG if k >= 3 else 1):+.3g}{" deg" if k >= 3 else " m"}'
            for k, (dof, value) in enumerate(zip(DOF_NAMES, self.setpoint)) if value != 0.0)
        speed = math.hypot(self.current[0], self.current[1])
        heading = math.degrees(math.atan2(self.current[1], self.current[0]))
        return (f'step at {self.step_at:g} s to {steps}; current {speed:.3f} m/s towards '
                f'{heading:.0f} deg; CoM error {np.linalg.norm(self.com_error) * 1000:.1f} mm; '
                f'servo {math.degrees(self.tilt_rate_limit):.0f} deg/s')

    def as_dict(self) -> dict[str, Any]:
        return {'index': self.index, 'seed': self.seed, 'setpoint': list(self.setpoint),
                'current': list(self.current), 'com_error': list(self.com_error),
                'tilt_rate_limit': self.tilt_rate_limit, 'step_at': self.step_at,
                'duration': self.duration}


def _unit_vector(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / max(float(np.linalg.norm(v)), 1e-300)


def sample_case(seed: int, index: int) -> StationKeepingCase:
    """Case ``index`` of the campaign with ``seed`` (independent of the campaign size)."""
    rng = np.random.default_rng([int(seed), int(index)])
    steps = rng.uniform(size=len(STEP_RANGES)) < 0.5
    if not steps.any():
        steps[rng.integers(len(STEP_RANGES))] = True
    values = rng.uniform(-1.0, 1.0, size=len(STEP_RANGES))
    setpoint = dict.fromkeys(DOF_NAMES, 0.0)
    for on, value, (dof, half) in zip(steps, values, STEP_RANGES):
        if on:
            setpoint[dof] = float(value * half)
    heading = rng.uniform(-math.pi, math.pi)
    speed = rng.uniform(0.0, MAX_CURRENT)
    com = _unit_vector(rng) * rng.uniform(0.0, MAX_COM_ERROR)
    rate = rng.uniform(*SERVO_RATES)
    return StationKeepingCase(
        index, int(seed), tuple(setpoint[d] for d in DOF_NAMES),
        (speed * math.cos(heading), speed * math.sin(heading), 0.0),
        tuple(float(v) for v in com), float(rate))


def sample_cases(n: int, seed: int) -> list[StationKeepingCase]:
    """``n`` cases of the campaign with ``seed`` (same arguments, same cases)."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise ValueError(f'n must be an integer >= 0, got {n!r}')
    return [sample_case(seed, i) for i in range(n)]


# --------------------------------------------------------------------------- criterion


@dataclass(frozen=True)
class HoldCriterion:
    """When a run counts as holding (SI units, rad).

    Every run settles: the standard deviation of each error over the last 20 s
    (``oscillation_std`` of :mod:`~tiltrov_ros.core.metrics`) is at most
    ``settle_position`` and ``settle_angle``. A pid run ends within
    ``pid_position`` and ``pid_angle`` of the setpoint in every DOF
    (``final_error``: mean |e| over the last 10 s); a pd run within
    ``pd_position`` in x, y and z (its steady offsets, disturbance / kp, are
    allowed; its attitude offsets are not bounded).
    """

    settle_position: float = 0.005
    settle_angle: float = 0.5 * DEG
    pid_position: float = 0.05
    pid_angle: float = 2.0 * DEG
    pd_position: float = 0.1


@dataclass(frozen=True)
class Verdict:
    """held, and one line per criterion missed (empty when held)."""

    held: bool
    reasons: tuple[str, ...] = field(default_factory=tuple)


def _show(dof: str, value: float) -> str:
    return (f'{dof} {value * 1000:.3g} mm' if dof in ('x', 'y', 'z')
            else f'{dof} {math.degrees(value):.3g} deg')


def hold_verdict(metrics: Mapping[str, Any], controller: str,
                 criterion: HoldCriterion = HoldCriterion()) -> Verdict:
    """Did the run hold? ``metrics`` from :func:`~tiltrov_ros.core.metrics.compute_metrics`."""
    reasons: list[str] = []
    positions, angles = DOF_NAMES[:3], DOF_NAMES[3:]

    def check(key: str, dofs: Sequence[str], limit: float, what: str) -> None:
        values = metrics.get(key) or {}
        for dof in dofs:
            value = values.get(dof)
            if value is None or not math.isfinite(value):
                reasons.append(f'{what}: {dof} not measured')
            elif value > limit:
                reasons.append(f'{what}: {_show(dof, value)} > {_show(dof, limit)}')

    check('oscillation_std', positions, criterion.settle_position, 'not settled (std, last 20 s)')
    check('oscillation_std', angles, criterion.settle_angle, 'not settled (std, last 20 s)')
    if controller == 'pid':
        check('final_error', positions, criterion.pid_position, 'final error')
        check('final_error', angles, criterion.pid_angle, 'final error')
    else:
        check('final_error', positions, criterion.pd_position, 'final error')
    return Verdict(not reasons, tuple(reasons))


# --------------------------------------------------------------------------- running


@dataclass(frozen=True)
class CaseResult:
    """One (case, controller) run: its metrics and verdict."""

    case: StationKeepingCase
    controller: str
    metrics: dict[str, Any]
    verdict: Verdict


AllocatorFactory = Callable[[Any], Any]


def run_case(case: StationKeepingCase, controller: str, *,
             allocator: AllocatorFactory | None = None,
             keep_log: Callable[[RunLog], None] | None = None) -> CaseResult:
    """Run ``case`` with ``controller`` headless and judge it.

    ``allocator``: optional ``StackConfig -> allocator`` (default: the shipped
    allocator configuration); ``keep_log``: called with the RunLog.
    """
    config = stack_config(case.scenario(), controller)
    alloc = allocator(config) if allocator is not None else config.build_allocator()
    log = run(config.build_plant(), config.build_controller(), alloc,
              config.scenario.reference.at, case.duration,
              control_period_ns=config.control_period_ns, meta=config.describe())
    if keep_log is not None:
        keep_log(log)
    metrics = compute_metrics(log)
    return CaseResult(case, controller, metrics, hold_verdict(metrics, controller))
