"""The reduced cost c(a, b) at one pair of tilts, with its gradient and Hessian, in plain floats.

The tilt search (:mod:`.optimum`) refines a few candidate tilts by Newton's
method; for so few points plain Python floats are several times faster than
numpy, so this module evaluates one point at a time (the vectorised twin,
:meth:`.thrusts.TiltProblem.exact`, evaluates grids; a test keeps them equal).

At tilts theta = (a, b) the thrusts f minimise f' G f - 2 g' f + |W tau|^2
within the box |f_i| <= f_max (G, g: the normal equations of eq. (4) in
thruster coordinates, built from the two 2 x 2 blocks of :mod:`.thrusts`).
With the bounds that are active held fixed and the free set F, the value
function c(theta) has (envelope theorem; Golub and Pereyra's variable
projection)

    dc/di     = f' G_i f - 2 g_i' f
    d2c/didj  = f' G_ij f - 2 g_ij' f - 2 q_i' G_FF^-1 q_j,   q_i = (G_i f - g_i)_F

(G_i = dG/d theta_i and so on). The box is solved by a primal active-set
method started from the caller's hint (the active set at a nearby point), so
along a Newton path it usually takes one linear solve.
"""

from __future__ import annotations

from collections.abc import Sequence
import math
from typing import NamedTuple

import numpy as np

from tiltrov_ros.core.allocation.thrusts import TiltProblem, _enumerate

# Relative slack on the thrust limit and on the multipliers' signs.
_SLACK = 1e-12
_MAX_ITERATIONS = 16


class Evaluation(NamedTuple):
    """c and its derivatives at tilts (a, b), scaled units (see :class:`.thrusts.TiltProblem`).

    thrusts: the optimal (scaled) thrusts; bounds: per thruster -1 (at -f_max),
    +1 (at +f_max), 0 (free) or 2 (failed, held at 0).
    """

    a: float
    b: float
    cost: float
    grad: tuple[float, float]
    hess: tuple[float, float, float]          # (c_aa, c_ab, c_bb)
    thrusts: tuple[float, float, float, float]
    bounds: tuple[int, int, int, int]


def _solve(M: list[list[float]], r: list[float]) -> list[float] | None:
    """Gaussian elimination with partial pivoting (n <= 4); None if singular."""
    n = len(r)
    A = [[*row, r[i]] for i, row in enumerate(M)]
    for k in range(n):
        p = max(range(k, n), key=lambda i: abs(A[i][k]))
        if A[p][k] == 0.0:
            return None
        if p != k:
            A[k], A[p] = A[p], A[k]
        pivot = A[k][k]
        for i in range(k + 1, n):
            factor = A[i][k] / pivot
            if factor != 0.0:
                row_i, row_k = A[i], A[k]
                for j in range(k, n + 1):
                    row_i[j] -= factor * row_k[j]
    x = [0.0] * n
    for i in range(n - 1, -1, -1):
        s = A[i][n] - sum(A[i][j] * x[j] for j in range(i + 1, n))
        x[i] = s / A[i][i]
    return x


def _sd_to_f(S11: float, S12: float, S22: float, D11: float, D12: float,
             D22: float) -> list[list[float]]:
    """A 4 x 4 thruster-coordinate matrix from the two 2 x 2 blocks (P_S' S P_S + P_D' D P_D)."""
    a, b, c, e, m, n = S11 + D11, S11 - D11, S12 + D12, S12 - D12, S22 + D22, S22 - D22
    return [[a, b, c, e], [b, a, e, c], [c, e, m, n], [e, c, n, m]]


def _sd_to_f_vec(s1: float, s2: float, d1: float, d2: float) -> list[float]:
    return [s1 + d1, s1 - d1, s2 + d2, s2 - d2]


