"""Frame conventions at the boundary: ENU/FLU odometry <-> the core's NED/FRD.

The model is Fossen's (earth NED, body FRD, ``odom_ned`` and ``base_link_frd``);
ROS robots publish their state estimate the REP-103/REP-105 way, the body
``base_link`` (x forward, y left, z up) in ``odom`` (x east, y north, z up),
as robot_localization does. These functions convert a pose and a body twist
between the two, exactly as the rotations say:

* earth: ``x_ned = y_enu``, ``y_ned = x_enu``, ``z_ned = -z_enu`` (a rotation by
  pi about (1, 1, 0)/sqrt(2), its own inverse);
* body: ``(x, y, z)_frd = (x, -y, -z)_flu`` (pi about x, its own inverse), for
  the linear and the angular velocity alike;
* orientation: ``R_ned_frd = R_ned_enu R_enu_flu R_flu_frd``, as quaternions
  (w, x, y, z). In Euler angles: roll the same, pitch negated, yaw
  ``pi/2 - yaw_enu``.

The same rotations are the REP-105 relations of the transform tree the plant
publishes (:data:`EARTH_RELATION`, :data:`BODY_RELATION` on ``/tf_static``, and
``odom -> base_link`` from :func:`pose_ned_to_enu` on ``/tf``), so an ENU tool
and a NED tool see one pose.

Pure numpy; the nodes call these on the arrays of a message.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core.kinematics import quat_multiply, quat_normalize

FloatArray = NDArray[np.float64]

#: The odometry conventions a node may be given (``odom_frame_convention``).
CONVENTIONS = ('ned', 'enu')

_S = math.sqrt(0.5)
#: R_ned_enu (ENU coordinates -> NED coordinates) and its quaternion (w, x, y, z).
_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_Q_NED_ENU = np.array([0.0, _S, _S, 0.0])
#: R_flu_frd = R_frd_flu = diag(1, -1, -1) and its quaternion.
_FLU_FRD = np.array([1.0, -1.0, -1.0])
_Q_FLU_FRD = np.array([0.0, 1.0, 0.0, 0.0])


#: The static transforms parent -> child of REP-105's pairs, as quaternions (w, x, y, z)
#: of the child frame's orientation in the parent (no translation): ``odom -> odom_ned``
#: (R_enu_ned, its own inverse) and ``base_link -> base_link_frd`` (R_flu_frd).
EARTH_RELATION = _Q_NED_ENU.copy()
BODY_RELATION = _Q_FLU_FRD.copy()


def _conjugate(q: FloatArray) -> FloatArray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def _positive(q: FloatArray) -> FloatArray:
    """The quaternion's sign with w >= 0 (both signs are the same rotation)."""
    return -q if q[0] < 0 else q


def enu_to_ned(position: ArrayLike, quaternion: ArrayLike, twist: ArrayLike
               ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ENU/FLU odometry -> NED/FRD: position (3) in ``odom``, orientation (w, x, y, z)
    of ``base_link`` in ``odom``, body twist (u v w p q r) in ``base_link``."""
    p = _NED_ENU @ np.asarray(position, dtype=float)
    q = quat_multiply(quat_multiply(_Q_NED_ENU, quat_normalize(quaternion)), _Q_FLU_FRD)
    nu = np.asarray(twist, dtype=float)
    return p, _positive(q), np.concatenate([_FLU_FRD * nu[:3], _FLU_FRD * nu[3:]])


def ned_to_enu(position: ArrayLike, quaternion: ArrayLike, twist: ArrayLike
               ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """NED/FRD -> ENU/FLU, the inverse of :func:`enu_to_ned`."""
    p, q = pose_ned_to_enu(position, quaternion)
    nu = np.asarray(twist, dtype=float)
    return p, q, np.concatenate([_FLU_FRD * nu[:3], _FLU_FRD * nu[3:]])


#: q -> conj(q_ned_enu) q conj(q_flu_frd), linear in q: the matrix, derived once (the plant
#: converts its pose at every step for /tf).
_TO_ENU = np.column_stack([quat_multiply(quat_multiply(_conjugate(_Q_NED_ENU), e),
                                         _conjugate(_Q_FLU_FRD)) for e in np.eye(4)])


def pose_ned_to_enu(position: ArrayLike, quaternion: ArrayLike
                    ) -> tuple[FloatArray, FloatArray]:
    """The pose of ``base_link_frd`` in ``odom_ned`` -> that of ``base_link`` in ``odom``
    (position, quaternion (w, x, y, z)): the transform ``odom -> base_link``. Raises
    ValueError for a quaternion that is zero or not finite."""
    values = pose_ned_to_enu_values(np.asarray(position, dtype=float).tolist(),
                                    np.asarray(quaternion, dtype=float).tolist())
    return np.array(values[:3]), np.array(values[3:])


def pose_ned_to_enu_values(position: Sequence[float], quaternion: Sequence[float]
                           ) -> tuple[float, ...]:
    """:func:`pose_ned_to_enu` in plain floats, the 7 numbers (x, y, z, w, qx, qy, qz):
    ``position`` (north, east, down) -> (east, north, up), and the unit quaternion times
    :data:`_TO_ENU`, whose rows are written out (the plant converts its pose at every
    step for /tf)."""
    north, east, down = position
    w, x, y, z = quaternion
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if not math.isfinite(norm) or norm == 0.0:
        raise ValueError(f'not a valid quaternion: {list(quaternion)!r}')
    k = _S / norm
    q = (-k * (w + z), -k * (x + y), k * (y - x), k * (z - w))
    if q[0] < 0:
        q = (-q[0], -q[1], -q[2], -q[3])
    return (east, north, -down, *q)
