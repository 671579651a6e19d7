"""The thrusts at given tilts within the limit: mirror ``..local._box``, ``..local._solve``
and ``..thrusts._enumerate``, for :func:`.tiltcost.evaluate`.

min f'Gf - 2g'f over |f_i| <= upper_i by the reference's primal active-set
method (started from the unconstrained thrusts and the caller's hint), and
when it does not settle every active set (3^4 of them). G and g live in the
evaluation's scratch ``work`` (offsets below), the bounds state in ``iwork``;
everything is float64 scalars and those two flat arrays, in the reference's
order of operations.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.kernels.layout import PROB_AVAILABLE, PROB_UPPER
from tiltrov_ros.core.allocation.local import _MAX_ITERATIONS, _SLACK

IntArray = NDArray[np.int64]

# Scratch of one evaluation, work: float64[WORK_SIZE].
_BLK = 0        # 60: block p (0 sums, 1 differences), derivative k (value, d/da, d/db,
#                 d2/da2, d2/dadb, d2/db2): (G11, G12, G22, g1, g2) at _BLK + 30 p + 5 k
_MATS = 60      # 96: the six 4 x 4 thruster-coordinate matrices, row-major, 16 apart
_VECS = 156     # 24: the six thruster-coordinate vectors, 4 apart
_X = 180        # 4: the thrusts
_TARGET = 184   # 4: the active-set step's target
_FIXED = 188    # 4: values of the held thrusters
_RHS = 192      # 4: right-hand side on the free set
_SOL = 196      # 4: solution on the free set
_AUG = 200      # 20: augmented 4 x 5 matrix of the elimination
_QA = 220       # 4: q_a on the free set
_QB = 224       # 4: q_b
_YA = 228       # 4: G_FF^-1 q_a
_YB = 232       # 4: G_FF^-1 q_b
_F0 = 236       # 4: the unconstrained thrusts
_EX = 240       # 4: one active set's thrusts (enumeration)
_EBEST = 244    # 4: the best of them
WORK_SIZE = 248
# iwork: int64[IWORK_SIZE].
_STATE = 0      # 4: -1, 0, +1, 2 per thruster
_FREE = 4       # 4: indices of the free thrusters
IWORK_SIZE = 8


@jit.kernel()
def _py_max(x: float, y: float) -> float:
    """Python's max(x, y): x unless y > x."""
    return y if y > x else x


@jit.kernel()
def _py_min(x: float, y: float) -> float:
    """Python's min(x, y): x unless y < x."""
    return y if y < x else x


@jit.kernel()
def _solve_free(work: FloatArray, iwork: IntArray, n: int, rhs: int, out: int) -> bool:
    """``..local._solve`` of G[free][free] y = work[rhs:rhs + n] into work[out:]
    (Gaussian elimination with partial pivoting); False if singular."""
    for r in range(n):
        i = iwork[_FREE + r]
        for c in range(n):
            work[_AUG + 5 * r + c] = work[_MATS + 4 * i + iwork[_FREE + c]]
        work[_AUG + 5 * r + n] = work[rhs + r]
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(work[_AUG + 5 * i + k]) > abs(work[_AUG + 5 * p + k]):
                p = i
        if work[_AUG + 5 * p + k] == 0.0:
            return False
        if p != k:
            for j in range(n + 1):
                t = work[_AUG + 5 * k + j]
                work[_AUG + 5 * k + j] = work[_AUG + 5 * p + j]
                work[_AUG + 5 * p + j] = t
        pivot = work[_AUG + 5 * k + k]
        for i in range(k + 1, n):
            factor = work[_AUG + 5 * i + k] / pivot
            if factor != 0.0:
                for j in range(k, n + 1):
                    work[_AUG + 5 * i + j] -= factor * work[_AUG + 5 * k + j]
    for i in range(n - 1, -1, -1):
        s = 0.0
        for j in range(i + 1, n):
            s += work[_AUG + 5 * i + j] * work[out + j]
        work[out + i] = (work[_AUG + 5 * i + n] - s) / work[_AUG + 5 * i + i]
    return True