def _box(G: list[list[float]], g: list[float], upper: Sequence[float],
         failed: Sequence[bool], start: list[float],
         hint: Sequence[int] | None) -> tuple[list[float], list[int]]:
    """min f'Gf - 2g'f over |f_i| <= upper_i by a primal active-set method."""
    state = [2 if failed[i] else 0 for i in range(4)]
    if hint is not None:
        for i in range(4):
            if state[i] != 2 and hint[i] in (-1, 1):
                state[i] = hint[i]
    else:
        for i in range(4):
            if state[i] != 2 and abs(start[i]) > upper[i]:
                state[i] = 1 if start[i] > 0 else -1
    x = [0.0 if state[i] == 2 else (state[i] * upper[i] if state[i] else
                                    min(max(start[i], -upper[i]), upper[i])) for i in range(4)]
    scale = max(abs(v) for v in g) + 1e-300
    for _ in range(_MAX_ITERATIONS):
        free = [i for i in range(4) if state[i] == 0]
        fixed_val = [0.0 if state[i] == 2 else state[i] * upper[i] for i in range(4)]
        target = list(fixed_val)
        if free:
            M = [[G[i][j] for j in free] for i in free]
            r = [g[i] - sum(G[i][j] * fixed_val[j] for j in range(4) if state[j] != 0)
                 for i in free]
            sol = _solve(M, r)
            if sol is None:
                break
            for i, v in zip(free, sol):
                target[i] = v
        # Step from x towards target, stopping at the first bound crossed.
        step, block = 1.0, -1
        for i in free:
            d = target[i] - x[i]
            if target[i] > upper[i] * (1 + _SLACK) and d > 0:
                t = (upper[i] - x[i]) / d
            elif target[i] < -upper[i] * (1 + _SLACK) and d < 0:
                t = (-upper[i] - x[i]) / d
            else:
                continue
            if t < step:
                step, block = max(t, 0.0), i
        x = [x[i] + step * (target[i] - x[i]) for i in range(4)]
        if block >= 0:
            state[block] = 1 if target[block] > 0 else -1
            x[block] = state[block] * upper[block]
            continue
        # Multipliers of the held bounds: at +f_max the gradient must be <= 0.
        worst, worst_i = 0.0, -1
        for i in range(4):
            if state[i] in (-1, 1):
                grad = sum(G[i][j] * x[j] for j in range(4)) - g[i]
                wrong = grad * state[i]           # > 0: the bound holds the thrust back wrongly
                if wrong > 1e-10 * scale and wrong > worst:
                    worst, worst_i = wrong, i
        if worst_i < 0:
            return x, state
        state[worst_i] = 0
    # Not settled (degenerate): enumerate every active set.
    up = np.array(upper, dtype=float)
    sol_all = _enumerate(np.array([G]), np.array([g]), -up, up)[0]
    x = [float(v) for v in sol_all]
    state = [2 if failed[i] else (1 if x[i] >= upper[i] * (1 - 1e-9) and upper[i] > 0 else
                                  (-1 if x[i] <= -upper[i] * (1 - 1e-9) and upper[i] > 0
                                   else 0)) for i in range(4)]
    return x, state


def evaluate(problem: TiltProblem, a: float, b: float,
             hint: Sequence[int] | None = None) -> Evaluation:
    """c, its gradient and Hessian at (a, b); ``hint``: bounds of a nearby evaluation."""
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    cc, ss, cs, sc = ca * cb, sa * sb, ca * sb, sa * cb
    s2a, c2a, s2b, c2b = 2.0 * sa * ca, ca * ca - sa * sa, 2.0 * sb * cb, cb * cb - sb * sb
    blocks = []
    for (A1, A2, B1, B2), (u1, v1, u2, v2) in ((problem.s_coef, problem.s_target),
                                                (problem.d_coef, problem.d_target)):
        dA = A2 - A1
        G11, G12, G22 = A1 * ca * ca + A2 * sa * sa, B1 * cc + B2 * ss, A1 * cb * cb + A2 * sb * sb
        g1, g2 = ca * u1 + sa * v1, cb * u2 + sb * v2
        blocks.append((
            (G11, G12, G22, g1, g2),
            # d/da, d/db, d2/da2, d2/dadb, d2/db2 of (G11, G12, G22, g1, g2)
            (dA * s2a, -B1 * sc + B2 * cs, 0.0, -sa * u1 + ca * v1, 0.0),
            (0.0, -B1 * cs + B2 * sc, dA * s2b, 0.0, -sb * u2 + cb * v2),
            (2.0 * dA * c2a, -G12, 0.0, -g1, 0.0),
            (0.0, B1 * ss + B2 * cc, 0.0, 0.0, 0.0),
            (0.0, -G12, 2.0 * dA * c2b, 0.0, -g2)))
    S, D = blocks
    upper = problem.upper.tolist()
    failed = [not v for v in problem.available.tolist()]
    # Unconstrained start from the two 2 x 2 blocks.
    sf, sr = solve2(*S[0])
    df, dr = solve2(*D[0])
    start = [sf, sr, df, dr]
    f0 = [0.5 * (sf + df), 0.5 * (sf - df), 0.5 * (sr + dr), 0.5 * (sr - dr)]
    if (hint is None or not any(hint)) and not any(failed) and all(
            abs(f0[i]) <= upper[i] * (1 + _SLACK) for i in range(4)):
        return _unconstrained(problem, a, b, blocks, start, f0)
    mats = []
    vecs = []
    for k in range(6):
        s, d = S[k], D[k]
        mats.append(_sd_to_f(s[0], s[1], s[2], d[0], d[1], d[2]))
        vecs.append(_sd_to_f_vec(s[3], s[4], d[3], d[4]))
    G, g = mats[0], vecs[0]
    ridge = 1e-12 * (G[0][0] + G[1][1] + G[2][2] + G[3][3]) + 1e-300
    for i in range(4):
        G[i][i] += ridge
    x, state = _box(G, g, upper, failed, f0, hint)
    Gx = [sum(G[i][j] * x[j] for j in range(4)) for i in range(4)]
    cost = max(problem.target_norm2 + sum(x[i] * (Gx[i] - 2.0 * g[i]) for i in range(4)), 0.0)

    def quad(k: int) -> float:
        M, v = mats[k], vecs[k]
        return sum(x[i] * sum(M[i][j] * x[j] for j in range(4)) for i in range(4)) \
            - 2.0 * sum(v[i] * x[i] for i in range(4))

    grad = (quad(1), quad(2))
    free = [i for i in range(4) if state[i] == 0]
    h = [quad(3), quad(4), quad(5)]
    if free:
        q = [[sum(mats[k][i][j] * x[j] for j in range(4)) - vecs[k][i] for i in free]
             for k in (1, 2)]
        M = [[G[i][j] for j in free] for i in free]
        ya, yb = _solve(M, q[0]), _solve(M, q[1])
        if ya is not None and yb is not None:
            h[0] -= 2.0 * sum(u * v for u, v in zip(q[0], ya))
            h[1] -= 2.0 * sum(u * v for u, v in zip(q[0], yb))
            h[2] -= 2.0 * sum(u * v for u, v in zip(q[1], yb))
    return Evaluation(a, b, cost, grad, (h[0], h[1], h[2]),
                      (x[0], x[1], x[2], x[3]), (state[0], state[1], state[2], state[3]))


