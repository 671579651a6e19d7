"""The pair decomposition of eq. (4): sums and differences of each pair's thrusts.

Thrusters 1, 2 share the front tilt alpha and 3, 4 the rear tilt beta. With
S_f = f1 + f2, D_f = f1 - f2 (front) and S_r = f3 + f4, D_r = f3 - f4 (rear),
eq. (4) reads exactly

    X = (S_f cos a + S_r cos b) / sqrt2       Y = (D_f cos a + D_r cos b) / sqrt2
    Z = -(S_f sin a + S_r sin b)              K = (d/2) (D_f sin a - D_r sin b)
    M = (l/2) (S_f sin a - S_r sin b)         N = k (D_f cos a - D_r cos b)

with k = (l + d) / (2 sqrt2): at given tilts the sums only make (X, Z, M) and
the differences only (Y, K, N), two independent 3 x 2 linear problems, coupled
by the tilts and by the thrust limit, which for a pair is the diamond
|S_p| + |D_p| <= 2 f_max (|f1|, |f2| <= f_max).

Each pair's two vectors S_p e(gamma) and D_p e(gamma), e(gamma) = (cos, sin),
are parallel. Their components that the wrench fixes are (the paper's
decomposition (5), (10)-(11) in these coordinates):

    Zf = S_f sin a = -Z/2 + M/l       Zr = S_r sin b = -Z/2 - M/l
    Df = D_f cos a = (sqrt2 Y + N/k)/2   Dr = D_r cos b = (sqrt2 Y - N/k)/2
    kappa = D_f sin a - D_r sin b = 2K/d    H = S_f cos a + S_r cos b = sqrt2 X

(the vertical thrust components z_i = f_i sin(gamma_i) and horizontal ones
h_i = f_i cos(gamma_i) are Zf = z1 + z2, Df = h1 - h2 and so on). This module
holds that change of variables, once; :mod:`.closed_form` solves it exactly,
:mod:`.thrusts` uses the block form for the thrusts at given tilts.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

SQRT2 = math.sqrt(2.0)
HALF_PI = 0.5 * math.pi
# A pair whose components (scaled so that max |tau_i| = 1) are below this has
# no thrust and a free tilt: its share of the wrench is below 1e-12 relative.
ZERO_PAIR = 1e-12


@dataclass(frozen=True)
class Geometry:
    """Thruster spacing l (``length``, along x) and d (``width``, along y), m."""

    length: float
    width: float

    @property
    def k(self) -> float:
        """(l + d) / (2 sqrt2), the yaw arm of eq. (4)."""
        return (self.length + self.width) / (2.0 * SQRT2)

    def pair_terms(self, tau: FloatArray) -> tuple[FloatArray, ...]:
        """(Zf, Zr, Df, Dr, kappa, H) of the module docstring, tau of shape (..., 6)."""
        X, Y, Z, K, M, N = np.moveaxis(np.asarray(tau, dtype=float), -1, 0)
        k = self.k
        return (-0.5 * Z + M / self.length, -0.5 * Z - M / self.length,
                0.5 * (SQRT2 * Y + N / k), 0.5 * (SQRT2 * Y - N / k),
                2.0 * K / self.width, SQRT2 * X)

    def pair_terms_scalar(self, tau: FloatArray) -> tuple[float, ...]:
        """:meth:`pair_terms` of one wrench, as plain floats (the per-call hot path)."""
        X, Y, Z, K, M, N = (float(v) for v in tau)
        k = self.k
        return (-0.5 * Z + M / self.length, -0.5 * Z - M / self.length,
                0.5 * (SQRT2 * Y + N / k), 0.5 * (SQRT2 * Y - N / k),
                2.0 * K / self.width, SQRT2 * X)


def fold_tilt(angle: FloatArray) -> FloatArray:
    """Fold a thrust-line angle into (-pi/2, pi/2] (the thrust takes the sign)."""
    folded = np.where(angle > HALF_PI, angle - math.pi, angle)
    return np.where(folded <= -HALF_PI, folded + math.pi, folded)


def pair_scalar(z_i: float, h_i: float, z_j: float,
                h_j: float) -> tuple[float, float, float, bool]:
    """Corrected (7)-(8) for one pair: signed thrusts, the pair's tilt, free flag.

    f_i is the signed length of thruster i's own (h_i, z_i); the pair's thrust
    line comes from its stronger thruster (atan2, folded into (-pi/2, pi/2]),
    and each thrust is the signed projection on that line.
    """
    n_i, n_j = math.hypot(z_i, h_i), math.hypot(z_j, h_j)
    if max(n_i, n_j) <= ZERO_PAIR:
        return 0.0, 0.0, 0.0, True
    z, h = (z_i, h_i) if n_i >= n_j else (z_j, h_j)
    gamma = math.atan2(z, h)
    if gamma > HALF_PI:
        gamma -= math.pi
    elif gamma <= -HALF_PI:
        gamma += math.pi
    c, s = math.cos(gamma), math.sin(gamma)
    return h_i * c + z_i * s, h_j * c + z_j * s, gamma, False


def pairs_to_actuators(z: FloatArray,
                       h: FloatArray) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Vectorised :func:`pair_scalar` over (..., 4) vertical/horizontal parts."""
    shape = z.shape[:-1]
    thrusts = np.zeros(z.shape)
    tilts = np.zeros((*shape, 2))
    free = np.zeros((*shape, 2), dtype=bool)
    for p, (i, j) in enumerate(((0, 1), (2, 3))):
        n_i, n_j = np.hypot(z[..., i], h[..., i]), np.hypot(z[..., j], h[..., j])
        lead = n_i >= n_j
        zero = np.maximum(n_i, n_j) <= ZERO_PAIR
        gamma = fold_tilt(np.arctan2(np.where(lead, z[..., i], z[..., j]),
                                     np.where(lead, h[..., i], h[..., j])))
        gamma = np.where(zero, 0.0, gamma)
        c, s = np.cos(gamma), np.sin(gamma)
        thrusts[..., i] = np.where(zero, 0.0, h[..., i] * c + z[..., i] * s)
        thrusts[..., j] = np.where(zero, 0.0, h[..., j] * c + z[..., j] * s)
        tilts[..., p] = gamma
        free[..., p] = zero
    return thrusts, tilts, free


def thrusts_from_sums(s_f: FloatArray, s_r: FloatArray, d_f: FloatArray,
                      d_r: FloatArray) -> FloatArray:
    """(..., 4) thrusts f1..f4 from the pair sums and differences."""
    return 0.5 * np.stack([s_f + d_f, s_f - d_f, s_r + d_r, s_r - d_r], axis=-1)


@dataclass(frozen=True)
class ExactConfig:
    """One exact solution of eq. (4): thrusts (4,) [N] and tilts (2,) [rad].

    ``family``: a member of a one-parameter family; ``tilt_free``: per pair,
    True when it has no thrust (any tilt will do).
    """

    thrusts: FloatArray
    tilts: FloatArray
    family: bool
    tilt_free: tuple[bool, bool]
