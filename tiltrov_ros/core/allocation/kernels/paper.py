"""Kernel mirroring :mod:`..paper`: the paper mode's answer when no exact solution qualifies."""

from __future__ import annotations

import math

import numpy as np

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import HALF_PI, FloatArray
from tiltrov_ros.core.allocation.kernels.layout import (
    CFG_FMAX,
    CFG_PINV,
    CFG_TILT_MAX,
    CFG_TILT_MIN,
    METHOD_CODE,
    VARIANTS,
)
from tiltrov_ros.core.allocation.kernels.limits import make
from tiltrov_ros.core.allocation.kernels.select import variant

_SATURATED = METHOD_CODE['saturated']
_PSEUDO = METHOD_CODE['pseudo']


@jit.kernel()
def _pseudo_pair(cfg: FloatArray, tau: FloatArray, i: int,
                 ref: float) -> tuple[float, float, float]:
    """Thrusters i, i + 1 of xi = 0 (q = pinv(A) tau): the pair's tilt (of the two
    thrusters' own angles (8), the one closer to ``ref``) and their signed thrusts."""
    z_i = z_j = h_i = h_j = 0.0
    for c in range(6):
        z_i += cfg[CFG_PINV + 6 * i + c] * tau[c]
        z_j += cfg[CFG_PINV + 6 * (i + 1) + c] * tau[c]
        h_i += cfg[CFG_PINV + 6 * (i + 4) + c] * tau[c]
        h_j += cfg[CFG_PINV + 6 * (i + 5) + c] * tau[c]
    left, right = ref, ref
    if np.hypot(z_i, h_i) > 0:
        left = _fold(np.arctan2(z_i, h_i))
    if np.hypot(z_j, h_j) > 0:
        right = _fold(np.arctan2(z_j, h_j))
    tilt = left if abs(left - ref) <= abs(right - ref) else right
    c, s = np.cos(tilt), np.sin(tilt)
    return tilt, h_i * c + z_i * s, h_j * c + z_j * s


@jit.kernel()
def _fold(angle: float) -> float:
    """``decomposition.fold_tilt``: a thrust-line angle into (-pi/2, pi/2]."""
    folded = angle - math.pi if angle > HALF_PI else angle
    return folded + math.pi if folded <= -HALF_PI else folded


@jit.kernel()
def paper_fallback(cfg: FloatArray, tau: FloatArray, conf: FloatArray, count: int, disc: float,
                   ref0: float, ref1: float, box: FloatArray, out: FloatArray) -> None:
    """``paper.paper_fallback`` over ``conf[:count]`` (Section 3.2 case 3, and
    saturation) into ``out``; ``ref0, ref1``: the previous tilts (0 without)."""
    best = -1
    m0 = m1 = 0.0
    for j in range(count):
        for v in range(VARIANTS):
            exists, f1, f2, f3, f4, a, b = variant(cfg, conf, j, v, ref0, ref1, box)
            if not exists:
                continue
            move = (a - ref0) * (a - ref0) + (b - ref1) * (b - ref1)
            thrust2 = f1 * f1 + f2 * f2 + f3 * f3 + f4 * f4
            if best < 0 or move < m0 or (move == m0 and thrust2 < m1):
                best, m0, m1 = j * VARIANTS + v, move, thrust2
    if best >= 0:
        _, f1, f2, f3, f4, a, b = variant(cfg, conf, best // VARIANTS, best % VARIANTS,
                                          ref0, ref1, box)
        method = _SATURATED
    else:
        a, f1, f2 = _pseudo_pair(cfg, tau, 0, ref0)
        b, f3, f4 = _pseudo_pair(cfg, tau, 2, ref1)
        method = _PSEUDO
    lo, hi, fmax = cfg[CFG_TILT_MIN], cfg[CFG_TILT_MAX], cfg[CFG_FMAX]
    a = min(max(min(max(a, lo), hi), box[0, 0]), box[0, 1])
    b = min(max(min(max(b, lo), hi), box[1, 0]), box[1, 1])
    f1, f2 = min(max(f1, -fmax), fmax), min(max(f2, -fmax), fmax)
    f3, f4 = min(max(f3, -fmax), fmax), min(max(f4, -fmax), fmax)
    make(cfg, tau, f1, f2, f3, f4, a, b, method, disc, out)