Block = tuple[tuple[float, float, float, float, float], ...]
Blocks = Sequence[Block]


def _unconstrained(problem: TiltProblem, a: float, b: float, blocks: Blocks,
                   start: list[float], f0: list[float]) -> Evaluation:
    """:func:`evaluate` when no bound is active: the two 2 x 2 blocks apart."""
    cost = problem.target_norm2
    ga = gb = haa = hab = hbb = 0.0
    for blk, (x1, x2) in zip(blocks, ((start[0], start[1]), (start[2], start[3]))):
        (G11, G12, G22, g1, g2) = blk[0]
        cost -= x1 * g1 + x2 * g2
        terms = []
        for k in (1, 2, 3, 4, 5):
            d11, d12, d22, dg1, dg2 = blk[k]
            terms.append(x1 * (d11 * x1 + 2.0 * d12 * x2) + d22 * x2 * x2
                         - 2.0 * (dg1 * x1 + dg2 * x2))
        ga += terms[0]
        gb += terms[1]
        # q_i = G_i x - g_i; the Hessian loses 2 q_i' G^-1 q_j.
        qa1 = blk[1][0] * x1 + blk[1][1] * x2 - blk[1][3]
        qa2 = blk[1][1] * x1 + blk[1][2] * x2 - blk[1][4]
        qb1 = blk[2][0] * x1 + blk[2][1] * x2 - blk[2][3]
        qb2 = blk[2][1] * x1 + blk[2][2] * x2 - blk[2][4]
        ya1, ya2 = solve2(G11, G12, G22, qa1, qa2)
        yb1, yb2 = solve2(G11, G12, G22, qb1, qb2)
        haa += terms[2] - 2.0 * (qa1 * ya1 + qa2 * ya2)
        hab += terms[3] - 2.0 * (qa1 * yb1 + qa2 * yb2)
        hbb += terms[4] - 2.0 * (qb1 * yb1 + qb2 * yb2)
    return Evaluation(a, b, max(cost, 0.0), (ga, gb), (haa, hab, hbb),
                      (f0[0], f0[1], f0[2], f0[3]), (0, 0, 0, 0))


def solve2(G11: float, G12: float, G22: float, g1: float, g2: float) -> tuple[float, float]:
    """:meth:`.thrusts.TiltProblem._solve2` for one point, in plain floats."""
    theta = 0.5 * math.atan2(2.0 * G12, G11 - G22)
    c, s = math.cos(theta), math.sin(theta)
    big = G11 * c * c + 2.0 * G12 * c * s + G22 * s * s
    small = G11 * s * s - 2.0 * G12 * c * s + G22 * c * c
    p = (c * g1 + s * g2) / big if big > 0.0 else 0.0
    q = (c * g2 - s * g1) / small if small > 1e-12 * big else 0.0
    return c * p - s * q, s * p + c * q
