"""Kernels of the reduced cost c(a, b): mirror :class:`..thrusts.TiltProblem` and :mod:`..local`.

c(a, b) is the least ||W (B(a, b) f - tau)||^2 over the thrusts |f_i| <= f_max
at tilts (a, b), eq. (4) split into its sums block (X, Z, M) and differences
block (Y, K, N) (:mod:`..decomposition`), each 2 x 2 normal equations.

* :func:`problem` fills a flat ``prob`` array (:mod:`.layout` ``PROB_*``) as
  ``TiltProblem(Geometry(l, d), tau, max_thrust, weights, available)`` does;
* :func:`bounds` / :func:`bounds_grid`: ``TiltProblem.bounds`` at one or many
  tilt pairs (the numpy reference's ``inf``/``nan`` semantics, point by point);
* :func:`evaluate`: ``..local.evaluate`` (cost, gradient and Hessian of c by the
  envelope theorem, the thrusts by a primal active-set method on the box
  |f_i| <= f_max, the 3^4 enumeration of ``..thrusts._enumerate`` when it does
  not settle) into a flat ``rec`` (``REC_*``).

Same operations in the same order as the reference, on float64 scalars and
flat scratch arrays (``work``, ``iwork``: :data:`.activeset.WORK_SIZE`,
:data:`.activeset.IWORK_SIZE`) that a caller evaluating many points allocates
once (:func:`evaluate_into`); the thrusts within the limit come from
:mod:`.activeset`.
"""

from __future__ import annotations

import math

import numpy as np

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import SQRT2, FloatArray
from tiltrov_ros.core.allocation.kernels.activeset import (
    _BLK,
    _F0,
    _FREE,
    _MATS,
    _QA,
    _QB,
    _STATE,
    _VECS,
    _X,
    _YA,
    _YB,
    IWORK_SIZE,
    WORK_SIZE,
    IntArray,
    _py_max,
    _solve_free,
    box,
)
from tiltrov_ros.core.allocation.kernels.layout import (
    CFG_AVAILABLE,
    CFG_FMAX,
    CFG_K,
    CFG_L,
    CFG_W,
    CFG_WEIGHTS,
    PROB_ALL_AVAILABLE,
    PROB_AVAILABLE,
    PROB_D_COEF,
    PROB_D_TARGET,
    PROB_FMAX,
    PROB_S_COEF,
    PROB_S_TARGET,
    PROB_SCALE,
    PROB_TARGET_NORM2,
    PROB_TAU,
    PROB_UPPER,
    REC_A,
    REC_B,
    REC_BOUNDS,
    REC_COST,
    REC_GRAD,
    REC_HESS,
    REC_THRUSTS,
)
from tiltrov_ros.core.allocation.local import _SLACK
from tiltrov_ros.core.allocation.thrusts import _RIDGE

_FLOAT_MAX = float(np.finfo(np.float64).max)


# --------------------------------------------------------------------------- the problem

