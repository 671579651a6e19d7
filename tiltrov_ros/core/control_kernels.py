"""The control laws compiled: tracking error, PD (16), PID with g_hat, the switching arithmetic.

Mirrors :func:`tiltrov_ros.core.controllers.tracking_error` (quaternion ->
ZYX Euler angles as :func:`~tiltrov_ros.core.kinematics.euler_from_quat`,
``ssa``, J(eta) of (A.1) with the gimbal guard) and the laws of
:mod:`tiltrov_ros.core.controllers`, which stay the reference; tests pin
these kernels to it (1e-12 relative). Python ends in the controllers'
``update``: they check the argument shapes, keep the PID's last time and the
switching baseline's mode rule, and call :func:`control_law` once per update
through :class:`CompiledLaw`.
"""

from __future__ import annotations

from collections.abc import Sequence
import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core import jit
from tiltrov_ros.core.jit import kernel
from tiltrov_ros.core.kinematics import GIMBAL_GUARD_COS, GIMBAL_LOCK_COS
from tiltrov_ros.core.params import RobotParams

FloatArray = NDArray[np.float64]

# --------------------------------------------------------------------------- layouts
# cfg: float64[CFG_SIZE], built once per controller (law_config).
CFG_KP = 0            # 6 entries: Kp, earth frame (x y z roll pitch yaw)
CFG_KD = 6            # 6 entries: Kd
CFG_KI = 12           # 6 entries: Ki (pid)
CFG_MAX_INTEGRAL = 18  # 6 entries: clamp of the integral (pid)
CFG_W = 24            # weight W [N] (pid: g_hat of the nominal robot)
CFG_B = 25            # buoyancy B [N]
CFG_RG = 26           # 3 entries: nominal r_g [m]
CFG_RB = 29           # 3 entries: r_b [m]
CFG_POSITION_SCALE = 32  # switching: group errors
CFG_ANGLE_SCALE = 33
CFG_TOLERANCE = 34    # 6 entries: pid anti-windup, the shortfall that counts (X..N)
CFG_SIZE = 40

# work: float64[WORK_SIZE], the tracking error (TrackingError's fields).
WORK_ETA = 0          # 6 entries
WORK_E = 6            # 6 entries
WORK_E_DOT = 12       # 6 entries
WORK_J = 18           # 36 entries, J(eta) row-major
WORK_TAU = 54         # 6 entries: scratch
WORK_SHORT = 60       # 6 entries: pid, the previous wrench's shortfall in the earth frame
WORK_SIZE = 66

# out: float64[OUT_SIZE]
OUT_TAU = 0           # 6 entries: the wrench (pd, pid; switching before its mask)
OUT_GROUPS = 6        # 2 entries: switching: (horizontal, vertical) normalised errors
OUT_SIZE = 8

LAW_PD = 0
LAW_PID = 1
LAW_SWITCHING = 2

#: control_law's answer besides 0 (done): a quaternion that cannot be normalised.
BAD_QUATERNION = 1
BAD_REFERENCE_QUATERNION = 2

_TWO_PI = 2.0 * math.pi


@kernel()
def ssa(angle: float) -> float:  # pragma: no cover - compiled
    """kinematics.ssa of one angle: wrapped to (-pi, pi]."""
    if -math.pi < angle <= math.pi:
        return angle
    wrapped = math.pi - (math.pi - angle) % _TWO_PI
    return math.pi if wrapped <= -math.pi else wrapped


@kernel()
def euler_from_unit_quat(q: FloatArray, inv: float, eta: FloatArray,
                         o: int) -> None:  # pragma: no cover - compiled
    """ZYX Euler angles of q * inv (kinematics.euler_from_quat) into eta[o:o + 3]."""
    w, x, y, z = q[0] * inv, q[1] * inv, q[2] * inv, q[3] * inv
    k = 2.0 / (w * w + x * x + y * y + z * z)
    # R = I + k (w S(eps) + S(eps)^2) (kinematics.Rquat), the entries the angles need.
    r00 = 1.0 + k * -(y * y + z * z)
    r01 = k * (-w * z + x * y)
    r10 = k * (w * z + x * y)
    r11 = 1.0 + k * -(x * x + z * z)
    r20 = k * (-w * y + x * z)
    r21 = k * (w * x + y * z)
    r22 = 1.0 + k * -(x * x + y * y)
    cth = math.hypot(r21, r22)
    eta[o + 1] = math.atan2(-r20, cth)
    if cth < GIMBAL_LOCK_COS:
        eta[o] = 0.0
        eta[o + 2] = ssa(math.atan2(-r01, r11))
    else:
        eta[o] = ssa(math.atan2(r21, r22))
        eta[o + 2] = ssa(math.atan2(r10, r00))


