"""The steady-wrench oracle: what holding a setpoint costs, and whether the thrusters can pay it.

Holding a pose eta_d still (nu = 0) in a constant current v_c, eq. (1) in
its relative-velocity form (:mod:`tiltrov_ros.core.dynamics`) leaves::

    tau_s = C(nu_r) nu_r + D(nu_r) nu_r + g(eta_d) - tau_ext,   nu_r = [-R(q_d)^T v_c; 0]

the Coriolis (Munk) term (A.3) and the drag (A.4) of the current in the body
frame at the setpoint attitude, the restoring forces g with the *true* center
of gravity (nominal r_g plus the center-of-mass error) and the external
wrench that lasts. :func:`steady_wrench` computes it.

:func:`judge` asks the allocator's global optimum (robust mode without
``previous``: an exact solution if one lies within the thrust limit, else the
least weighted error over every tilt, :mod:`.allocation.robust`) whether some
configuration produces tau_s within the wrench tolerance
(:func:`~tiltrov_ros.core.allocation.shortfall_tolerances`: 0.4 N, 0.08 N m
for the shipped robot), once within the servo range and once over the full
circle (+-180 deg). A range at least 180 deg wide already holds every thrust
line (a tilt and its twin pi away are the same line, the thrust negated): the
two answers differ only for narrower ranges. What a wide range changes is
whether the servos can *reach* the configuration continuously, which no
static test answers: the wander oracle (:mod:`.wander`) asks it of the demand
as the current wanders (docs/campaign.md, "Verdicts").

The result's ``ratio`` is the largest shortfall in units of its tolerance:
at most 1 means attainable. :class:`HoldMonitor` asks the same of the demand
the allocator sees, live (the ``thrust_allocator`` node's ``/diagnostics``): reach
only; whether a run held, and why not, is :mod:`.hold`'s, after the run, with the
wander of the current (:mod:`.wander`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core.allocation import (
    SHORTFALL_FRACTION,
    ThrustAllocator,
    shortfall_tolerances,
)
from tiltrov_ros.core.allocation.allocator import DEFAULT_WEIGHTS
from tiltrov_ros.core.dynamics import (
    coriolis_matrix,
    damping_matrix,
    relative_velocity,
    restoring_forces,
)
from tiltrov_ros.core.kinematics import Rquat, quat_normalize
from tiltrov_ros.core.names import WRENCH_DOFS
from tiltrov_ros.core.params import RobotParams

FloatArray = NDArray[np.float64]

#: The full circle of a servo that turns past vertical: the counterfactual range.
FULL_CIRCLE = (-math.pi, math.pi)


def steady_wrench(robot: RobotParams, quaternion: ArrayLike, current: ArrayLike,
                  external: ArrayLike | None = None) -> FloatArray:
    """tau_s (X Y Z K M N), N and N m: the body wrench that holds the attitude
    ``quaternion`` (w, x, y, z) still in the NED ``current`` (m/s) against the
    ``external`` wrench that lasts. ``robot`` is the true one (its r_g with the
    center-of-mass error: :meth:`~tiltrov_ros.core.disturbances.Disturbances.true_params`).
    """
    R = Rquat(quat_normalize(quaternion))
    nu_r = relative_velocity(np.zeros(6), R, current)        # [-R^T v_c; 0]
    tau = (coriolis_matrix(robot, nu_r) @ nu_r                # (A.3), the Munk moment
           + damping_matrix(robot, nu_r) @ nu_r               # (A.4) + linear
           + restoring_forces(robot, R))                      # g(eta), true r_g
    if external is not None:
        tau = tau - np.asarray(external, dtype=float)
    out: FloatArray = tau
    return out


@dataclass(frozen=True)
class Attainable:
    """The global optimum's answer for one wrench and one tilt range.

    achieved : (6,) eq. (4) of the best configuration
    shortfall : (6,) wrench - achieved
    ratio : max |shortfall_k| / tolerance_k (<= 1: attainable)
    tilts : (tilt_front, tilt_rear) of that configuration, rad
    """

    achieved: FloatArray
    shortfall: FloatArray
    ratio: float
    tilts: tuple[float, float]

    @property
    def attainable(self) -> bool:
        return self.ratio <= 1.0


@dataclass(frozen=True)
class SteadyVerdict:
    """tau_s against the servo range (``in_range``) and the full circle (``full_circle``)."""

    wrench: FloatArray
    in_range: Attainable
    full_circle: Attainable

    @property
    def verdict(self) -> str:
        """``attainable``; ``servo_range`` (only past the servos' range); ``physics``
        (no tilt on the full circle produces it)."""
        if self.in_range.attainable:
            return 'attainable'
        return 'servo_range' if self.full_circle.attainable else 'physics'


class Oracle:
    """The global optimum for one robot, within its servo range and over the full
    circle (the robust allocator without ``previous``, built once)."""

    def __init__(self, robot: RobotParams, weights: Sequence[float] = DEFAULT_WEIGHTS,
                 fraction: float = SHORTFALL_FRACTION) -> None:
        self.robot = robot
        self.tolerances = shortfall_tolerances(robot, fraction)
        limits = (robot.tilt_min, robot.tilt_max)
        self._inside = self._allocator(limits, weights)
        self._full = self._inside if limits == FULL_CIRCLE else \
            self._allocator(FULL_CIRCLE, weights)

    def _allocator(self, limits: tuple[float, float], weights: Sequence[float]
                   ) -> ThrustAllocator:
        r = self.robot
        return ThrustAllocator(r.length, r.width, r.max_thrust, limits, math.inf, 'robust',
                               weights, planning=False)

    def _best(self, allocator: ThrustAllocator, tau: FloatArray) -> Attainable:
        result = allocator.allocate(tau)
        achieved = np.asarray(result.achieved, dtype=float)
        shortfall = tau - achieved
        return Attainable(achieved, shortfall, float(np.max(np.abs(shortfall) / self.tolerances)),
                          (result.tilt_front, result.tilt_rear))

    def judge(self, wrench: ArrayLike) -> SteadyVerdict:
        """``wrench`` within the servo range and over the full circle."""
        tau = np.asarray(wrench, dtype=float)
        inside = self._best(self._inside, tau)
        full = inside if self._full is self._inside else self._best(self._full, tau)
        return SteadyVerdict(tau, inside, full)


def judge(robot: RobotParams, wrench: ArrayLike, weights: Sequence[float] = DEFAULT_WEIGHTS,
          fraction: float = SHORTFALL_FRACTION) -> SteadyVerdict:
    """``wrench`` within ``robot``'s tilt range and over the full circle (:class:`Oracle`)."""
    return Oracle(robot, weights, fraction).judge(wrench)


@dataclass(frozen=True)
class RunSetting:
    """What a run's meta says the oracles need: the robot with its true center of mass,
    the disturbances, and the allocator's weights."""

    robot: RobotParams
    disturbances: Mapping[str, Any]
    external: tuple[float, ...]
    weights: tuple[float, ...]


def run_setting(meta: Mapping[str, Any]) -> RunSetting | None:
    """The :class:`RunSetting` of a run's meta (``robot``, ``disturbances``,
    ``allocator_weights``: :meth:`~tiltrov_ros.core.runner.StackConfig.describe`); None
    when the meta lacks them or the lasting external wrench is unknown."""
    robot_doc, dist = meta.get('robot'), meta.get('disturbances')
    if not isinstance(robot_doc, Mapping) or not isinstance(dist, Mapping):
        return None
    external = dist.get('external_wrench_lasting')
    if not isinstance(external, Sequence) or isinstance(external, str):
        return None
    try:
        nominal = RobotParams.from_mapping(robot_doc)
        r_g = tuple(g + e for g, e in zip(nominal.center_of_gravity, dist['com_error']))
        weights = meta.get('allocator_weights') or DEFAULT_WEIGHTS
        return RunSetting(replace(nominal, center_of_gravity=r_g), dist,
                          tuple(float(v) for v in external), tuple(float(w) for w in weights))
    except (TypeError, ValueError, KeyError):     # ParameterError is a ValueError
        return None


def from_meta(meta: Mapping[str, Any], quaternion: ArrayLike) -> SteadyVerdict | None:
    """The verdict for a run's final setpoint attitude from its meta (:func:`run_setting`);
    None when the meta lacks what it needs."""
    setting = run_setting(meta)
    if setting is None:
        return None
    try:
        tau = steady_wrench(setting.robot, quaternion, setting.disturbances['current'],
                            setting.external)
        return judge(setting.robot, tau, setting.weights)
    except (TypeError, ValueError, KeyError):     # ParameterError is a ValueError
        return None


#: s: the window over which :class:`HoldMonitor` looks at the demand.
HOLD_WINDOW = 2.0
#: A demand is steady when no component spreads (max - min over the window) by
#: more than this many wrench tolerances: the controller asks for one wrench.
STEADY_SPREAD = 5.0
#: The allocator fell short (beyond the tolerance) at this fraction of the
#: window's ticks at least.
SHORT_FRACTION = 0.5


class HoldMonitor:
    """What the allocator says live: whether the steady demand is within the servo
    range's reach. Reach only, never a verdict on holding: whether a run holds, and
    why not, is judged after the run (:mod:`tiltrov_ros.core.hold`).

    Fed every tick with the wrench asked for and the one achieved
    (:meth:`update`); at the end of each window of :data:`HOLD_WINDOW` it judges
    the window: when the demand was steady (:data:`STEADY_SPREAD`) and short at
    :data:`SHORT_FRACTION` of the ticks at least, the :class:`Oracle` is asked
    about its mean. ``verdict`` is then that answer (``verdict.in_range`` not
    attainable: no tilt within the range produces the demand;
    ``verdict.full_circle``: whether servos turning all the way round would), else
    None. The window's ticks come from the control period; a stamp going back
    calls for :meth:`reset`.
    """

    def __init__(self, robot: RobotParams, control_period: float,
                 weights: Sequence[float] = DEFAULT_WEIGHTS,
                 fraction: float = SHORTFALL_FRACTION) -> None:
        self.oracle = Oracle(robot, weights, fraction)
        self.size = max(1, round(HOLD_WINDOW / control_period))
        self._wrenches = np.zeros((self.size, 6))
        self._short = np.zeros(self.size, dtype=bool)
        self.reset()

    def reset(self) -> None:
        self._count = 0
        self.verdict: SteadyVerdict | None = None

    @property
    def out_of_reach(self) -> bool:
        """The last window's steady demand lies beyond the servo range's reach."""
        return self.verdict is not None and not self.verdict.in_range.attainable

    def update(self, wrench: ArrayLike, achieved: ArrayLike) -> None:
        """One tick: the wrench asked for and the one achieved (N, N m)."""
        k = self._count % self.size
        self._wrenches[k] = wrench
        self._short[k] = bool(np.any(np.abs(self._wrenches[k] - np.asarray(achieved))
                                     > self.oracle.tolerances))
        self._count += 1
        if self._count % self.size:
            return
        spread = np.ptp(self._wrenches, axis=0)
        steady = bool(np.all(spread <= STEADY_SPREAD * self.oracle.tolerances))
        if steady and np.mean(self._short) >= SHORT_FRACTION:
            self.verdict = self.oracle.judge(np.mean(self._wrenches, axis=0))
        else:
            self.verdict = None

    def report(self) -> tuple[str, dict[str, Any]]:
        """For /diagnostics: :meth:`message` and the values (``out_of_reach``, the last
        judged ``steady_demand`` and its ``steady_shortfall``, N and N m)."""
        v = self.verdict
        return self.message(), {
            'out_of_reach': self.out_of_reach,
            'steady_demand': [] if v is None else [float(x) for x in v.wrench],
            'steady_shortfall': [] if v is None else [float(x) for x in v.in_range.shortfall]}

    def message(self) -> str:
        """One line for /diagnostics ('' while nothing is to be said)."""
        v = self.verdict
        if v is None or v.in_range.attainable:
            return ''
        short = ', '.join(f'{dof} {value:+.3g}' for dof, value, tol in
                          zip(WRENCH_DOFS, v.in_range.shortfall, self.oracle.tolerances)
                          if abs(value) > tol)
        beyond = ('within reach of servos turning past vertical' if v.full_circle.attainable
                  else 'beyond the reach of every tilt on the full circle too')
        return (f'steady demand out of the servo range\'s reach: short by {short} at every '
                f'tilt in range ({beyond})')
