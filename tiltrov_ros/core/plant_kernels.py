"""The plant step compiled: rigid body (RK4 or Euler), actuators and current in one kernel.

Mirrors, line for line, the float path of :class:`tiltrov_ros.core.plant.Plant`
(:class:`~tiltrov_ros.core.dynamics.RigidBody`'s derivative, eq. (4) as A q of
eq. (5), :class:`~tiltrov_ros.core.actuators.ThrusterBank`,
:class:`~tiltrov_ros.core.actuators.TiltServos` and
:meth:`~tiltrov_ros.core.disturbances.OceanCurrent.advance`), which stays the
reference; tests pin this kernel to it (1e-12 relative after many steps).

Python ends in :meth:`Plant.step`: it evaluates a callable external wrench and
draws the current's normal numbers (one Generator call for n steps, the same
sequence as n calls), then :func:`plant_steps` runs the n steps, updating the
state arrays in place and, when asked, writing one log row per step.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core.actuators import (
    THRUST,
    THRUST_CMD,
    THRUST_WORKING,
    TILT,
    TILT_CMD,
    TILT_VELOCITY,
)
from tiltrov_ros.core.disturbances import CURRENT_B, CURRENT_VELOCITY
from tiltrov_ros.core.jit import kernel
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.thrust_map import allocation_matrix

FloatArray = NDArray[np.float64]

# --------------------------------------------------------------------------- constants
# cfg: float64[CFG_SIZE], built once per plant (:func:`plant_config`).
CFG_M = 0             # 6 entries: diagonal of M (A.2)
CFG_INV_M = 6         # 6 entries: 1 / M_ii
CFG_DQ = 12           # 6 entries: quadratic damping (A.4)
CFG_DL = 18           # 6 entries: linear damping
CFG_WMB = 24          # W - B [N]
CFG_C = 25            # 3 entries: W r_g - B r_b [N m]
CFG_A = 28            # 48 entries: A of eq. (5), row-major (6 x 8)
CFG_H = 76            # plant step h [s]
CFG_DECAY = 77        # thrusters: exp(-h / T)
CFG_MAX_MOVE = 78     # servos: rate limit * h [rad]
CFG_RK4 = 79          # 1.0 RK4, 0.0 forward Euler
CFG_RANDOM = 80       # 1.0 when the current has a Gauss-Markov part
CFG_PHI = 81          # 3 entries: exp(-h / T_c)
CFG_GAIN = 84         # 3 entries: sigma sqrt(1 - phi^2)
CFG_MEAN = 87         # 3 entries: mean current in NED [m/s]
CFG_SIZE = 90

# log: float64[n, LOG_WIDTH], one row per step: the sample after it (PlantSample).
LOG_T = 0             # t [s] = seconds(t_ns)
LOG_X = 1             # 13 entries: position, quaternion (w x y z), nu
LOG_TILTS = 14        # 2 entries
LOG_TILT_VELOCITIES = 16  # 2 entries
LOG_THRUSTS = 18      # 4 entries
LOG_WIDTH = 22

#: float64[WORK_SIZE]: the kernel's scratch (k1..k4, the stage state, tau, current).
WORK_SIZE = 5 * 13 + 6 + 3


def plant_config(params: RobotParams, h: float, decay: float, rk4: bool,
                 random: bool, phi: tuple[float, ...], gain: tuple[float, ...],
                 mean: tuple[float, ...]) -> FloatArray:
    """The constants of :func:`plant_steps` for the plant's *true* robot ``params``."""
    cfg = np.zeros(CFG_SIZE)
    cfg[CFG_M:CFG_M + 6] = params.mass_matrix
    cfg[CFG_INV_M:CFG_INV_M + 6] = [1.0 / m for m in params.mass_matrix]
    cfg[CFG_DQ:CFG_DQ + 6] = params.quadratic_damping
    cfg[CFG_DL:CFG_DL + 6] = params.linear_damping
    cfg[CFG_WMB] = params.weight - params.buoyancy
    cfg[CFG_C:CFG_C + 3] = [params.weight * g - params.buoyancy * b
                            for g, b in zip(params.center_of_gravity,
                                            params.center_of_buoyancy)]
    cfg[CFG_A:CFG_A + 48] = allocation_matrix(params.length, params.width).reshape(-1)
    cfg[CFG_H] = h
    cfg[CFG_DECAY] = decay
    cfg[CFG_MAX_MOVE] = params.tilt_rate_limit * h
    cfg[CFG_RK4] = 1.0 if rk4 else 0.0
    cfg[CFG_RANDOM] = 1.0 if random else 0.0
    cfg[CFG_PHI:CFG_PHI + 3] = phi
    cfg[CFG_GAIN:CFG_GAIN + 3] = gain
    cfg[CFG_MEAN:CFG_MEAN + 3] = mean
    return cfg


# --------------------------------------------------------------------------- kernels

