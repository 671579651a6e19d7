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
        self._thrusts = start
        self._command = list(start)
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
        return tuple(self._thrusts)

    @property
    def command_held(self) -> tuple[float, ...]:
        """The command in force (after saturation), N."""
        return tuple(self._command)

    def command(self, thrusts: ArrayLike) -> bool:
        """Hold a new command (4 thrusts, N); saturated to the limit.

        Returns False, and keeps the previous command, if any value is not finite.
        """
        values = _as_floats(thrusts, 4, 'thrust command')
        if not all(math.isfinite(v) for v in values):
            self.rejected += 1
            return False
        lim = self.max_thrust
        self._command = [_clip(v, -lim, lim) for v in values]
        return True

    def set_failed(self, indices: Sequence[int]) -> None:
        """Mark thrusters (indices 0..3) failed; the others work again."""
        failed = tuple(sorted({int(i) for i in indices}))
        if any(i not in range(4) for i in failed):
            raise ParameterError('failed_thrusters', f'got {list(indices)!r}; allowed: '
                                 'indices 0..3 (thruster_1..thruster_4)')
        self.failed = failed

    def step(self, h: float) -> None:
        """Advance the thrusts by h seconds toward the held command (exact first order);
        a failed thruster's target is zero."""
        if h != self._h:
            self._h = h
            self._decay = math.exp(-h / self.time_constant) if self.time_constant > 0 else 0.0
        e = self._decay
        target = self._command
        if self.failed:
            target = [0.0 if i in self.failed else c for i, c in enumerate(target)]
        self._thrusts = [c + (f - c) * e for f, c in zip(self._thrusts, target)]


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
        self._angles = start
        self._velocities = [0.0, 0.0]
        self._command = list(start)
        self.rejected = 0

    @classmethod
    def from_params(cls, params: RobotParams, initial: ArrayLike = (0.0, 0.0)) -> TiltServos:
        return cls(params.tilt_min, params.tilt_max, params.tilt_rate_limit, initial)

    @property
    def angles(self) -> tuple[float, ...]:
        """Actual (tilt_front, tilt_rear), rad."""
        return tuple(self._angles)

    @property
    def velocities(self) -> tuple[float, ...]:
        """(a_k - a_{k-1}) / h of each servo, rad/s (zero before the first step)."""
        return tuple(self._velocities)

    @property
    def command_held(self) -> tuple[float, ...]:
        """The command in force (after clipping to the angle limits), rad."""
        return tuple(self._command)

    def command(self, tilts: Sequence[float] | ArrayLike) -> bool:
        """Hold a new command (tilt_front, tilt_rear), rad; clipped to the angle limits.

        Returns False, and keeps the previous command, if any value is not finite.
        """
        values = _as_floats(tilts, 2, 'tilt command')
        if not all(math.isfinite(v) for v in values):
            self.rejected += 1
            return False
        self._command = [_clip(v, self.tilt_min, self.tilt_max) for v in values]
        return True

    def step(self, h: float) -> None:
        """Move each angle toward the held command by at most rate_limit * h."""
        max_move = self.rate_limit * h
        new = [c if abs(c - a) <= max_move else a + math.copysign(max_move, c - a)
               for a, c in zip(self._angles, self._command)]
        self._velocities = [(n - a) / h for n, a in zip(new, self._angles)]
        self._angles = new
