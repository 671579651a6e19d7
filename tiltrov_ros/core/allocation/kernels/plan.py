"""Kernels of the tilt planner: mirror :mod:`..planner` (``path``, ``routes``, ``plan``).

Targets come as rows (a, b, c) of a float array; a route is a row of
:func:`routes`' output (``ROUTE_*``). The route costs sum the cheap upper
bounds of :mod:`.tiltcost` along each path in numpy's pairwise order
(:func:`_pairwise_sum`), so that a choice between two routes of nearly equal
cost falls the same way as in the reference.
"""

from __future__ import annotations

import math

import numpy as np

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.kernels.tiltcost import bounds

# A route (a row of routes()' output): which target, its first step, length and cost.
ROUTE_TARGET = 0          # index into targets
ROUTE_FIRST = 1           # 2 entries: the tilts after the first step
ROUTE_TICKS = 3           # calls to the target
ROUTE_COST = 4            # summed along the path, then the target to the horizon
ROUTE_SIZE = 5


@jit.kernel()
def _ticks(start: float, goal: float, step: float) -> int:
    """Calls one tilt takes from ``start`` to ``goal`` at ``step`` per call."""
    return math.ceil(abs(goal - start) / step - 1e-9)


@jit.kernel()
def _toward(start: float, goal: float, step: float, k: int) -> float:
    """The tilt after ``k`` steps of ``step`` from ``start`` towards ``goal``."""
    d = goal - start
    sign = 0.0 if d == 0.0 else (1.0 if d > 0.0 else (-1.0 if d < 0.0 else d))
    lo, hi = min(start, goal), max(start, goal)
    return min(max(start + sign * step * k, lo), hi)


@jit.kernel()
def path_length(start: FloatArray, goal: FloatArray, step: float, order: int) -> int:
    """len(``..planner.path(start, goal, step, order)``)."""
    n1, n2 = _ticks(start[0], goal[0], step), _ticks(start[1], goal[1], step)
    return max(n1, n2) if order == 0 else n1 + n2


@jit.kernel()
def path_point(start: FloatArray, goal: FloatArray, step: float, order: int,
               k: int) -> tuple[float, float]:
    """Row ``k`` of ``..planner.path(start, goal, step, order)``: the tilts after k + 1
    calls (order 0: both servos at full rate; 1: front first; 2: rear first)."""
    if order == 0:
        return (_toward(start[0], goal[0], step, k + 1),
                _toward(start[1], goal[1], step, k + 1))
    first = 0 if order == 1 else 1
    n1 = _ticks(start[first], goal[first], step)
    if k < n1:
        moving, held = _toward(start[first], goal[first], step, k + 1), start[1 - first]
    else:
        moving = goal[first]
        held = _toward(start[1 - first], goal[1 - first], step, k - n1 + 1)
    return (moving, held) if first == 0 else (held, moving)


@jit.kernel()
def _block_sum(a: FloatArray, lo: int, n: int) -> float:
    """numpy's pairwise sum of a[lo:lo + n] for n <= 128: eight running sums."""
    if n < 8:
        s = 0.0
        for i in range(n):
            s += a[lo + i]
        return s
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - n % 8:
        j = lo + i
        r0, r1, r2, r3 = r0 + a[j], r1 + a[j + 1], r2 + a[j + 2], r3 + a[j + 3]
        r4, r5, r6, r7 = r4 + a[j + 4], r5 + a[j + 5], r6 + a[j + 6], r7 + a[j + 7]
        i += 8
    res: float = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@jit.kernel()
def _pairwise_sum(a: FloatArray, n: int) -> float:
    """float(np.sum(a[:n])): numpy's pairwise summation, which halves a run longer
    than 128 (at a multiple of 8) and adds the halves' sums. The halving runs on an
    explicit stack: numba's cache cannot hold a recursive kernel."""
    if n <= 128:
        return 0.0 + _block_sum(a, 0, n)
    los, ns = np.empty(64, dtype=np.int64), np.empty(64, dtype=np.int64)
    stage, sums = np.zeros(64, dtype=np.int64), np.empty(64)
    los[0], ns[0], stage[0] = 0, n, 0
    sp, vp = 1, 0
    while sp:
        t = sp - 1
        if ns[t] <= 128:
            sums[vp] = _block_sum(a, los[t], ns[t])
            vp += 1
            sp -= 1
            continue
        half = ns[t] // 2
        half -= half % 8
        if stage[t] < 2:                    # descend into the first, then the second half
            start = los[t] if stage[t] == 0 else los[t] + half
            length = half if stage[t] == 0 else ns[t] - half
            stage[t] += 1
            los[sp], ns[sp], stage[sp] = start, length, 0
            sp += 1
        else:                               # both halves summed: add them
            vp -= 1
            sums[vp - 1] = sums[vp - 1] + sums[vp]
            sp -= 1
    total: float = 0.0 + sums[0]
    return total


