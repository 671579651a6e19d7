"""Rigid-body dynamics of the robot: eqs. (1)-(3) with M (A.2), C (A.3), D (A.4), g(eta).

State ``x`` (13,) = [position in NED (3, m), quaternion (w, x, y, z) of the body
FRD orientation in NED (4), nu = (u v w p q r) in the body frame (6, m/s, rad/s)].

Equations, with the ocean current in the relative-velocity form::

    p_dot = R(q) nu_1                                          (2), translation
    q_dot = T(q) nu_2                                          (2), as a quaternion
    M nu_r_dot + C(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau    (1) relative to the water
    nu_r  = nu - nu_c,  nu_c = [R(q)^T v_c; 0]                 v_c: current in NED
    nu_dot = nu_r_dot + nu_c_dot,  nu_c_dot = [-omega x R^T v_c; 0]

For a constant, irrotational current this is Fossen's relative-velocity form
of (1) (Fossen 2021, Sec. 10.3): M of (A.2) lumps rigid-body and added mass,
and C(nu_r) of (A.3) with the relative velocity means a robot drifting with the
water feels neither drag nor a Munk moment. In still water (v_c = 0) it is
exactly eq. (1). A slowly varying (Gauss-Markov) current is held over each
plant step; its own rate is neglected, as usual.

Two implementations of the same right-hand side:

* :func:`f` - the reference, one numpy line per equation, citing the paper and
  Fossen (2021);
* :class:`RigidBody` - the same arithmetic in straight-line Python floats for
  the plant's hot loop (a 13-element state makes numpy's per-call overhead
  dominate). A test checks that they agree to 1e-12.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core.kinematics import Rquat, Smtrx, Tquat, euler_from_quat
from tiltrov_ros.core.params import RobotParams

FloatArray = NDArray[np.float64]

STATE_SIZE = 13
#: Slices of the state vector.
POSITION = slice(0, 3)
QUATERNION = slice(3, 7)
NU = slice(7, 13)

_E3 = np.array([0.0, 0.0, 1.0])


def mass_matrix(params: RobotParams) -> FloatArray:
    """M = M_RB + M_A of (A.2), 6x6 diagonal, kg and kg m^2."""
    return params.M


def m2c(M: ArrayLike, nu: ArrayLike) -> FloatArray:
    """Coriolis-centripetal matrix C(nu) from a 6x6 mass matrix (Fossen 2021, Sec. 3.3).

    C(nu) = [[0, -S(M11 nu1 + M12 nu2)], [-S(M11 nu1 + M12 nu2), -S(M21 nu1 + M22 nu2)]]
    with M symmetrised first. C is skew-symmetric, so nu^T C(nu) nu = 0. For the
    diagonal M of (A.2) it reproduces (A.3) element by element.
    """
    Mm = np.asarray(M, dtype=float)
    Mm = 0.5 * (Mm + Mm.T)
    v = np.asarray(nu, dtype=float)
    nu1, nu2 = v[:3], v[3:]
    a = Mm[:3, :3] @ nu1 + Mm[:3, 3:] @ nu2
    b = Mm[3:, :3] @ nu1 + Mm[3:, 3:] @ nu2
    C = np.zeros((6, 6))
    C[:3, 3:] = -Smtrx(a)
    C[3:, :3] = -Smtrx(a)
    C[3:, 3:] = -Smtrx(b)
    return C


def coriolis_matrix(params: RobotParams, nu: ArrayLike) -> FloatArray:
    """C(nu) of (A.3): ``m2c`` of the robot's M."""
    return m2c(params.M, nu)


def damping_matrix(params: RobotParams, nu: ArrayLike) -> FloatArray:
    """D(nu) = diag(d_i |nu_i|) of (A.4) plus the optional linear damping diag(d_lin,i)."""
    v = np.asarray(nu, dtype=float)
    return np.diag(np.asarray(params.quadratic_damping) * np.abs(v)
                   + np.asarray(params.linear_damping))


def gvect(W: float, B: float, R: ArrayLike, r_g: ArrayLike, r_b: ArrayLike) -> FloatArray:
    """Restoring forces and moments g(eta) of a submerged body (Fossen 2021, Sec. 4.1).

    g = -[f_g + f_b; r_g x f_g + r_b x f_b] with f_g = R^T (0, 0, W) and
    f_b = -R^T (0, 0, B). Computed from the rotation matrix R (body to NED), so it
    holds at every attitude, pitch +-90 deg included. With Euler angles it equals
    Fossen's closed form, e.g. g_5 = (z_g W - z_b B) sin(theta) + (x_g W - x_b B)
    cos(theta) cos(phi).

    Parameters
    ----------
    W, B : float
        Weight and buoyancy, N.
    R : array_like, (3, 3)
        Rotation body -> NED.
    r_g, r_b : array_like, (3,)
        Centers of gravity and buoyancy in the body frame, m.
    """
    k = np.asarray(R, dtype=float).T @ _E3
    f_g = W * k
    f_b = -B * k
    return -np.concatenate([f_g + f_b,
                            np.cross(np.asarray(r_g, dtype=float), f_g)
                            + np.cross(np.asarray(r_b, dtype=float), f_b)])