@jit.kernel('void(float64[::1], float64[::1], float64[::1])', group='allocation')
def problem(cfg: FloatArray, tau: FloatArray, prob: FloatArray) -> None:
    """Fill ``prob`` as ``TiltProblem(Geometry(l, d), tau, max_thrust, weights, available)``:
    the scaled wrench and limit, and the blocks of eq. (4)'s normal equations."""
    fmax = cfg[CFG_FMAX]
    big = abs(tau[0])
    for i in range(1, 6):
        if abs(tau[i]) > big:
            big = abs(tau[i])
    scale = big if big >= fmax else fmax                      # max(max |tau_i|, f_max)
    prob[PROB_SCALE] = scale
    for i in range(6):
        prob[PROB_TAU + i] = tau[i] / scale
    X, Y, Z = prob[PROB_TAU], prob[PROB_TAU + 1], prob[PROB_TAU + 2]
    K, M, N = prob[PROB_TAU + 3], prob[PROB_TAU + 4], prob[PROB_TAU + 5]
    f = fmax / scale
    prob[PROB_FMAX] = f
    every = 1.0
    for i in range(4):
        on = cfg[CFG_AVAILABLE + i] != 0.0
        prob[PROB_AVAILABLE + i] = 1.0 if on else 0.0
        prob[PROB_UPPER + i] = f if on else 0.0
        if not on:
            every = 0.0
    prob[PROB_ALL_AVAILABLE] = every
    w = cfg[CFG_WEIGHTS:CFG_WEIGHTS + 6]
    wX, wY, wZ = w[0] ** 2, w[1] ** 2, w[2] ** 2
    wK, wM, wN = w[3] ** 2, w[4] ** 2, w[5] ** 2
    l, d, k = cfg[CFG_L], cfg[CFG_W], cfg[CFG_K]
    prob[PROB_S_COEF] = wX / 2
    prob[PROB_S_COEF + 1] = wZ + wM * l * l / 4
    prob[PROB_S_COEF + 2] = wX / 2
    prob[PROB_S_COEF + 3] = wZ - wM * l * l / 4
    prob[PROB_D_COEF] = wY / 2 + wN * k * k
    prob[PROB_D_COEF + 1] = wK * d * d / 4
    prob[PROB_D_COEF + 2] = wY / 2 - wN * k * k
    prob[PROB_D_COEF + 3] = -wK * d * d / 4
    p = wX * X / SQRT2
    prob[PROB_S_TARGET] = p
    prob[PROB_S_TARGET + 1] = -wZ * Z + wM * M * l / 2
    prob[PROB_S_TARGET + 2] = p
    prob[PROB_S_TARGET + 3] = -wZ * Z - wM * M * l / 2
    q = wY * Y / SQRT2
    prob[PROB_D_TARGET] = q + wN * N * k
    prob[PROB_D_TARGET + 1] = wK * K * d / 2
    prob[PROB_D_TARGET + 2] = q - wN * N * k
    prob[PROB_D_TARGET + 3] = -wK * K * d / 2
    prob[PROB_TARGET_NORM2] = (wX * X * X + wY * Y * Y + wZ * Z * Z + wK * K * K
                               + wM * M * M + wN * N * N)


# --------------------------------------------------------------------------- the bounds

@jit.kernel()
def _maximum(x: float, y: float) -> float:
    """np.maximum of two floats (NaN propagates)."""
    if x != x or y != y:
        return math.nan
    return x if x >= y else y


@jit.kernel()
def _minimum(x: float, y: float) -> float:
    """np.minimum of two floats (NaN propagates)."""
    if x != x or y != y:
        return math.nan
    return x if x <= y else y


@jit.kernel()
def _clip01(x: float) -> float:
    """np.clip(x, 0, 1) of a float (NaN propagates)."""
    return _minimum(_maximum(x, 0.0), 1.0)


@jit.kernel()
def _divide(x: float, y: float) -> float:
    """x / y with numpy's semantics (inf or NaN for y = 0), without a warning."""
    if y != 0.0:
        return x / y
    if x != x or x == 0.0:
        return math.nan
    return math.inf if (x > 0.0) == (math.copysign(1.0, y) > 0.0) else -math.inf


@jit.kernel()
def _solve2_grid(G11: float, G12: float, G22: float, g1: float, g2: float
                 ) -> tuple[float, float]:
    """``TiltProblem._solve2`` at one point (eliminated eigenvalues as inf)."""
    theta = 0.5 * math.atan2(2.0 * G12, G11 - G22)
    c, s = math.cos(theta), math.sin(theta)
    big = G11 * c * c + 2.0 * G12 * c * s + G22 * s * s
    small = G11 * s * s - 2.0 * G12 * c * s + G22 * c * c
    big = big if big > 0.0 else math.inf
    small = small if small > _RIDGE * big else math.inf
    p, q = (c * g1 + s * g2) / big, (c * g2 - s * g1) / small
    return c * p - s * q, s * p + c * q


