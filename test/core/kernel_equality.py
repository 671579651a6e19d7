"""Pinning the compiled allocation to the numpy reference, call by call.

Two allocators with the same settings, ``backend='numpy'`` (the reference)
and ``backend='numba'`` (the kernels), answer the same call; :class:`Tally`
checks the two answers:

* method, feasible, stuck and whether there is a target: equal;
* the weighted error: equal to 1e-9 relative (floor: 1e-12 of the wrench's
  scale, where an exact answer's error is rounding);
* thrusts, tilts, achieved wrench and target: equal to 1e-9 (thrusts and the
  wrench relative to the scale max(|tau|, f_max)) -- unless the two answers
  tie: the kernels' point, costed by the reference's own formulas
  (``ThrustAllocator.wrench`` and ``weighted_error``), has the reference's
  weighted error to 1e-9 relative, within the limits. A tie is counted (and
  its case kept for the message), never taken for an equality; a point that
  differs without such a tie fails.

A per-tick optimum (``optimized``) may also stop a hair apart: its search ends
when the predicted decrease falls below 1e-7 of the cost (optimum.py), so
rounding that differs in the last iterations leaves the two weighted errors
equal to :data:`STOP_RTOL` only (seen once in 500 calls of current_hold with
the pid's anti-windup). The decrease is measured on the search's objective,
the error's cost plus the motion penalty around the previous tilts, so where
the error is tiny and the penalty is not, the errors of the two stopping points
can differ by more (2e-5 relative, at an error of 9.3e-4, in a station-keeping
sample) while the points are :data:`STOP_TILTS` apart or less. Either is
counted as a tie too, with the kernels' point costed by the reference.

Both sides must also be consistent: the achieved wrench is eq. (4) of the
thrusts and tilts.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation import AllocationResult, BatchResult, ThrustAllocator
from tiltrov_ros.core.allocation.decomposition import fold_tilt
from tiltrov_ros.core.thrust_map import allocation_matrix

RTOL = 1e-9
#: The per-tick optimum's stopping point: errors equal to this (relative) tie.
STOP_RTOL = 1e-6
#: rad: or the two stopping points' tilts this close (the same minimum, 7e-7 rad apart
#: in that sample).
STOP_TILTS = 1e-5

#: The compiled side needs numba; under TILTROV_BACKEND=numpy the reference has
#: nothing to be compared with (the reference's own tests still run).
needs_kernels = pytest.mark.skipif(
    not jit.compiled(), reason='the compiled kernels are not available in this process '
    f'({jit.describe()["reason"]}): nothing to compare the numpy reference with')


def pair(length: float = 0.6, width: float = 0.4, max_thrust: float = 40.0,
         **kwargs: object) -> tuple[ThrustAllocator, ThrustAllocator]:
    """The reference and the kernels with the same settings."""
    return (ThrustAllocator(length, width, max_thrust, backend='numpy', **kwargs),
            ThrustAllocator(length, width, max_thrust, backend='numba', **kwargs))


def _scale(alloc: ThrustAllocator, tau: np.ndarray) -> float:
    return max(float(np.linalg.norm(tau)), alloc.max_thrust)


@dataclass
class Tally:
    """Calls compared, and the ties among them (what, where)."""

    calls: int = 0
    ties: list[str] = field(default_factory=list)

    def error_close(self, alloc: ThrustAllocator, tau: np.ndarray, a: float, b: float) -> bool:
        floor = 1e-12 * _scale(alloc, tau) * float(np.max(alloc.weights))
        return abs(a - b) <= RTOL * max(abs(a), abs(b)) + floor

    def same(self, alloc: ThrustAllocator, r: AllocationResult, k: AllocationResult,
             where: str, previous: AllocationResult | None = None) -> bool:
        """Assert ``k`` (kernels) answers as ``r`` (reference); False when they tie.
        ``previous``: the call's (the paper rule's ties are measured from it)."""
        self.calls += 1
        tau = r.requested
        np.testing.assert_array_equal(k.requested, r.requested, err_msg=where)
        assert (k.method, k.feasible, k.stuck) == (r.method, r.feasible, r.stuck), (
            f'{where}: reference {r.method} feasible={r.feasible} stuck={r.stuck}, '
            f'kernels {k.method} feasible={k.feasible} stuck={k.stuck}')
        assert (k.target is None) == (r.target is None), f'{where}: {r.target} vs {k.target}'
        if r.method == 'pseudo' and _pseudo_tie(alloc, r, k, previous):
            self.ties.append(f'{where}: pseudo, the paper rule has two angles equally near')
            return False
        if not self.error_close(alloc, tau, r.error, k.error):
            near = max(abs(k.tilt_front - r.tilt_front), abs(k.tilt_rear - r.tilt_rear))
            stopped = (r.method == 'optimized'
                       and (abs(r.error - k.error) <= STOP_RTOL * max(r.error, k.error)
                            or near <= STOP_TILTS)
                       and self.error_close(alloc, tau, k.error, _cost(alloc, tau, k)))
            assert stopped, (f'{where}: weighted error {r.error!r} (reference) vs '
                             f'{k.error!r} (kernels)')
            self.ties.append(f'{where}: optimized, the search stopped {k.error / r.error - 1:.2g}'
                             ' apart in error')
            return False
        for res in (r, k):
            np.testing.assert_allclose(
                res.achieved, alloc.wrench(res.thrusts, res.tilt_front, res.tilt_rear),
                rtol=0, atol=1e-12 * _scale(alloc, tau), err_msg=where)
        s = _scale(alloc, tau)
        apart = max(float(np.max(np.abs(k.thrusts - r.thrusts))) / s,
                    abs(k.tilt_front - r.tilt_front), abs(k.tilt_rear - r.tilt_rear),
                    float(np.max(np.abs(k.achieved - r.achieved))) / s)
        if r.target is not None and k.target is not None:
            apart = max(apart, abs(k.target[0] - r.target[0]), abs(k.target[1] - r.target[1]))
        if apart <= RTOL:
            return True
        # A tie? The kernels' point costed by the reference, within the limits.
        lo, hi = alloc.tilt_limits
        cost = _cost(alloc, tau, k)
        within = (np.all(np.abs(k.thrusts) <= alloc.max_thrust)
                  and lo <= k.tilt_front <= hi and lo <= k.tilt_rear <= hi)
        assert within and self.error_close(alloc, tau, r.error, cost), (
            f'{where}: the answers differ by {apart:.3g} without a tie: reference '
            f'{r.thrusts}, ({r.tilt_front}, {r.tilt_rear}), error {r.error}; kernels '
            f'{k.thrusts}, ({k.tilt_front}, {k.tilt_rear}), error {k.error} (reference '
            f'cost there {cost})')
        self.ties.append(f'{where}: {r.method}, points {apart:.2g} apart, error {r.error:.6g}')
        return False

    def call(self, ref: ThrustAllocator, ker: ThrustAllocator, tau: np.ndarray,
             previous: AllocationResult | None, where: str) -> tuple[AllocationResult, bool]:
        """``allocate`` on both; the reference's answer and whether the two are the same."""
        r = ref.allocate(tau, previous)
        return r, self.same(ref, r, ker.allocate(tau, previous), where, previous)

    def check_ties(self, share: float = 0.02) -> None:
        """Ties are rare (two optima equal to 1e-9): at most ``share`` of the calls."""
        assert len(self.ties) <= max(1, share * self.calls), (
            f'{len(self.ties)} ties in {self.calls} calls:\n' + '\n'.join(self.ties[:20]))


