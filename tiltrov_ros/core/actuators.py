"""Actuator models: four thrusters and two tilt servos.

The plant applies the actuators' *actual* state to eq. (4), never the raw
command. Both models hold the last accepted command (zero-order hold) and move
toward it one plant step at a time.

Thrusters (:class:`ThrusterBank`)
    The command is saturated to [-max_thrust, max_thrust], then each thrust
    follows it with a first-order lag of time constant T, discretised exactly
    for a command held over the step: f <- c + (f - c) exp(-h / T). A step
    command c from f = 0 therefore gives f(t_k) = c (1 - exp(-t_k / T)) at every
    step, and the thrust never leaves the limits. T = 0 means f = c at once.

Tilt servos (:class:`TiltServos`)
    The command is clipped to [tilt_min, tilt_max]; each angle moves toward it
    by at most ``rate_limit * h`` per step (a rate-limited servo with no
    overshoot), so 0 -> 90 deg takes (90 deg / rate limit) s and never less.
    The reported velocity is the backward difference (a_k - a_{k-1}) / h, the
    rate at which the servo arrived at its current angle (zero initially); it
    never exceeds the rate limit.

State arrays
    Each model keeps its state in one small float64 array (``state``, the
    layout below) so that the plant's compiled step
    (:mod:`tiltrov_ros.core.plant_kernels`) updates it in place; the methods
    here are the reference it is tested against.

Non-finite commands
    A command with any NaN or infinite element is rejected as a whole (the
    thrust vector and the tilt pair are rejected separately, as they arrive in
    separate ``thrust_cmd`` and ``tilt_cmd`` messages): the previous command stays
    in force, ``command`` returns False and the ``rejected`` counter grows, so
    the node can report it on ``/diagnostics``. Nothing non-finite ever reaches
    the actuator state or the body. A command of the wrong length is a
    programming error and raises ValueError.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.params import RobotParams

FloatArray = NDArray[np.float64]


# ThrusterBank.state: float64[THRUSTER_STATE]
THRUST = 0               # 4 entries: actual thrusts [N]
THRUST_CMD = 4           # 4 entries: the command in force (saturated) [N]
THRUST_WORKING = 8       # 4 entries: 1.0 working, 0.0 failed
THRUSTER_STATE = 12
# TiltServos.state: float64[SERVO_STATE]
TILT = 0                 # 2 entries: actual (tilt_front, tilt_rear) [rad]
TILT_VELOCITY = 2        # 2 entries: backward differences [rad/s]
TILT_CMD = 4             # 2 entries: the command in force (clipped) [rad]
SERVO_STATE = 6


def thruster_decay(time_constant: float, h: float) -> float:
    """exp(-h / T): the first-order lag over one step of h s (0 for an ideal thruster)."""
    return math.exp(-h / time_constant) if time_constant > 0 else 0.0


def _as_floats(values: ArrayLike, n: int, what: str) -> list[float]:
    out = np.asarray(values, dtype=float).reshape(-1)
    if out.shape != (n,):
        raise ValueError(f'{what}: expected {n} values, got shape {np.shape(values)}')
    return [float(v) for v in out]


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


class ThrusterBank:
    """Four thrusters: saturation, then a first-order response (see the module docstring).

    Parameters
    ----------
    max_thrust : float
        Limit in both directions, N (> 0).
    time_constant : float
        First-order time constant T, s (>= 0; 0: ideal).
    initial : array_like, (4,)
        Initial thrusts (and command), N, within the limits.
    """

    def __init__(self, max_thrust: float, time_constant: float,
                 initial: ArrayLike = (0.0, 0.0, 0.0, 0.0)) -> None:
        if not (math.isfinite(max_thrust) and max_thrust > 0.0):
            raise ParameterError('robot.max_thrust', f'got {max_thrust!r}; allowed: (0, inf)')
        if not (math.isfinite(time_constant) and time_constant >= 0.0):
            raise ParameterError('robot.thruster_time_constant',
                                 f'got {time_constant!r}; allowed: [0, inf)')
        self.max_thrust = float(max_thrust)
        self.time_constant = float(time_constant)
        start = _as_floats(initial, 4, 'initial thrusts')
        if not all(math.isfinite(v) and abs(v) <= self.max_thrust for v in start):
            raise ParameterError('initial thrusts',
                                 f'got {start!r}; allowed: 4 finite values in '
                                 f'[-{self.max_thrust:g}, {self.max_thrust:g}] N')
        #: thrusts, command and working flags (layout: ``THRUST``, ``THRUST_CMD``,
        #: ``THRUST_WORKING``), updated in place.
        self.state = np.zeros(THRUSTER_STATE)
        self.state[THRUST:THRUST + 4] = start
        self.state[THRUST_CMD:THRUST_CMD + 4] = start
        self.state[THRUST_WORKING:THRUST_WORKING + 4] = 1.0
        self.rejected = 0
        #: Indices 0..3 of failed thrusters: they ignore their command and spin down
        #: to zero thrust with the time constant.
        self.failed: tuple[int, ...] = ()
        self._h = -1.0
        self._decay = 0.0

    @classmethod
    def from_params(cls, params: RobotParams, initial: ArrayLike = (0.0, 0.0, 0.0, 0.0)
                    ) -> ThrusterBank:
        return cls(params.max_thrust, params.thruster_time_constant, initial)

    @property
    def thrusts(self) -> tuple[float, ...]:
        """Actual thrusts of thruster_1..4, N."""
        return tuple(self.state[THRUST:THRUST + 4].tolist())

    @property
    def command_held(self) -> tuple[float, ...]:
        """The command in force (after saturation), N."""
        return tuple(self.state[THRUST_CMD:THRUST_CMD + 4].tolist())

    def command(self, thrusts: ArrayLike) -> bool:
        """Hold a new command (4 thrusts, N); saturated to the limit.

        Returns False, and keeps the previous command, if any value is not finite.
        """
        values = _as_floats(thrusts, 4, 'thrust command')
        if not all(math.isfinite(v) for v in values):
            self.rejected += 1
            return False
        lim = self.max_thrust
        self.state[THRUST_CMD:THRUST_CMD + 4] = [_clip(v, -lim, lim) for v in values]
        return True

    def set_failed(self, indices: Sequence[int]) -> None:
        """Mark thrusters (indices 0..3) failed; the others work again."""
        failed = tuple(sorted({int(i) for i in indices}))
        if any(i not in range(4) for i in failed):
            raise ParameterError('failed_thrusters', f'got {list(indices)!r}; allowed: '
                                 'indices 0..3 (thruster_1..thruster_4)')
        self.failed = failed
        self.state[THRUST_WORKING:THRUST_WORKING + 4] = [0.0 if i in failed else 1.0
                                                         for i in range(4)]

    def step(self, h: float) -> None:
        """Advance the thrusts by h seconds toward the held command (exact first order);
        a failed thruster's target is zero."""
        if h != self._h:
            self._h = h
            self._decay = thruster_decay(self.time_constant, h)
        e = self._decay
        values = self.state.tolist()
        target = values[THRUST_CMD:THRUST_CMD + 4]
        if self.failed:
            target = [0.0 if i in self.failed else c for i, c in enumerate(target)]
        self.state[THRUST:THRUST + 4] = [c + (f - c) * e for f, c in
                                         zip(values[THRUST:THRUST + 4], target)]