@jit.kernel()
def bounds_trig(prob: FloatArray, ca: float, sa: float, cb: float, sb: float
                ) -> tuple[float, float]:
    """:func:`bounds` from the cosines and sines of the tilts."""
    cc, ss = ca * cb, sa * sb
    ca2, sa2, cb2, sb2 = ca * ca, sa * sa, cb * cb, sb * sb
    A1, A2, B1, B2 = (prob[PROB_S_COEF], prob[PROB_S_COEF + 1], prob[PROB_S_COEF + 2],
                      prob[PROB_S_COEF + 3])
    u1, v1, u2, v2 = (prob[PROB_S_TARGET], prob[PROB_S_TARGET + 1], prob[PROB_S_TARGET + 2],
                      prob[PROB_S_TARGET + 3])
    Sg1, Sg2 = ca * u1 + sa * v1, cb * u2 + sb * v2
    sf, sr = _solve2_grid(A1 * ca2 + A2 * sa2, B1 * cc + B2 * ss, A1 * cb2 + A2 * sb2, Sg1, Sg2)
    A1, A2, B1, B2 = (prob[PROB_D_COEF], prob[PROB_D_COEF + 1], prob[PROB_D_COEF + 2],
                      prob[PROB_D_COEF + 3])
    u1, v1, u2, v2 = (prob[PROB_D_TARGET], prob[PROB_D_TARGET + 1], prob[PROB_D_TARGET + 2],
                      prob[PROB_D_TARGET + 3])
    Dg1, Dg2 = ca * u1 + sa * v1, cb * u2 + sb * v2
    df, dr = _solve2_grid(A1 * ca2 + A2 * sa2, B1 * cc + B2 * ss, A1 * cb2 + A2 * sb2, Dg1, Dg2)
    yS = sf * Sg1 + sr * Sg2
    yD = df * Dg1 + dr * Dg2
    tn2 = prob[PROB_TARGET_NORM2]
    lower = _maximum(tn2 - yS - yD, 0.0)
    if prob[PROB_ALL_AVAILABLE] == 0.0:
        return lower, lower
    lim = 2.0 * prob[PROB_FMAX]
    asf, asr, adf, adr = abs(sf), abs(sr), abs(df), abs(dr)
    load = _maximum(asf + adf, asr + adr)
    s = _minimum(1.0, lim / _maximum(load, 1e-300))
    gain = s * (2.0 - s) * (yS + yD)
    keep_s = 0.0                 # sums kept whole, differences scaled
    if asf <= lim and asr <= lim:
        t = _clip01(_minimum(_divide(lim - asf, adf), _divide(lim - asr, adr)))
        keep_s = yS + t * (2.0 - t) * yD
    keep_d = 0.0                 # and the other way round
    if adf <= lim and adr <= lim:
        t = _clip01(_minimum(_divide(lim - adf, asf), _divide(lim - adr, asr)))
        keep_d = yD + t * (2.0 - t) * yS
    keep = _maximum(keep_s, keep_d)
    if keep != keep:             # np.nan_to_num
        keep = 0.0
    elif abs(keep) == math.inf:
        keep = math.copysign(_FLOAT_MAX, keep)
    gain = _maximum(gain, keep)
    return lower, _maximum(tn2 - gain, lower)


@jit.kernel('UniTuple(float64, 2)(float64[::1], float64, float64)', group='allocation')
def bounds(prob: FloatArray, a: float, b: float) -> tuple[float, float]:
    """(lower, upper) of ``TiltProblem.bounds`` at one pair of tilts (scaled units)."""
    return bounds_trig(prob, math.cos(a), math.sin(a), math.cos(b), math.sin(b))


@jit.kernel('void(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1])',
            group='allocation')
def bounds_grid(prob: FloatArray, A: FloatArray, B: FloatArray, lower: FloatArray,
                upper: FloatArray) -> None:
    """``TiltProblem.bounds(A, B)`` into ``lower``, ``upper`` (1-D, the length of A)."""
    for i in range(A.shape[0]):
        lower[i], upper[i] = bounds_trig(prob, math.cos(A[i]), math.sin(A[i]),
                                         math.cos(B[i]), math.sin(B[i]))


