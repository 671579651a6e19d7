"""Kernels mirroring :mod:`..families`: the one-parameter families of exact solutions.

:func:`symmetric` is ``families.symmetric_family`` (the closed-form members of
family F1 when Y = K = N = 0), :func:`family_uv` the samples of
``families.family_samples`` (with ``kink_points``) for one wrench, as (U, V)
rows in the reference's slot order.
"""

from __future__ import annotations

import math

import numpy as np

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import FloatArray
from tiltrov_ros.core.allocation.families import FAMILY_RTOL, FAMILY_SAMPLES
from tiltrov_ros.core.allocation.kernels.decomposition import pair_scalar, pair_terms, peak
from tiltrov_ros.core.allocation.kernels.layout import (
    CFG_FMAX,
    CONF_FAMILY,
    CONF_FREE,
    CONF_THRUSTS,
    CONF_TILTS,
)

# The reference's sample grids, computed by numpy as it computes them (numba freezes
# global arrays into the compiled code).
_HALF = (FAMILY_SAMPLES + 1) // 2
_SPREAD = np.tan(np.linspace(-1.5, 1.5, FAMILY_SAMPLES))
_RATIO_HALF = np.exp(np.linspace(-3.0, 3.0, _HALF))
_RATIO = np.concatenate([_RATIO_HALF, _RATIO_HALF[: FAMILY_SAMPLES - _HALF]])
_SIGN = np.concatenate([np.ones(_HALF), -np.ones(FAMILY_SAMPLES - _HALF)])


@jit.kernel()
def symmetric(cfg: FloatArray, tau: FloatArray, has_prev: bool, p0: float, p1: float,
              box: FloatArray, values: FloatArray, conf: FloatArray, first: int) -> int:
    """``families.symmetric_family``: the members of F1 that can be chosen when
    Y = K = N = 0, into ``conf[first:]`` (ascending V); -1 when the wrench is not of
    this kind. ``values``: scratch of at least 13 floats."""
    scale = peak(tau)
    if scale == 0.0:
        return -1
    Zf, Zr, Df, Dr, kappa, H = pair_terms(cfg, tau, scale)
    mag = max(abs(Zf), abs(Zr), abs(Df), abs(Dr), abs(kappa), abs(H))
    if max(abs(Df), abs(Dr), abs(kappa)) > FAMILY_RTOL * mag:
        return -1
    n = 0
    n = _add(values, n, 0.5 * H)
    n = _add(values, n, 0.0)
    n = _add(values, n, H)
    limit = 2.0 * cfg[CFG_FMAX] / scale        # |(h, z)| of a pair's thruster, x2
    for p in range(2):
        Zp, sign, offset = (Zf, 1.0, 0.0) if p == 0 else (Zr, -1.0, H)
        for m in range(3 if has_prev else 2):
            t = box[p, m] if m < 2 else (p0 if p == 0 else p1)
            tan_t = math.tan(t)
            if abs(tan_t) > 1e-12 and abs(tan_t) < 1e12:
                n = _add(values, n, (Zp / tan_t - offset) * sign)   # h_p = Zp / tan(t)
        if limit > abs(Zp):
            reach = math.sqrt(limit * limit - Zp * Zp)
            n = _add(values, n, (reach - offset) * sign)
            n = _add(values, n, (-reach - offset) * sign)
    # sorted(set(values)): insertion sort, the values are few.
    for i in range(1, n):
        v = values[i]
        j = i - 1
        while j >= 0 and values[j] > v:
            values[j + 1] = values[j]
            j -= 1
        values[j + 1] = v
    row = first
    for i in range(n):
        V = values[i]
        f1, f2, alpha, free_f = pair_scalar(0.5 * Zf, 0.5 * V, 0.5 * Zf, 0.5 * V)
        f3, f4, beta, free_r = pair_scalar(0.5 * Zr, 0.5 * (H - V), 0.5 * Zr, 0.5 * (H - V))
        conf[row, CONF_THRUSTS] = f1 * scale
        conf[row, CONF_THRUSTS + 1] = f2 * scale
        conf[row, CONF_THRUSTS + 2] = f3 * scale
        conf[row, CONF_THRUSTS + 3] = f4 * scale
        conf[row, CONF_TILTS] = alpha
        conf[row, CONF_TILTS + 1] = beta
        conf[row, CONF_FAMILY] = 1.0
        conf[row, CONF_FREE] = 1.0 if free_f else 0.0
        conf[row, CONF_FREE + 1] = 1.0 if free_r else 0.0
        row += 1
    return n


