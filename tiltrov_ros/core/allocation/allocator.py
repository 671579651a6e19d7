"""Thrust allocation for four thrusters that share two tilt servos (Section 3).

The paper's method, made correct and complete (``mode='paper'``), and a robust
allocator built on it (``mode='robust'``, the default). The decomposition is in
:mod:`.decomposition`, the exact solutions in :mod:`.closed_form` and
:mod:`.families`, the thrusts at given tilts in :mod:`.thrusts`.

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
  hovering. (**) of :mod:`.closed_form` divides by neither; what remains are the
  one-parameter families of solutions, which the paper does not cover.

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
mode, within ``max_tilt_step`` of ``previous``) qualify. Within a family, the
member with the least thrust among those that qualify (:mod:`.families`), ties
going to the least tilt motion.

Robust mode
-----------
Exact whenever an exact solution qualifies: then the same answer as the
paper mode. When none does (negative discriminant, thrust beyond the limit,
tilts out of range or out of reach), it returns the attainable configuration
with the least weighted wrench error ||W (tau(f, alpha, beta) - tau_d)||: from
warm starts (the closed-form candidates and the paper mode's answer brought
into reach, the previous tilts, a coarse grid), a damped Gauss-Newton search
over the two tilts in which the thrusts are always the exact solution of a
box-constrained linear least-squares problem (:func:`.thrusts.bounded_lstsq`),
the variable projection. The paper mode's answer is kept if nothing
beats it, so the robust error is never worse than the paper mode's.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import replace
import itertools
import math
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core.allocation.closed_form import (
    EXACT_RTOL,
    Solved,
    candidates,
    family_rows,
    solve_batch,
    symmetric_rows,
)
from tiltrov_ros.core.allocation.decomposition import (
    HALF_PI,
    ExactConfig,
    FloatArray,
    Geometry,
    fold_tilt,
)
from tiltrov_ros.core.allocation.families import symmetric_family
from tiltrov_ros.core.allocation.results import (
    FEASIBILITY_RTOL,
    AllocationResult,
    BatchResult,
    infeasible_rows,
    norm,
    tilts_only,
)
from tiltrov_ros.core.allocation.thrusts import bounded_lstsq
from tiltrov_ros.core.errors import AllocationError
from tiltrov_ros.core.thrust_map import allocation_matrix, thrust_wrench

Mode = Literal['paper', 'robust']

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
#: Robust mode: wrench components below this fraction of the largest one may be
#: read as zero to reach a family of solutions (see ``_snapped_candidates``).
SNAP_RTOL = 1e-5
# Tilt motions (sum of squared changes, rad^2) closer than this are ties.
_MOVE_RESOLUTION = 1e-12
# Rows per vectorised chunk of allocate_batch.
_BATCH_CHUNK = 2048
# Slack on the limits when checking a candidate.
_LIMIT_SLACK = 1e-12


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
        self.geometry = Geometry(self.length, self.width)
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
            configs, disc = candidates(self.geometry, tau)
            if configs is None:
                # A family: the symmetric one in closed form, else the vectorised
                # selector (hundreds of samples).
                symmetric = symmetric_family(self.geometry, self.max_thrust, tau, prev, box)
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

    def _plan(self, tau: FloatArray, configs: list[ExactConfig], best: AllocationResult,
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
        significant = best.error > STUCK_RTOL * max(norm(tau), self.max_thrust)
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
            scaled, _ = candidates(self.geometry, tau * scale)
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

    def _target(self, tau: FloatArray, configs: list[ExactConfig],
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
                if norm(achieved - tau) > EXACT_RTOL * max(norm(tau), self.max_thrust):
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
            prev_i = None if prev is None else tilts_only(prev[i])
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
        error = norm(diff * (self.weights / self.weights.max())) * float(self.weights.max())
        tol = FEASIBILITY_RTOL * max(norm(tau), self.max_thrust)
        feasible = norm(diff) <= tol
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

    def _choose_family(self, tau: FloatArray,
                       prev: FloatArray | None) -> AllocationResult | None:
        """The family member :meth:`_choose` would pick, by the vectorised selector."""
        rows, f, t = self._choose_rows(tau[None, :], None if prev is None else prev[None, :])
        if not len(rows):
            return None
        method = 'family' if np.any(f[0]) else 'zero'
        return self._make(tau, f[0], t[0], method, math.nan)

    def _snapped_candidates(self, tau: FloatArray) -> list[ExactConfig]:
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
        configs, _ = candidates(self.geometry, snapped)
        return self._configs_from_batch(snapped) if configs is None else configs

    def _configs_from_batch(self, tau: FloatArray) -> list[ExactConfig]:
        solved = solve_batch(self.geometry, tau[None, :])
        return [ExactConfig(solved.thrusts[0, j], solved.tilts[0, j], bool(solved.family[0, j]),
                        (bool(solved.tilt_free[0, j, 0]), bool(solved.tilt_free[0, j, 1])))
                for j in np.flatnonzero(solved.valid[0])]

    def _variants(self, cfg: ExactConfig, prev: FloatArray | None,
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

    def _choose(self, tau: FloatArray, configs: list[ExactConfig], disc: float,
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
        exact_tol = EXACT_RTOL * norm(tau)
        for _, f, a, b, family in ranked:
            a, b = min(max(a, lo), hi), min(max(b, lo), hi)
            result = self._make(tau, np.array(f), np.array([a, b]),
                                'zero' if not any(f) else ('family' if family else 'exact'),
                                disc)
            if strict and norm(result.achieved - tau) > exact_tol:
                continue
            ca = min(max(a, float(box[0, 0])), float(box[0, 1]))
            cb = min(max(b, float(box[1, 0])), float(box[1, 1]))
            if (ca, cb) != (a, b):                   # paper mode only
                result = self._make(tau, np.array(f), np.array([ca, cb]), 'saturated', disc)
            return result
        return None

    def _paper_fallback(self, tau: FloatArray, configs: list[ExactConfig], disc: float,
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
            angles = fold_tilt(np.arctan2(z, h))
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
        return bounded_lstsq(B, tau * w, -upper, upper)

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
        family = family_rows(self.geometry, taus)
        # Symmetric family rows go through allocate() (closed form), so the
        # batch form answers exactly as single calls do.
        family &= ~symmetric_rows(self.geometry, taus)
        symmetric = symmetric_rows(self.geometry, taus)
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
        solved = solve_batch(self.geometry, taus, aims)
        used = solved.valid.any(axis=0)                          # slots some row needs
        solved = Solved(solved.thrusts[:, used], solved.tilts[:, used], solved.valid[:, used],
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