class TiltServos:
    """The two tilt servos (tilt_front alpha, tilt_rear beta): angle and rate limits.

    Parameters
    ----------
    tilt_min, tilt_max : float
        Angle limits, rad.
    rate_limit : float
        Maximum angular speed, rad/s (> 0).
    initial : array_like, (2,)
        Initial angles (and command), rad, within the limits.
    """

    def __init__(self, tilt_min: float, tilt_max: float, rate_limit: float,
                 initial: ArrayLike = (0.0, 0.0)) -> None:
        if not (math.isfinite(tilt_min) and math.isfinite(tilt_max) and tilt_min < tilt_max):
            raise ParameterError('robot.tilt_min',
                                 f'got [{tilt_min!r}, {tilt_max!r}]; allowed: tilt_min < tilt_max')
        if not (math.isfinite(rate_limit) and rate_limit > 0.0):
            raise ParameterError('robot.tilt_rate_limit', f'got {rate_limit!r}; allowed: (0, inf)')
        self.tilt_min = float(tilt_min)
        self.tilt_max = float(tilt_max)
        self.rate_limit = float(rate_limit)
        start = _as_floats(initial, 2, 'initial tilts')
        if not all(math.isfinite(v) and self.tilt_min <= v <= self.tilt_max for v in start):
            raise ParameterError('initial tilts',
                                 f'got {start!r}; allowed: 2 values in '
                                 f'[{self.tilt_min:g}, {self.tilt_max:g}] rad')
        #: angles, velocities and command (layout: ``TILT``, ``TILT_VELOCITY``,
        #: ``TILT_CMD``), updated in place.
        self.state = np.zeros(SERVO_STATE)
        self.state[TILT:TILT + 2] = start
        self.state[TILT_CMD:TILT_CMD + 2] = start
        self.rejected = 0

    @classmethod
    def from_params(cls, params: RobotParams, initial: ArrayLike = (0.0, 0.0)) -> TiltServos:
        return cls(params.tilt_min, params.tilt_max, params.tilt_rate_limit, initial)

    @property
    def angles(self) -> tuple[float, ...]:
        """Actual (tilt_front, tilt_rear), rad."""
        return tuple(self.state[TILT:TILT + 2].tolist())

    @property
    def velocities(self) -> tuple[float, ...]:
        """(a_k - a_{k-1}) / h of each servo, rad/s (zero before the first step)."""
        return tuple(self.state[TILT_VELOCITY:TILT_VELOCITY + 2].tolist())

    @property
    def command_held(self) -> tuple[float, ...]:
        """The command in force (after clipping to the angle limits), rad."""
        return tuple(self.state[TILT_CMD:TILT_CMD + 2].tolist())

    def command(self, tilts: Sequence[float] | ArrayLike) -> bool:
        """Hold a new command (tilt_front, tilt_rear), rad; clipped to the angle limits.

        Returns False, and keeps the previous command, if any value is not finite.
        """
        values = _as_floats(tilts, 2, 'tilt command')
        if not all(math.isfinite(v) for v in values):
            self.rejected += 1
            return False
        self.state[TILT_CMD:TILT_CMD + 2] = [_clip(v, self.tilt_min, self.tilt_max)
                                             for v in values]
        return True

    def step(self, h: float) -> None:
        """Move each angle toward the held command by at most rate_limit * h."""
        max_move = self.rate_limit * h
        values = self.state.tolist()
        angles = values[TILT:TILT + 2]
        new = [c if abs(c - a) <= max_move else a + math.copysign(max_move, c - a)
               for a, c in zip(angles, values[TILT_CMD:TILT_CMD + 2])]
        self.state[TILT_VELOCITY:TILT_VELOCITY + 2] = [(n - a) / h for n, a in zip(new, angles)]
        self.state[TILT:TILT + 2] = new