@kernel()
def inverse_norm(q: FloatArray) -> float:  # pragma: no cover - compiled
    """1 / |q|, or 0.0 when |q| is zero or not finite (kinematics.quat_normalize refuses)."""
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if not (math.isfinite(n) and n > 0.0):
        return 0.0
    return 1.0 / n


@kernel()
def guarded_trig(eta: FloatArray) -> tuple[float, ...]:  # pragma: no cover - compiled
    """(cos phi, sin phi, cos theta, sin theta, cos psi, sin psi) of eta's angles for
    J(eta) (A.1), theta held just short of +-90 deg (the gimbal guard, as
    controllers.tracking_error does)."""
    phi, theta, psi = eta[3], eta[4], eta[5]
    if math.fabs(math.cos(theta)) < GIMBAL_GUARD_COS:
        theta = math.copysign(math.acos(GIMBAL_GUARD_COS), theta)
    return (math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta),
            math.cos(psi), math.sin(psi))


@kernel('int64(float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], '
        'float64[::1], float64[::1])', group='control')
def tracking(position: FloatArray, quaternion: FloatArray, nu: FloatArray,
             ref_position: FloatArray, ref_quaternion: FloatArray, ref_velocity: FloatArray,
             work: FloatArray) -> int:  # pragma: no cover - compiled
    """controllers.tracking_error into work (eta, e, e_dot, J); 0, or BAD_* (nothing
    written) for a quaternion that cannot be normalised."""
    inv = inverse_norm(quaternion)
    if inv == 0.0:
        return BAD_QUATERNION
    inv_d = inverse_norm(ref_quaternion)
    if inv_d == 0.0:
        return BAD_REFERENCE_QUATERNION
    eta = work[WORK_ETA:WORK_ETA + 6]
    e = work[WORK_E:WORK_E + 6]
    for i in range(3):
        eta[i] = position[i]
        e[i] = ref_position[i] - position[i]
    euler_from_unit_quat(quaternion, inv, eta, 3)
    euler_from_unit_quat(ref_quaternion, inv_d, e, 3)       # eta_d's angles, for now
    for i in range(3, 6):
        e[i] = ssa(e[i] - eta[i])
    # J(eta) (A.1), evaluated just short of pitch +-90 deg.
    cphi, sphi, cth, sth, cpsi, spsi = guarded_trig(eta)
    J = work[WORK_J:WORK_J + 36]
    for i in range(36):
        J[i] = 0.0
    # Rzyx (upper left) and Tzyx (lower right) as in kinematics.
    J[0] = cpsi * cth
    J[1] = -spsi * cphi + cpsi * sth * sphi
    J[2] = spsi * sphi + cpsi * cphi * sth
    J[6] = spsi * cth
    J[7] = cpsi * cphi + sphi * sth * spsi
    J[8] = -cpsi * sphi + sth * spsi * cphi
    J[12] = -sth
    J[13] = cth * sphi
    J[14] = cth * cphi
    J[21] = 1.0
    J[22] = sphi * sth / cth
    J[23] = cphi * sth / cth
    J[28] = cphi
    J[29] = -sphi
    J[34] = sphi / cth
    J[35] = cphi / cth
    for i in range(6):
        acc = 0.0
        for j in range(6):
            acc += J[6 * i + j] * nu[j]
        work[WORK_E_DOT + i] = ref_velocity[i] - acc
    return 0


@kernel()
def earth_shortfall(eta: FloatArray, short: FloatArray,
                    earth: FloatArray) -> None:  # pragma: no cover - compiled
    """earth = J(eta)^-T short (controllers.earth_shortfall): R (A.1) on the forces,
    T(eta)^-T on the moments, with the gimbal guard of J."""
    cphi, sphi, cth, sth, cpsi, spsi = guarded_trig(eta)
    x, y, z = short[0], short[1], short[2]
    earth[0] = cpsi * cth * x + (-spsi * cphi + cpsi * sth * sphi) * y \
        + (spsi * sphi + cpsi * cphi * sth) * z
    earth[1] = spsi * cth * x + (cpsi * cphi + sphi * sth * spsi) * y \
        + (-cpsi * sphi + sth * spsi * cphi) * z
    earth[2] = -sth * x + cth * sphi * y + cth * cphi * z
    k, m, n = short[3], short[4], short[5]
    # T^-1 = [[1, 0, -s_th], [0, c_phi, c_th s_phi], [0, -s_phi, c_th c_phi]], transposed.
    earth[3] = k
    earth[4] = cphi * m - sphi * n
    earth[5] = -sth * k + cth * sphi * m + cth * cphi * n


