"""The robot scene of ``robot_markers`` compiled: every number the markers show, in one kernel.

Mirrors :func:`tiltrov_ros.core.visual.robot_scene` (the numpy reference: the
normalized quaternion, ``Rquat``, eq. (4)'s thruster positions and directions
rotated into ``odom_ned``, :func:`~tiltrov_ros.core.visual.quat_from_z`, the
arrows), which stays the reference; a test pins this kernel to it (1e-12
relative). The plant publishes the markers every ``markers_period`` of sim
time, tens to hundreds of times per wall second in lockstep: the reference's
forty-odd small numpy calls took 60-100 us each time, the kernel a few.

Python ends in :func:`tiltrov_ros.core.visual.robot_scene_values`: it packs the
inputs into one array (:data:`IN_SIZE`), checks the quaternion, makes one call
and returns the flat values in :data:`~tiltrov_ros.core.visual.SCENE_FIELDS`
order.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core.jit import kernel

FloatArray = NDArray[np.float64]

# inputs: float64[IN_SIZE]
IN_LENGTH = 0              # l [m]
IN_WIDTH = 1               # d [m]
IN_POSITION = 2            # 3 entries: NED [m]
IN_QUATERNION = 5          # 4 entries: w x y z (any norm but zero)
IN_TILTS = 9               # 2 entries: actual tilt_front, tilt_rear [rad]
IN_THRUSTS = 11            # 4 entries: actual thrusts [N]
IN_COMMANDED_TILTS = 15    # 2 entries
IN_COMMANDED_THRUSTS = 17  # 4 entries
IN_WRENCH_CMD = 21         # 6 entries: X Y Z K M N
IN_WRENCH_ACHIEVED = 27    # 6 entries
IN_SCALES = 33             # 3 entries: m per N of thrust and force, m per N m of moment
IN_SIZE = 36

# out: float64[OUT_SIZE], the Scene's fields flat (visual.SCENE_FIELDS)
OUT_BODY_POSITION = 0
OUT_BODY_QUATERNION = 3
OUT_BODY_SIZE = 7
OUT_THRUSTER_POSITIONS = 10
OUT_THRUSTER_QUATERNIONS = 22
OUT_THRUST_ACTUAL = 38
OUT_THRUST_COMMANDED = 62
OUT_FORCE_DEMANDED = 86
OUT_FORCE_ACHIEVED = 92
OUT_MOMENT_DEMANDED = 98
OUT_MOMENT_ACHIEVED = 104
OUT_SIZE = 110

#: visual.BODY_MARGIN and BODY_HEIGHT, thrust_map.SQRT1_2 (constants of the reference).
_MARGIN_L, _MARGIN_D, _HEIGHT = 0.2, 0.1, 0.25
_SQRT1_2 = math.sqrt(0.5)


@kernel('void(float64[::1], float64[::1])', group='visual')
def scene_kernel(inputs: FloatArray, out: FloatArray) -> None:
    """The scene of ``inputs`` (see :data:`IN_SIZE`) into ``out`` (:data:`OUT_SIZE`)."""
    half_l, half_d = 0.5 * inputs[IN_LENGTH], 0.5 * inputs[IN_WIDTH]
    p = inputs[IN_POSITION:IN_POSITION + 3]
    q = inputs[IN_QUATERNION:IN_QUATERNION + 4]
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    w, x, y, z = q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm
    # Rquat: I + (2 / |q|^2) (w S(eps) + S(eps)^2), eps = (x, y, z)
    s2 = 2.0 / (w * w + x * x + y * y + z * z)
    r00, r01, r02 = 1.0 + s2 * (-z * z - y * y), s2 * (-w * z + x * y), s2 * (w * y + x * z)
    r10, r11, r12 = s2 * (w * z + x * y), 1.0 + s2 * (-z * z - x * x), s2 * (-w * x + y * z)
    r20, r21, r22 = s2 * (-w * y + x * z), s2 * (w * x + y * z), 1.0 + s2 * (-y * y - x * x)
    for j in range(3):
        out[OUT_BODY_POSITION + j] = p[j]
    out[OUT_BODY_QUATERNION] = w
    out[OUT_BODY_QUATERNION + 1] = x
    out[OUT_BODY_QUATERNION + 2] = y
    out[OUT_BODY_QUATERNION + 3] = z
    out[OUT_BODY_SIZE] = inputs[IN_LENGTH] + _MARGIN_L
    out[OUT_BODY_SIZE + 1] = inputs[IN_WIDTH] + _MARGIN_D
    out[OUT_BODY_SIZE + 2] = _HEIGHT
    at = OUT_THRUSTER_POSITIONS
    for i in range(4):
        # thrust_map.thruster_positions (front-left, front-right, rear-right, rear-left),
        # rotated into odom_ned: p + R r_i
        rx = half_l if i < 2 else -half_l
        ry = -half_d if i == 0 or i == 3 else half_d
        out[at + 3 * i] = p[0] + (r00 * rx + r01 * ry + r02 * 0.0)
        out[at + 3 * i + 1] = p[1] + (r10 * rx + r11 * ry + r12 * 0.0)
        out[at + 3 * i + 2] = p[2] + (r20 * rx + r21 * ry + r22 * 0.0)
    for arrows in range(2):
        tilts = IN_TILTS if arrows == 0 else IN_COMMANDED_TILTS
        thrusts = IN_THRUSTS if arrows == 0 else IN_COMMANDED_THRUSTS
        base = OUT_THRUST_ACTUAL if arrows == 0 else OUT_THRUST_COMMANDED
        for i in range(4):
            # thrust_map.thruster_directions (eq. (4)), rotated into odom_ned: R h_i
            tilt = inputs[tilts + (0 if i < 2 else 1)]
            c = math.cos(tilt)
            hx, hy, hz = c * _SQRT1_2, c * _SQRT1_2 * (1.0 if i % 2 == 0 else -1.0), -math.sin(tilt)
            ax = r00 * hx + r01 * hy + r02 * hz
            ay = r10 * hx + r11 * hy + r12 * hz
            az = r20 * hx + r21 * hy + r22 * hz
            force = inputs[IN_SCALES] * inputs[thrusts + i]
            for j in range(3):
                out[base + 6 * i + j] = out[at + 3 * i + j]
            out[base + 6 * i + 3] = out[at + 3 * i] + force * ax
            out[base + 6 * i + 4] = out[at + 3 * i + 1] + force * ay
            out[base + 6 * i + 5] = out[at + 3 * i + 2] + force * az
            if arrows == 0:
                _quat_from_z(ax, ay, az, out, OUT_THRUSTER_QUATERNIONS + 4 * i)
    for k in range(4):
        # the demanded and achieved force (k 0, 1) and moment (k 2, 3) from the body origin
        vector = (IN_WRENCH_CMD, IN_WRENCH_ACHIEVED, IN_WRENCH_CMD + 3,
                  IN_WRENCH_ACHIEVED + 3)[k]
        scale = inputs[IN_SCALES + 1] if k < 2 else inputs[IN_SCALES + 2]
        base = (OUT_FORCE_DEMANDED, OUT_FORCE_ACHIEVED, OUT_MOMENT_DEMANDED,
                OUT_MOMENT_ACHIEVED)[k]
        v0, v1, v2 = inputs[vector], inputs[vector + 1], inputs[vector + 2]
        for j in range(3):
            out[base + j] = p[j]
        out[base + 3] = p[0] + scale * (r00 * v0 + r01 * v1 + r02 * v2)
        out[base + 4] = p[1] + scale * (r10 * v0 + r11 * v1 + r12 * v2)
        out[base + 5] = p[2] + scale * (r20 * v0 + r21 * v1 + r22 * v2)


@kernel()
def _quat_from_z(dx: float, dy: float, dz: float, out: FloatArray, at: int) -> None:
    """visual.quat_from_z of the unit (dx, dy, dz) into ``out[at:at + 4]``."""
    if dz < -1.0 + 1e-12:                   # opposite: half a turn about x
        out[at], out[at + 1], out[at + 2], out[at + 3] = 0.0, 1.0, 0.0, 0.0
        return
    a, b, c = 1.0 + dz, -dy, dx
    n = math.sqrt(a * a + b * b + c * c + 0.0 * 0.0)
    out[at], out[at + 1], out[at + 2], out[at + 3] = a / n, b / n, c / n, 0.0 / n
