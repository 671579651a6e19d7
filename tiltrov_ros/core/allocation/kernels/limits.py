"""Kernels mirroring :mod:`..limits`: the reach of a call, how a result is made, twins.

A result is written into an ``out`` array (:mod:`.layout`, ``OUT_*``) as
``Limits.make`` builds an :class:`..results.AllocationResult`: the achieved
wrench by eq. (5), the weighted error and the feasibility test.
"""

from __future__ import annotations

import math
import sys

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.kernels.layout import (
    CFG_AVAILABLE,
    CFG_FMAX,
    CFG_K,
    CFG_L,
    CFG_STEP,
    CFG_TILT_MAX,
    CFG_TILT_MIN,
    CFG_W,
    CFG_WEIGHTS,
    OUT_ACHIEVED,
    OUT_DISC,
    OUT_ERROR,
    OUT_FEASIBLE,
    OUT_METHOD,
    OUT_STUCK,
    OUT_TARGET,
    OUT_THRUSTS,
    OUT_TILTS,
)
from tiltrov_ros.core.allocation.limits import LIMIT_SLACK
from tiltrov_ros.core.allocation.results import FEASIBILITY_RTOL
from tiltrov_ros.core.thrust_map import SQRT1_2

_FLOAT_MAX = sys.float_info.max
_S = float(SQRT1_2)


@jit.kernel()
def norm6(v0: float, v1: float, v2: float, v3: float, v4: float, v5: float) -> float:
    """``results.norm`` of six numbers: the Euclidean norm without intermediate
    overflow, capped at the largest float."""
    m = max(abs(v0), abs(v1), abs(v2), abs(v3), abs(v4), abs(v5))
    if (abs(v0) == math.inf or abs(v1) == math.inf or abs(v2) == math.inf
            or abs(v3) == math.inf or abs(v4) == math.inf or abs(v5) == math.inf):
        return _FLOAT_MAX
    if not (v0 == v0 and v1 == v1 and v2 == v2 and v3 == v3 and v4 == v4 and v5 == v5):
        return math.nan
    if m == 0.0:
        return 0.0
    a0, a1, a2, a3, a4, a5 = v0 / m, v1 / m, v2 / m, v3 / m, v4 / m, v5 / m
    out = m * math.sqrt(a0 * a0 + a1 * a1 + a2 * a2 + a3 * a3 + a4 * a4 + a5 * a5)
    return min(out, _FLOAT_MAX)


@jit.kernel()
def plain_norm6(v0: float, v1: float, v2: float, v3: float, v4: float, v5: float) -> float:
    """``np.linalg.norm`` of six numbers (the square root of the sum of squares)."""
    return math.sqrt(v0 * v0 + v1 * v1 + v2 * v2 + v3 * v3 + v4 * v4 + v5 * v5)


@jit.kernel()
def wrench_of(cfg: FloatArray, f1: float, f2: float, f3: float, f4: float, a: float,
              b: float) -> tuple[float, float, float, float, float, float]:
    """Eq. (5), tau = A q, with q = (f1 sa, f2 sa, f3 sb, f4 sb, f1 ca, f2 ca, f3 cb, f4 cb)."""
    return wrench_sc(cfg, f1, f2, f3, f4, math.sin(a), math.cos(a), math.sin(b), math.cos(b))


@jit.kernel()
def wrench_sc(cfg: FloatArray, f1: float, f2: float, f3: float, f4: float, sa: float,
              ca: float, sb: float, cb: float) -> tuple[float, float, float, float, float, float]:
    """:func:`wrench_of` from the tilts' sines and cosines."""
    q0, q1, q2, q3 = f1 * sa, f2 * sa, f3 * sb, f4 * sb
    q4, q5, q6, q7 = f1 * ca, f2 * ca, f3 * cb, f4 * cb
    hd, hl, k = cfg[CFG_W] / 2, cfg[CFG_L] / 2, cfg[CFG_K]
    return (_S * q4 + _S * q5 + _S * q6 + _S * q7,
            _S * q4 - _S * q5 + _S * q6 - _S * q7,
            -q0 - q1 - q2 - q3,
            hd * q0 - hd * q1 - hd * q2 + hd * q3,
            hl * q0 + hl * q1 - hl * q2 - hl * q3,
            k * q4 - k * q5 - k * q6 + k * q7)