def restoring_forces(params: RobotParams, R: ArrayLike) -> FloatArray:
    """g(eta) of eq. (1) for the robot at attitude R (see :func:`gvect`)."""
    return gvect(params.weight, params.buoyancy, R, params.r_g, params.r_b)


def relative_velocity(nu: ArrayLike, R: ArrayLike, current: ArrayLike | None) -> FloatArray:
    """nu_r = nu - [R^T v_c; 0]: body velocity relative to the water (current v_c in NED)."""
    v = np.array(nu, dtype=float)
    if current is not None:
        v[:3] -= np.asarray(R, dtype=float).T @ np.asarray(current, dtype=float)
    return v


def f(t: float, x: ArrayLike, u: ArrayLike, params: RobotParams,
      current: ArrayLike | None = None) -> FloatArray:
    """Reference right-hand side x_dot = f(t, x, u) of the rigid body.

    Parameters
    ----------
    t : float
        Time, s (unused: the model is time-invariant; kept for the integrators).
    x : array_like, (13,)
        State [position NED (m), quaternion (w, x, y, z), nu (m/s, rad/s)].
    u : array_like, (6,)
        Body wrench tau = (X Y Z K M N), N and N m: eq. (4) of the actuator
        state plus any external wrench.
    params : RobotParams
        The robot (the plant passes the *true* one, with the center-of-mass error).
    current : array_like, (3,), optional
        Ocean current in NED, m/s (None: still water).

    Returns
    -------
    ndarray, (13,)
        [p_dot, q_dot, nu_dot].
    """
    xv = np.asarray(x, dtype=float)
    tau = np.asarray(u, dtype=float)
    q = xv[QUATERNION]
    nu = xv[NU]
    R = Rquat(q)                                            # Fossen 2021, Sec. 2.2.2
    p_dot = R @ nu[:3]                                      # (2), translation
    q_dot = Tquat(q) @ nu[3:]                               # (2), attitude as a quaternion
    nu_r = relative_velocity(nu, R, current)
    M = mass_matrix(params)                                 # (A.2)
    rhs = (tau
           - coriolis_matrix(params, nu_r) @ nu_r           # (A.3), relative velocity
           - damping_matrix(params, nu_r) @ nu_r            # (A.4) + linear
           - restoring_forces(params, R))                   # g(eta)
    nu_dot = np.linalg.solve(M, rhs)                        # (1), nu_r_dot
    nu_c = nu - nu_r                                        # [R^T v_c; 0]
    nu_dot[:3] -= np.cross(nu[3:], nu_c[:3])                # + nu_c_dot (constant v_c in NED)
    return np.concatenate([p_dot, q_dot, nu_dot])


def kinetic_energy(params: RobotParams, nu: ArrayLike) -> float:
    """1/2 nu^T M nu, J (rigid body plus added mass)."""
    v = np.asarray(nu, dtype=float)
    return 0.5 * float(v @ params.M @ v)


def potential_energy(params: RobotParams, position: ArrayLike, R: ArrayLike) -> float:
    """Potential of gravity and buoyancy, J, zero with both centers at the NED origin.

    V = -W z_CG + B z_CB with z the NED depth of each center; its rate is
    nu^T g(eta), so without input and current d(T + V)/dt = -nu^T D(nu) nu <= 0.
    """
    p = np.asarray(position, dtype=float)
    Rm = np.asarray(R, dtype=float)
    z_cg = float(p[2]) + float(Rm[2] @ params.r_g)
    z_cb = float(p[2]) + float(Rm[2] @ params.r_b)
    return -params.weight * z_cg + params.buoyancy * z_cb


def eta_from_state(x: ArrayLike) -> FloatArray:
    """eta = (x, y, z, phi, theta, psi) of a state, m and rad (ZYX Euler angles)."""
    xv = np.asarray(x, dtype=float)
    return np.concatenate([xv[POSITION], euler_from_quat(xv[QUATERNION])])


Derivative = Callable[[Sequence[float], Sequence[float], Sequence[float]], list[float]]


class RigidBody:
    """The right-hand side of :func:`f` in straight-line float arithmetic (the hot path).

    ``body.derivative(x, tau, current)`` takes and returns plain sequences of
    floats: x (13), tau (6), current in NED (3). Equal to :func:`f` to rounding
    (tested to 1e-12); every line below mirrors a line of :func:`f`.
    """

    def __init__(self, params: RobotParams) -> None:
        self.params = params
        self.derivative: Derivative = _make_derivative(params)


