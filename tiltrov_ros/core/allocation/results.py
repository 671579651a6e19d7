"""What the allocator returns: one result per wrench, or a batch of them."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
import math
import sys

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core.params import RobotParams

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Relative tolerance under which a wrench counts as produced (``feasible``):
#: ||achieved - requested|| <= FEASIBILITY_RTOL * max(||requested||, max_thrust).
#: The closed form itself is exact to rounding (tests check 1e-9).
FEASIBILITY_RTOL = 1e-6
#: What counts as *short* for the robot (as opposed to ``feasible``, exact to
#: rounding): a wrench component that misses by more than this fraction of a
#: thruster's range, max_thrust for the forces and max_thrust x min(l, d) / 2 for
#: the moments (0.4 N and 0.08 N m for the shipped robot). Below it the error is
#: within what a real thruster resolves, and the steady pose offset it causes
#: under the shipped PD gains (force / kp) is under 4.2 mm and 0.17 deg. The
#: robust mode's trade of a millinewton of wrench for less servo motion while
#: hovering (DEFAULT_MOTION_PENALTY) stays below it.
SHORTFALL_FRACTION = 0.01


@dataclass(frozen=True)
class AllocationResult:
    """Thrusts and tilts for one wrench.

    Attributes
    ----------
    thrusts : (4,) thrusts of thruster_1..4 [N]
    tilt_front, tilt_rear : alpha and beta [rad]
    achieved : (6,) wrench that the thrusts and tilts produce by eq. (4)
    feasible : True when ``achieved`` equals the request (see FEASIBILITY_RTOL)
    requested : (6,) the wrench asked for (non-finite components read as 0)
    method : how it was found: ``exact`` (a root of (**)), ``family`` (a member
        of a one-parameter family), ``zero`` (zero wrench), ``saturated`` (paper
        mode: the chosen root clipped to the limits), ``pseudo`` (paper mode:
        Section 3.2 case 3, Delta < 0), ``optimized`` (robust fallback),
        ``fixed_tilt`` (:meth:`ThrustAllocator.allocate_fixed`), ``transit``
        (robust: tilts on their way to an exact solution out of reach)
    discriminant : discriminant of (**) for the wrench scaled to max |tau_i| = 1;
        NaN where (**) does not apply (families, zero wrench, fixed tilts)
    error : weighted wrench error ||W (achieved - requested)||
    target : robust mode, ``transit``: the tilts the servos are heading for
        (:mod:`.planner`), else None
    stuck : robust mode: consecutive calls, this one included, without an exact
        solution within reach (0 when this one is exact)
    """

    thrusts: FloatArray
    tilt_front: float
    tilt_rear: float
    achieved: FloatArray
    feasible: bool
    requested: FloatArray
    method: str
    discriminant: float
    error: float
    target: tuple[float, float] | None = None
    stuck: int = 0

    @property
    def tilts(self) -> FloatArray:
        """(tilt_front, tilt_rear) [rad]."""
        return np.array([self.tilt_front, self.tilt_rear])


@dataclass(frozen=True)
class BatchResult:
    """Allocation of many wrenches, one row each (:meth:`ThrustAllocator.allocate_batch`:
    rows independent; :func:`allocate_sequence`: rows chained through ``previous``)."""

    thrusts: FloatArray      # (n, 4) [N]
    tilt_front: FloatArray   # (n,) [rad]
    tilt_rear: FloatArray    # (n,) [rad]
    achieved: FloatArray     # (n, 6)
    feasible: BoolArray      # (n,)
    error: FloatArray        # (n,) weighted wrench error

    @property
    def tilts(self) -> FloatArray:
        """(n, 2): (tilt_front, tilt_rear) [rad]."""
        return np.column_stack([self.tilt_front, self.tilt_rear])

    @classmethod
    def stack(cls, results: Sequence[AllocationResult]) -> BatchResult:
        """Rows of single results, in order."""
        n = len(results)
        return cls(np.array([r.thrusts for r in results], dtype=float).reshape(n, 4),
                   np.array([r.tilt_front for r in results], dtype=float),
                   np.array([r.tilt_rear for r in results], dtype=float),
                   np.array([r.achieved for r in results], dtype=float).reshape(n, 6),
                   np.array([r.feasible for r in results], dtype=bool),
                   np.array([r.error for r in results], dtype=float))


def infeasible_rows(requested: ArrayLike, achieved: ArrayLike, max_thrust: float) -> BoolArray:
    """The allocator's feasibility test, row by row, negated: True where
    ||achieved - requested|| > FEASIBILITY_RTOL * max(||requested||, max_thrust).

    ``requested`` and ``achieved`` are (n, 6); a row with a NaN is not counted
    infeasible (a value missing from a recording says nothing either way).
    """
    req = np.asarray(requested, dtype=float)
    miss = np.linalg.norm(np.asarray(achieved, dtype=float) - req, axis=-1)
    tol = FEASIBILITY_RTOL * np.maximum(np.linalg.norm(req, axis=-1), max_thrust)
    out: BoolArray = miss > tol
    return out


def tilts_only(prev: FloatArray) -> AllocationResult:
    """A stand-in previous result that carries only tilts (batch fallback)."""
    z = np.zeros(6)
    return AllocationResult(np.zeros(4), float(prev[0]), float(prev[1]), z, True, z,
                            'previous', math.nan, 0.0)


def shortfall_tolerances(robot: RobotParams, fraction: float = SHORTFALL_FRACTION
                         ) -> FloatArray:
    """Per component (X Y Z K M N) the shortfall above which a wrench counts as not
    achieved for the robot (see :data:`SHORTFALL_FRACTION`)."""
    force = fraction * robot.max_thrust
    moment = force * min(robot.length, robot.width) / 2.0
    return np.array([force] * 3 + [moment] * 3)


def from_tilts(previous: AllocationResult | None, tilts: Sequence[float]) -> AllocationResult:
    """``previous`` with its tilts replaced by ``tilts`` (the servos' measured angles):
    the next allocation then moves the tilts least, and at most ``max_tilt_step``,
    from where the servos are rather than from where they were told to go (the
    paper: the servos "could not follow the change of the tilting angle exactly").
    The robust mode's state (method, target, stuck) is kept."""
    if previous is None:
        return tilts_only(np.array([float(tilts[0]), float(tilts[1])]))
    return replace(previous, tilt_front=float(tilts[0]), tilt_rear=float(tilts[1]))


def norm(v: FloatArray) -> float:
    """Euclidean norm without intermediate overflow, capped at the largest float."""
    return min(math.hypot(*v.tolist()), sys.float_info.max)