@jit.kernel()
def _add(values: FloatArray, n: int, v: float) -> int:
    """Add ``v`` to the first ``n`` values unless present (a set); the new count."""
    for i in range(n):
        if values[i] == v:
            return n
    values[n] = v
    return n + 1


@jit.kernel()
def _kinks(fixed0: float, fixed1: float, fixed2: float, fixed3: float, slope0: float,
           slope1: float, slope2: float, slope3: float, offset0: float, offset1: float,
           offset2: float, offset3: float, uv: FloatArray, row: int, col: int) -> None:
    """``families.kink_points`` of one wrench into ``uv[row:row + 10, col]``."""
    fixed = (fixed0, fixed1, fixed2, fixed3)
    slope = (slope0, slope1, slope2, slope3)
    offset = (offset0, offset1, offset2, offset3)
    for i in range(4):
        uv[row + i, col] = -2.0 * offset[i] / slope[i]
    r = row + 4
    for i in range(4):
        for j in range(i + 1, 4):
            num = ((fixed[j] * fixed[j] + offset[j] * offset[j])
                   - (fixed[i] * fixed[i] + offset[i] * offset[i]))
            den = slope[i] * offset[i] - slope[j] * offset[j]
            uv[r, col] = num / den if den != 0 else math.nan
            r += 1
    for i in range(row, row + 10):
        # A point beyond any sensible scale (a denominator at rounding level) is useless.
        if not abs(uv[i, col]) < 1e150:
            uv[i, col] = math.nan


@jit.kernel()
def family_uv(Zf: float, Zr: float, Df: float, Dr: float, kappa: float, H: float, P: float,
              mag: float, families: int, aims: FloatArray, n_aims: int, uv: FloatArray,
              first: int) -> int:
    """``families.family_samples`` of one wrench: (U, V) of its family slots into
    ``uv[first:]`` in the reference's order (F1, F2, F3), only the families it is on
    (``families``: bits 1, 2, 4); returns the end of the slots written.

    ``aims`` (2, MAX_AIMS): tilts per pair to aim at, the first ``n_aims`` columns."""
    s = FAMILY_SAMPLES
    row = first
    if families & 1:              # F1 (U = 0): z fixed, h_i = s_i V/2 + c_i
        for j in range(s):
            uv[row + j, 1] = 0.5 * H + mag * _SPREAD[j]
        _kinks(0.5 * Zf, 0.5 * Zf, 0.5 * (Zr - kappa), 0.5 * (Zr + kappa),
               1.0, 1.0, -1.0, -1.0, 0.5 * Df, 0.5 * -Df, 0.5 * (H + Dr), 0.5 * (H - Dr),
               uv, row + s, 1)
        r = row + s + 10
        for i in range(n_aims):
            uv[r + i, 1] = Zf / math.tan(aims[0, i])
            uv[r + n_aims + i, 1] = H - Zr / math.tan(aims[1, i])
        r += 2 * n_aims
        for j in range(row, r):
            uv[j, 0] = 0.0
        row = r
    if families & 2:              # F2 (V = 0): h fixed, z_i = s_i U/2 + c_i
        for j in range(s):
            uv[row + j, 0] = 0.5 * kappa + mag * _SPREAD[j]
        _kinks(0.5 * Df, 0.5 * -Df, 0.5 * (H + Dr), 0.5 * (H - Dr),
               1.0, -1.0, 1.0, -1.0, 0.5 * Zf, 0.5 * Zf, 0.5 * (Zr - kappa),
               0.5 * (Zr + kappa), uv, row + s, 0)
        r = row + s + 10
        for i in range(n_aims):
            uv[r + i, 0] = Df * math.tan(aims[0, i])
            uv[r + n_aims + i, 0] = kappa + Dr * math.tan(aims[1, i])
        r += 2 * n_aims
        for j in range(row, r):
            uv[j, 1] = 0.0
        row = r
    if families & 4:              # F3 (V = P/U): U = +-sqrt|P| times a ratio
        root = math.sqrt(abs(P))
        for j in range(s):
            u = _SIGN[j] * root * _RATIO[j]
            uv[row + j, 0] = u
            uv[row + j, 1] = P / u
        row += s
    return row