@kernel()
def derivative(x: FloatArray, xo: int, tau: FloatArray, vc: FloatArray, cfg: FloatArray,
               out: FloatArray, oo: int) -> None:  # pragma: no cover - compiled
    """x_dot of :class:`~tiltrov_ros.core.dynamics.RigidBody` for x[xo:xo + 13], into
    out[oo:oo + 13] (every line mirrors a line there)."""
    qw, qx, qy, qz = x[xo + 3], x[xo + 4], x[xo + 5], x[xo + 6]
    u, v, w = x[xo + 7], x[xo + 8], x[xo + 9]
    p, q, r = x[xo + 10], x[xo + 11], x[xo + 12]
    # R(q) for q / |q| (Fossen 2021, Sec. 2.2.2).
    s = 2.0 / (qw * qw + qx * qx + qy * qy + qz * qz)
    xx, yy, zz = qx * qx, qy * qy, qz * qz
    xy, xz, yz = qx * qy, qx * qz, qy * qz
    wx, wy, wz = qw * qx, qw * qy, qw * qz
    R11, R12, R13 = 1.0 - s * (yy + zz), s * (xy - wz), s * (xz + wy)
    R21, R22, R23 = s * (xy + wz), 1.0 - s * (xx + zz), s * (yz - wx)
    R31, R32, R33 = s * (xz - wy), s * (yz + wx), 1.0 - s * (xx + yy)
    # (2): p_dot = R nu_1, q_dot = T(q) nu_2.
    out[oo + 0] = R11 * u + R12 * v + R13 * w
    out[oo + 1] = R21 * u + R22 * v + R23 * w
    out[oo + 2] = R31 * u + R32 * v + R33 * w
    out[oo + 3] = -0.5 * (qx * p + qy * q + qz * r)
    out[oo + 4] = 0.5 * (qw * p - qz * q + qy * r)
    out[oo + 5] = 0.5 * (qz * p + qw * q - qx * r)
    out[oo + 6] = 0.5 * (-qy * p + qx * q + qw * r)
    # nu_c = [R^T v_c; 0], nu_r = nu - nu_c.
    vc1, vc2, vc3 = vc[0], vc[1], vc[2]
    cu = R11 * vc1 + R21 * vc2 + R31 * vc3
    cv = R12 * vc1 + R22 * vc2 + R32 * vc3
    cw = R13 * vc1 + R23 * vc2 + R33 * vc3
    ur, vr, wr = u - cu, v - cv, w - cw
    # C(nu_r) nu_r of (A.3) = [omega x a; nu_r1 x a + omega x b].
    a1, a2, a3 = cfg[CFG_M] * ur, cfg[CFG_M + 1] * vr, cfg[CFG_M + 2] * wr
    b1, b2, b3 = cfg[CFG_M + 3] * p, cfg[CFG_M + 4] * q, cfg[CFG_M + 5] * r
    C1 = q * a3 - r * a2
    C2 = r * a1 - p * a3
    C3 = p * a2 - q * a1
    C4 = vr * a3 - wr * a2 + q * b3 - r * b2
    C5 = wr * a1 - ur * a3 + r * b1 - p * b3
    C6 = ur * a2 - vr * a1 + p * b2 - q * b1
    # (1) with D of (A.4) plus linear and g(eta) = -[(W - B) k; c x k], k = R^T e_3.
    im, dq, dl = CFG_INV_M, CFG_DQ, CFG_DL
    wmb = cfg[CFG_WMB]
    c1, c2, c3 = cfg[CFG_C], cfg[CFG_C + 1], cfg[CFG_C + 2]
    out[oo + 7] = (cfg[im] * (tau[0] - C1 - (cfg[dq] * math.fabs(ur) + cfg[dl]) * ur
                              + wmb * R31) - (q * cw - r * cv))
    out[oo + 8] = (cfg[im + 1] * (tau[1] - C2 - (cfg[dq + 1] * math.fabs(vr) + cfg[dl + 1]) * vr
                                  + wmb * R32) - (r * cu - p * cw))
    out[oo + 9] = (cfg[im + 2] * (tau[2] - C3 - (cfg[dq + 2] * math.fabs(wr) + cfg[dl + 2]) * wr
                                  + wmb * R33) - (p * cv - q * cu))
    out[oo + 10] = cfg[im + 3] * (tau[3] - C4 - (cfg[dq + 3] * math.fabs(p) + cfg[dl + 3]) * p
                                  + (c2 * R33 - c3 * R32))
    out[oo + 11] = cfg[im + 4] * (tau[4] - C5 - (cfg[dq + 4] * math.fabs(q) + cfg[dl + 4]) * q
                                  + (c3 * R31 - c1 * R33))
    out[oo + 12] = cfg[im + 5] * (tau[5] - C6 - (cfg[dq + 5] * math.fabs(r) + cfg[dl + 5]) * r
                                  + (c1 * R32 - c2 * R31))