def _cost(alloc: ThrustAllocator, tau: np.ndarray, k: AllocationResult) -> float:
    """The weighted error of ``k``'s thrusts and tilts by the reference's formulas."""
    return float(alloc.weighted_error(tau[None], alloc.wrench(
        k.thrusts[None], np.array([k.tilt_front]), np.array([k.tilt_rear])))[0])


def _pseudo_tie(alloc: ThrustAllocator, r: AllocationResult, k: AllocationResult,
                previous: AllocationResult | None) -> bool:
    """Whether ``k`` is the paper mode's pseudo answer (Section 3.2 case 3) with the
    other of a pair's two thruster angles where both are equally near the previous
    tilt (to 1e-9 rad: rounding decides): the rule's tie, its thrusts as the rule
    makes them at those tilts."""
    tau = r.requested
    c = np.linalg.pinv(allocation_matrix(alloc.length, alloc.width)) @ tau
    z, h = c[:4], c[4:]
    angles = fold_tilt(np.arctan2(z, h))
    lo, hi = alloc.tilt_limits
    ref = np.zeros(2)
    if previous is not None and np.all(np.isfinite(previous.tilts)):
        ref = np.clip(previous.tilts, lo, hi)
    box = alloc.limits.box(None if previous is None or not np.all(np.isfinite(previous.tilts))
                           else ref)
    tied = False
    for p, (i, j) in enumerate(((0, 1), (2, 3))):
        left, right = angles[i], angles[j]
        options = [float(np.clip(np.clip(t, lo, hi), *box[p])) for t in (left, right)]
        if abs(r.tilts[p] - k.tilts[p]) <= RTOL:
            continue
        if not (abs(abs(left - ref[p]) - abs(right - ref[p])) <= RTOL
                and all(min(abs(t - o) for o in options) <= RTOL for t in (r.tilts[p],
                                                                            k.tilts[p]))):
            return False
        tied = True
    t = np.repeat(k.tilts, 2)
    f = np.clip(h * np.cos(t) + z * np.sin(t), -alloc.max_thrust, alloc.max_thrust)
    f[list(alloc.failed_thrusters)] = 0.0
    return tied and bool(np.allclose(k.thrusts, f, rtol=0, atol=RTOL * _scale(alloc, tau)))