@kernel('int64(int64, float64, boolean, float64[::1], float64[::1], float64[::1], '
        'float64[::1], float64[::1], float64[::1], float64[::1], float64[::1], '
        'float64[::1], float64[::1], boolean, float64[::1], float64[::1])', group='control')
def control_law(law: int, dt: float, integrate: bool, position: FloatArray,
                quaternion: FloatArray, nu: FloatArray, ref_position: FloatArray,
                ref_quaternion: FloatArray, ref_velocity: FloatArray, cfg: FloatArray,
                integral: FloatArray, work: FloatArray, out: FloatArray, antiwindup: bool,
                achieved: FloatArray, last: FloatArray) -> int:  # pragma: no cover - compiled
    """One update of the law ``law`` (LAW_*) into out; 0, or BAD_* with nothing changed.

    pd, eq. (16): tau = J^T (Kp e + Kd e_dot). pid: the integral (when
    ``integrate``) becomes clip(integral + e dt, -max, max), except in a DOF where
    the previous wrench ``last`` fell short of it (``antiwindup``: last - achieved,
    taken to the earth frame, beyond the tolerance in the direction e pushes), then
    tau = g_hat(eta) + J^T (Kp e + Kd e_dot + Ki integral), copied into ``last``.
    switching: the pd wrench and the two groups' normalised errors.
    """
    status = tracking(position, quaternion, nu, ref_position, ref_quaternion, ref_velocity,
                      work)
    if status != 0:
        return status
    e = work[WORK_E:WORK_E + 6]
    e_dot = work[WORK_E_DOT:WORK_E_DOT + 6]
    short = work[WORK_SHORT:WORK_SHORT + 6]
    if law == LAW_PID and integrate and antiwindup:
        tau = work[WORK_TAU:WORK_TAU + 6]           # scratch: the body shortfall
        for i in range(6):
            tau[i] = last[i] - achieved[i]
        earth_shortfall(work[WORK_ETA:WORK_ETA + 6], tau, short)
    else:
        for i in range(6):
            short[i] = 0.0
    earth = out[OUT_TAU:OUT_TAU + 6]            # Kp e + ..., then overwritten by J^T of it
    for i in range(6):
        earth[i] = cfg[CFG_KP + i] * e[i] + cfg[CFG_KD + i] * e_dot[i]
    if law == LAW_PID:
        for i in range(6):
            wound = (math.fabs(short[i]) > cfg[CFG_TOLERANCE + i]
                     and short[i] * e[i] > 0.0)
            if integrate and not wound:
                lim = cfg[CFG_MAX_INTEGRAL + i]
                v = integral[i] + e[i] * dt
                integral[i] = -lim if v < -lim else lim if v > lim else v
            earth[i] = earth[i] + cfg[CFG_KI + i] * integral[i]
    tau = work[WORK_TAU:WORK_TAU + 6]
    for i in range(6):
        acc = 0.0
        for j in range(6):
            acc += work[WORK_J + 6 * j + i] * earth[j]
        tau[i] = acc
    if law == LAW_PID:
        # g_hat = -[f_g + f_b; r_g x f_g + r_b x f_b], f_g = W k, f_b = -B k, k = R^T e_3.
        inv = inverse_norm(quaternion)
        w, x, y, z = (quaternion[0] * inv, quaternion[1] * inv, quaternion[2] * inv,
                      quaternion[3] * inv)
        s = 2.0 / (w * w + x * x + y * y + z * z)
        k0, k1, k2 = s * (-w * y + x * z), s * (w * x + y * z), 1.0 + s * -(x * x + y * y)
        W, B = cfg[CFG_W], cfg[CFG_B]
        fg0, fg1, fg2 = W * k0, W * k1, W * k2
        fb0, fb1, fb2 = -B * k0, -B * k1, -B * k2
        g0, g1, g2 = cfg[CFG_RG], cfg[CFG_RG + 1], cfg[CFG_RG + 2]
        b0, b1, b2 = cfg[CFG_RB], cfg[CFG_RB + 1], cfg[CFG_RB + 2]
        tau[0] -= fg0 + fb0
        tau[1] -= fg1 + fb1
        tau[2] -= fg2 + fb2
        tau[3] -= (g1 * fg2 - g2 * fg1) + (b1 * fb2 - b2 * fb1)
        tau[4] -= (g2 * fg0 - g0 * fg2) + (b2 * fb0 - b0 * fb2)
        tau[5] -= (g0 * fg1 - g1 * fg0) + (b0 * fb1 - b1 * fb0)
    for i in range(6):
        out[OUT_TAU + i] = tau[i]
        if law == LAW_PID:
            last[i] = tau[i]
    if law == LAW_SWITCHING:
        ps, an = cfg[CFG_POSITION_SCALE], cfg[CFG_ANGLE_SCALE]
        out[OUT_GROUPS] = math.sqrt((e[0] / ps) ** 2 + (e[1] / ps) ** 2 + (e[5] / an) ** 2)
        out[OUT_GROUPS + 1] = math.sqrt((e[2] / ps) ** 2 + (e[3] / an) ** 2
                                        + (e[4] / an) ** 2)
    return 0