@kernel()
def thrust_wrench(thr: FloatArray, srv: FloatArray, cfg: FloatArray,
                  out: FloatArray) -> None:  # pragma: no cover - compiled
    """Eq. (4) of the actual thrusts and tilts as A q of eq. (5), into out[0:6]."""
    sa, ca = math.sin(srv[TILT]), math.cos(srv[TILT])
    sb, cb = math.sin(srv[TILT + 1]), math.cos(srv[TILT + 1])
    f1, f2, f3, f4 = thr[THRUST], thr[THRUST + 1], thr[THRUST + 2], thr[THRUST + 3]
    q0, q1, q2, q3 = f1 * sa, f2 * sa, f3 * sb, f4 * sb
    q4, q5, q6, q7 = f1 * ca, f2 * ca, f3 * cb, f4 * cb
    for i in range(6):
        a = CFG_A + 8 * i
        out[i] = (cfg[a] * q0 + cfg[a + 1] * q1 + cfg[a + 2] * q2 + cfg[a + 3] * q3
                  + cfg[a + 4] * q4 + cfg[a + 5] * q5 + cfg[a + 6] * q6 + cfg[a + 7] * q7)


@kernel('void(int64, int64, int64, float64[::1], float64[::1], float64[::1], float64[::1], '
        'float64[::1], float64[:, ::1], int64, float64[:, ::1], float64[:, ::1], float64[::1])',
        group='plant')
def plant_steps(n: int, t0_ns: int, step_ns: int, x: FloatArray, thr: FloatArray,
                srv: FloatArray, cur: FloatArray, cfg: FloatArray, ext: FloatArray,
                ext_stride: int, noise: FloatArray, log: FloatArray,
                work: FloatArray) -> None:  # pragma: no cover - compiled
    """n plant steps from t0_ns (see :mod:`tiltrov_ros.core.plant` for one step).

    x (13), thr, srv, cur: the state arrays, updated in place. ext: the external
    wrench of step k in row k * ext_stride (stride 0: constant). noise: row k the
    normal draws of step k (used when the current is random). log: row k gets
    the sample after step k when it has rows (else nothing is logged). work:
    float64[WORK_SIZE] scratch.
    """
    h = cfg[CFG_H]
    hh = 0.5 * h
    h6 = h / 6.0
    rk4 = cfg[CFG_RK4] > 0.5
    decay = cfg[CFG_DECAY]
    max_move = cfg[CFG_MAX_MOVE]
    tau_o = 65
    vc_o = 71
    tau = work[tau_o:tau_o + 6]
    vc = work[vc_o:vc_o + 3]
    for k in range(n):
        # 1. The actuators' wrench (4) plus the external one at t_k, held over the step.
        thrust_wrench(thr, srv, cfg, tau)
        row = k * ext_stride
        for i in range(6):
            tau[i] = tau[i] + ext[row, i]
        for i in range(3):
            vc[i] = cur[CURRENT_VELOCITY + i]
        # 2. The rigid body: RK4 (k1..k4 at work[0:52], the stage state at work[52:65]).
        if rk4:
            derivative(x, 0, tau, vc, cfg, work, 0)
            for i in range(13):
                work[52 + i] = x[i] + hh * work[i]
            derivative(work, 52, tau, vc, cfg, work, 13)
            for i in range(13):
                work[52 + i] = x[i] + hh * work[13 + i]
            derivative(work, 52, tau, vc, cfg, work, 26)
            for i in range(13):
                work[52 + i] = x[i] + h * work[26 + i]
            derivative(work, 52, tau, vc, cfg, work, 39)
            for i in range(13):
                x[i] = x[i] + h6 * (work[i] + 2.0 * work[13 + i] + 2.0 * work[26 + i]
                                    + work[39 + i])
        else:
            derivative(x, 0, tau, vc, cfg, work, 0)
            for i in range(13):
                x[i] = x[i] + h * work[i]
        inv = 1.0 / math.sqrt(x[3] * x[3] + x[4] * x[4] + x[5] * x[5] + x[6] * x[6])
        for i in range(3, 7):
            x[i] = x[i] * inv
        # 3. Actuators toward the held commands (failed thrusters toward zero) ...
        for i in range(4):
            c = thr[THRUST_CMD + i] if thr[THRUST_WORKING + i] > 0.5 else 0.0
            thr[THRUST + i] = c + (thr[THRUST + i] - c) * decay
        for j in range(2):
            a = srv[TILT + j]
            c = srv[TILT_CMD + j]
            if math.fabs(c - a) <= max_move:
                new = c
            else:
                new = a + math.copysign(max_move, c - a)
            srv[TILT_VELOCITY + j] = (new - a) / h
            srv[TILT + j] = new
        # ... and the current's Gauss-Markov part to t_{k+1}.
        if cfg[CFG_RANDOM] > 0.5:
            for i in range(3):
                b = cfg[CFG_PHI + i] * cur[CURRENT_B + i] + cfg[CFG_GAIN + i] * noise[k, i]
                cur[CURRENT_B + i] = b
                cur[CURRENT_VELOCITY + i] = cfg[CFG_MEAN + i] + b
        if log.shape[0] > 0:
            log[k, LOG_T] = float(t0_ns + (k + 1) * step_ns) / 1e9
            for i in range(13):
                log[k, LOG_X + i] = x[i]
            for j in range(2):
                log[k, LOG_TILTS + j] = srv[TILT + j]
                log[k, LOG_TILT_VELOCITIES + j] = srv[TILT_VELOCITY + j]
            for i in range(4):
                log[k, LOG_THRUSTS + i] = thr[THRUST + i]