def _make_derivative(params: RobotParams) -> Derivative:
    m1, m2, m3, m4, m5, m6 = params.mass_matrix
    i1, i2, i3, i4, i5, i6 = (1.0 / m for m in params.mass_matrix)
    d1, d2, d3, d4, d5, d6 = params.quadratic_damping
    l1, l2, l3, l4, l5, l6 = params.linear_damping
    wmb = params.weight - params.buoyancy
    # c = W r_g - B r_b: the moment arm of the restoring moment.
    c1, c2, c3 = (params.weight * g - params.buoyancy * b
                  for g, b in zip(params.center_of_gravity, params.center_of_buoyancy))
    fabs = math.fabs

    def derivative(x: Sequence[float], tau: Sequence[float],
                   vc: Sequence[float]) -> list[float]:
        _, _, _, qw, qx, qy, qz, u, v, w, p, q, r = x
        # R(q) for q / |q| (Fossen 2021, Sec. 2.2.2), as in kinematics.Rquat.
        s = 2.0 / (qw * qw + qx * qx + qy * qy + qz * qz)
        xx, yy, zz = qx * qx, qy * qy, qz * qz
        xy, xz, yz = qx * qy, qx * qz, qy * qz
        wx, wy, wz = qw * qx, qw * qy, qw * qz
        R11, R12, R13 = 1.0 - s * (yy + zz), s * (xy - wz), s * (xz + wy)
        R21, R22, R23 = s * (xy + wz), 1.0 - s * (xx + zz), s * (yz - wx)
        R31, R32, R33 = s * (xz - wy), s * (yz + wx), 1.0 - s * (xx + yy)
        # (2): p_dot = R nu_1, q_dot = T(q) nu_2.
        dn = R11 * u + R12 * v + R13 * w
        de = R21 * u + R22 * v + R23 * w
        dd = R31 * u + R32 * v + R33 * w
        dqw = -0.5 * (qx * p + qy * q + qz * r)
        dqx = 0.5 * (qw * p - qz * q + qy * r)
        dqy = 0.5 * (qz * p + qw * q - qx * r)
        dqz = 0.5 * (-qy * p + qx * q + qw * r)
        # nu_c = [R^T v_c; 0], nu_r = nu - nu_c.
        vc1, vc2, vc3 = vc
        cu = R11 * vc1 + R21 * vc2 + R31 * vc3
        cv = R12 * vc1 + R22 * vc2 + R32 * vc3
        cw = R13 * vc1 + R23 * vc2 + R33 * vc3
        ur, vr, wr = u - cu, v - cv, w - cw
        # C(nu_r) nu_r of (A.3) = [omega x a; nu_r1 x a + omega x b],
        # a = M11 nu_r1, b = M22 nu_2.
        a1, a2, a3 = m1 * ur, m2 * vr, m3 * wr
        b1, b2, b3 = m4 * p, m5 * q, m6 * r
        C1 = q * a3 - r * a2
        C2 = r * a1 - p * a3
        C3 = p * a2 - q * a1
        C4 = vr * a3 - wr * a2 + q * b3 - r * b2
        C5 = wr * a1 - ur * a3 + r * b1 - p * b3
        C6 = ur * a2 - vr * a1 + p * b2 - q * b1
        # g(eta) = -[(W - B) k; c x k], k = R^T e_3 (Fossen 2021, Sec. 4.1).
        t1, t2, t3, t4, t5, t6 = tau
        # (1): nu_r_dot = M^-1 (tau - C(nu_r) nu_r - D(nu_r) nu_r - g), D of (A.4)
        # plus linear; nu_dot = nu_r_dot - omega x nu_c1 (constant current in NED).
        return [
            dn, de, dd, dqw, dqx, dqy, dqz,
            i1 * (t1 - C1 - (d1 * fabs(ur) + l1) * ur + wmb * R31) - (q * cw - r * cv),
            i2 * (t2 - C2 - (d2 * fabs(vr) + l2) * vr + wmb * R32) - (r * cu - p * cw),
            i3 * (t3 - C3 - (d3 * fabs(wr) + l3) * wr + wmb * R33) - (p * cv - q * cu),
            i4 * (t4 - C4 - (d4 * fabs(p) + l4) * p + (c2 * R33 - c3 * R32)),
            i5 * (t5 - C5 - (d5 * fabs(q) + l5) * q + (c3 * R31 - c1 * R33)),
            i6 * (t6 - C6 - (d6 * fabs(r) + l6) * r + (c1 * R32 - c2 * R31)),
        ]

    return derivative
