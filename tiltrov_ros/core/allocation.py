"""Thrust allocation for four thrusters that share two tilt servos (Section 3).

The paper's method, made correct and complete (``mode='paper'``), and a robust
allocator built on it (``mode='robust'``, the default).

Decomposition (Section 3.1)
---------------------------
tau = A q (5) with q = (f_i sin(tilt_i), f_i cos(tilt_i)): the vertical
components z = q[0:4] only enter (Z, K, M) and the horizontal ones h = q[4:8]
only (X, Y, N). The pseudo-inverse c = A^+ tau plus the two null-space
directions of A give q = c + N xi, eqs. (10)-(11). One tilt per pair imposes
(9): q1 q6 = q2 q5 and q3 q8 = q4 q7.

Re-derivation used here
-----------------------
Write each pair with sums and differences: for the front pair
Zf = z1 + z2, Uf = z1 - z2, Hf = h1 + h2, Df = h1 - h2 (rear: Zr, Ur, Hr, Dr).
The wrench fixes four of them,

    Zf = -Z/2 + M/l,   Zr = -Z/2 - M/l,                  (rows Z, M of (4))
    Df = (sqrt2 Y + N/k)/2,  Dr = (sqrt2 Y - N/k)/2,     (rows Y, N; k = (l+d)/(2 sqrt2))
    Uf - Ur = kappa = 2K/d,  Hf + Hr = H = sqrt2 X,      (rows K, X)

and leaves two null-space coordinates free, U = Uf and V = Hf
(U = c1 - c2 - 2 xi2 and V = c5 + c6 - 2 xi1 in the paper's notation).
Constraint (9) for a pair, z1 h2 = z2 h1, is exactly Uf Hf = Zf Df, so (9) is

    U V = P,   (U - kappa)(H - V) = Q,   P = Zf Df,  Q = Zr Dr,        (*)

two rectangular hyperbolas. For U not in {0, kappa}, eliminating V gives the
quadratic that replaces (12)-(15):

    H U^2 - (P + Q + kappa H) U + kappa P = 0.                         (**)

Errors in the printed formulas (each checked by a test in
``test/core/test_allocation.py``):

* (7) pairs the wrong components: f1 = sign(q5) sqrt(q1^2 + q5^2) (printed
  sqrt(q1^2 + q3^2)), and likewise f2 from (q2, q6), f3 from (q3, q7), f4 from
  (q4, q8).
* (14): c_bar = (-c1 + c2) b2 + (c1 c6 - c2 c5); the printed c_bar drops the
  constant term of the first equation of (12).
* (8) uses arctan(q1/q5), which loses the quadrant and divides by zero at
  +-90 deg; here the tilt is atan2 folded into the tilt range, with a signed
  thrust.
* (13) divides by -c1 + c2 + c3 - c4, which is -2K/d for the minimum-norm c,
  and (15) by a_bar = 2 b1, proportional to X/K: they vanish for every
  left-right symmetric wrench (K = 0) and whenever X = 0, that is in ordinary
  hovering. (**) divides by neither; what remains are the one-parameter
  families of solutions below, which the paper does not cover.

Solution sets of (*):

* generic: the roots of (**) (one double root when its discriminant is zero,
  none when it is negative: the paper's Delta < 0), plus U = 0 or U = kappa when
  they solve (*);
* family F1 (P = Q = kappa = 0, e.g. surge + heave + pitch): U = 0, V free;
* family F2 (P = Q = H = 0, e.g. pure heave or pure pitch): V = 0, U free;
* family F3 (kappa = H = 0, P = -Q != 0): V = P/U, U free.

A tilt gamma and gamma +- pi give the same thrust line (the thrust changes
sign): every such alternative within the tilt range is a candidate too, so a
tilt near +90 deg is not flipped to -90 deg when it need not be.

Choosing the solution (Section 3.2, completed)
----------------------------------------------
Among discrete solutions, the one whose tilts move least from ``previous``
(sum of squared tilt changes; from 0 without ``previous``), as in the paper,
ties going to positive thrust (at +-90 deg from neutral: the thrust line can
then turn on past vertical without a 180 deg flip);
only solutions within the thrust limit and the tilt range (and, in robust
mode, within ``max_tilt_step`` of ``previous``) qualify. Within a family, "moves
the tilts least" has no minimiser worth having (it pushes the thrusts to their
limit to avoid any tilt motion), so the member with the least thrust
(sum f_i^2) among those that qualify is chosen, ties going to the least tilt
motion; the unconstrained least-thrust member is the pseudo-inverse solution
xi = 0 (F1: V = H/2, F2: U = kappa/2, F3: U^2 = |P|).

Robust mode
-----------
Exact whenever an exact solution qualifies: then the same answer as the
paper mode. When none does (negative discriminant, thrust beyond the limit,
tilts out of range or out of reach), it returns the attainable configuration
with the least weighted wrench error ||W (tau(f, alpha, beta) - tau_d)||: from
warm starts (the closed-form candidates and the paper mode's answer brought
into reach, the previous tilts, a coarse grid), a damped Gauss-Newton search
over the two tilts in which the thrusts are always the exact solution of a
box-constrained linear least-squares problem (:func:`_bounded_lstsq`), the
variable projection. The paper mode's answer is kept if nothing
beats it, so the robust error is never worse than the paper mode's.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, replace
import itertools
import math
from pathlib import Path
import sys
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core.errors import AllocationError, ParameterError
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.thrust_map import allocation_matrix, thrust_wrench
from tiltrov_ros.core.yamlfile import read_yaml

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

Mode = Literal['paper', 'robust']

SQRT2 = math.sqrt(2.0)
HALF_PI = 0.5 * math.pi
#: Default per-DOF weights (X, Y, Z, K, M, N) of the wrench error in robust mode:
#: depth and attitude first.
DEFAULT_WEIGHTS = (1.0, 1.0, 10.0, 10.0, 10.0, 1.0)

#: Robust fallback: a tilt motion of 1 rad weighs like this fraction of
#: max(|tau|, max_thrust) of weighted wrench error, so the servos do not chase
#: differences that are tiny compared with the wrench.
DEFAULT_MOTION_PENALTY = 1e-3
#: Robust mode: a best reachable answer counts as stuck only while its weighted
#: error exceeds this fraction of max(|tau|, max_thrust): a flip is worth its
#: disturbance only against an error that matters.
STUCK_RTOL = 0.02
#: Relative tolerance under which a wrench counts as produced (``feasible``):
#: ||achieved - requested|| <= FEASIBILITY_RTOL * max(||requested||, max_thrust).
#: The closed form itself is exact to rounding (tests check 1e-9).
FEASIBILITY_RTOL = 1e-6
#: Robust mode: wrench components below this fraction of the largest one may be
#: read as zero to reach a family of solutions (see ``_snapped_candidates``).
SNAP_RTOL = 1e-5
# Tilt motions (sum of squared changes, rad^2) closer than this are ties.
_MOVE_RESOLUTION = 1e-12
# Slack on a negative discriminant of (**) read as a double root (rounding).
_DISC_RTOL = 1e-13
# A candidate of the closed form must reproduce the wrench to this (relative).
_EXACT_RTOL = 1e-10
# Relative size under which P, Q, kappa, H count as zero (family detection).
_FAMILY_RTOL = 1e-12
# A pair whose components (scaled so that max |tau_i| = 1) are below this has
# no thrust and a free tilt: its share of the wrench is below 1e-12 relative.
_ZERO_PAIR = 1e-12
# Samples along a one-parameter family of exact solutions.
_FAMILY_SAMPLES = 33
# Rows per vectorised chunk of allocate_batch.
_BATCH_CHUNK = 2048
# Regularisation of the thrust least squares (relative to the Gram matrix).
_RIDGE = 1e-12
# Slack on the limits when checking a candidate.
_LIMIT_SLACK = 1e-12


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
    target : robust mode, when not feasible: the tilts of the exact solution
        out of reach that the servos are (or would be) heading for, else None
    stuck : robust mode: consecutive infeasible calls with such a target
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


#: What counts as *short* for the robot (as opposed to ``feasible``, exact to
#: rounding): a wrench component that misses by more than this fraction of a
#: thruster's range, max_thrust for the forces and max_thrust x min(l, d) / 2 for
#: the moments (0.4 N and 0.08 N m for the shipped robot). Below it the error is
#: within what a real thruster resolves, and the steady pose offset it causes
#: under the shipped PD gains (force / kp) is under 4.2 mm and 0.17 deg. The
#: robust mode's trade of a millinewton of wrench for less servo motion while
#: hovering (DEFAULT_MOTION_PENALTY) stays below it.
SHORTFALL_FRACTION = 0.01


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
        return _tilts_only(np.array([float(tilts[0]), float(tilts[1])]))
    return replace(previous, tilt_front=float(tilts[0]), tilt_rear=float(tilts[1]))


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


@dataclass(frozen=True)
class AllocatorConfig:
    """The ``thrust_allocator`` parameters (``config/thrust_allocator.yaml``).

    mode : ``'robust'`` or ``'paper'``
    max_tilt_step : rad per control period; <= 0 means the servo's reach,
        ``tilt_rate_limit * control_period``
    weights : per-DOF weights (X, Y, Z, K, M, N) of the wrench error
    """

    mode: Mode = 'robust'
    max_tilt_step: float = -1.0
    weights: tuple[float, ...] = DEFAULT_WEIGHTS

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *,
                     source: str | None = None) -> AllocatorConfig:
        """From the ``ros__parameters`` of ``thrust_allocator`` (other keys ignored)."""
        mode = values.get('mode', 'robust')
        if mode not in ('paper', 'robust'):
            raise ParameterError('mode', f"got {mode!r}; allowed: 'robust', 'paper'",
                                 source=source)
        step = values.get('max_tilt_step', -1.0)
        if isinstance(step, bool) or not isinstance(step, (int, float)) or math.isnan(step):
            raise ParameterError('max_tilt_step', f'got {step!r}; allowed: a number of rad '
                                 '(<= 0: the servo reach per control period)', source=source)
        weights = values.get('weights', DEFAULT_WEIGHTS)
        # Any sequence: a list from YAML, array('d') from the ROS parameter service.
        if (isinstance(weights, (str, bytes)) or not isinstance(weights, Sequence)
                or len(weights) != 6
                or not all(isinstance(w, (int, float)) and not isinstance(w, bool)
                           and math.isfinite(w) and w > 0 for w in weights)):
            shown = list(weights) if isinstance(weights, Sequence) else weights
            raise ParameterError('weights', f'got {shown!r}; allowed: 6 finite numbers > 0',
                                 source=source)
        return cls(mode, float(step), tuple(float(w) for w in weights))

    def tilt_step(self, robot: RobotParams, control_period: float) -> float:
        """max_tilt_step in rad, ``auto`` (<= 0) resolved from the servo rate."""
        if self.max_tilt_step > 0:
            return self.max_tilt_step
        return robot.tilt_rate_limit * control_period

    def build(self, robot: RobotParams, control_period: float,
              failed_thrusters: Collection[int] = ()) -> ThrustAllocator:
        """The allocator for ``robot`` (geometry, thrust limit, tilt range and reach)."""
        return ThrustAllocator(robot.length, robot.width, robot.max_thrust,
                               (robot.tilt_min, robot.tilt_max),
                               self.tilt_step(robot, control_period), self.mode,
                               self.weights, failed_thrusters)


ALLOCATOR_YAML = 'thrust_allocator.yaml'


def load_allocator_config(path: str | Path | None = None) -> AllocatorConfig:
    """Read ``thrust_allocator: ros__parameters:`` from a YAML file (default: shipped)."""
    if path is None:
        from tiltrov_ros.paths import config_file
        path = config_file(ALLOCATOR_YAML)
    source = str(path)
    document = read_yaml(path)
    section = document.get('thrust_allocator') if isinstance(document, Mapping) else None
    params = section.get('ros__parameters') if isinstance(section, Mapping) else None
    if not isinstance(params, Mapping):
        raise ParameterError('thrust_allocator', 'no thrust_allocator: ros__parameters: '
                             'block found', source=source)
    return AllocatorConfig.from_mapping(params, source=source)


@dataclass(frozen=True)
class _Config:
    """One exact candidate (thrusts scaled back to the request)."""

    thrusts: FloatArray      # (4,)
    tilts: FloatArray        # (2,)
    family: bool
    tilt_free: tuple[bool, bool]   # pair with zero thrust: any tilt will do


class ThrustAllocator:
    """Allocate a body wrench to four thrusts and two tilts.

    The API of ``../shared/notes/interfaces.md``: ``allocate(wrench, previous)``
    returns an :class:`AllocationResult`.

    Parameters
    ----------
    length, width : l and d, thruster spacing along x and y [m]
    max_thrust : thrust limit of each thruster, both directions [N]
    tilt_limits : (min, max) tilt angle [rad], within [-pi, pi]
    max_tilt_step : how far each tilt may move from ``previous`` in one call [rad]
    mode : ``'robust'`` (default) or ``'paper'``
    weights : per-DOF weights (X, Y, Z, K, M, N) of the wrench error
    failed_thrusters : indices 0..3 of thrusters that produce no thrust
    flip_planning : robust mode, edge trap: plan 180 deg flips (see ``_plan``);
        off by default (measured: it bounds the edge trap of
        test_closed_loop.py, 1.21 m -> 0.18 m, but costs station keeping in a
        current, current_hold pid: 2.3 mm -> 179 mm final surge error)
    escape_ticks : with flip_planning, calls to wait at a tilt limit before
        flipping (default: as many as the 180 deg flip takes)
    motion_penalty : robust fallback: weighted wrench error, as a fraction of
        max(|tau|, max_thrust), that 1 rad of tilt motion is worth
    """

    def __init__(self, length: float, width: float, max_thrust: float = 40.0,
                 tilt_limits: tuple[float, float] = (-HALF_PI, HALF_PI),
                 max_tilt_step: float = math.inf, mode: Mode = 'robust',
                 weights: Sequence[float] = DEFAULT_WEIGHTS,
                 failed_thrusters: Collection[int] = (),
                 flip_planning: bool = False, escape_ticks: int | None = None,
                 motion_penalty: float = DEFAULT_MOTION_PENALTY) -> None:
        if not (math.isfinite(length) and length > 0):
            raise AllocationError(f'length must be a finite number > 0 m, got {length}')
        if not (math.isfinite(width) and width > 0):
            raise AllocationError(f'width must be a finite number > 0 m, got {width}')
        if not (math.isfinite(max_thrust) and max_thrust > 0):
            raise AllocationError(f'max_thrust must be a finite number > 0 N, got {max_thrust}')
        lo, hi = (float(v) for v in tilt_limits)
        if not (math.isfinite(lo) and math.isfinite(hi) and -math.pi <= lo < hi <= math.pi):
            raise AllocationError(
                f'tilt_limits must satisfy -pi <= min < max <= pi, got {tilt_limits}')
        if not (max_tilt_step > 0):
            raise AllocationError(f'max_tilt_step must be > 0 rad, got {max_tilt_step}')
        if mode not in ('paper', 'robust'):
            raise AllocationError(f"mode must be 'paper' or 'robust', got {mode!r}")
        w = np.array(weights, dtype=float)
        if w.shape != (6,) or not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise AllocationError(f'weights must be 6 finite numbers > 0, got {weights}')
        failed = sorted({int(i) for i in failed_thrusters})
        if any(i not in range(4) for i in failed):
            raise AllocationError(f'failed_thrusters must be indices 0..3, got {failed}')
        if escape_ticks is None:
            # Ski rental: wait at the edge as long as the flip itself would take
            # (180 deg at max_tilt_step per call), then flip: never more than
            # twice the cost of the better choice made in hindsight.
            escape_ticks = (math.ceil(math.pi / max_tilt_step)
                            if math.isfinite(max_tilt_step) else 1)
        if isinstance(escape_ticks, bool) or not isinstance(escape_ticks, int) or escape_ticks < 1:
            raise AllocationError(f'escape_ticks must be an integer >= 1, got {escape_ticks!r}')
        if not (math.isfinite(motion_penalty) and motion_penalty >= 0):
            raise AllocationError(f'motion_penalty must be a finite number >= 0, '
                                  f'got {motion_penalty}')
        self.flip_planning = bool(flip_planning)
        self.escape_ticks = escape_ticks
        self.motion_penalty = float(motion_penalty)
        self.length = float(length)
        self.width = float(width)
        self.max_thrust = float(max_thrust)
        self.tilt_limits = (lo, hi)
        self.max_tilt_step = float(max_tilt_step)
        self.mode: Mode = mode
        self.weights = w
        self.failed_thrusters = tuple(failed)
        self._available = np.ones(4, dtype=bool)
        self._available[failed] = False
        self._A = allocation_matrix(self.length, self.width)
        self._A_pinv = np.linalg.pinv(self._A)
        self._k = (self.length + self.width) / (2.0 * SQRT2)
        # Columns of eq. (4) per thruster: b_i(gamma) = A_z,i sin(gamma) + A_h,i cos(gamma).
        self._Az = self._A[:, :4]
        self._Ah = self._A[:, 4:]

    def __repr__(self) -> str:
        return (f'ThrustAllocator(length={self.length}, width={self.width}, '
                f'max_thrust={self.max_thrust}, tilt_limits={self.tilt_limits}, '
                f'max_tilt_step={self.max_tilt_step}, mode={self.mode!r}, '
                f'weights={tuple(self.weights)}, failed_thrusters={self.failed_thrusters})')

    # ------------------------------------------------------------------ public API

    def wrench(self, thrusts: ArrayLike, tilt_front: ArrayLike,
               tilt_rear: ArrayLike) -> FloatArray:
        """Eq. (4) with this allocator's geometry."""
        return thrust_wrench(thrusts, tilt_front, tilt_rear, self.length, self.width)

    def allocate(self, wrench: ArrayLike,
                 previous: AllocationResult | None = None) -> AllocationResult:
        """Thrusts and tilts that produce ``wrench`` = (X, Y, Z, K, M, N).

        ``previous`` is an earlier result: the tilts move least from it and at
        most ``max_tilt_step``. Non-finite wrench components are read as 0 and
        the result is then never ``feasible``.
        """
        tau, finite = self._check_wrench(wrench)
        prev = self._previous_tilts(previous)
        box = self._tilt_box(prev)
        if self.mode == 'robust' and self.failed_thrusters:
            # The closed form cannot hold a thruster at zero: optimise directly.
            result = self._optimize(tau, prev, box, starts=[], incumbent=None)
        else:
            configs, disc = self._candidates(tau)
            if configs is None:
                # A family: the symmetric one in closed form, else the vectorised
                # selector (hundreds of samples).
                symmetric = self._symmetric_family(tau, prev, box)
                result_or_none = (None if symmetric is None
                                  else self._choose(tau, symmetric, math.nan, prev, box))
                if result_or_none is None:
                    result_or_none = self._choose_family(tau, prev)
                configs = self._configs_from_batch(tau) if result_or_none is None else []
            else:
                result_or_none = self._choose(tau, configs, disc, prev, box)
            if result_or_none is None and self.mode == 'robust':
                snapped = self._snapped_candidates(tau)
                result_or_none = self._choose(tau, snapped, disc, prev, box, strict=False)
                if result_or_none is not None and not result_or_none.feasible:
                    result_or_none = None
                configs = configs + snapped
            if result_or_none is not None:
                result = result_or_none
            else:
                paper = self._paper_fallback(tau, configs, disc, prev, box)
                if self.mode == 'paper':
                    result = paper
                else:
                    starts = [paper.tilts] + [c.tilts for c in configs]
                    result = self._optimize(tau, prev, box, starts=starts, incumbent=paper)
                    result = replace(result, discriminant=disc)
                    result = self._plan(tau, configs, result, previous, prev, box)
        return self._finish(result, finite)

    def _plan(self, tau: FloatArray, configs: list[_Config], best: AllocationResult,
              previous: AllocationResult | None, prev: FloatArray | None,
              box: FloatArray) -> AllocationResult:
        """Tilt planning: head for an exact solution that is out of reach.

        ``best`` is the best answer within reach and not feasible. The edge
        trap: a pair stands at a tilt limit and stays there, and the thrust line
        it would need lies past that limit, a 180 deg flip away. If that has
        lasted ``escape_ticks`` calls in a row with an error over STUCK_RTOL,
        and an exact solution exists within the thrust limit and tilt range
        (the target: see :meth:`_target`), the servos move a full step per call
        towards it, the thrusts giving the best wrench at those tilts, until it
        is within reach. Otherwise ``best`` is kept, counting the call. Servos
        merely on their way (still in range, the next call gets closer) and
        small errors never start a transit.
        """
        if not self.flip_planning or prev is None or not math.isfinite(self.max_tilt_step):
            return best
        underway = previous is not None and previous.method == 'transit'
        lo, hi = self.tilt_limits
        at_edge = any(min(abs(p - lo), abs(p - hi)) < 1e-9 and abs(b - p) < 1e-9
                      for p, b in zip(prev, best.tilts))
        significant = best.error > STUCK_RTOL * max(_norm(tau), self.max_thrust)
        if not underway and not (at_edge and significant):
            return best
        stuck = (previous.stuck if previous is not None else 0) + 1
        if stuck < self.escape_ticks and not underway:
            return replace(best, stuck=stuck)
        target = self._target(tau, configs, prev)
        # Beyond the capacity there is nothing exact to head for; the same wrench
        # scaled down shows the way (the thrust line it needs lies past the edge).
        scale = 0.5
        while target is None and scale > 0.01:
            scaled, _ = self._candidates(tau * scale)
            if scaled is None:
                scaled = self._configs_from_batch(tau * scale)
            target = self._target(tau * scale, scaled, prev)
            scale *= 0.5
        if target is None:
            return replace(best, stuck=stuck)
        step = np.clip(target - prev, -self.max_tilt_step, self.max_tilt_step)
        tilts = np.clip(prev + step, box[:, 0], box[:, 1])
        # The thrusts give the best weighted wrench at the intermediate tilts
        # (depth and attitude first). Measured on the closed-loop edge trap of
        # test_closed_loop.py: equal weights cost 19 deg of pitch instead of
        # 7 deg, and silencing the travelling pair 21 deg (no pitch authority
        # during the sweep).
        thrusts, _, _ = self._thrusts_for_tilts(tau, tilts[None, :])
        transit = self._make(tau, thrusts[0], tilts, 'transit', best.discriminant)
        return replace(transit, target=(float(target[0]), float(target[1])), stuck=stuck)

    def _target(self, tau: FloatArray, configs: list[_Config],
                prev: FloatArray) -> FloatArray | None:
        """The exact solution within thrust limit and tilt range (reach ignored)
        to head for: fewest pairs out of reach first (one pair moves while the
        other keeps working), then least tilt motion; None if there is none."""
        fmax = self.max_thrust * (1.0 + _LIMIT_SLACK)
        lo, hi = self.tilt_limits
        full = np.array([[lo, hi], [lo, hi]])
        reach = self.max_tilt_step * (1.0 + 1e-12)
        best: tuple[tuple[int, float], FloatArray] | None = None
        for cfg in configs:
            for f, (a, b) in self._variants(cfg, prev, full):
                if max(abs(v) for v in f) > fmax:
                    continue
                if not (lo - _LIMIT_SLACK <= a <= hi + _LIMIT_SLACK
                        and lo - _LIMIT_SLACK <= b <= hi + _LIMIT_SLACK):
                    continue
                achieved = self.wrench(np.array(f), a, b)
                if _norm(achieved - tau) > _EXACT_RTOL * max(_norm(tau), self.max_thrust):
                    continue
                away = int(abs(a - prev[0]) > reach) + int(abs(b - prev[1]) > reach)
                key = (away, (a - prev[0]) ** 2 + (b - prev[1]) ** 2)
                if best is None or key < best[0]:
                    best = (key, np.array([a, b]))
        return None if best is None else best[1]

    def allocate_fixed(self, wrench: ArrayLike, tilt_front: float, tilt_rear: float,
                       previous: AllocationResult | None = None) -> AllocationResult:
        """Thrusts for tilts held at (``tilt_front``, ``tilt_rear``).

        The linear allocation of the switching baseline (tilts at 0 or 90 deg):
        the thrusts minimise the weighted wrench error within the thrust limit.
        The tilts are clipped to the range and to ``max_tilt_step`` from
        ``previous``; a non-finite requested tilt keeps the previous one.
        """
        tau, finite = self._check_wrench(wrench)
        prev = self._previous_tilts(previous)
        box = self._tilt_box(prev)
        request = np.array([tilt_front, tilt_rear], dtype=float)
        keep = prev if prev is not None else np.zeros(2)
        request = np.where(np.isfinite(request), request, keep)
        tilts = np.clip(request, box[:, 0], box[:, 1])
        thrusts, _, _ = self._thrusts_for_tilts(tau, tilts[None, :])
        result = self._make(tau, thrusts[0], tilts, 'fixed_tilt', math.nan)
        return self._finish(result, finite)

    def allocate_batch(self, wrenches: ArrayLike,
                       previous_tilts: ArrayLike | None = None) -> BatchResult:
        """Allocate many wrenches at once, each row on its own.

        The closed form is vectorised over the rows; rows without a qualifying
        exact solution go one by one through :meth:`allocate`'s fallback (the
        paper's, or the robust optimiser). ``previous_tilts``: (n, 2) or None.
        """
        taus = np.array(wrenches, dtype=float)
        if taus.ndim != 2 or taus.shape[1] != 6:
            raise AllocationError(f'wrenches must have shape (n, 6), got {taus.shape}')
        n = len(taus)
        finite = np.all(np.isfinite(taus), axis=1)
        taus = np.where(np.isfinite(taus), taus, 0.0)
        prev: FloatArray | None = None
        if previous_tilts is not None:
            prev = np.array(previous_tilts, dtype=float)
            if prev.shape != (n, 2):
                raise AllocationError(
                    f'previous_tilts must have shape ({n}, 2), got {prev.shape}')
            prev = np.where(np.isfinite(prev), prev, 0.0)
            prev = np.clip(prev, *self.tilt_limits)
        thrusts = np.zeros((n, 4))
        tilts = np.zeros((n, 2))
        todo = np.ones(n, dtype=bool)
        if not (self.mode == 'robust' and self.failed_thrusters):
            for start in range(0, n, _BATCH_CHUNK):     # chunks stay in cache
                part = slice(start, min(start + _BATCH_CHUNK, n))
                rows, f, t = self._choose_batch(taus[part],
                                                None if prev is None else prev[part])
                rows = rows + start
                thrusts[rows], tilts[rows] = f, t
                todo[rows] = False
        for i in np.flatnonzero(todo):
            prev_i = None if prev is None else _tilts_only(prev[i])
            res = self.allocate(taus[i], prev_i)
            thrusts[i], tilts[i] = res.thrusts, res.tilts
        thrusts[:, ~self._available] = 0.0
        achieved = self.wrench(thrusts, tilts[:, 0], tilts[:, 1])
        error = self.weighted_error(taus, achieved)
        feasible = finite & ~infeasible_rows(taus, achieved, self.max_thrust)
        return BatchResult(thrusts, tilts[:, 0].copy(), tilts[:, 1].copy(), achieved,
                           feasible, error)

    def weighted_error(self, requested: ArrayLike, achieved: ArrayLike) -> FloatArray:
        """||W (achieved - requested)|| row by row ((n, 6) -> (n,)), W = ``weights``."""
        diff = np.asarray(achieved, dtype=float) - np.asarray(requested, dtype=float)
        out: FloatArray = np.linalg.norm(diff * self.weights, axis=-1)
        return out

    # ------------------------------------------------------------------ boundaries

    @staticmethod
    def _check_wrench(wrench: ArrayLike) -> tuple[FloatArray, bool]:
        try:
            tau = np.array(wrench, dtype=float)
        except (TypeError, ValueError) as exc:
            raise AllocationError(f'wrench must be 6 numbers, got {wrench!r}') from exc
        if tau.shape != (6,):
            raise AllocationError(f'wrench must have shape (6,), got {tau.shape}')
        finite = bool(np.all(np.isfinite(tau)))
        return (tau if finite else np.where(np.isfinite(tau), tau, 0.0)), finite

    def _previous_tilts(self, previous: AllocationResult | None) -> FloatArray | None:
        if previous is None:
            return None
        prev = np.array([previous.tilt_front, previous.tilt_rear], dtype=float)
        if not np.all(np.isfinite(prev)):
            return None
        clipped: FloatArray = np.clip(prev, *self.tilt_limits)
        return clipped

    def _tilt_box(self, prev: FloatArray | None) -> FloatArray:
        """[[lo, hi] front, [lo, hi] rear] reachable in this call."""
        lo, hi = self.tilt_limits
        if prev is None or not math.isfinite(self.max_tilt_step):
            return np.array([[lo, hi], [lo, hi]])
        return np.column_stack([np.maximum(lo, prev - self.max_tilt_step),
                                np.minimum(hi, prev + self.max_tilt_step)])

    def _make(self, tau: FloatArray, thrusts: FloatArray, tilts: FloatArray, method: str,
              discriminant: float) -> AllocationResult:
        f = np.array(thrusts, dtype=float)
        f[~self._available] = 0.0
        a, b = float(tilts[0]), float(tilts[1])
        sa, ca, sb, cb = math.sin(a), math.cos(a), math.sin(b), math.cos(b)
        f1, f2, f3, f4 = f.tolist()
        # Eq. (5): tau = A q, the same map as eq. (4).
        q = np.array([f1 * sa, f2 * sa, f3 * sb, f4 * sb, f1 * ca, f2 * ca, f3 * cb, f4 * cb])
        achieved = self._A @ q
        diff = achieved - tau
        error = _norm(diff * (self.weights / self.weights.max())) * float(self.weights.max())
        tol = FEASIBILITY_RTOL * max(_norm(tau), self.max_thrust)
        feasible = _norm(diff) <= tol
        return AllocationResult(f, a, b, achieved, feasible, tau.copy(), method,
                                float(discriminant), error)

    def _finish(self, result: AllocationResult, finite: bool) -> AllocationResult:
        """Last line of defence: limits hold and nothing non-finite leaves."""
        lo, hi = self.tilt_limits
        fmax = self.max_thrust
        if (lo <= result.tilt_front <= hi and lo <= result.tilt_rear <= hi
                and all(-fmax <= v <= fmax for v in result.thrusts.tolist())):
            return result if finite else replace(result, feasible=False)
        f = np.clip(np.nan_to_num(result.thrusts, nan=0.0, posinf=0.0, neginf=0.0),
                    -self.max_thrust, self.max_thrust)
        t = np.clip(np.nan_to_num(result.tilts, nan=0.0), *self.tilt_limits)
        if not (np.array_equal(f, result.thrusts) and np.array_equal(t, result.tilts)):
            result = self._make(result.requested, f, t, result.method, result.discriminant)
        if not finite:
            result = replace(result, feasible=False)
        return result

    # ------------------------------------------------------------------ closed form

    def _candidates(self, tau: FloatArray) -> tuple[list[_Config] | None, float]:
        """Exact solutions of (*) for one wrench, and the discriminant of (**).

        None instead of the list when the solutions form a one-parameter family
        (see :meth:`_choose_family` and :meth:`_configs_from_batch`).
        """
        scale = max(abs(float(v)) for v in tau)
        if scale == 0.0:
            return [_Config(np.zeros(4), np.zeros(2), False, (True, True))], math.nan
        X, Y, Z, K, M, N = (float(v) / scale for v in tau)
        Zf, Zr = -0.5 * Z + M / self.length, -0.5 * Z - M / self.length
        Df, Dr = 0.5 * (SQRT2 * Y + N / self._k), 0.5 * (SQRT2 * Y - N / self._k)
        kappa, H = 2.0 * K / self.width, SQRT2 * X
        P, Q = Zf * Df, Zr * Dr
        mag = max(abs(Zf), abs(Zr), abs(Df), abs(Dr), abs(kappa), abs(H))
        tol1, tol2 = _FAMILY_RTOL * mag, _FAMILY_RTOL * mag * mag
        small_P, small_Q = abs(P) <= tol2, abs(Q) <= tol2
        small_k, small_H = abs(kappa) <= tol1, abs(H) <= tol1
        if ((small_P and small_Q and (small_k or small_H))
                or (small_k and small_H and abs(P + Q) <= tol2)):
            return None, math.nan
        a, b, c = H, -(P + Q + kappa * H), kappa * P
        disc = b * b - 4.0 * a * c
        roots: list[float] = []
        # Rounding in b comes from cancelling P + Q + kappa H, so the slack on
        # the discriminant scales with those terms, not with b^2 alone.
        slack = _DISC_RTOL * (abs(b) * (abs(P) + abs(Q) + abs(kappa * H)) + abs(4.0 * a * c))
        if disc >= -slack:
            sq = math.sqrt(max(disc, 0.0))
            qq = -0.5 * (b + (sq if b >= 0 else -sq))
            if a != 0.0:
                roots.append(qq / a)
            if qq != 0.0:
                roots.append(c / qq)
            elif a == 0.0:
                roots.append(0.0)
        if small_P:
            roots.append(0.0)
        if small_Q:
            roots.append(kappa)
        configs = []
        for U in roots:
            use_p = abs(U) >= abs(U - kappa)
            if (U if use_p else U - kappa) == 0.0:
                continue          # U = kappa = 0 leaves V free: a family, handled above
            V = P / U if use_p else H - Q / (U - kappa)
            if not (math.isfinite(U) and math.isfinite(V)):
                continue
            size = mag * mag + abs(U * V) + abs((U - kappa) * (H - V))
            if (abs(U * V - P) > 1e-9 * size
                    or abs((U - kappa) * (H - V) - Q) > 1e-9 * size):
                continue
            z = (0.5 * (Zf + U), 0.5 * (Zf - U), 0.5 * (Zr + U - kappa),
                 0.5 * (Zr - U + kappa))
            h = (0.5 * (V + Df), 0.5 * (V - Df), 0.5 * (H - V + Dr), 0.5 * (H - V - Dr))
            f1, f2, alpha, free_f = _pair_scalar(z[0], h[0], z[1], h[1])
            f3, f4, beta, free_r = _pair_scalar(z[2], h[2], z[3], h[3])
            with np.errstate(over='ignore'):      # inf thrusts fail the limit check
                thrusts = np.array([f1, f2, f3, f4]) * scale
            configs.append(_Config(thrusts, np.array([alpha, beta]), False, (free_f, free_r)))
        return configs, disc

    def _symmetric_family(self, tau: FloatArray, prev: FloatArray | None,
                          box: FloatArray) -> list[_Config] | None:
        """The members of family F1 that can be chosen, when Y = K = N = 0.

        Then each pair's two thrusters are alike: (h, z) = (V, Zf)/2 at the front
        and (H - V, Zr)/2 at the rear, so tan(alpha) = Zf / V,
        tan(beta) = Zr / (H - V), and the thrusts squared sum to
        (V^2 + (H - V)^2 + Zf^2 + Zr^2)/2, a convex quadratic in V. Its least
        value over the V that qualify (a union of intervals bounded by a tilt at
        an edge of its reach, a thrust at its limit, or a pair without
        horizontal force) is V = H/2 or one of those bounds: these few members
        are returned (None when the wrench is not of this kind), for
        :meth:`_choose` to pick among, as it picks among exact roots.
        """
        scale = max(abs(float(v)) for v in tau)
        if scale == 0.0:
            return None
        X, Y, Z, K, M, N = (float(v) / scale for v in tau)
        Zf, Zr = -0.5 * Z + M / self.length, -0.5 * Z - M / self.length
        Df, Dr = 0.5 * (SQRT2 * Y + N / self._k), 0.5 * (SQRT2 * Y - N / self._k)
        kappa, H = 2.0 * K / self.width, SQRT2 * X
        mag = max(abs(Zf), abs(Zr), abs(Df), abs(Dr), abs(kappa), abs(H))
        if max(abs(Df), abs(Dr), abs(kappa)) > _FAMILY_RTOL * mag:
            return None
        values = {0.5 * H, 0.0, H}
        limit = 2.0 * self.max_thrust / scale          # |(h, z)| of a pair's thruster, x2
        for p, (Zp, sign, offset) in enumerate(((Zf, 1.0, 0.0), (Zr, -1.0, H))):
            tilts = [float(box[p, 0]), float(box[p, 1])]
            if prev is not None:
                tilts.append(float(prev[p]))
            for t in tilts:
                tan_t = math.tan(t)
                if abs(tan_t) > 1e-12 and abs(tan_t) < 1e12:
                    values.add((Zp / tan_t - offset) * sign)     # h_p = Zp / tan(t)
            if limit > abs(Zp):
                reach = math.sqrt(limit * limit - Zp * Zp)
                values.update(((reach - offset) * sign, (-reach - offset) * sign))
        configs = []
        for V in sorted(values):
            f1, f2, alpha, free_f = _pair_scalar(0.5 * Zf, 0.5 * V, 0.5 * Zf, 0.5 * V)
            f3, f4, beta, free_r = _pair_scalar(0.5 * Zr, 0.5 * (H - V), 0.5 * Zr,
                                                0.5 * (H - V))
            with np.errstate(over='ignore'):
                thrusts = np.array([f1, f2, f3, f4]) * scale
            configs.append(_Config(thrusts, np.array([alpha, beta]), True, (free_f, free_r)))
        return configs

    def _choose_family(self, tau: FloatArray,
                       prev: FloatArray | None) -> AllocationResult | None:
        """The family member :meth:`_choose` would pick, by the vectorised selector."""
        rows, f, t = self._choose_rows(tau[None, :], None if prev is None else prev[None, :])
        if not len(rows):
            return None
        method = 'family' if np.any(f[0]) else 'zero'
        return self._make(tau, f[0], t[0], method, math.nan)

    def _snapped_candidates(self, tau: FloatArray) -> list[_Config]:
        """Exact candidates of tau with its tiny components (< SNAP_RTOL) set to zero.

        A wrench a hair away from a degenerate one (roll moment, sway and yaw
        at rounding level, as an integrator makes them) has only discrete
        solutions, ill-conditioned and far apart; the family of the wrench
        without those hairs is next to it. Robust mode only, and only taken when
        the true error of a candidate is within the feasibility tolerance.
        """
        peak = float(np.max(np.abs(tau)))
        snapped = np.where(np.abs(tau) <= SNAP_RTOL * peak, 0.0, tau)
        if np.array_equal(snapped, tau):
            return []
        configs, _ = self._candidates(snapped)
        return self._configs_from_batch(snapped) if configs is None else configs

    def _configs_from_batch(self, tau: FloatArray) -> list[_Config]:
        solved = _solve_batch(tau[None, :], self.length, self.width, self._k)
        return [_Config(solved.thrusts[0, j], solved.tilts[0, j], bool(solved.family[0, j]),
                        (bool(solved.tilt_free[0, j, 0]), bool(solved.tilt_free[0, j, 1])))
                for j in np.flatnonzero(solved.valid[0])]

    def _variants(self, cfg: _Config, prev: FloatArray | None,
                  box: FloatArray) -> list[tuple[tuple[float, ...], tuple[float, float]]]:
        """(thrusts, tilts) of a candidate for every equivalent tilt in range.

        gamma + pi turns the thrust line around: same line, thrust negated. A
        pair without thrust takes the previous tilt (or 0), clipped into reach.
        """
        lo, hi = self.tilt_limits
        per_pair: list[list[tuple[float, float]]] = []
        for p in range(2):
            if cfg.tilt_free[p]:
                rest = float(prev[p]) if prev is not None else 0.0
                per_pair.append([(min(max(rest, float(box[p, 0])), float(box[p, 1])), 1.0)])
                continue
            gamma = float(cfg.tilts[p])
            options = [(gamma + shift, sign) for shift, sign in
                       ((0.0, 1.0), (math.pi, -1.0), (-math.pi, -1.0))
                       if lo - _LIMIT_SLACK <= gamma + shift <= hi + _LIMIT_SLACK]
            per_pair.append(options or [(gamma, 1.0)])
        f1, f2, f3, f4 = (float(v) for v in cfg.thrusts)
        return [((f1 * s_f, f2 * s_f, f3 * s_r, f4 * s_r), (alpha, beta))
                for (alpha, s_f), (beta, s_r) in itertools.product(*per_pair)]

    def _choose(self, tau: FloatArray, configs: list[_Config], disc: float,
                prev: FloatArray | None, box: FloatArray,
                strict: bool = True) -> AllocationResult | None:
        """The exact candidate the rule of Section 3.2 picks among those that qualify.

        Qualify: thrusts within the limit, tilts within the range and, in robust
        mode, within ``max_tilt_step`` of ``previous``. Paper mode then clips the
        tilts to ``max_tilt_step`` (losing exactness, reported as 'saturated').
        ``strict``: the pick must reproduce the wrench to rounding (the residual
        of (*) can hide an amplified error in nearly degenerate cases); a pick
        that does not is dropped and the next one taken.
        Plain floats: this is the hot path of every control cycle.
        """
        ref0, ref1 = (float(prev[0]), float(prev[1])) if prev is not None else (0.0, 0.0)
        fmax = self.max_thrust * (1.0 + _LIMIT_SLACK)
        lo, hi = self.tilt_limits
        if self.mode == 'robust':
            lo0, hi0 = float(box[0, 0]) - _LIMIT_SLACK, float(box[0, 1]) + _LIMIT_SLACK
            lo1, hi1 = float(box[1, 0]) - _LIMIT_SLACK, float(box[1, 1]) + _LIMIT_SLACK
        else:
            lo0 = lo1 = lo - _LIMIT_SLACK
            hi0 = hi1 = hi + _LIMIT_SLACK
        ranked = []
        for cfg in configs:
            for f, (a, b) in self._variants(cfg, prev, box):
                if max(abs(f[0]), abs(f[1]), abs(f[2]), abs(f[3])) > fmax:
                    continue
                if not (lo0 <= a <= hi0 and lo1 <= b <= hi1):
                    continue
                # Tilt motions within _MOVE_RESOLUTION rad^2 count as ties.
                move = round(((a - ref0) ** 2 + (b - ref1) ** 2) / _MOVE_RESOLUTION)
                thrust2 = f[0] * f[0] + f[1] * f[1] + f[2] * f[2] + f[3] * f[3]
                # Ties (gamma = +-90 deg from neutral) go to positive thrust:
                # then the thrust line can turn on past vertical without a flip.
                reverse = -(f[0] + f[1] + f[2] + f[3])
                key = ((thrust2, move, reverse, 0.0) if cfg.family
                       else (0.0, move, reverse, thrust2))
                ranked.append((key, f, a, b, cfg.family))
        ranked.sort(key=lambda item: item[0])
        exact_tol = _EXACT_RTOL * _norm(tau)
        for _, f, a, b, family in ranked:
            a, b = min(max(a, lo), hi), min(max(b, lo), hi)
            result = self._make(tau, np.array(f), np.array([a, b]),
                                'zero' if not any(f) else ('family' if family else 'exact'),
                                disc)
            if strict and _norm(result.achieved - tau) > exact_tol:
                continue
            ca = min(max(a, float(box[0, 0])), float(box[0, 1]))
            cb = min(max(b, float(box[1, 0])), float(box[1, 1]))
            if (ca, cb) != (a, b):                   # paper mode only
                result = self._make(tau, np.array(f), np.array([ca, cb]), 'saturated', disc)
            return result
        return None

    def _paper_fallback(self, tau: FloatArray, configs: list[_Config], disc: float,
                        prev: FloatArray | None, box: FloatArray) -> AllocationResult:
        """Section 3.2 case 3, and saturation: a pseudo solution within the limits.

        With real roots that all violate the limits, the root the paper's rule
        picks (least tilt motion) is clipped to them. With no real root
        (Delta < 0), xi = 0: q = c, each thruster's own angle from (8), per pair
        the one of left/right closer to ``previous``, each thrust the signed
        projection of its (horizontal, vertical) component on that line, then
        clipped to the limits.
        """
        ref = prev if prev is not None else np.zeros(2)
        options = [v for cfg in configs for v in self._variants(cfg, prev, box)]
        if options:
            f_best, t_best = min(options, key=lambda v: (
                (v[1][0] - ref[0]) ** 2 + (v[1][1] - ref[1]) ** 2, sum(x * x for x in v[0])))
            thrusts, tilts = np.array(f_best), np.array(t_best)
            method = 'saturated'
        else:
            c = self._A_pinv @ tau
            z, h = c[:4], c[4:]
            angles = _fold_tilt(np.arctan2(z, h))
            strength = np.hypot(z, h)
            tilts = np.zeros(2)
            for p, (i, j) in enumerate(((0, 1), (2, 3))):
                left = angles[i] if strength[i] > 0 else ref[p]
                right = angles[j] if strength[j] > 0 else ref[p]
                tilts[p] = left if abs(left - ref[p]) <= abs(right - ref[p]) else right
            pair = np.array([0, 0, 1, 1])
            thrusts = h * np.cos(tilts[pair]) + z * np.sin(tilts[pair])
            method = 'pseudo'
        tilts = np.clip(np.clip(tilts, *self.tilt_limits), box[:, 0], box[:, 1])
        thrusts = np.clip(thrusts, -self.max_thrust, self.max_thrust)
        return self._make(tau, thrusts, tilts, method, disc)

    # ------------------------------------------------------------------ robust fallback

    def _error_weights(self, tau: FloatArray) -> FloatArray:
        """Weights divided by the request's size: the same minimiser, no overflow."""
        size = max(float(np.max(np.abs(tau))), self.max_thrust)
        weights: FloatArray = self.weights / size
        return weights

    def _thrusts_for_tilts(self, tau: FloatArray, tilts: FloatArray
                           ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Box-constrained weighted least-squares thrusts for each row of tilts (m, 2).

        Returns thrusts (m, 4), the (scaled) weighted residuals (m, 6) and their
        squared norms (m,) (scaled units: see :meth:`_error_weights`).
        """
        w = self._error_weights(tau)
        gamma = tilts[:, [0, 0, 1, 1]]                              # (m, 4)
        B = (self._Az[None] * np.sin(gamma)[:, None, :]
             + self._Ah[None] * np.cos(gamma)[:, None, :]) * w[None, :, None]
        upper = np.where(self._available, self.max_thrust, 0.0)
        return _bounded_lstsq(B, tau * w, -upper, upper)

    def _nearest_in_box(self, tilts: FloatArray, box: FloatArray) -> FloatArray:
        """Per tilt, of gamma and gamma +- pi (the same thrust line), the one
        nearest to the reachable box, clipped into it: a warm start."""
        out = np.empty(2)
        for p in range(2):
            options = np.float64(tilts[p]) + np.array([0.0, math.pi, -math.pi])
            clipped = np.clip(options, box[p, 0], box[p, 1])
            out[p] = clipped[int(np.argmin(np.abs(options - clipped)))]
        return out

    def _optimize(self, tau: FloatArray, prev: FloatArray | None, box: FloatArray,
                  starts: list[FloatArray],
                  incumbent: AllocationResult | None) -> AllocationResult:
        """Least weighted wrench error over the thrusts and the reachable tilts.

        Stage 1: the warm starts (closed-form candidates and the paper mode's
        answer brought into reach, the previous tilts), each with its exact
        thrust least squares; one that already delivers the wrench within the
        feasibility tolerance is taken (the common case: the exact solution
        lies just beyond a tilt limit or the tilt step). Stage 2: a coarse grid
        joins them and the best two are refined by
        :meth:`_reduced_gauss_newton`.
        """
        lo, hi = box[:, 0], box[:, 1]
        points = [self._nearest_in_box(s, box) for s in starts if np.all(np.isfinite(s))]
        if prev is not None:
            points.append(np.clip(prev, lo, hi))
        result: AllocationResult | None = None
        if points:
            cand = np.array(points)
            thrusts, _, cost = self._thrusts_for_tilts(tau, cand)
            k = int(np.argmin(cost + self._motion_cost(cand, prev)))
            result = self._make(tau, thrusts[k], cand[k], 'optimized', math.nan)
        if result is None or not result.feasible:
            grid = (0.0, 0.5, 1.0)
            points.extend(lo + (hi - lo) * np.array([a, b]) for a in grid for b in grid)
            cand = np.unique(np.array(points), axis=0)
            thrusts, _, cost = self._thrusts_for_tilts(tau, cand)
            cost = cost + self._motion_cost(cand, prev)
            order = np.argsort(cost, kind='stable')
            best_f, best_t, best_c = thrusts[order[0]], cand[order[0]], float(cost[order[0]])
            for k in order[:2]:
                f, t, c = self._reduced_gauss_newton(tau, cand[k], box, prev)
                if c < best_c:
                    best_f, best_t, best_c = f, t, c
            result = self._make(tau, best_f, best_t, 'optimized', math.nan)
        if incumbent is not None and incumbent.error <= result.error:
            return incumbent
        return result

    def _motion_cost(self, tilts: FloatArray, prev: FloatArray | None) -> FloatArray:
        """(motion_penalty |t - prev|)^2 per row of tilts (m, 2), in the scaled units
        of :meth:`_thrusts_for_tilts`' costs; zero without a previous result."""
        if prev is None:
            return np.zeros(len(tilts))
        out: FloatArray = self.motion_penalty ** 2 * np.sum((tilts - prev) ** 2, axis=1)
        return out

    def _reduced_gauss_newton(self, tau: FloatArray, t0: FloatArray, box: FloatArray,
                              prev: FloatArray | None = None,
                              iterations: int = 12) -> tuple[FloatArray, FloatArray, float]:
        """Damped Gauss-Newton over the two tilts on the reduced problem.

        Variable projection: for given tilts the thrusts are the exact bounded
        least-squares solution, so only the tilts are searched. The Jacobian of
        the reduced residual is a forward difference; each trial point is
        evaluated together with its two neighbours in one batched solve, so an
        accepted step comes with its next Jacobian. Steps are projected onto the
        box and accepted only if they lower the error.
        """
        lo, hi = box[:, 0], box[:, 1]
        delta = 1e-7

        # The motion penalty joins the residual: sqrt(mu) (t - prev), Jacobian sqrt(mu) I.
        mu = self.motion_penalty if prev is not None else 0.0
        anchor = prev if prev is not None else np.zeros(2)

        def evaluate(t: FloatArray) -> tuple[FloatArray, FloatArray, float, FloatArray]:
            d = np.where(t + delta <= hi, delta, -delta)   # neighbours stay in the box
            pts = np.array([t, [t[0] + d[0], t[1]], [t[0], t[1] + d[1]]])
            f, r, _ = self._thrusts_for_tilts(tau, pts)
            J = np.vstack([((r[1:] - r[0]) / d[:, None]).T, mu * np.eye(2)])
            res = np.concatenate([r[0], mu * (t - anchor)])
            return f[0], res, float(res @ res), J

        t = np.clip(t0, lo, hi)
        f, r, cost, J = evaluate(t)
        lam = 1e-6
        for _ in range(iterations):
            JtJ, g = J.T @ J, J.T @ r
            improved = False
            for _ in range(5):                       # at most five damping increases
                step = -np.linalg.solve(JtJ + lam * (np.diag(np.diag(JtJ)) + 1e-12 * np.eye(2)),
                                        g)
                trial = np.clip(t + step, lo, hi)
                if np.max(np.abs(trial - t)) < 1e-8:    # no move left worth making
                    break
                f_t, r_t, c_t, J_t = evaluate(trial)
                if c_t < cost:
                    improved = c_t < cost * (1 - 1e-6)
                    t, f, r, cost, J = trial, f_t, r_t, c_t, J_t
                    lam = max(lam / 10.0, 1e-12)
                    break
                lam *= 10.0
            if not improved or cost <= 1e-32:
                break
        return f, t, cost

    # ------------------------------------------------------------------ batch

    def _choose_batch(self, taus: FloatArray, prev: FloatArray | None
                      ) -> tuple[NDArray[np.intp], FloatArray, FloatArray]:
        """Vectorised :meth:`_choose` for the rows whose pick is exact.

        Returns the row indices done, their thrusts (k, 4) and tilts (k, 2).
        Rows on a family (many candidate slots) and the others (four slots)
        are solved apart, so a few hovering rows do not slow the rest down.
        """
        family = _family_rows(taus, self.length, self.width, self._k)
        # Symmetric family rows go through allocate() (closed form), so the
        # batch form answers exactly as single calls do.
        family &= ~_symmetric_rows(taus, self.length, self.width, self._k)
        symmetric = _symmetric_rows(taus, self.length, self.width, self._k)
        rows_out, f_out, t_out = [], [], []
        for subset in (np.flatnonzero(~family & ~symmetric), np.flatnonzero(family)):
            if len(subset) == 0:
                continue
            sub_prev = None if prev is None else prev[subset]
            rows, f, t = self._choose_rows(taus[subset], sub_prev)
            rows_out.append(subset[rows])
            f_out.append(f)
            t_out.append(t)
        if not rows_out:
            return np.zeros(0, dtype=np.intp), np.zeros((0, 4)), np.zeros((0, 2))
        return np.concatenate(rows_out), np.concatenate(f_out), np.concatenate(t_out)

    def _choose_rows(self, taus: FloatArray, prev: FloatArray | None
                     ) -> tuple[NDArray[np.intp], FloatArray, FloatArray]:
        n = len(taus)
        lo, hi = self.tilt_limits
        ref = np.zeros((n, 2)) if prev is None else prev
        if prev is None or not math.isfinite(self.max_tilt_step):
            box_lo, box_hi = np.full((n, 2), lo), np.full((n, 2), hi)
        else:
            box_lo = np.maximum(lo, prev - self.max_tilt_step)
            box_hi = np.minimum(hi, prev + self.max_tilt_step)
        aims = np.stack([ref, box_lo, box_hi], axis=2)           # (n, 2, 3)
        solved = _solve_batch(taus, self.length, self.width, self._k, aims)
        used = solved.valid.any(axis=0)                          # slots some row needs
        solved = _Solved(solved.thrusts[:, used], solved.tilts[:, used], solved.valid[:, used],
                         solved.family[:, used], solved.tilt_free[:, used],
                         solved.discriminant)
        # Equivalent tilts gamma + {0, pi, -pi} per pair: 9 variants per candidate.
        shifts = np.array([0.0, math.pi, -math.pi])
        signs = np.array([1.0, -1.0, -1.0])
        va = np.repeat(np.arange(3), 3)                                 # (9,)
        vb = np.tile(np.arange(3), 3)
        tilts = solved.tilts[:, :, None, :] + np.stack([shifts[va], shifts[vb]], axis=1)
        sign = np.stack([signs[va], signs[va], signs[vb], signs[vb]], axis=1)  # (9, 4)
        thrusts = solved.thrusts[:, :, None, :] * sign                  # (n, m, 9, 4)
        free = solved.tilt_free[:, :, None, :]                          # (n, m, 1, 2)
        # A free pair rests at its previous tilt, once (variant 0 only).
        rest = np.clip(ref, box_lo, box_hi)[:, None, None, :]
        is_base = np.stack([va == 0, vb == 0], axis=1)[None, None]      # (1, 1, 9, 2)
        tilts = np.where(free, rest, tilts)
        ok = solved.valid[:, :, None] & np.all(~free | is_base, axis=3)
        fmax = self.max_thrust * (1.0 + _LIMIT_SLACK)
        ok &= np.all(np.abs(thrusts) <= fmax, axis=3)
        ok &= np.all((tilts >= lo - _LIMIT_SLACK) & (tilts <= hi + _LIMIT_SLACK), axis=3)
        if self.mode == 'robust':
            ok &= np.all((tilts >= box_lo[:, None, None, :] - _LIMIT_SLACK)
                         & (tilts <= box_hi[:, None, None, :] + _LIMIT_SLACK), axis=3)
        fam = solved.family[:, :, None] & np.ones((1, 1, 9), dtype=bool)
        move = np.round(np.sum((tilts - ref[:, None, None, :]) ** 2, axis=3) / _MOVE_RESOLUTION)
        thrust2 = np.sum(thrusts ** 2, axis=3)
        reverse = -np.sum(thrusts, axis=3).reshape(n, -1)
        primary = np.where(ok, np.where(fam, thrust2, 0.0), np.inf).reshape(n, -1)
        secondary = move.reshape(n, -1)
        quaternary = np.where(fam, 0.0, thrust2).reshape(n, -1)
        rows = np.flatnonzero(ok.reshape(n, -1).any(axis=1))
        pick: NDArray[np.intp] = np.lexsort((quaternary, reverse, secondary, primary),
                                            axis=1)[rows, 0]
        f = thrusts.reshape(n, -1, 4)[rows, pick]
        t = np.clip(tilts.reshape(n, -1, 2)[rows, pick], lo, hi)
        if self.mode == 'paper':
            t = np.clip(t, box_lo[rows], box_hi[rows])
        achieved = thrust_wrench(f, t[:, 0], t[:, 1], self.length, self.width)
        tau = taus[rows]
        tol = FEASIBILITY_RTOL * np.maximum(np.linalg.norm(tau, axis=1), self.max_thrust)
        good = np.linalg.norm(achieved - tau, axis=1) <= tol
        return rows[good], f[good], t[good]


def allocate_sequence(allocator: ThrustAllocator, wrenches: ArrayLike,
                      tilt_requests: ArrayLike | None = None, *,
                      previous: AllocationResult | None = None) -> list[AllocationResult]:
    """Allocate ``wrenches`` (n, 6) in order, as the ``thrust_allocator`` node does.

    Each call's ``previous`` is the answer to the row before (the first row's is
    ``previous``), so the tilts move least and within ``max_tilt_step`` along
    the sequence. ``tilt_requests`` (n, 2), optional: rows with finite values
    hold the tilts there (:meth:`ThrustAllocator.allocate_fixed`, the switching
    baseline's tilt request), rows with a NaN are allocated freely.
    """
    taus = np.asarray(wrenches, dtype=float)
    if taus.ndim != 2 or taus.shape[1] != 6:
        raise AllocationError(f'wrenches must have shape (n, 6), got {taus.shape}')
    requests = None
    if tilt_requests is not None:
        requests = np.asarray(tilt_requests, dtype=float)
        if requests.shape != (len(taus), 2):
            raise AllocationError(f'tilt_requests must have shape ({len(taus)}, 2), '
                                  f'got {requests.shape}')
    results: list[AllocationResult] = []
    for i, tau in enumerate(taus):
        request = None if requests is None else requests[i]
        if request is not None and bool(np.all(np.isfinite(request))):
            previous = allocator.allocate_fixed(tau, float(request[0]), float(request[1]),
                                                previous=previous)
        else:
            previous = allocator.allocate(tau, previous=previous)
        results.append(previous)
    return results


def _norm(v: FloatArray) -> float:
    """Euclidean norm without intermediate overflow, capped at the largest float."""
    return min(math.hypot(*v.tolist()), sys.float_info.max)


def _tilts_only(prev: FloatArray) -> AllocationResult:
    """A stand-in previous result that carries only tilts (batch fallback)."""
    z = np.zeros(6)
    return AllocationResult(np.zeros(4), float(prev[0]), float(prev[1]), z, True, z,
                            'previous', math.nan, 0.0)


def _fold_tilt(angle: FloatArray) -> FloatArray:
    """Fold a thrust-line angle into (-pi/2, pi/2] (the thrust takes the sign)."""
    folded = np.where(angle > HALF_PI, angle - math.pi, angle)
    return np.where(folded <= -HALF_PI, folded + math.pi, folded)


def _pair_geometry(tau: FloatArray, length: float, width: float,
                   k: float) -> tuple[FloatArray, ...]:
    """Zf, Zr, Df, Dr, kappa, H of the module docstring (for tau of shape (..., 6))."""
    X, Y, Z, K, M, N = np.moveaxis(np.asarray(tau), -1, 0)
    Zf = -0.5 * Z + M / length
    Zr = -0.5 * Z - M / length
    Df = 0.5 * (SQRT2 * Y + N / k)
    Dr = 0.5 * (SQRT2 * Y - N / k)
    kappa = 2.0 * K / width
    H = SQRT2 * X
    return Zf, Zr, Df, Dr, kappa, H


def _pair_scalar(z_i: float, h_i: float, z_j: float,
                 h_j: float) -> tuple[float, float, float, bool]:
    """Corrected (7)-(8) for one pair: signed thrusts, the pair's tilt, free flag.

    f_i is the signed length of thruster i's own (h_i, z_i); the pair's thrust
    line comes from its stronger thruster (atan2, folded into (-pi/2, pi/2]),
    and each thrust is the signed projection on that line.
    """
    n_i, n_j = math.hypot(z_i, h_i), math.hypot(z_j, h_j)
    if max(n_i, n_j) <= _ZERO_PAIR:
        return 0.0, 0.0, 0.0, True
    z, h = (z_i, h_i) if n_i >= n_j else (z_j, h_j)
    gamma = math.atan2(z, h)
    if gamma > HALF_PI:
        gamma -= math.pi
    elif gamma <= -HALF_PI:
        gamma += math.pi
    c, s = math.cos(gamma), math.sin(gamma)
    return h_i * c + z_i * s, h_j * c + z_j * s, gamma, False


@dataclass(frozen=True)
class _Solved:
    """Exact candidates for n wrenches, m candidate slots each."""

    thrusts: FloatArray       # (n, m, 4)
    tilts: FloatArray         # (n, m, 2)
    valid: BoolArray          # (n, m)
    family: BoolArray         # (n, m)
    tilt_free: BoolArray      # (n, m, 2)
    discriminant: FloatArray  # (n,)


def _classify(tau: FloatArray, length: float, width: float, k: float
              ) -> tuple[tuple[FloatArray, ...], tuple[BoolArray, BoolArray, BoolArray],
                         FloatArray]:
    """Pair quantities of tau / s and the family flags, for tau (n, 6).

    Returns ((Zf, Zr, Df, Dr, kappa, H, P, Q, mag), (fam1, fam2, fam3), s).
    """
    n = len(tau)
    peak = np.max(np.abs(tau), axis=1)
    s = np.where(peak > 0, peak, 1.0)
    Zf, Zr, Df, Dr, kappa, H = _pair_geometry(tau / s[:, None], length, width, k)
    P, Q = Zf * Df, Zr * Dr
    mag = np.maximum.reduce([np.abs(Zf), np.abs(Zr), np.abs(Df), np.abs(Dr),
                             np.abs(kappa), np.abs(H), np.full(n, 1e-300)])
    tol1, tol2 = _FAMILY_RTOL * mag, _FAMILY_RTOL * mag ** 2
    small_P, small_Q = np.abs(P) <= tol2, np.abs(Q) <= tol2
    small_k, small_H = np.abs(kappa) <= tol1, np.abs(H) <= tol1
    fam1 = small_P & small_Q & small_k
    fam2 = small_P & small_Q & small_H
    fam3 = small_k & small_H & (np.abs(P + Q) <= tol2) & ~(small_P & small_Q)
    return (Zf, Zr, Df, Dr, kappa, H, P, Q, mag), (fam1, fam2, fam3), s


def _symmetric_rows(tau: FloatArray, length: float, width: float, k: float) -> BoolArray:
    """Rows of family F1 with Y = K = N = 0 (see ThrustAllocator._symmetric_family)."""
    (_, _, Df, Dr, kappa, _, _, _, mag), _, _ = _classify(tau, length, width, k)
    tol = _FAMILY_RTOL * mag
    out: BoolArray = ((np.abs(Df) <= tol) & (np.abs(Dr) <= tol) & (np.abs(kappa) <= tol)
                      & (np.max(np.abs(tau), axis=1) > 0))
    return out


def _family_rows(tau: FloatArray, length: float, width: float, k: float) -> BoolArray:
    """Rows whose solutions form a one-parameter family (or the zero wrench)."""
    _, (fam1, fam2, fam3), _ = _classify(tau, length, width, k)
    family: BoolArray = fam1 | fam2 | fam3
    return family


def _solve_batch(tau: FloatArray, length: float, width: float, k: float,
                 aims: FloatArray | None = None) -> _Solved:
    """All exact (U, V) of (*) for each row of tau (n, 6), mapped to actuators.

    The vectorised twin of :meth:`ThrustAllocator._candidates` (a test keeps
    them equal), with the one-parameter families sampled. The problem is
    homogeneous of degree one in tau: it is solved for tau / s
    (s = max |tau_i|) and the thrusts are scaled back, so huge wrenches do not
    overflow and tolerances are relative.
    """
    (Zf, Zr, Df, Dr, kappa, H, P, Q, mag), (fam1, fam2, fam3), s = _classify(
        tau, length, width, k)
    peak = np.max(np.abs(tau), axis=1)
    tol2 = _FAMILY_RTOL * mag ** 2
    small_P, small_Q = np.abs(P) <= tol2, np.abs(Q) <= tol2
    any_family = fam1 | fam2 | fam3

    # Roots of (**), a U^2 + b U + c = 0, in the cancellation-free form.
    a, b, c = H, -(P + Q + kappa * H), kappa * P
    disc = b * b - 4 * a * c
    slack = _DISC_RTOL * (np.abs(b) * (np.abs(P) + np.abs(Q) + np.abs(kappa * H))
                          + np.abs(4 * a * c))
    real = disc >= -slack
    sq = np.sqrt(np.maximum(disc, 0.0))
    qq = -0.5 * (b + np.where(b >= 0, sq, -sq))
    with np.errstate(divide='ignore', invalid='ignore'):
        u1 = np.where(a != 0, qq / a, np.nan)
        u2 = np.where(qq != 0, c / qq, np.where(a == 0, 0.0, np.nan))
    roots = [np.where(real, u1, np.nan), np.where(real, u2, np.nan),
             np.where(small_P, 0.0, np.nan), np.where(small_Q, kappa, np.nan)]
    U = np.stack(roots, axis=1)
    U = np.where(any_family[:, None], np.nan, U)
    with np.errstate(divide='ignore', invalid='ignore'):
        v_p = P[:, None] / U
        v_q = H[:, None] - Q[:, None] / (U - kappa[:, None])
    V = np.where(np.abs(U) >= np.abs(U - kappa[:, None]), v_p, v_q)
    family = np.zeros(U.shape, dtype=bool)
    if np.any(any_family):
        fu, fv = _family_samples(fam1, fam2, fam3, (Zf, Zr, Df, Dr, kappa, H), P, mag, aims)
        U = np.concatenate([U, fu], axis=1)
        V = np.concatenate([V, fv], axis=1)
        family = np.concatenate([family, np.ones(fu.shape, dtype=bool)], axis=1)

    valid = np.isfinite(U) & np.isfinite(V)
    U = np.where(valid, U, 0.0)
    V = np.where(valid, V, 0.0)
    kap, HH = kappa[:, None], H[:, None]
    size = mag[:, None] ** 2 + np.abs(U * V) + np.abs((U - kap) * (HH - V))
    valid &= np.abs(U * V - P[:, None]) <= 1e-9 * size
    valid &= np.abs((U - kap) * (HH - V) - Q[:, None]) <= 1e-9 * size

    z = 0.5 * np.stack([Zf[:, None] + U, Zf[:, None] - U,
                        Zr[:, None] + U - kap, Zr[:, None] - U + kap], axis=2)
    h = 0.5 * np.stack([V + Df[:, None], V - Df[:, None],
                        HH - V + Dr[:, None], HH - V - Dr[:, None]], axis=2)
    thrusts, tilts, free = _pairs_to_actuators(z, h)
    # Verify every candidate on eq. (4) (scaled units): (*) can hide an amplified error.
    # Thrusts this far beyond the wrench's scale are of no use (and would overflow).
    valid &= np.all(np.abs(thrusts) < 1e100, axis=2)
    thrusts = np.where(valid[..., None], thrusts, 0.0)
    unit = tau / s[:, None]
    achieved = thrust_wrench(thrusts, tilts[..., 0], tilts[..., 1], length, width)
    error = np.linalg.norm(achieved - unit[:, None, :], axis=2)
    valid &= error <= _EXACT_RTOL * np.linalg.norm(unit, axis=1)[:, None]
    # The zero wrench: everything is zero and both tilts are free.
    zero_row = peak == 0
    valid[zero_row, 1:] = False
    valid[zero_row, 0] = True
    thrusts[zero_row] = 0.0
    free[zero_row] = True
    with np.errstate(over='ignore', invalid='ignore'):  # inf thrusts fail the limit check
        thrusts = thrusts * s[:, None, None]
    return _Solved(thrusts, tilts, valid, family, free,
                   np.where(any_family | zero_row, np.nan, disc))


def _kink_points(fixed: FloatArray, slope: FloatArray, offset: FloatArray) -> FloatArray:
    """Where the largest of sqrt(a_i^2 + (s_i t / 2 + c_i)^2) over i can be least, per row.

    Along families F1 and F2 each thruster's force is sqrt(a_i^2 + (s_i t/2 + c_i)^2)
    with s_i = +-1: the squares share their leading coefficient, so two of them
    are equal where a *linear* equation holds. The minimiser of the largest
    force is where one term is least (s_i t/2 + c_i = 0) or two are equal:
    4 + 6 points, given here (n, 10) (NaN where two terms never meet).
    fixed, slope, offset: (n, 4) each.
    """
    points = [-2.0 * offset[:, i] / slope[:, i] for i in range(4)]
    for i, j in itertools.combinations(range(4), 2):
        num = (fixed[:, j] ** 2 + offset[:, j] ** 2) - (fixed[:, i] ** 2 + offset[:, i] ** 2)
        den = slope[:, i] * offset[:, i] - slope[:, j] * offset[:, j]
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            points.append(np.where(den != 0, num / den, np.nan))
    out = np.stack(points, axis=1)
    # A point beyond any sensible scale (a denominator at rounding level) is
    # useless and would overflow later: drop it.
    return np.where(np.abs(out) < 1e150, out, np.nan)


def _family_samples(fam1: BoolArray, fam2: BoolArray, fam3: BoolArray,
                    geometry: tuple[FloatArray, ...], P: FloatArray, mag: FloatArray,
                    aims: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """(U, V) samples along the one-parameter families, NaN where a row has none.

    Spread around each family's least-thrust member, which is included
    (F1, U = 0: V = H/2; F2, V = 0: U = kappa/2; F3, V = P/U: U = +-sqrt|P|),
    plus, for F1 and F2, the candidates for the member whose largest thruster
    force is least (:func:`_kink_points`): if any member is within the thrust
    limit, that one is, so solutions at the limit are not missed. ``aims``
    (n, 2, k): tilts per pair (front, rear) to aim at, e.g. the previous tilts
    and the edges of their reach; along F1 and F2 a pair's tilt is explicit
    in the family parameter (F1: tan(alpha) = Zf / V, tan(beta) = Zr / (H - V);
    F2: tan(alpha) = U / Df, tan(beta) = (U - kappa) / Dr), so the members with
    those tilts are added.
    """
    Zf, Zr, Df, Dr, kappa, H = geometry
    n, s = len(H), _FAMILY_SAMPLES
    spread = mag[:, None] * np.tan(np.linspace(-1.5, 1.5, s))[None, :]
    ones = np.ones(n)
    # F1 (U = 0): z fixed, h_i = s_i V/2 + c_i.
    f1_kinks = _kink_points(0.5 * np.stack([Zf, Zf, Zr - kappa, Zr + kappa], axis=1),
                            np.stack([ones, ones, -ones, -ones], axis=1),
                            0.5 * np.stack([Df, -Df, H + Dr, H - Dr], axis=1))
    # F2 (V = 0): h fixed, z_i = s_i U/2 + c_i.
    f2_kinks = _kink_points(0.5 * np.stack([Df, -Df, H + Dr, H - Dr], axis=1),
                            np.stack([ones, -ones, ones, -ones], axis=1),
                            0.5 * np.stack([Zf, Zf, Zr - kappa, Zr + kappa], axis=1))
    f1_v = np.concatenate([0.5 * H[:, None] + spread, f1_kinks], axis=1)
    f2_u = np.concatenate([0.5 * kappa[:, None] + spread, f2_kinks], axis=1)
    if aims is not None:
        tan_f, tan_r = np.tan(aims[:, 0, :]), np.tan(aims[:, 1, :])
        with np.errstate(divide='ignore', invalid='ignore', over='ignore'):
            f1_v = np.concatenate([f1_v, Zf[:, None] / tan_f,
                                   H[:, None] - Zr[:, None] / tan_r], axis=1)
            f2_u = np.concatenate([f2_u, Df[:, None] * tan_f,
                                   kappa[:, None] + Dr[:, None] * tan_r], axis=1)
        f1_v = np.where(np.isfinite(f1_v), f1_v, np.nan)
        f2_u = np.where(np.isfinite(f2_u), f2_u, np.nan)
    m = f1_v.shape[1]
    nan = np.full((n, m), np.nan)
    f1_u = np.where(fam1[:, None], 0.0, nan)
    f1_v = np.where(fam1[:, None], f1_v, nan)
    f2_u = np.where(fam2[:, None], f2_u, nan)
    f2_v = np.where(fam2[:, None], 0.0, nan)
    half = (s + 1) // 2
    ratio = np.exp(np.linspace(-3.0, 3.0, half))
    sign = np.concatenate([np.ones(half), -np.ones(s - half)])
    ratio = np.concatenate([ratio, ratio[: s - half]])
    u3 = np.where(fam3[:, None], sign * np.sqrt(np.abs(P))[:, None] * ratio,
                  np.full((n, s), np.nan))
    with np.errstate(divide='ignore', invalid='ignore'):
        v3 = np.where(fam3[:, None], P[:, None] / u3, np.nan)
    return (np.concatenate([f1_u, f2_u, u3], axis=1),
            np.concatenate([f1_v, f2_v, v3], axis=1))


def _pairs_to_actuators(z: FloatArray,
                        h: FloatArray) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Vectorised :func:`_pair_scalar` over (..., 4) vertical/horizontal parts."""
    shape = z.shape[:-1]
    thrusts = np.zeros(z.shape)
    tilts = np.zeros((*shape, 2))
    free = np.zeros((*shape, 2), dtype=bool)
    for p, (i, j) in enumerate(((0, 1), (2, 3))):
        n_i, n_j = np.hypot(z[..., i], h[..., i]), np.hypot(z[..., j], h[..., j])
        lead = n_i >= n_j
        zero = np.maximum(n_i, n_j) <= _ZERO_PAIR
        gamma = _fold_tilt(np.arctan2(np.where(lead, z[..., i], z[..., j]),
                                      np.where(lead, h[..., i], h[..., j])))
        gamma = np.where(zero, 0.0, gamma)
        c, s = np.cos(gamma), np.sin(gamma)
        thrusts[..., i] = np.where(zero, 0.0, h[..., i] * c + z[..., i] * s)
        thrusts[..., j] = np.where(zero, 0.0, h[..., j] * c + z[..., j] * s)
        tilts[..., p] = gamma
        free[..., p] = zero
    return thrusts, tilts, free


# ---------------------------------------------------------------------- bounded LS


# Active-set patterns of four variables: 0 free, 1 at the lower bound, 2 at the upper.
_PATTERNS = np.array(list(itertools.product((0, 1, 2), repeat=4)))


def _bounded_lstsq(B: FloatArray, target: FloatArray, lower: FloatArray,
                   upper: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """min ||B x - target||^2 with lower <= x <= upper, exactly, for a stack B (m, 6, 4).

    The unconstrained solution is tried first; rows where it leaves the box
    try every active set (each variable free, at its lower or at its upper
    bound: 3^4 patterns) at once and keep the best one whose free variables
    stay within their bounds: for a convex quadratic that is the global
    minimum. A tiny ridge makes singular configurations (both tilts at 90 deg,
    say) pick the least-thrust solution.
    """
    G = np.einsum('mij,mik->mjk', B, B)
    G = G + _RIDGE * (np.trace(G, axis1=1, axis2=2)[:, None, None] + 1e-300) * np.eye(4)
    g = np.einsum('mij,i->mj', B, target)
    x = np.linalg.solve(G, g[..., None])[..., 0]
    slack = 1e-9 * (np.abs(upper) + 1.0)
    inside = np.all((x >= lower - slack) & (x <= upper + slack), axis=1) & (lower < upper).all()
    out = np.flatnonzero(~inside)
    if len(out):
        x[out] = _enumerate_active_sets(G[out], g[out], lower, upper)
    x = np.clip(x, lower, upper)
    resid = np.einsum('mij,mj->mi', B, x) - target
    return x, resid, np.sum(resid ** 2, axis=1)


def _enumerate_active_sets(G: FloatArray, g: FloatArray, lower: FloatArray,
                           upper: FloatArray) -> FloatArray:
    """Best feasible active-set solution of min x'Gx/2 - g'x for each row."""
    pats = _PATTERNS
    degenerate = lower == upper          # failed thrusters: only 'at the bound'
    allowed = ~np.any(degenerate & (pats != 1), axis=1)
    pats = pats[allowed]
    fixed = pats > 0                                                # (p, 4)
    value = np.where(pats == 1, lower, np.where(pats == 2, upper, 0.0))
    eye = np.eye(4)
    # Free rows: G_FF x_F = g_F - G_F,fix x_fix; fixed rows: x_i = bound.
    Gs = np.where(fixed[None, :, :, None], eye[None, None],
                  np.where(fixed[None, :, None, :], 0.0, G[:, None]))
    rhs = np.where(fixed[None], value[None],
                   g[:, None, :] - np.einsum('mjk,pk->mpj', G, value))
    x = np.linalg.solve(Gs, rhs[..., None])[..., 0]                 # (m, p, 4)
    slack = 1e-9 * (np.abs(upper) + 1.0)
    feasible = np.all((x >= lower - slack) & (x <= upper + slack), axis=2)
    x = np.clip(x, lower, upper)
    cost = 0.5 * np.einsum('mpj,mjk,mpk->mp', x, G, x) - np.einsum('mpj,mj->mp', x, g)
    cost = np.where(feasible, cost, np.inf)
    best = np.argmin(cost, axis=1)
    result: FloatArray = x[np.arange(len(G)), best]
    return result