@jit.kernel()
def _enumerate(prob: FloatArray, work: FloatArray, iwork: IntArray) -> None:
    """``..thrusts._enumerate`` of one row into work[_X:]: the best feasible thrusts of
    min x'Gx - 2 g'x over the 3^4 active sets (free, at -upper, at +upper)."""
    best, have = math.inf, False
    for pattern in range(81):                       # itertools.product order
        skip = False
        n = 0
        for i in range(4):
            digit = (pattern // (27, 9, 3, 1)[i]) % 3
            up = prob[PROB_UPPER + i]
            if up == 0.0 and digit != 1:            # degenerate (failed): at the bound only
                skip = True
            work[_FIXED + i] = -up if digit == 1 else (up if digit == 2 else 0.0)
            if digit == 0:
                iwork[_FREE + n] = i
                n += 1
        if skip:
            continue
        for r in range(n):
            i = iwork[_FREE + r]
            s = 0.0
            for j in range(4):
                s += work[_MATS + 4 * i + j] * work[_FIXED + j]
            work[_RHS + r] = work[_VECS + i] - s
        solved = _solve_free(work, iwork, n, _RHS, _SOL) if n else True
        for i in range(4):
            work[_EX + i] = work[_FIXED + i]
        for r in range(n):
            work[_EX + iwork[_FREE + r]] = work[_SOL + r]
        feasible = solved
        for i in range(4):
            up = prob[PROB_UPPER + i]
            slack = 1e-9 * (abs(up) + 1e-300)
            x = work[_EX + i]
            if not (x >= -up - slack and x <= up + slack):
                feasible = False
            work[_EX + i] = _py_min(_py_max(x, -up), up)
        quad, lin = 0.0, 0.0
        for i in range(4):
            for j in range(4):
                quad += work[_EX + i] * work[_MATS + 4 * i + j] * work[_EX + j]
            lin += work[_EX + i] * work[_VECS + i]
        cost = quad - 2.0 * lin if feasible else math.inf
        if not have or cost < best:                 # argmin: the first on ties
            best, have = cost, True
            for i in range(4):
                work[_EBEST + i] = work[_EX + i]
    for i in range(4):
        work[_X + i] = work[_EBEST + i]


@jit.kernel()
def box(prob: FloatArray, work: FloatArray, iwork: IntArray, hint: IntArray,
        has_hint: bool) -> None:
    """``..local._box``: min f'Gf - 2g'f over |f_i| <= upper_i by a primal active-set
    method from work[_F0:] (G, g: work[_MATS:], work[_VECS:]); thrusts into work[_X:],
    bounds into iwork[_STATE:]."""
    for i in range(4):
        iwork[_STATE + i] = 2 if prob[PROB_AVAILABLE + i] == 0.0 else 0
    for i in range(4):
        if iwork[_STATE + i] == 2:
            continue
        if has_hint:
            if hint[i] == -1 or hint[i] == 1:
                iwork[_STATE + i] = hint[i]
        elif abs(work[_F0 + i]) > prob[PROB_UPPER + i]:
            iwork[_STATE + i] = 1 if work[_F0 + i] > 0 else -1
    for i in range(4):
        st, up, f = iwork[_STATE + i], prob[PROB_UPPER + i], work[_F0 + i]
        work[_X + i] = 0.0 if st == 2 else (st * up if st != 0 else
                                             _py_min(_py_max(f, -up), up))
    scale = abs(work[_VECS])
    for i in range(1, 4):
        scale = _py_max(scale, abs(work[_VECS + i]))
    scale += 1e-300
    for _ in range(_MAX_ITERATIONS):
        n = 0
        for i in range(4):
            st = iwork[_STATE + i]
            work[_FIXED + i] = 0.0 if st == 2 else st * prob[PROB_UPPER + i]
            work[_TARGET + i] = work[_FIXED + i]
            if st == 0:
                iwork[_FREE + n] = i
                n += 1
        if n:
            for r in range(n):
                i = iwork[_FREE + r]
                s = 0.0
                for j in range(4):
                    if iwork[_STATE + j] != 0:
                        s += work[_MATS + 4 * i + j] * work[_FIXED + j]
                work[_RHS + r] = work[_VECS + i] - s
            if not _solve_free(work, iwork, n, _RHS, _SOL):
                break
            for r in range(n):
                work[_TARGET + iwork[_FREE + r]] = work[_SOL + r]
        # Step from x towards target, stopping at the first bound crossed.
        step, block = 1.0, -1
        for r in range(n):
            i = iwork[_FREE + r]
            up, x, tg = prob[PROB_UPPER + i], work[_X + i], work[_TARGET + i]
            d = tg - x
            if tg > up * (1 + _SLACK) and d > 0:
                t = (up - x) / d
            elif tg < -up * (1 + _SLACK) and d < 0:
                t = (-up - x) / d
            else:
                continue
            if t < step:
                step, block = _py_max(t, 0.0), i
        for i in range(4):
            work[_X + i] = work[_X + i] + step * (work[_TARGET + i] - work[_X + i])
        if block >= 0:
            iwork[_STATE + block] = 1 if work[_TARGET + block] > 0 else -1
            work[_X + block] = iwork[_STATE + block] * prob[PROB_UPPER + block]
            continue
        # Multipliers of the held bounds: at +f_max the gradient must be <= 0.
        worst, worst_i = 0.0, -1
        for i in range(4):
            st = iwork[_STATE + i]
            if st == -1 or st == 1:
                s = 0.0
                for j in range(4):
                    s += work[_MATS + 4 * i + j] * work[_X + j]
                wrong = (s - work[_VECS + i]) * st
                if wrong > 1e-10 * scale and wrong > worst:
                    worst, worst_i = wrong, i
        if worst_i < 0:
            return
        iwork[_STATE + worst_i] = 0
    # Not settled (degenerate): enumerate every active set.
    _enumerate(prob, work, iwork)
    for i in range(4):
        up, x = prob[PROB_UPPER + i], work[_X + i]
        if prob[PROB_AVAILABLE + i] == 0.0:
            iwork[_STATE + i] = 2
        elif x >= up * (1 - 1e-9) and up > 0:
            iwork[_STATE + i] = 1
        elif x <= -up * (1 - 1e-9) and up > 0:
            iwork[_STATE + i] = -1
        else:
            iwork[_STATE + i] = 0