def stand_in(alloc: ThrustAllocator, tilts: np.ndarray) -> AllocationResult:
    """The previous result ``allocate_batch`` gives a row: its tilts (non-finite read
    as 0, clipped into range) and nothing else."""
    t = np.clip(np.where(np.isfinite(tilts), tilts, 0.0), *alloc.tilt_limits)
    return alloc.allocate_fixed(np.zeros(6), float(t[0]), float(t[1]))


def same_batch(ref: ThrustAllocator, ker: ThrustAllocator, r: BatchResult, k: BatchResult,
               taus: np.ndarray, prev: np.ndarray | None, tally: Tally, where: str) -> None:
    """Row by row: as :meth:`Tally.same` on the fields a batch has. A row that differs
    is answered by single calls from the row's previous (as the batch's fallback does):
    it must be a tie there, each batch row equal to its backend's single answer."""
    clean = np.where(np.isfinite(taus), taus, 0.0)
    np.testing.assert_array_equal(k.feasible, r.feasible, err_msg=where)
    for i in range(len(taus)):
        tally.calls += 1
        tau = clean[i]
        s = _scale(ref, tau)
        apart = max(float(np.max(np.abs(k.thrusts[i] - r.thrusts[i]))) / s,
                    abs(k.tilt_front[i] - r.tilt_front[i]), abs(k.tilt_rear[i] - r.tilt_rear[i]),
                    float(np.max(np.abs(k.achieved[i] - r.achieved[i]))) / s)
        if apart <= RTOL and tally.error_close(ref, tau, r.error[i], k.error[i]):
            continue
        previous = None if prev is None else stand_in(ref, prev[i])
        r1, k1 = ref.allocate(tau, previous), ker.allocate(tau, previous)
        for batch, single in ((r, r1), (k, k1)):
            np.testing.assert_allclose(batch.thrusts[i], single.thrusts, rtol=0,
                                       atol=RTOL * s, err_msg=f'{where} row {i}')
            np.testing.assert_allclose(batch.tilts[i], single.tilts, rtol=0, atol=RTOL,
                                       err_msg=f'{where} row {i}')
        tally.calls -= 1
        assert not tally.same(ref, r1, k1, f'{where} row {i}', previous), (
            f'{where} row {i}: the batches differ, the single calls do not')