# --------------------------------------------------------------------------- one evaluation

@jit.kernel()
def solve2(G11: float, G12: float, G22: float, g1: float, g2: float) -> tuple[float, float]:
    """``..local.solve2``: least-norm solution of the 2 x 2 normal equations."""
    theta = 0.5 * math.atan2(2.0 * G12, G11 - G22)
    c, s = math.cos(theta), math.sin(theta)
    big = G11 * c * c + 2.0 * G12 * c * s + G22 * s * s
    small = G11 * s * s - 2.0 * G12 * c * s + G22 * c * c
    p = (c * g1 + s * g2) / big if big > 0.0 else 0.0
    q = (c * g2 - s * g1) / small if small > 1e-12 * big else 0.0
    return c * p - s * q, s * p + c * q


@jit.kernel()
def _blocks(prob: FloatArray, a: float, b: float, work: FloatArray) -> None:
    """The two blocks and their derivatives at (a, b) into work[_BLK:] (``..local.evaluate``)."""
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    cc, ss, cs, sc = ca * cb, sa * sb, ca * sb, sa * cb
    s2a, c2a, s2b, c2b = 2.0 * sa * ca, ca * ca - sa * sa, 2.0 * sb * cb, cb * cb - sb * sb
    for p in range(2):
        cof = PROB_S_COEF if p == 0 else PROB_D_COEF
        tgt = PROB_S_TARGET if p == 0 else PROB_D_TARGET
        A1, A2, B1, B2 = prob[cof], prob[cof + 1], prob[cof + 2], prob[cof + 3]
        u1, v1, u2, v2 = prob[tgt], prob[tgt + 1], prob[tgt + 2], prob[tgt + 3]
        dA = A2 - A1
        G11, G12, G22 = A1 * ca * ca + A2 * sa * sa, B1 * cc + B2 * ss, A1 * cb * cb + A2 * sb * sb
        g1, g2 = ca * u1 + sa * v1, cb * u2 + sb * v2
        o = _BLK + 30 * p
        for i in range(30):
            work[o + i] = 0.0
        work[o], work[o + 1], work[o + 2], work[o + 3], work[o + 4] = G11, G12, G22, g1, g2
        # d/da, d/db, d2/da2, d2/dadb, d2/db2 of (G11, G12, G22, g1, g2)
        work[o + 5], work[o + 6], work[o + 8] = dA * s2a, -B1 * sc + B2 * cs, -sa * u1 + ca * v1
        work[o + 11], work[o + 12], work[o + 14] = -B1 * cs + B2 * sc, dA * s2b, -sb * u2 + cb * v2
        work[o + 15], work[o + 16], work[o + 18] = 2.0 * dA * c2a, -G12, -g1
        work[o + 21] = B1 * ss + B2 * cc
        work[o + 26], work[o + 27], work[o + 29] = -G12, 2.0 * dA * c2b, -g2


@jit.kernel()
def _to_thrusters(work: FloatArray) -> None:
    """The six thruster-coordinate matrices and vectors from the blocks
    (``..local._sd_to_f``, ``_sd_to_f_vec``: P_S' S P_S + P_D' D P_D)."""
    for k in range(6):
        s, d = _BLK + 5 * k, _BLK + 30 + 5 * k
        a, b = work[s] + work[d], work[s] - work[d]
        c, e = work[s + 1] + work[d + 1], work[s + 1] - work[d + 1]
        m, n = work[s + 2] + work[d + 2], work[s + 2] - work[d + 2]
        o = _MATS + 16 * k
        work[o], work[o + 1], work[o + 2], work[o + 3] = a, b, c, e
        work[o + 4], work[o + 5], work[o + 6], work[o + 7] = b, a, e, c
        work[o + 8], work[o + 9], work[o + 10], work[o + 11] = c, e, m, n
        work[o + 12], work[o + 13], work[o + 14], work[o + 15] = e, c, n, m
        v = _VECS + 4 * k
        work[v], work[v + 1] = work[s + 3] + work[d + 3], work[s + 3] - work[d + 3]
        work[v + 2], work[v + 3] = work[s + 4] + work[d + 4], work[s + 4] - work[d + 4]


