"""Wrench controllers: the paper's PD (16), the switching baseline, and a PID beyond it.

Every controller has one method, ``update(t, position, quaternion, nu,
reference) -> ControlOutput``, fed with exactly what the ``odom``,
``setpoint`` and ``setpoint_velocity`` messages carry (see ARCHITECTURE.md), so
the ROS node and the headless runner give the same numbers.

* ``pd`` - eq. (16): tau = J(eta)^T (Kp e + Kd e_dot), e = eta_d - eta in the
  earth frame (angle errors wrapped to (-pi, pi]), e_dot = eta_d_dot - J(eta) nu
  (the paper's e_dot = -J nu when regulating, plus the reference velocity when
  tracking).
* ``switching`` - the selective switching controller of the paper's
  reference [2] (Jin et al., IEEE/ASME T-Mech 2015), reconstructed: a
  horizontal mode (both tilts 0 deg: surge, sway, yaw controlled) and a
  vertical mode (both tilts 90 deg: heave, roll, pitch controlled). It asks the
  allocator for those tilts (``ControlOutput.tilt_request``), so the
  allocation in each mode is linear. Rule: the mode switches when the other
  group's normalised error exceeds the current group's by the hysteresis
  factor and the dwell time since the last switch has passed; while the servos
  travel (|delta tilt| / rate limit + settle time) the wrench is zero.
* ``pid`` - PD plus the restoring forces g(eta) of the controller's nominal
  model and integral action with a clamp (anti-windup): the constant moment of
  the center-of-mass modeling error and the net buoyancy leave no steady-state
  error. With ``gains.antiwindup`` > 0 (off by default: measured in
  docs/campaign.md, it lost runs as often as it saved them) and the wrench the
  allocator achieved of its previous command (``update(..., achieved=...)``:
  ``wrench_achieved``, one tick late), the integral of a DOF stops while that
  command fell short by more than ``antiwindup`` wrench tolerances in the
  direction the error pushes: it cannot wind up against a wrench the thrusters
  do not produce.

With the numba backend (:mod:`tiltrov_ros.core.jit`) each ``update`` makes one
call of the compiled law (:mod:`tiltrov_ros.core.control_kernels`); the numpy
code here (:func:`tracking_error` and the laws' reference branches) is the
reference the kernels are tested against. ``controller.compiled`` says which
runs (tests set it to compare the two).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any, ClassVar, Literal, NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core import control_kernels as ck
from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation import shortfall_tolerances
from tiltrov_ros.core.dynamics import restoring_forces
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.kinematics import (
    GIMBAL_GUARD_COS,
    J,
    Rquat,
    euler_from_quat,
    quat_normalize,
    ssa,
)
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.paramtable import SHIPPED, Param, ParamTable, ros_parameters
from tiltrov_ros.paths import config_file

FloatArray = NDArray[np.float64]

ControllerKind = Literal['pd', 'switching', 'pid']
CONTROLLER_KINDS: tuple[str, ...] = ('pd', 'switching', 'pid')
CONTROLLER_YAML = 'wrench_controller.yaml'

# Switching baseline: the wrench components each mode can produce.
_HORIZONTAL = np.array([1.0, 1.0, 0.0, 0.0, 0.0, 1.0])
_VERTICAL = np.array([0.0, 0.0, 1.0, 1.0, 1.0, 0.0])


class Reference(NamedTuple):
    """Desired pose and its rate, as the ``setpoint`` messages carry them.

    position : (3,) eta_d position in NED [m]
    quaternion : (4,) (w, x, y, z) desired attitude
    velocity : (6,) d(eta_d)/dt: (x, y, z) rates [m/s], (roll, pitch, yaw) rates [rad/s]
    """

    position: FloatArray
    quaternion: FloatArray
    velocity: FloatArray

    @classmethod
    def hold(cls, position: ArrayLike = (0.0, 0.0, 0.0),
             quaternion: ArrayLike = (1.0, 0.0, 0.0, 0.0)) -> Reference:
        """A constant setpoint with no feed-forward."""
        return cls(np.array(position, dtype=float), np.array(quaternion, dtype=float),
                   np.zeros(6))


@dataclass(frozen=True)
class ControlOutput:
    """A controller's answer for one control tick.

    wrench : (6,) body wrench (X, Y, Z, K, M, N) [N, N m]
    tilt_request : None, or (tilt_front, tilt_rear) [rad] for a fixed-tilt allocation
    mode : what the controller is doing (``pd``, ``pid``, ``horizontal``,
        ``vertical``, ``transition``), for diagnostics and logs
    """

    wrench: FloatArray
    tilt_request: tuple[float, float] | None = None
    mode: str = ''


class Controller(Protocol):
    """What the runner and the ``wrench_controller`` node call."""

    def reset(self) -> None: ...

    def update(self, t: float, position: FloatArray, quaternion: FloatArray, nu: FloatArray,
               reference: Reference, achieved: FloatArray | None = None
               ) -> ControlOutput: ...


# --------------------------------------------------------------------------- configuration

_GAIN_UNITS = 'per DOF x y z roll pitch yaw: '
#: ``gains.*``: per-DOF gains in the earth frame (defaults: the shipped file's).
GAINS = ParamTable('gains', [
    Param('kp', 'floats', SHIPPED, 'proportional gains', _GAIN_UNITS + 'N/m, N m/rad', size=6,
          low=0.0),
    Param('kd', 'floats', SHIPPED, 'derivative gains', _GAIN_UNITS + 'N s/m, N m s/rad',
          size=6, low=0.0),
    Param('ki', 'floats', SHIPPED, 'pid only: integral gains (may be left out: zero)',
          _GAIN_UNITS + 'N/(m s), N m/(rad s)', size=6, low=0.0),
    Param('integral_limit', 'floats', SHIPPED, 'pid only: bound on abs(ki integral(e)) per DOF, '
          'the anti-windup clamp (may be left out: zero)', _GAIN_UNITS + 'N, N m', size=6,
          low=0.0),
    Param('antiwindup', 'float', 0.0, 'pid only: the integral of a DOF holds still while the '
          'previous wrench fell short there (wrench_achieved) by more than this many wrench '
          'tolerances (0.4 N, 0.08 N m for the paper\'s robot) in the direction the error '
          'pushes; 0: off', '-', low=0.0, high=1e6),
], prefix='gains')
_ZERO_GAINS = {'ki': (0.0,) * 6, 'integral_limit': (0.0,) * 6, 'antiwindup': 0.0}

#: ``switching.*``: the rule of the switching baseline (see the module docstring).
SWITCHING = ParamTable('switching', [
    Param('hysteresis', 'float', 0.5, "switching only: switch when the other group's error "
          "exceeds (1 + hysteresis) times the current group's", '-', low=0.0, high=1e6),
    Param('dwell_time', 'float', 1.0, 'switching only: least time between two switches', 's',
          low=0.0, high=1e6),
    Param('position_scale', 'float', 0.05, 'switching only: normalises position errors', 'm',
          low=1e-6, high=1e6),
    Param('angle_scale', 'float', 0.05, 'switching only: normalises angle errors', 'rad',
          low=1e-6, high=1e6),
    Param('deadband', 'float', 0.2, 'switching only: normalised error under which no switch '
          'happens', '-', low=0.0, high=1e6),
    Param('settle_time', 'float', 0.1, 'switching only: added to the servo travel before '
          'thrust resumes', 's', low=0.0, high=1e6),
], prefix='switching')

#: ``controller``: the control law.
CONTROL_LAW = ParamTable('control law', [
    Param('controller', 'str', 'pd', 'control law: pd (eq. 16), switching (baseline: tilts 0 '
          'or 90 deg, with tilt_request), pid (pd + g(eta) + clamped integral)',
          choices=CONTROLLER_KINDS, read_only=True),
])


@dataclass(frozen=True)
class Gains:
    """Per-DOF gains in the earth frame, order (x, y, z, roll, pitch, yaw).

    kp : N/m, N m/rad; kd : N s/m, N m s/rad; ki : N/(m s), N m/(rad s);
    integral_limit : bound on |Ki * integral(e)| per DOF [N, N m] (anti-windup).
    antiwindup : the shortfall, in wrench tolerances, that holds the integral (0: off).
    ``ki``, ``integral_limit`` and ``antiwindup`` are used by ``pid`` only.
    """

    kp: tuple[float, ...]
    kd: tuple[float, ...]
    ki: tuple[float, ...] = (0.0,) * 6
    integral_limit: tuple[float, ...] = (0.0,) * 6
    antiwindup: float = 0.0

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, source: str | None = None) -> Gains:
        """From the ``gains`` block (:data:`GAINS`); ``ki``, ``integral_limit`` and
        ``antiwindup`` may be absent."""
        return cls(**GAINS.complete(values, source=source, defaults=_ZERO_GAINS))


@dataclass(frozen=True)
class SwitchingSettings:
    """Rule of the switching baseline (see the module docstring; :data:`SWITCHING`).

    hysteresis : the other group's error must exceed (1 + hysteresis) times the
        current group's to switch [-]
    dwell_time : least time between two switches [s]
    position_scale, angle_scale : errors are normalised by these [m], [rad]
    deadband : normalised error under which no switch happens [-]
    settle_time : added to the servo travel time before thrust resumes [s]
    """

    hysteresis: float = SWITCHING['hysteresis'].default
    dwell_time: float = SWITCHING['dwell_time'].default
    position_scale: float = SWITCHING['position_scale'].default
    angle_scale: float = SWITCHING['angle_scale'].default
    deadband: float = SWITCHING['deadband'].default
    settle_time: float = SWITCHING['settle_time'].default

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *,
                     source: str | None = None) -> SwitchingSettings:
        """From the ``switching`` block; absent keys take their defaults."""
        return cls(**SWITCHING.complete(values, source=source))


@dataclass(frozen=True)
class ControllerConfig:
    """Which controller and its tuning: the ``wrench_controller`` parameters."""

    kind: ControllerKind
    gains: Gains
    switching: SwitchingSettings = field(default_factory=SwitchingSettings)
    source: str | None = field(default=None, compare=False, repr=False)

    def with_kind(self, kind: str) -> ControllerConfig:
        checked = CONTROL_LAW.check('controller', kind, source=self.source)
        return ControllerConfig(checked, self.gains, self.switching, self.source)

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *,
                     source: str | None = None) -> ControllerConfig:
        """From the ``ros__parameters`` of ``wrench_controller`` (other keys ignored)."""
        kind = CONTROL_LAW.complete({'controller': values['controller']}
                                   if 'controller' in values else {},
                                   source=source)['controller']
        gains = values.get('gains')
        if not isinstance(gains, Mapping):
            raise ParameterError('gains', 'missing; needs kp and kd (6 numbers each)',
                                 source=source)
        switching = values.get('switching', {})
        if not isinstance(switching, Mapping):
            raise ParameterError('switching', f'got {switching!r}; allowed: a mapping',
                                 source=source)
        return cls(kind, Gains.from_mapping(gains, source=source),
                   SwitchingSettings.from_mapping(switching, source=source), source)


def load_controller_config(path: str | Path | None = None) -> ControllerConfig:
    """Read ``wrench_controller: ros__parameters:`` from a YAML file (default: shipped)."""
    path = config_file(CONTROLLER_YAML) if path is None else Path(path)
    params = ros_parameters(path, node=CONTROLLER_YAML.removesuffix('.yaml'))
    if params is None:
        raise ParameterError('wrench_controller', 'no wrench_controller: ros__parameters: '
                             'block found', source=str(path))
    return ControllerConfig.from_mapping(params, source=str(path))


def make_controller(config: ControllerConfig, robot: RobotParams) -> Controller:
    """The controller ``config.kind`` names, with ``robot`` as its nominal model."""
    if config.kind == 'pd':
        return PDController(config.gains)
    if config.kind == 'pid':
        return PIDController(config.gains, robot)
    return SwitchingController(config.gains, config.switching, robot)


# --------------------------------------------------------------------------- the laws


@dataclass(frozen=True)
class TrackingError:
    """eta, e = eta_d - eta (angles wrapped), e_dot = eta_d_dot - J nu, and J(eta)."""

    eta: FloatArray
    e: FloatArray
    e_dot: FloatArray
    J: FloatArray


def tracking_error(position: ArrayLike, quaternion: ArrayLike, nu: ArrayLike,
                   reference: Reference) -> TrackingError:
    """The earth-frame errors of eq. (16), from odometry-shaped inputs."""
    q = quat_normalize(quaternion)
    q_d = quat_normalize(reference.quaternion)
    eta = np.concatenate([np.asarray(position, dtype=float), euler_from_quat(q)])
    eta_d = np.concatenate([np.asarray(reference.position, dtype=float), euler_from_quat(q_d)])
    e = eta_d - eta
    e[3:] = ssa(e[3:])
    # J(eta) is singular at pitch +-90 deg: evaluate it just short of there.
    eta_j = eta.copy()
    if abs(math.cos(eta_j[4])) < GIMBAL_GUARD_COS:
        eta_j[4] = math.copysign(math.acos(GIMBAL_GUARD_COS), eta_j[4])
    Jm = J(eta_j)
    e_dot = np.asarray(reference.velocity, dtype=float) - Jm @ np.asarray(nu, dtype=float)
    return TrackingError(eta, e, e_dot, Jm)


def earth_shortfall(err: TrackingError, short: ArrayLike) -> FloatArray:
    """A body-wrench shortfall (X Y Z K M N) in the earth-frame coordinates of the PID's
    terms: J(eta)^-T short, since tau = J^T (Kp e + ...)."""
    out: FloatArray = np.linalg.solve(err.J.T, np.asarray(short, dtype=float))
    return out


class PDController:
    """Eq. (16): tau = J(eta)^T (Kp e + Kd e_dot)."""

    def __init__(self, gains: Gains) -> None:
        self.gains = gains
        self._kp = np.array(gains.kp)
        self._kd = np.array(gains.kd)
        self.compiled = jit.compiled()
        self._law = (ck.CompiledLaw(ck.LAW_PD, ck.law_config(gains.kp, gains.kd))
                     if self.compiled else None)

    def reset(self) -> None:
        """PD has no state."""

    def update(self, t: float, position: FloatArray, quaternion: FloatArray, nu: FloatArray,
               reference: Reference, achieved: FloatArray | None = None) -> ControlOutput:
        """``achieved`` is ignored (pd has no integral to hold)."""
        if self.compiled and self._law is not None:
            out = self._law(position, quaternion, nu, reference)
            return ControlOutput(out[ck.OUT_TAU:ck.OUT_TAU + 6].copy(), None, 'pd')
        err = tracking_error(position, quaternion, nu, reference)
        return ControlOutput(err.J.T @ (self._kp * err.e + self._kd * err.e_dot), None, 'pd')


class PIDController:
    """PD (16) + g_hat(eta) + J^T Ki integral(e), with the integral clamped.

    g_hat is the restoring-force vector of the controller's nominal robot (it
    does not know the center-of-mass error); the integral removes what remains.
    The integral of each DOF is clamped so that |Ki integral(e)| stays within
    ``integral_limit`` (clamping anti-windup); it integrates with the time
    between updates (the control period), never more than 1 s at a time. With
    ``gains.antiwindup`` > 0 it holds still in a DOF where the previous command
    fell short (``achieved``: :func:`earth_shortfall` of last - achieved beyond
    ``antiwindup`` times the wrench tolerance,
    :func:`~tiltrov_ros.core.allocation.shortfall_tolerances`, with the sign of
    the error there).
    """

    def __init__(self, gains: Gains, robot: RobotParams) -> None:
        self.gains = gains
        self.robot = robot
        self._kp = np.array(gains.kp)
        self._kd = np.array(gains.kd)
        self._ki = np.array(gains.ki)
        limit = np.array(gains.integral_limit)
        with np.errstate(divide='ignore', invalid='ignore'):
            self._max_integral = np.where(self._ki > 0, limit / self._ki, 0.0)
        self._tolerance = gains.antiwindup * shortfall_tolerances(robot)
        self.compiled = jit.compiled()
        self._law = (ck.CompiledLaw(ck.LAW_PID, ck.law_config(
            gains.kp, gains.kd, gains.ki, self._max_integral, robot=robot,
            tolerance=self._tolerance)) if self.compiled else None)
        self._last = np.zeros(6)
        self.reset()

    @property
    def uses_achieved(self) -> bool:
        """The anti-windup reads the achieved wrench (``gains.antiwindup`` > 0)."""
        return self.gains.antiwindup > 0.0

    @property
    def integral(self) -> FloatArray:
        """integral(e) per DOF (earth frame), clamped; the compiled law updates it in place."""
        return self._integral

    @integral.setter
    def integral(self, value: ArrayLike) -> None:
        self._integral = np.array(value, dtype=np.float64).reshape(6)

    def reset(self) -> None:
        self.integral = np.zeros(6)
        self._last_t: float | None = None     # also: no previous command in self._last

    def resume(self, t: float, integral: ArrayLike, last: ArrayLike | None = None) -> None:
        """Continue as the controller that answered the tick at ``t`` (s) with the
        integral ``integral`` after it and the wrench ``last`` (None: unknown, no
        anti-windup at the next tick): the next update is that controller's, to the bit
        (a respawned controller resumes its predecessor, nodes/handoff.py)."""
        self.integral = integral
        self._last_t = float(t)
        self._last = (np.array(last, dtype=np.float64).reshape(6) if last is not None
                      else np.full(6, np.nan))

    def update(self, t: float, position: FloatArray, quaternion: FloatArray, nu: FloatArray,
               reference: Reference, achieved: FloatArray | None = None) -> ControlOutput:
        """``achieved``: what the allocator achieved of this controller's previous wrench
        (None: unknown; the integral then integrates as without it)."""
        previous = self._last_t
        got = (achieved if previous is not None and self.uses_achieved
               and np.all(np.isfinite(self._last)) else None)
        if self.compiled and self._law is not None:
            dt = 0.0 if previous is None else min(max(t - previous, 0.0), 1.0)
            out = self._law(position, quaternion, nu, reference, dt=dt,
                            integrate=previous is not None, integral=self._integral,
                            achieved=got, last=self._last)
            self._last_t = t
            return ControlOutput(out[ck.OUT_TAU:ck.OUT_TAU + 6].copy(), None, 'pid')
        err = tracking_error(position, quaternion, nu, reference)
        if previous is not None:
            dt = min(max(t - previous, 0.0), 1.0)
            moved = np.clip(self.integral + err.e * dt, -self._max_integral,
                            self._max_integral)
            if got is not None:
                short = earth_shortfall(err, self._last - np.asarray(got, dtype=float))
                wound = (np.abs(short) > self._tolerance) & (short * err.e > 0.0)
                moved = np.where(wound, self.integral, moved)
            self.integral = moved
        self._last_t = t
        g_hat = restoring_forces(self.robot, Rquat(quat_normalize(quaternion)))
        earth = self._kp * err.e + self._kd * err.e_dot + self._ki * self.integral
        self._last = g_hat + err.J.T @ earth
        return ControlOutput(self._last.copy(), None, 'pid')


class SwitchingController:
    """The selective switching baseline (see the module docstring for the rule)."""

    MODE_TILTS: ClassVar[dict[str, tuple[float, float]]] = {
        'horizontal': (0.0, 0.0), 'vertical': (0.5 * math.pi, 0.5 * math.pi)}

    def __init__(self, gains: Gains, settings: SwitchingSettings, robot: RobotParams) -> None:
        self.gains = gains
        self.settings = settings
        self.robot = robot
        self._kp = np.array(gains.kp)
        self._kd = np.array(gains.kd)
        self.compiled = jit.compiled()
        self._law = (ck.CompiledLaw(ck.LAW_SWITCHING, ck.law_config(
            gains.kp, gains.kd, scales=(settings.position_scale, settings.angle_scale)))
            if self.compiled else None)
        self.reset()

    def reset(self) -> None:
        self.mode: str | None = None
        self.tilts = (0.0, 0.0)            # where the servos were last sent
        self._switched_at = -math.inf
        self._moving_until = -math.inf
        self.switches = 0

    def _group_errors(self, e: FloatArray) -> tuple[float, float]:
        s = self.settings
        h = math.sqrt((e[0] / s.position_scale) ** 2 + (e[1] / s.position_scale) ** 2
                      + (e[5] / s.angle_scale) ** 2)
        v = math.sqrt((e[2] / s.position_scale) ** 2 + (e[3] / s.angle_scale) ** 2
                      + (e[4] / s.angle_scale) ** 2)
        return h, v

    def _switch_to(self, mode: str, t: float) -> None:
        target = self.MODE_TILTS[mode]
        travel = max(abs(target[0] - self.tilts[0]), abs(target[1] - self.tilts[1]))
        self._moving_until = t + travel / self.robot.tilt_rate_limit + self.settings.settle_time
        self._switched_at = t
        self.tilts = target
        self.mode = mode
        self.switches += 1

    def update(self, t: float, position: FloatArray, quaternion: FloatArray, nu: FloatArray,
               reference: Reference, achieved: FloatArray | None = None) -> ControlOutput:
        """``achieved`` is ignored (the baseline has no integral)."""
        tau: FloatArray | None = None
        if self.compiled and self._law is not None:
            out = self._law(position, quaternion, nu, reference)
            tau = out[ck.OUT_TAU:ck.OUT_TAU + 6]
            horizontal, vertical = out[ck.OUT_GROUPS:ck.OUT_GROUPS + 2].tolist()
        else:
            err = tracking_error(position, quaternion, nu, reference)
            horizontal, vertical = self._group_errors(err.e)
        if self.mode is None:
            # Start where the error is larger; depth and attitude first on a tie.
            self._switch_to('horizontal' if horizontal > vertical else 'vertical', t)
        elif t >= self._moving_until and t - self._switched_at >= self.settings.dwell_time:
            current, other = ((horizontal, vertical) if self.mode == 'horizontal'
                              else (vertical, horizontal))
            if (other > self.settings.deadband
                    and other > (1.0 + self.settings.hysteresis) * current):
                self._switch_to('vertical' if self.mode == 'horizontal' else 'horizontal', t)
        if t < self._moving_until:
            return ControlOutput(np.zeros(6), self.tilts, 'transition')
        if tau is None:
            tau = err.J.T @ (self._kp * err.e + self._kd * err.e_dot)
        mask = _HORIZONTAL if self.mode == 'horizontal' else _VERTICAL
        return ControlOutput(tau * mask, self.tilts, str(self.mode))


def retune(controller: Controller, config: ControllerConfig, robot: RobotParams) -> Controller:
    """A controller with ``config``'s gains that carries on from ``controller``'s state.

    For run-time gain changes (the ``wrench_controller`` node's parameters):
    the PID keeps its integral (clamped to the new limit) and the time of its
    last update; the switching baseline keeps its mode, its tilts and its
    switch and transition times. A different ``config.kind`` starts afresh.
    """
    new = make_controller(config, robot)
    if isinstance(controller, PIDController) and isinstance(new, PIDController):
        new.integral = np.clip(controller.integral, -new._max_integral, new._max_integral)
        new._last_t = controller._last_t
        new._last = controller._last.copy()
    elif isinstance(controller, SwitchingController) and isinstance(new, SwitchingController):
        new.mode = controller.mode
        new.tilts = controller.tilts
        new._switched_at = controller._switched_at
        new._moving_until = controller._moving_until
        new.switches = controller.switches
    return new