# --------------------------------------------------------------------------- Python side

def law_config(kp: Sequence[float], kd: Sequence[float], ki: Sequence[float] = (0.0,) * 6,
               max_integral: ArrayLike = (0.0,) * 6, *, robot: RobotParams | None = None,
               scales: tuple[float, float] = (0.0, 0.0),
               tolerance: ArrayLike = (0.0,) * 6) -> FloatArray:
    """The cfg array of a law: gains, the PID's integral clamp, nominal robot (W, B,
    r_g, r_b for g_hat) and anti-windup tolerance, the switching baseline's (position,
    angle) error scales."""
    cfg = np.zeros(CFG_SIZE)
    cfg[CFG_KP:CFG_KP + 6] = kp
    cfg[CFG_KD:CFG_KD + 6] = kd
    cfg[CFG_KI:CFG_KI + 6] = ki
    cfg[CFG_MAX_INTEGRAL:CFG_MAX_INTEGRAL + 6] = max_integral
    if robot is not None:
        cfg[CFG_W], cfg[CFG_B] = robot.weight, robot.buoyancy
        cfg[CFG_RG:CFG_RG + 3] = robot.r_g
        cfg[CFG_RB:CFG_RB + 3] = robot.r_b
    cfg[CFG_POSITION_SCALE], cfg[CFG_ANGLE_SCALE] = scales
    cfg[CFG_TOLERANCE:CFG_TOLERANCE + 6] = tolerance
    return cfg


def _vector(value: ArrayLike, n: int, what: str) -> FloatArray:
    """``value`` as a C-contiguous float64 (n,) array (itself when it already is one)."""
    if (type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (n,)
            and value.flags.c_contiguous):
        return value
    arr = np.ascontiguousarray(value, dtype=np.float64)
    if arr.shape != (n,):
        raise ValueError(f'{what}: expected {n} values, got shape {arr.shape}')
    return arr


class CompiledLaw:
    """One controller's compiled law (:func:`control_law`) and its buffers.

    Built once per controller (compiling or loading the kernels then, never in a
    tick); ``__call__`` checks the inputs' shapes, calls the kernel and returns its
    ``out`` buffer (reused: copy what you keep). A quaternion that cannot be
    normalised raises ValueError, as :func:`~tiltrov_ros.core.kinematics.quat_normalize`
    does, and changes nothing.
    """

    def __init__(self, law: int, cfg: FloatArray) -> None:
        self.law = law
        self.cfg = cfg
        self.work = np.zeros(WORK_SIZE)
        self.out = np.zeros(OUT_SIZE)
        self._no_integral = np.zeros(6)
        self._no_achieved = np.zeros(6)
        self._no_last = np.zeros(6)
        jit.warmup(('control',))

    def __call__(self, position: ArrayLike, quaternion: ArrayLike, nu: ArrayLike,
                 reference: Any, *, dt: float = 0.0, integrate: bool = False,
                 integral: FloatArray | None = None, achieved: ArrayLike | None = None,
                 last: FloatArray | None = None) -> FloatArray:
        """``reference``: a controllers.Reference (position, quaternion, velocity).
        pid: ``last`` the controller's previous wrench (rewritten with this one) and
        ``achieved`` what the allocator achieved of it (None: unknown, no anti-windup)."""
        q = _vector(quaternion, 4, 'quaternion')
        q_d = _vector(reference.quaternion, 4, 'reference quaternion')
        got = (self._no_achieved if achieved is None
               else _vector(achieved, 6, 'achieved wrench'))
        status = control_law(self.law, float(dt), integrate, _vector(position, 3, 'position'),
                             q, _vector(nu, 6, 'nu'),
                             _vector(reference.position, 3, 'reference position'), q_d,
                             _vector(reference.velocity, 6, 'reference velocity'),
                             self.cfg, self._no_integral if integral is None else integral,
                             self.work, self.out, achieved is not None, got,
                             self._no_last if last is None else last)
        if status:
            bad = q if status == BAD_QUATERNION else q_d
            raise ValueError(f'not a valid quaternion: {bad!r}')
        return self.out
