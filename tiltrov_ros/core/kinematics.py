"""Kinematics: ZYX Euler angles, J(eta) of (A.1), unit quaternions (w, x, y, z).

Frames: earth NED (``odom_ned``), body FRD (``base_link_frd``). Euler angles are
ZYX (yaw psi, pitch theta, roll phi), as in the paper's (A.1) and Fossen (2021,
Sec. 2.2.1). The attitude is *integrated* as a unit quaternion (Fossen 2021,
Sec. 2.2.2), which has no singularity; Euler angles are derived from it for
whoever needs them (controllers, logs, plots).

Names follow Fossen's Python/MATLAB toolboxes: ``ssa``, ``Smtrx``, ``Rzyx``,
``Tzyx``, ``Rquat``, ``Tquat``.
"""

from __future__ import annotations

import math
from typing import overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

_TWO_PI = 2.0 * math.pi
#: |cos(theta)| below which Tzyx and J are refused (gimbal lock).
GIMBAL_LOCK_COS = 1e-9
#: |cos(theta)| under which the controllers evaluate J(eta) at a pitch just short of
#: +-90 deg (J is singular there).
GIMBAL_GUARD_COS = 1e-6


@overload
def ssa(angle: float) -> float: ...
@overload
def ssa(angle: FloatArray) -> FloatArray: ...


def ssa(angle: float | FloatArray) -> float | FloatArray:
    """Smallest signed angle: ``angle`` wrapped to (-pi, pi], rad.

    ``pi`` maps to ``pi`` and ``-pi`` to ``pi`` (the interval is open at -pi).
    Works element-wise on arrays.
    """
    # pi - ((pi - a) mod 2 pi) lies in (-pi, pi] exactly, except that the mod can
    # round up to 2 pi for a tiny negative (pi - a); that case is pi.
    # Angles already in range are returned unchanged (bit for bit).
    if isinstance(angle, np.ndarray):
        wrapped = np.pi - np.mod(np.pi - angle, _TWO_PI)
        wrapped = np.where(wrapped <= -np.pi, np.pi, wrapped)
        return np.where((angle > -np.pi) & (angle <= np.pi), angle, wrapped)
    if -math.pi < angle <= math.pi:
        return float(angle)
    wrapped_f = math.pi - (math.pi - angle) % _TWO_PI
    return math.pi if wrapped_f <= -math.pi else wrapped_f


def Smtrx(a: ArrayLike) -> FloatArray:
    """Skew-symmetric matrix S(a) with S(a) b = a x b (Fossen 2021, Sec. 2.1)."""
    x, y, z = np.asarray(a, dtype=float)
    return np.array([[0.0, -z, y],
                     [z, 0.0, -x],
                     [-y, x, 0.0]])


def Rzyx(phi: float, theta: float, psi: float) -> FloatArray:
    """Rotation matrix R = Rz(psi) Ry(theta) Rx(phi), body to NED.

    The upper-left block of J(eta) in (A.1); Fossen (2021, Sec. 2.2.1).
    """
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cpsi, spsi = math.cos(psi), math.sin(psi)
    return np.array([
        [cpsi * cth, -spsi * cphi + cpsi * sth * sphi, spsi * sphi + cpsi * cphi * sth],
        [spsi * cth, cpsi * cphi + sphi * sth * spsi, -cpsi * sphi + sth * spsi * cphi],
        [-sth, cth * sphi, cth * cphi],
    ])


def Tzyx(phi: float, theta: float) -> FloatArray:
    """Euler-rate matrix T with (phi, theta, psi)_dot = T (p, q, r).

    The lower-right block of J(eta) in (A.1); Fossen (2021, Sec. 2.2.1).

    Raises
    ------
    ValueError
        At pitch +-90 deg (|cos(theta)| < ``GIMBAL_LOCK_COS``), where T does not
        exist. Integrate the attitude as a quaternion instead.
    """
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    if abs(cth) < GIMBAL_LOCK_COS:
        raise ValueError(f'Tzyx is singular at pitch theta = {theta!r} rad (+-90 deg)')
    return np.array([
        [1.0, sphi * sth / cth, cphi * sth / cth],
        [0.0, cphi, -sphi],
        [0.0, sphi / cth, cphi / cth],
    ])


def J(eta: ArrayLike) -> FloatArray:
    """The 6x6 transformation J(eta) of (A.1): eta_dot = J(eta) nu, eq. (2).

    ``eta`` = (x, y, z, phi, theta, psi) in NED, m and rad. Singular at pitch
    +-90 deg (see :func:`Tzyx`).
    """
    e = np.asarray(eta, dtype=float)
    if e.shape != (6,):
        raise ValueError(f'eta must have shape (6,), got {e.shape}')
    out = np.zeros((6, 6))
    out[:3, :3] = Rzyx(e[3], e[4], e[5])
    out[3:, 3:] = Tzyx(e[3], e[4])
    return out


# ---------------------------------------------------------------------------
# Unit quaternions q = (w, x, y, z), the body FRD orientation in NED.
# ---------------------------------------------------------------------------

def quat_normalize(q: ArrayLike) -> FloatArray:
    """q / |q|. Raises ValueError for a zero or non-finite quaternion."""
    v = np.asarray(q, dtype=float)
    n = float(np.linalg.norm(v))
    if v.shape != (4,) or not math.isfinite(n) or n == 0.0:
        raise ValueError(f'not a valid quaternion: {v!r}')
    return v / n


