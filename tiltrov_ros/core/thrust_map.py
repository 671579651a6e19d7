"""The thrust map of the tilting-thruster robot: eq. (4) and its linear form (5).

Geometry (the joints of :mod:`tiltrov_ros.core.names`; checked against r_i x F_i by a test):

========== ======================== ================================
joint      position in base_link_frd horizontal direction at tilt 0
========== ======================== ================================
thruster_1 (+l/2, -d/2, 0)           (+1, +1, 0)/sqrt(2)
thruster_2 (+l/2, +d/2, 0)           (+1, -1, 0)/sqrt(2)
thruster_3 (-l/2, +d/2, 0)           (+1, +1, 0)/sqrt(2)
thruster_4 (-l/2, -d/2, 0)           (+1, -1, 0)/sqrt(2)
========== ======================== ================================

``tilt_front`` (alpha) turns thrusters 1 and 2, ``tilt_rear`` (beta) 3 and 4.
A thruster tilted by gamma pushes along ``cos(gamma) h_i + sin(gamma) (0, 0, -1)``
with ``h_i`` its horizontal direction: at +90 deg a positive thrust points up.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

SQRT1_2 = np.sqrt(0.5)

# Sign of the y component of each thruster's horizontal direction (x is always +).
_HORIZONTAL_Y_SIGN = np.array([1.0, -1.0, 1.0, -1.0])
# Which tilt turns each thruster: 0 = front (alpha), 1 = rear (beta).
THRUSTER_TILT_INDEX = np.array([0, 0, 1, 1])


def thruster_positions(length: float, width: float) -> FloatArray:
    """Positions r_i of the four thrusters in ``base_link_frd``, shape (4, 3), m."""
    half_l, half_d = 0.5 * length, 0.5 * width
    return np.array([[half_l, -half_d, 0.0],
                     [half_l, half_d, 0.0],
                     [-half_l, half_d, 0.0],
                     [-half_l, -half_d, 0.0]])


def thruster_directions(tilt_front: float, tilt_rear: float) -> FloatArray:
    """Unit thrust directions of the four thrusters at the given tilts, shape (4, 3)."""
    tilts = np.array([tilt_front, tilt_front, tilt_rear, tilt_rear])
    cos_t, sin_t = np.cos(tilts), np.sin(tilts)
    return np.column_stack([cos_t * SQRT1_2, cos_t * SQRT1_2 * _HORIZONTAL_Y_SIGN, -sin_t])


def allocation_matrix(length: float, width: float) -> FloatArray:
    """The constant matrix A of eq. (5), shape (6, 8), so that tau = A q.

    q = (f1 s_a, f2 s_a, f3 s_b, f4 s_b, f1 c_a, f2 c_a, f3 c_b, f4 c_b): the first
    four columns take the vertical thrust components, the last four the
    horizontal ones.
    """
    l, d = float(length), float(width)
    k = (l + d) / (2.0 * np.sqrt(2.0))
    s = SQRT1_2
    return np.array([
        [0.0, 0.0, 0.0, 0.0, s, s, s, s],
        [0.0, 0.0, 0.0, 0.0, s, -s, s, -s],
        [-1.0, -1.0, -1.0, -1.0, 0.0, 0.0, 0.0, 0.0],
        [d / 2, -d / 2, -d / 2, d / 2, 0.0, 0.0, 0.0, 0.0],
        [l / 2, l / 2, -l / 2, -l / 2, 0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, k, -k, -k, k],
    ])


def q_vector(thrusts: ArrayLike, tilt_front: ArrayLike, tilt_rear: ArrayLike) -> FloatArray:
    """The decomposed input q of eq. (5), shape (..., 8), from thrusts (..., 4) and tilts."""
    f = np.asarray(thrusts, dtype=float)
    alpha = np.asarray(tilt_front, dtype=float)[..., None]
    beta = np.asarray(tilt_rear, dtype=float)[..., None]
    tilts = np.concatenate([alpha, alpha, beta, beta], axis=-1)
    return np.concatenate([f * np.sin(tilts), f * np.cos(tilts)], axis=-1)


def thrust_wrench(thrusts: ArrayLike, tilt_front: ArrayLike, tilt_rear: ArrayLike,
                  length: float, width: float) -> FloatArray:
    """The body wrench tau = (X, Y, Z, K, M, N) of eq. (4), shape (..., 6).

    Vectorised: ``thrusts`` has shape (..., 4) and the tilts shape (...), so a
    whole time series or a Monte-Carlo batch is evaluated in one call.
    """
    q = q_vector(thrusts, tilt_front, tilt_rear)
    return q @ allocation_matrix(length, width).T
