"""Kernels mirroring :mod:`..decomposition`: the pair sums and differences of eq. (4).

The change of variables into (Zf, Zr, Df, Dr, kappa, H) and the corrected
(7)-(8) per pair, in plain floats.
"""

from __future__ import annotations

import math

import numpy as np

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation.decomposition import HALF_PI, SQRT2, ZERO_PAIR, FloatArray
from tiltrov_ros.core.allocation.kernels.layout import CFG_K, CFG_L, CFG_W


@jit.kernel()
def peak(tau: FloatArray) -> float:
    """max |tau_i|."""
    out = 0.0
    for i in range(6):
        out = max(out, abs(tau[i]))
    return out


@jit.kernel()
def pair_terms(cfg: FloatArray, tau: FloatArray, s: float) -> tuple[float, float, float, float,
                                                            float, float]:
    """``Geometry.pair_terms_scalar(tau / s)``: (Zf, Zr, Df, Dr, kappa, H) of eq. (4)."""
    X, Y, Z = tau[0] / s, tau[1] / s, tau[2] / s
    K, M, N = tau[3] / s, tau[4] / s, tau[5] / s
    length, width, k = cfg[CFG_L], cfg[CFG_W], cfg[CFG_K]
    return (-0.5 * Z + M / length, -0.5 * Z - M / length,
            0.5 * (SQRT2 * Y + N / k), 0.5 * (SQRT2 * Y - N / k),
            2.0 * K / width, SQRT2 * X)


@jit.kernel()
def pair_scalar(z_i: float, h_i: float, z_j: float,
                h_j: float) -> tuple[float, float, float, bool]:
    """``decomposition.pair_scalar``: corrected (7)-(8) for one pair (signed thrusts,
    the pair's tilt folded into (-pi/2, pi/2], free flag)."""
    n_i, n_j = math.hypot(z_i, h_i), math.hypot(z_j, h_j)
    if max(n_i, n_j) <= ZERO_PAIR:
        return 0.0, 0.0, 0.0, True
    if n_i >= n_j:
        gamma = math.atan2(z_i, h_i)
    else:
        gamma = math.atan2(z_j, h_j)
    if gamma > HALF_PI:
        gamma -= math.pi
    elif gamma <= -HALF_PI:
        gamma += math.pi
    c, s = math.cos(gamma), math.sin(gamma)
    return h_i * c + z_i * s, h_j * c + z_j * s, gamma, False


@jit.kernel()
def pair_vector(z_i: float, h_i: float, z_j: float,
                h_j: float) -> tuple[float, float, float, bool, float, float]:
    """One pair of ``decomposition.pairs_to_actuators`` (finite inputs), with the
    tilt's sine and cosine: (f_i, f_j, gamma, free, sin gamma, cos gamma)."""
    n_i, n_j = np.hypot(z_i, h_i), np.hypot(z_j, h_j)
    if max(n_i, n_j) <= ZERO_PAIR:
        return 0.0, 0.0, 0.0, True, 0.0, 1.0
    if n_i >= n_j:
        gamma = np.arctan2(z_i, h_i)
    else:
        gamma = np.arctan2(z_j, h_j)
    if gamma > HALF_PI:
        gamma -= math.pi
    if gamma <= -HALF_PI:
        gamma += math.pi
    c, s = np.cos(gamma), np.sin(gamma)
    return h_i * c + z_i * s, h_j * c + z_j * s, gamma, False, s, c