def quat_multiply(a: ArrayLike, b: ArrayLike) -> FloatArray:
    """Hamilton product a (x) b of quaternions (w, x, y, z)."""
    aw, ax, ay, az = np.asarray(a, dtype=float)
    bw, bx, by, bz = np.asarray(b, dtype=float)
    return np.array([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw])


def Rquat(q: ArrayLike) -> FloatArray:
    """Rotation matrix (body to NED) of the quaternion q = (w, x, y, z).

    R = I + 2 w S(eps) + 2 S(eps)^2 for a unit q (Fossen 2021, Sec. 2.2.2),
    evaluated as I + (2 / |q|^2)(w S(eps) + S(eps)^2), so R is exactly the
    rotation of q / |q| even when q has drifted from unit norm.
    """
    v = np.asarray(q, dtype=float)
    w, eps = v[0], v[1:]
    S = Smtrx(eps)
    R: FloatArray = np.eye(3) + (2.0 / float(v @ v)) * (w * S + S @ S)
    return R


def Tquat(q: ArrayLike) -> FloatArray:
    """The 4x3 matrix T(q) with q_dot = T(q) (p, q, r) (Fossen 2021, Sec. 2.2.2).

    T(q) = 1/2 [-eps^T; w I + S(eps)], i.e. q_dot = 1/2 q (x) (0, omega).
    """
    v = np.asarray(q, dtype=float)
    w, eps = v[0], v[1:]
    out = np.empty((4, 3))
    out[0] = -eps
    out[1:] = w * np.eye(3) + Smtrx(eps)
    return 0.5 * out


def quat_from_euler(phi: float, theta: float, psi: float) -> FloatArray:
    """Unit quaternion of ZYX Euler angles: q = q_z(psi) (x) q_y(theta) (x) q_x(phi)."""
    cr, sr = math.cos(0.5 * phi), math.sin(0.5 * phi)
    cp, sp = math.cos(0.5 * theta), math.sin(0.5 * theta)
    cy, sy = math.cos(0.5 * psi), math.sin(0.5 * psi)
    return np.array([cr * cp * cy + sr * sp * sy,
                     sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy])


def euler_from_rotation(R: ArrayLike) -> FloatArray:
    """ZYX Euler angles (phi, theta, psi), rad, of a rotation matrix (inverse of Rzyx).

    theta in [-pi/2, pi/2], phi and psi in (-pi, pi]. At theta = +-90 deg
    (cos(theta) < ``GIMBAL_LOCK_COS``) only psi -+ phi is defined: this returns
    phi = 0 and the psi that reproduces R.
    """
    m = np.asarray(R, dtype=float)
    cth = math.hypot(m[2, 1], m[2, 2])
    theta = math.atan2(-m[2, 0], cth)
    if cth < GIMBAL_LOCK_COS:
        # R[0,1] = -sin(psi -+ phi), R[1,1] = cos(psi -+ phi) at theta = +-90 deg.
        return np.array([0.0, theta, ssa(math.atan2(-m[0, 1], m[1, 1]))])
    phi = math.atan2(m[2, 1], m[2, 2])
    psi = math.atan2(m[1, 0], m[0, 0])
    return np.array([ssa(phi), theta, ssa(psi)])


def euler_from_quat(q: ArrayLike) -> FloatArray:
    """ZYX Euler angles (phi, theta, psi), rad, of a quaternion (w, x, y, z)."""
    return euler_from_rotation(Rquat(q))


def euler_from_quat_rows(q: ArrayLike) -> FloatArray:
    """:func:`euler_from_quat` of each row of ``q`` (n, 4), vectorised: (n, 3).

    The same formulas, R of :func:`Rquat` written out entry by entry and the
    angles of :func:`euler_from_rotation` (gimbal lock included); equal to the
    row-by-row result to rounding (under 1e-13 rad; the Euler angles amplify
    rounding near pitch +-90 deg).
    """
    v = np.asarray(q, dtype=float).reshape(-1, 4)
    w, x, y, z = v[:, 0], v[:, 1], v[:, 2], v[:, 3]
    k = 2.0 / np.einsum('ij,ij->i', v, v)
    # R = I + k (w S(eps) + S(eps)^2), the entries the angles need.
    r00 = 1.0 + k * -(y * y + z * z)
    r01 = k * (-w * z + x * y)
    r10 = k * (w * z + x * y)
    r11 = 1.0 + k * -(x * x + z * z)
    r20 = k * (-w * y + x * z)
    r21 = k * (w * x + y * z)
    r22 = 1.0 + k * -(x * x + y * y)
    cth = np.hypot(r21, r22)
    theta = np.arctan2(-r20, cth)
    lock = cth < GIMBAL_LOCK_COS
    phi = np.where(lock, 0.0, ssa(np.arctan2(r21, r22)))
    psi = ssa(np.where(lock, np.arctan2(-r01, r11), np.arctan2(r10, r00)))
    out: FloatArray = np.column_stack([phi, theta, psi])
    return out


def quat_from_rotation(R: ArrayLike) -> FloatArray:
    """Unit quaternion (w >= 0) of a rotation matrix (Shepperd's method)."""
    m = np.asarray(R, dtype=float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    # Pick the largest of 4 w^2, 4 x^2, 4 y^2, 4 z^2 for numerical stability.
    cands = [trace, m[0, 0], m[1, 1], m[2, 2]]
    k = int(np.argmax(cands))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    out = np.array(q)
    return out if out[0] >= 0.0 else -out