@jit.kernel()
def _unconstrained(prob: FloatArray, a: float, b: float, work: FloatArray,
                   rec: FloatArray) -> None:
    """``..local._unconstrained``: no bound active, the two 2 x 2 blocks apart."""
    cost = prob[PROB_TARGET_NORM2]
    ga = gb = haa = hab = hbb = 0.0
    for p in range(2):
        o = _BLK + 30 * p
        x1, x2 = work[_F0 + 2 * p], work[_F0 + 2 * p + 1]     # (S_f, S_r), then (D_f, D_r)
        G11, G12, G22, g1, g2 = work[o], work[o + 1], work[o + 2], work[o + 3], work[o + 4]
        cost -= x1 * g1 + x2 * g2
        ta = tb = taa = tab = tbb = 0.0
        for k in range(1, 6):
            q = o + 5 * k
            d11, d12, d22, dg1, dg2 = work[q], work[q + 1], work[q + 2], work[q + 3], work[q + 4]
            term = x1 * (d11 * x1 + 2.0 * d12 * x2) + d22 * x2 * x2 - 2.0 * (dg1 * x1 + dg2 * x2)
            if k == 1:
                ta = term
            elif k == 2:
                tb = term
            elif k == 3:
                taa = term
            elif k == 4:
                tab = term
            else:
                tbb = term
        ga += ta
        gb += tb
        # q_i = G_i x - g_i; the Hessian loses 2 q_i' G^-1 q_j.
        qa1 = work[o + 5] * x1 + work[o + 6] * x2 - work[o + 8]
        qa2 = work[o + 6] * x1 + work[o + 7] * x2 - work[o + 9]
        qb1 = work[o + 10] * x1 + work[o + 11] * x2 - work[o + 13]
        qb2 = work[o + 11] * x1 + work[o + 12] * x2 - work[o + 14]
        ya1, ya2 = solve2(G11, G12, G22, qa1, qa2)
        yb1, yb2 = solve2(G11, G12, G22, qb1, qb2)
        haa += taa - 2.0 * (qa1 * ya1 + qa2 * ya2)
        hab += tab - 2.0 * (qa1 * yb1 + qa2 * yb2)
        hbb += tbb - 2.0 * (qb1 * yb1 + qb2 * yb2)
    rec[REC_A], rec[REC_B], rec[REC_COST] = a, b, _py_max(cost, 0.0)
    rec[REC_GRAD], rec[REC_GRAD + 1] = ga, gb
    rec[REC_HESS], rec[REC_HESS + 1], rec[REC_HESS + 2] = haa, hab, hbb
    for i in range(4):
        rec[REC_THRUSTS + i] = work[_X + i]
        rec[REC_BOUNDS + i] = 0.0


@jit.kernel()
def _quad(work: FloatArray, k: int) -> float:
    """x' M_k x - 2 v_k' x at the thrusts (``quad`` in ``..local.evaluate``)."""
    outer = 0.0
    for i in range(4):
        inner = 0.0
        for j in range(4):
            inner += work[_MATS + 16 * k + 4 * i + j] * work[_X + j]
        outer += work[_X + i] * inner
    lin = 0.0
    for i in range(4):
        lin += work[_VECS + 4 * k + i] * work[_X + i]
    return outer - 2.0 * lin


