"""Thrust allocation for four thrusters that share two tilt servos (Section 3).

The paper's method, made correct and complete (``mode='paper'``), and a robust
allocator built on it (``mode='robust'``, the default):

* :mod:`.decomposition`: the pair sums and differences of eq. (4);
* :mod:`.closed_form`, :mod:`.families`: every exact solution, the quadratic
  that replaces the paper's (12)-(15) and the one-parameter families where the
  printed formulas divide by zero;
* :mod:`.selection`: the choice among exact solutions (Section 3.2, completed);
* :mod:`.paper`: the paper mode's answer when none qualifies (Section 3.2, case 3);
* :mod:`.thrusts`, :mod:`.local`, :mod:`.optimum`: the thrusts at given tilts and
  the per-tick optimum over the tilts within reach;
* :mod:`.planner`, :mod:`.robust`: the robust mode's answer when no exact
  solution is within reach, servo travel planned over a receding horizon;
* :mod:`.compiled`, :mod:`.kernels`: all of the above as numba kernels, one
  kernel call per ``allocate``; which one answers is chosen per allocator
  (``backend``, default the process's :func:`tiltrov_ros.core.jit.backend`).
  The modules above stay the reference that tests pin the kernels to.

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
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import replace
import math
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.closed_form import candidates
from tiltrov_ros.core.allocation.compiled import Compiled
from tiltrov_ros.core.allocation.decomposition import HALF_PI, FloatArray, Geometry
from tiltrov_ros.core.allocation.families import symmetric_family
from tiltrov_ros.core.allocation.limits import Limits
from tiltrov_ros.core.allocation.local import evaluate
from tiltrov_ros.core.allocation.paper import paper_fallback
from tiltrov_ros.core.allocation.results import (
    AllocationResult,
    BatchResult,
    infeasible_rows,
    tilts_only,
)
from tiltrov_ros.core.allocation.robust import Options, fallback
from tiltrov_ros.core.allocation.selection import (
    choose,
    choose_batch,
    choose_family,
    configs_from_batch,
    snapped_candidates,
)
from tiltrov_ros.core.allocation.thrusts import TiltProblem
from tiltrov_ros.core.errors import AllocationError
from tiltrov_ros.core.thrust_map import thrust_wrench

Mode = Literal['paper', 'robust']
Backend = Literal['numba', 'numpy']

#: Default per-DOF weights (X, Y, Z, K, M, N) of the wrench error in robust mode:
#: depth and attitude (yaw included) first.
DEFAULT_WEIGHTS = (1.0, 1.0, 10.0, 10.0, 10.0, 10.0)
#: The default while a thruster has failed: three thrusters cannot hold every DOF,
#: and yaw gives way to depth, roll and pitch (weighing yaw 10 there cost 0.32 m of
#: depth in the thruster_failure scenario).
FAILED_WEIGHTS = (1.0, 1.0, 10.0, 10.0, 10.0, 1.0)
#: Robust fallback: a tilt motion of 1 rad weighs like this fraction of
#: max(|tau|, max_thrust) of weighted wrench error, so the servos do not chase
#: differences that are tiny compared with the wrench.
DEFAULT_MOTION_PENALTY = 1e-3
# Rows per vectorised chunk of allocate_batch.
_BATCH_CHUNK = 2048


class ThrustAllocator:
    """Allocate a body wrench to four thrusts and two tilts.

    ``allocate(wrench, previous)`` returns an :class:`AllocationResult`.

    Parameters
    ----------
    length, width : l and d, thruster spacing along x and y [m]
    max_thrust : thrust limit of each thruster, both directions [N]
    tilt_limits : (min, max) tilt angle [rad], within [-pi, pi]; a range wider
        than pi reaches some thrust lines from two servo angles
    max_tilt_step : how far each tilt may move from ``previous`` in one call [rad]
    mode : ``'robust'`` (default) or ``'paper'``
    weights : per-DOF weights (X, Y, Z, K, M, N) of the wrench error; default
        :data:`DEFAULT_WEIGHTS`, :data:`FAILED_WEIGHTS` with ``failed_thrusters``
    failed_thrusters : indices 0..3 of thrusters that produce no thrust
    motion_penalty : robust fallback: weighted wrench error, as a fraction of
        max(|tau|, max_thrust), that 1 rad of tilt motion is worth
    planning : robust mode: plan the servos' travel when the best configuration
        is out of reach (:mod:`.planner`); False: the per-tick optimum only
    horizon : planning horizon in calls (default: two 180 deg servo travels)
    backend : ``'numba'`` (the compiled kernels of :mod:`.kernels`), ``'numpy'``
        (this package's reference implementation) or None: the process's
        (:func:`tiltrov_ros.core.jit.backend`, ``TILTROV_BACKEND``). Same answers.
    """

    def __init__(self, length: float, width: float, max_thrust: float = 40.0,
                 tilt_limits: tuple[float, float] = (-HALF_PI, HALF_PI),
                 max_tilt_step: float = math.inf, mode: Mode = 'robust',
                 weights: Sequence[float] | None = None,
                 failed_thrusters: Collection[int] = (),
                 motion_penalty: float = DEFAULT_MOTION_PENALTY,
                 planning: bool = True, horizon: int | None = None,
                 backend: Backend | None = None) -> None:
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
        if weights is None:
            weights = FAILED_WEIGHTS if len(failed_thrusters) else DEFAULT_WEIGHTS
        w = np.array(weights, dtype=float)
        if w.shape != (6,) or not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise AllocationError(f'weights must be 6 finite numbers > 0, got {weights}')
        failed = sorted({int(i) for i in failed_thrusters})
        if any(i not in range(4) for i in failed):
            raise AllocationError(f'failed_thrusters must be indices 0..3, got {failed}')
        if not (math.isfinite(motion_penalty) and motion_penalty >= 0):
            raise AllocationError(f'motion_penalty must be a finite number >= 0, '
                                  f'got {motion_penalty}')
        if horizon is None:
            horizon = (2 * math.ceil(math.pi / max_tilt_step)
                       if math.isfinite(max_tilt_step) else 1)
        if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1:
            raise AllocationError(f'horizon must be an integer >= 1, got {horizon!r}')
        if backend is None:
            backend = 'numba' if jit.compiled() else 'numpy'
        if backend not in ('numba', 'numpy'):
            raise AllocationError(f"backend must be None, 'numba' or 'numpy', got {backend!r}")
        if backend == 'numba' and not jit.compiled():
            raise AllocationError("backend='numba' needs the compiled kernels, but this process "
                                  f"runs the numpy reference ({jit.describe()['reason']})")
        self.length = float(length)
        self.width = float(width)
        self.max_thrust = float(max_thrust)
        self.tilt_limits = (lo, hi)
        self.max_tilt_step = float(max_tilt_step)
        self.mode: Mode = mode
        self.weights = w
        self.failed_thrusters = tuple(failed)
        self.motion_penalty = float(motion_penalty)
        self.planning = bool(planning)
        self.horizon = horizon
        self.geometry = Geometry(self.length, self.width)
        available = np.ones(4, dtype=bool)
        available[failed] = False
        self.limits = Limits(self.geometry, self.max_thrust, lo, hi, self.max_tilt_step, w,
                             available, mode)
        self._options = Options(self.motion_penalty, self.planning, horizon)
        #: ``'numba'`` or ``'numpy'``: which implementation answers.
        self.backend: Backend = backend
        self._compiled = (Compiled(self.limits, self.motion_penalty, self.planning, horizon)
                          if backend == 'numba' else None)

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
        if self._compiled is not None:
            return self._compiled.allocate(self._wrench_array(wrench), previous)
        tau, finite = self._check_wrench(wrench)
        prev = self._previous_tilts(previous)
        limits = self.limits
        box = limits.box(prev)
        if self.mode == 'robust' and self.failed_thrusters:
            # The closed form cannot hold a thruster at zero: optimise directly.
            direct = fallback(limits, self._options, tau, [], math.nan, previous, prev, box,
                              None)
            return self._finish(direct, finite)
        configs, disc = candidates(self.geometry, tau)
        result: AllocationResult | None
        if configs is None:
            # A family: the symmetric one in closed form, else the vectorised selector.
            symmetric = symmetric_family(self.geometry, self.max_thrust, tau, prev, box)
            result = None if symmetric is None else choose(limits, tau, symmetric, math.nan,
                                                           prev, box)
            if result is None:
                result = choose_family(limits, tau, prev)
            configs = configs_from_batch(limits, tau) if result is None else []
        else:
            result = choose(limits, tau, configs, disc, prev, box)
        if result is None and self.mode == 'robust':
            snapped = snapped_candidates(limits, tau)
            result = choose(limits, tau, snapped, disc, prev, box, strict=False)
            if result is not None and not result.feasible:
                result = None
            configs = configs + snapped
        if result is None:
            paper = paper_fallback(limits, tau, configs, disc, prev, box)
            if self.mode == 'paper':
                result = paper
            else:
                result = fallback(limits, self._options, tau, configs, disc, previous, prev,
                                  box, paper)
        return self._finish(result, finite)

    def allocate_fixed(self, wrench: ArrayLike, tilt_front: float, tilt_rear: float,
                       previous: AllocationResult | None = None) -> AllocationResult:
        """Thrusts for tilts held at (``tilt_front``, ``tilt_rear``).

        The linear allocation of the switching baseline (tilts at 0 or 90 deg):
        the thrusts minimise the weighted wrench error within the thrust limit.
        The tilts are clipped to the range and to ``max_tilt_step`` from
        ``previous``; a non-finite requested tilt keeps the previous one.
        """
        if self._compiled is not None:
            request = np.array([tilt_front, tilt_rear], dtype=float)
            return self._compiled.allocate_fixed(self._wrench_array(wrench), float(request[0]),
                                                 float(request[1]), previous)
        tau, finite = self._check_wrench(wrench)
        prev = self._previous_tilts(previous)
        box = self.limits.box(prev)
        request = np.array([tilt_front, tilt_rear], dtype=float)
        keep = prev if prev is not None else np.zeros(2)
        request = np.where(np.isfinite(request), request, keep)
        tilts = np.clip(request, box[:, 0], box[:, 1])
        result = self.limits.make(tau, self.thrusts_at(tau, tilts), tilts, 'fixed_tilt')
        return self._finish(result, finite)

    def thrusts_at(self, wrench: ArrayLike, tilts: ArrayLike) -> FloatArray:
        """(4,) thrusts [N] with the least weighted error at the given (2,) tilts."""
        if self._compiled is not None:
            tau = np.array(wrench, dtype=float).ravel()
            t = np.asarray(tilts, dtype=float).ravel()
            finite = bool(np.all(np.isfinite(tau)) and np.all(np.isfinite(t)))
            if tau.shape == (6,) and t.shape == (2,) and finite:
                return self._compiled.thrusts_at(tau, float(t[0]), float(t[1]))
        problem = TiltProblem(self.geometry, wrench, self.max_thrust, self.weights,
                              self.limits.available)
        t = np.asarray(tilts, dtype=float)
        e = evaluate(problem, float(t[0]), float(t[1]))
        out: FloatArray = np.array(e.thrusts) * problem.scale
        return out

    def allocate_batch(self, wrenches: ArrayLike,
                       previous_tilts: ArrayLike | None = None) -> BatchResult:
        """Allocate many wrenches at once, each row on its own.

        The closed form is vectorised over the rows; rows without a qualifying
        exact solution go one by one through :meth:`allocate`'s fallback (the
        paper's, or the robust optimiser). ``previous_tilts``: (n, 2) or None.
        """
        taus = np.array(wrenches, dtype=float, order='C')
        if taus.ndim != 2 or taus.shape[1] != 6:
            raise AllocationError(f'wrenches must have shape (n, 6), got {taus.shape}')
        n = len(taus)
        given: FloatArray | None = None
        if previous_tilts is not None:
            given = np.array(previous_tilts, dtype=float, order='C')
            if given.shape != (n, 2):
                raise AllocationError(
                    f'previous_tilts must have shape ({n}, 2), got {given.shape}')
        if self._compiled is not None:
            return self._compiled.allocate_batch(taus, given)
        finite = np.all(np.isfinite(taus), axis=1)
        taus = np.where(np.isfinite(taus), taus, 0.0)
        prev: FloatArray | None = None
        if given is not None:
            prev = np.clip(np.where(np.isfinite(given), given, 0.0), *self.tilt_limits)
        thrusts = np.zeros((n, 4))
        tilts = np.zeros((n, 2))
        todo = np.ones(n, dtype=bool)
        if not (self.mode == 'robust' and self.failed_thrusters):
            for start in range(0, n, _BATCH_CHUNK):     # chunks stay in cache
                part = slice(start, min(start + _BATCH_CHUNK, n))
                rows, f, t = choose_batch(self.limits, taus[part],
                                          None if prev is None else prev[part])
                rows = rows + start
                thrusts[rows], tilts[rows] = f, t
                todo[rows] = False
        for i in np.flatnonzero(todo):
            prev_i = None if prev is None else tilts_only(prev[i])
            res = self.allocate(taus[i], prev_i)
            thrusts[i], tilts[i] = res.thrusts, res.tilts
        thrusts[:, ~np.asarray(self.limits.available, dtype=bool)] = 0.0
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
    def _wrench_array(wrench: ArrayLike) -> FloatArray:
        """A fresh (6,) float array of ``wrench``, or one clear error."""
        try:
            tau = np.array(wrench, dtype=float)
        except (TypeError, ValueError) as exc:
            raise AllocationError(f'wrench must be 6 numbers, got {wrench!r}') from exc
        if tau.shape != (6,):
            raise AllocationError(f'wrench must have shape (6,), got {tau.shape}')
        return tau

    @classmethod
    def _check_wrench(cls, wrench: ArrayLike) -> tuple[FloatArray, bool]:
        tau = cls._wrench_array(wrench)
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
            result = self.limits.make(result.requested, f, t, result.method,
                                      result.discriminant)
        if not finite:
            result = replace(result, feasible=False)
        return result


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