@jit.kernel()
def routes(prob: FloatArray, start: FloatArray, step: float, targets: FloatArray,
           n_targets: int, horizon: int, out: FloatArray) -> int:
    """``..planner.routes``: every route to every target out of reach, in the
    reference's order, into out[:n] (rows ``ROUTE_*``, at least 3 ``n_targets``);
    returns n."""
    longest = 0
    for t in range(n_targets):
        for order in range(3):
            longest = max(longest, path_length(start, targets[t, :2], step, order))
    along = np.empty(max(longest, 1))
    n = 0
    for t in range(n_targets):
        goal = targets[t, :2]
        away_a = abs(goal[0] - start[0]) > step * (1 + 1e-12)
        away_b = abs(goal[1] - start[1]) > step * (1 + 1e-12)
        if not (away_a or away_b):
            continue                                # within reach: the per-tick optimum
        for order in range(3 if away_a and away_b else 1):
            length = path_length(start, goal, step, order)
            for k in range(length):
                a, b = path_point(start, goal, step, order, k)
                along[k] = bounds(prob, a, b)[1]
            if length >= horizon:
                cost = _pairwise_sum(along, horizon)
            else:
                cost = _pairwise_sum(along, length) + (horizon - length) * targets[t, 2]
            out[n, ROUTE_TARGET] = t
            out[n, ROUTE_FIRST], out[n, ROUTE_FIRST + 1] = path_point(start, goal, step, order, 0)
            out[n, ROUTE_TICKS] = length
            out[n, ROUTE_COST] = cost
            n += 1
    return n


@jit.kernel('boolean(float64[::1], float64[::1], float64, float64, float64[:, ::1], int64, '
            'int64, float64[::1], float64[::1])', group='allocation')
def plan(prob: FloatArray, start: FloatArray, step: float, local_cost: float,
         targets: FloatArray, n_targets: int, horizon: int, kept: FloatArray,
         out: FloatArray) -> bool:
    """``..planner.plan(problem, start, step, local_cost, targets[:n_targets], horizon,
    kept or None)`` (kept NaN: None): out[0:2] the tilts, out[2:5] the target
    (a, b, c); False for None."""
    n_targets = max(0, min(n_targets, targets.shape[0]))
    if n_targets == 0 or not math.isfinite(step):
        return False
    options = np.empty((3 * n_targets, ROUTE_SIZE))
    n = routes(prob, start, step, targets, n_targets, horizon, options)
    if n == 0:
        return False
    chosen = -1
    if not (math.isnan(kept[0]) or math.isnan(kept[1])):
        first_going = -1
        for r in range(n):
            t = int(options[r, ROUTE_TARGET])
            if (abs(targets[t, 0] - kept[0]) <= 1e-9 and abs(targets[t, 1] - kept[1]) <= 1e-9):
                if first_going < 0:
                    first_going = r
                if chosen < 0 or options[r, ROUTE_COST] < options[chosen, ROUTE_COST]:
                    chosen = r
        if first_going >= 0 and not (
                targets[int(options[first_going, ROUTE_TARGET]), 2] < local_cost):
            chosen = -1
    if chosen < 0:
        best = 0
        for r in range(1, n):
            if options[r, ROUTE_COST] < options[best, ROUTE_COST]:
                best = r
        if not options[best, ROUTE_COST] < horizon * local_cost:
            return False
        chosen = best
    t = int(options[chosen, ROUTE_TARGET])
    out[0], out[1] = options[chosen, ROUTE_FIRST], options[chosen, ROUTE_FIRST + 1]
    out[2], out[3], out[4] = targets[t, 0], targets[t, 1], targets[t, 2]
    return True