@jit.kernel()
def evaluate_into(prob: FloatArray, a: float, b: float, hint: IntArray, has_hint: bool,
                  rec: FloatArray, work: FloatArray, iwork: IntArray) -> None:
    """:func:`evaluate` with the caller's scratch (work: float64[WORK_SIZE], iwork:
    int64[IWORK_SIZE])."""
    _blocks(prob, a, b, work)
    S, D = _BLK, _BLK + 30
    sf, sr = solve2(work[S], work[S + 1], work[S + 2], work[S + 3], work[S + 4])
    df, dr = solve2(work[D], work[D + 1], work[D + 2], work[D + 3], work[D + 4])
    work[_F0], work[_F0 + 1], work[_F0 + 2], work[_F0 + 3] = sf, sr, df, dr
    work[_X], work[_X + 1] = 0.5 * (sf + df), 0.5 * (sf - df)
    work[_X + 2], work[_X + 3] = 0.5 * (sr + dr), 0.5 * (sr - dr)
    plain = prob[PROB_ALL_AVAILABLE] != 0.0
    if has_hint:
        for i in range(4):
            if hint[i] != 0:
                plain = False
    for i in range(4):
        if not abs(work[_X + i]) <= prob[PROB_UPPER + i] * (1 + _SLACK):
            plain = False
    if plain:
        _unconstrained(prob, a, b, work, rec)
        return
    for i in range(4):
        work[_F0 + i] = work[_X + i]                 # the box starts from the thrusts f0
    _to_thrusters(work)
    G = _MATS
    ridge = 1e-12 * (work[G] + work[G + 5] + work[G + 10] + work[G + 15]) + 1e-300
    for i in range(4):
        work[G + 5 * i] += ridge
    box(prob, work, iwork, hint, has_hint)
    s = 0.0
    for i in range(4):
        gx = 0.0
        for j in range(4):
            gx += work[G + 4 * i + j] * work[_X + j]
        s += work[_X + i] * (gx - 2.0 * work[_VECS + i])
    cost = prob[PROB_TARGET_NORM2] + s
    ga, gb = _quad(work, 1), _quad(work, 2)
    haa, hab, hbb = _quad(work, 3), _quad(work, 4), _quad(work, 5)
    n = 0
    for i in range(4):
        if iwork[_STATE + i] == 0:
            iwork[_FREE + n] = i
            n += 1
    if n:
        for r in range(n):
            i = iwork[_FREE + r]
            sa = sb = 0.0
            for j in range(4):
                sa += work[_MATS + 16 + 4 * i + j] * work[_X + j]
                sb += work[_MATS + 32 + 4 * i + j] * work[_X + j]
            work[_QA + r] = sa - work[_VECS + 4 + i]
            work[_QB + r] = sb - work[_VECS + 8 + i]
        if _solve_free(work, iwork, n, _QA, _YA) and _solve_free(work, iwork, n, _QB, _YB):
            taa = tab = tbb = 0.0
            for r in range(n):
                taa += work[_QA + r] * work[_YA + r]
                tab += work[_QA + r] * work[_YB + r]
                tbb += work[_QB + r] * work[_YB + r]
            haa -= 2.0 * taa
            hab -= 2.0 * tab
            hbb -= 2.0 * tbb
    rec[REC_A], rec[REC_B], rec[REC_COST] = a, b, _py_max(cost, 0.0)
    rec[REC_GRAD], rec[REC_GRAD + 1] = ga, gb
    rec[REC_HESS], rec[REC_HESS + 1], rec[REC_HESS + 2] = haa, hab, hbb
    for i in range(4):
        rec[REC_THRUSTS + i] = work[_X + i]
        rec[REC_BOUNDS + i] = float(iwork[_STATE + i])


@jit.kernel('void(float64[::1], float64, float64, int64[::1], boolean, float64[::1])',
            group='allocation')
def evaluate(prob: FloatArray, a: float, b: float, hint: IntArray, has_hint: bool,
             rec: FloatArray) -> None:
    """``..local.evaluate(problem, a, b, hint if has_hint else None)`` into ``rec``
    (hint: int64[4] of -1/0/+1/2; None and (0, 0, 0, 0) differ there)."""
    evaluate_into(prob, a, b, hint, has_hint, rec, np.empty(WORK_SIZE),
                  np.empty(IWORK_SIZE, dtype=np.int64))