@jit.kernel()
def make(cfg: FloatArray, tau: FloatArray, f1: float, f2: float, f3: float, f4: float, a: float,
         b: float, method: float, disc: float, out: FloatArray) -> None:
    """``Limits.make``: the result for these thrusts and tilts into ``out``."""
    av = CFG_AVAILABLE
    f1 = f1 if cfg[av] != 0.0 else 0.0
    f2 = f2 if cfg[av + 1] != 0.0 else 0.0
    f3 = f3 if cfg[av + 2] != 0.0 else 0.0
    f4 = f4 if cfg[av + 3] != 0.0 else 0.0
    X, Y, Z, K, M, N = wrench_of(cfg, f1, f2, f3, f4, a, b)
    d0, d1, d2 = X - tau[0], Y - tau[1], Z - tau[2]
    d3, d4, d5 = K - tau[3], M - tau[4], N - tau[5]
    w = CFG_WEIGHTS
    wmax = max(cfg[w], cfg[w + 1], cfg[w + 2], cfg[w + 3], cfg[w + 4], cfg[w + 5])
    error = norm6(d0 * (cfg[w] / wmax), d1 * (cfg[w + 1] / wmax), d2 * (cfg[w + 2] / wmax),
                  d3 * (cfg[w + 3] / wmax), d4 * (cfg[w + 4] / wmax),
                  d5 * (cfg[w + 5] / wmax)) * wmax
    size = max(norm6(tau[0], tau[1], tau[2], tau[3], tau[4], tau[5]), cfg[CFG_FMAX])
    feasible = norm6(d0, d1, d2, d3, d4, d5) <= FEASIBILITY_RTOL * size
    out[OUT_THRUSTS] = f1
    out[OUT_THRUSTS + 1] = f2
    out[OUT_THRUSTS + 2] = f3
    out[OUT_THRUSTS + 3] = f4
    out[OUT_TILTS] = a
    out[OUT_TILTS + 1] = b
    out[OUT_ACHIEVED] = X
    out[OUT_ACHIEVED + 1] = Y
    out[OUT_ACHIEVED + 2] = Z
    out[OUT_ACHIEVED + 3] = K
    out[OUT_ACHIEVED + 4] = M
    out[OUT_ACHIEVED + 5] = N
    out[OUT_FEASIBLE] = 1.0 if feasible else 0.0
    out[OUT_METHOD] = method
    out[OUT_DISC] = disc
    out[OUT_ERROR] = error
    out[OUT_TARGET] = math.nan
    out[OUT_TARGET + 1] = math.nan
    out[OUT_STUCK] = 0.0


@jit.kernel()
def box(cfg: FloatArray, has_prev: bool, p0: float, p1: float, out: FloatArray) -> None:
    """``Limits.box``: [[lo, hi] front, [lo, hi] rear] reachable in this call, into
    ``out`` (2, 2)."""
    lo, hi, step = cfg[CFG_TILT_MIN], cfg[CFG_TILT_MAX], cfg[CFG_STEP]
    if not has_prev or not math.isfinite(step):
        out[0, 0] = out[1, 0] = lo
        out[0, 1] = out[1, 1] = hi
        return
    out[0, 0], out[0, 1] = max(lo, p0 - step), min(hi, p0 + step)
    out[1, 0], out[1, 1] = max(lo, p1 - step), min(hi, p1 + step)


@jit.kernel()
def twins(cfg: FloatArray, angle: float) -> tuple[int, float, float, float, float, float, float]:
    """``Limits.twins``: (count, servo angle, thrust sign, ...) of every tilt in range with
    the thrust line of ``angle`` (at most three in a range of at most 2 pi)."""
    lo, hi = cfg[CFG_TILT_MIN], cfg[CFG_TILT_MAX]
    k = math.ceil((lo - LIMIT_SLACK - angle) / math.pi)
    n = 0
    t0 = t1 = t2 = s0 = s1 = s2 = 0.0
    while angle + k * math.pi <= hi + LIMIT_SLACK and n < 3:
        t = min(max(angle + k * math.pi, lo), hi)
        s = -1.0 if k % 2 else 1.0
        if n == 0:
            t0, s0 = t, s
        elif n == 1:
            t1, s1 = t, s
        else:
            t2, s2 = t, s
        n += 1
        k += 1
    return n, t0, s0, t1, s1, t2, s2
