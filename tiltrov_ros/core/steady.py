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
static test answers; the campaign's counterfactual run does
(docs/campaign.md, "Verdicts").

The result's ``ratio`` is the largest shortfall in units of its tolerance:
at most 1 means attainable.
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


def attainable(robot: RobotParams, wrench: ArrayLike, tilt_limits: tuple[float, float],
               weights: Sequence[float] = DEFAULT_WEIGHTS,
               fraction: float = SHORTFALL_FRACTION) -> Attainable:
    """The best configuration for ``wrench`` over every tilt in ``tilt_limits`` and
    every thrust within the limit (the robust allocator without ``previous``)."""
    tau = np.asarray(wrench, dtype=float)
    allocator = ThrustAllocator(robot.length, robot.width, robot.max_thrust, tilt_limits,
                                math.inf, 'robust', weights, planning=False)
    result = allocator.allocate(tau)
    achieved = np.asarray(result.achieved, dtype=float)
    shortfall = tau - achieved
    ratio = float(np.max(np.abs(shortfall) / shortfall_tolerances(robot, fraction)))
    return Attainable(achieved, shortfall, ratio, (result.tilt_front, result.tilt_rear))


def judge(robot: RobotParams, wrench: ArrayLike, weights: Sequence[float] = DEFAULT_WEIGHTS,
          fraction: float = SHORTFALL_FRACTION) -> SteadyVerdict:
    """``wrench`` within ``robot``'s tilt range and over the full circle."""
    tau = np.asarray(wrench, dtype=float)
    inside = attainable(robot, tau, (robot.tilt_min, robot.tilt_max), weights, fraction)
    full = inside if (robot.tilt_min, robot.tilt_max) == FULL_CIRCLE else \
        attainable(robot, tau, FULL_CIRCLE, weights, fraction)
    return SteadyVerdict(tau, inside, full)


def from_meta(meta: Mapping[str, Any], quaternion: ArrayLike) -> SteadyVerdict | None:
    """The verdict for a run's final setpoint attitude from its meta (``robot``,
    ``disturbances``, ``allocator_weights``: :meth:`~tiltrov_ros.core.runner.StackConfig.
    describe`); None when the meta lacks them or the lasting external wrench is unknown."""
    robot_doc, dist = meta.get('robot'), meta.get('disturbances')
    if not isinstance(robot_doc, Mapping) or not isinstance(dist, Mapping):
        return None
    external = dist.get('external_wrench_lasting')
    if not isinstance(external, Sequence) or isinstance(external, str):
        return None
    try:
        nominal = RobotParams.from_mapping(robot_doc)
        r_g = tuple(g + e for g, e in zip(nominal.center_of_gravity, dist['com_error']))
        robot = replace(nominal, center_of_gravity=r_g)
        weights = meta.get('allocator_weights') or DEFAULT_WEIGHTS
        tau = steady_wrench(robot, quaternion, dist['current'], external)
        return judge(robot, tau, tuple(float(w) for w in weights))
    except (TypeError, ValueError, KeyError):     # ParameterError is a ValueError
        return None
