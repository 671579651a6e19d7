"""What the robot looks like in the earth frame: the geometry of ``robot_markers``.

From the pose (``odom``), the actual tilts and thrusts (``joint_states``), the
commanded ones (``tilt_cmd``, ``thrust_cmd``) and the demanded and achieved
wrench (``wrench_cmd``, ``wrench_achieved``), :func:`robot_scene` places, in
``odom_ned``:

* the body, a box around the thrusters (l + 0.2 m by d + 0.1 m by 0.25 m);
* each thruster, a cylinder at r_i (``thrust_map.thruster_positions``) along its
  thrust direction at its actual tilt (``thrust_map.thruster_directions``, eq. (4));
* an arrow per thruster for the actual thrust and one for the commanded thrust
  (at the commanded tilt), ``thrust_scale`` m per N;
* the demanded and achieved force (``force_scale`` m per N) and moment
  (``moment_scale`` m per N m) as arrows from the body origin, rotated into
  the earth frame.

Pure numpy; the visualizer node turns a :class:`Scene` into messages. The plant
takes the scene's numbers flat (:func:`robot_scene_values`, in
:data:`SCENE_FIELDS` order), from a compiled kernel when the kernels run
(:mod:`tiltrov_ros.core.visual_kernels`; :func:`robot_scene` is its reference).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math
from typing import cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tiltrov_ros.core import jit
from tiltrov_ros.core.kinematics import Rquat, quat_normalize
from tiltrov_ros.core.thrust_map import thruster_directions, thruster_positions

FloatArray = NDArray[np.float64]

#: m added to l, d around the thrusters, and the body's height (a drawing, not the model).
BODY_MARGIN = (0.2, 0.1)
BODY_HEIGHT = 0.25
#: m: each thruster drawn as a cylinder (diameter, length) along its thrust.
THRUSTER_SIZE = (0.09, 0.12)
#: RGBA of the hull and of the thrusters: robot_markers and the URDF draw them alike.
HULL_RGBA = (0.55, 0.6, 0.7, 0.6)
THRUSTER_RGBA = (0.15, 0.15, 0.15, 1.0)


def body_size(length: float, width: float) -> FloatArray:
    """The hull's box (along the body's x, y, z), m, for thruster spacings l and d."""
    return np.array([length + BODY_MARGIN[0], width + BODY_MARGIN[1], BODY_HEIGHT])


@dataclass(frozen=True)
class Scales:
    """Arrow lengths: m per N of thrust and force, m per N m of moment."""

    thrust: float = 0.01
    force: float = 0.005
    moment: float = 0.02


@dataclass(frozen=True)
class Scene:
    """The robot in the earth frame (every point in ``odom_ned``, m)."""

    body_position: FloatArray          # (3,)
    body_quaternion: FloatArray        # (4,) w x y z
    body_size: FloatArray              # (3,) along the body's x, y, z
    thruster_positions: FloatArray     # (4, 3)
    thruster_quaternions: FloatArray   # (4, 4): a cylinder's z axis along the thrust
    thrust_actual: FloatArray          # (4, 2, 3): start and end of each arrow
    thrust_commanded: FloatArray       # (4, 2, 3)
    force_demanded: FloatArray         # (2, 3)
    force_achieved: FloatArray         # (2, 3)
    moment_demanded: FloatArray        # (2, 3)
    moment_achieved: FloatArray        # (2, 3)


def quat_from_z(direction: ArrayLike) -> FloatArray:
    """The shortest rotation (w, x, y, z) taking the z axis to the unit ``direction``."""
    d = np.asarray(direction, dtype=float)
    if d[2] < -1.0 + 1e-12:                 # opposite: half a turn about x
        return np.array([0.0, 1.0, 0.0, 0.0])
    return quat_normalize(np.array([1.0 + d[2], -d[1], d[0], 0.0]))


def robot_scene(position: ArrayLike, quaternion: ArrayLike, length: float, width: float, *,
                tilts: ArrayLike, thrusts: ArrayLike, commanded_tilts: ArrayLike,
                commanded_thrusts: ArrayLike, wrench_cmd: ArrayLike,
                wrench_achieved: ArrayLike, scales: Scales = Scales()) -> Scene:
    """The :class:`Scene` of one state (see the module docstring)."""
    p = np.asarray(position, dtype=float)
    q = quat_normalize(quaternion)
    R = Rquat(q)
    at = p + thruster_positions(length, width) @ R.T

    def arrows(tilt: ArrayLike, force: ArrayLike) -> FloatArray:
        a = np.asarray(tilt, dtype=float)
        along = thruster_directions(float(a[0]), float(a[1])) @ R.T
        ends = at + scales.thrust * np.asarray(force, dtype=float)[:, None] * along
        return np.stack([at, ends], axis=1)

    def from_body(vector: FloatArray, scale: float) -> FloatArray:
        return np.stack([p, p + scale * (R @ vector)])

    a = np.asarray(tilts, dtype=float)
    directions = thruster_directions(float(a[0]), float(a[1])) @ R.T
    demanded = np.asarray(wrench_cmd, dtype=float)
    achieved = np.asarray(wrench_achieved, dtype=float)
    return Scene(
        body_position=p, body_quaternion=q,
        body_size=body_size(length, width),
        thruster_positions=at,
        thruster_quaternions=np.array([quat_from_z(d) for d in directions]),
        thrust_actual=arrows(tilts, thrusts),
        thrust_commanded=arrows(commanded_tilts, commanded_thrusts),
        force_demanded=from_body(demanded[:3], scales.force),
        force_achieved=from_body(achieved[:3], scales.force),
        moment_demanded=from_body(demanded[3:], scales.moment),
        moment_achieved=from_body(achieved[3:], scales.moment))


#: The Scene's fields in the order of their numbers in :func:`scene_values` (the body's
#: size too: it is the robot's), and their shapes.
SCENE_FIELDS = ('body_position', 'body_quaternion', 'body_size', 'thruster_positions',
                'thruster_quaternions', 'thrust_actual', 'thrust_commanded', 'force_demanded',
                'force_achieved', 'moment_demanded', 'moment_achieved')
SCENE_SHAPES = {'body_position': (3,), 'body_quaternion': (4,), 'body_size': (3,),
                'thruster_positions': (4, 3), 'thruster_quaternions': (4, 4),
                'thrust_actual': (4, 2, 3), 'thrust_commanded': (4, 2, 3),
                'force_demanded': (2, 3), 'force_achieved': (2, 3), 'moment_demanded': (2, 3),
                'moment_achieved': (2, 3)}
#: Numbers in a scene (110).
SCENE_SIZE = sum(math.prod(shape) for shape in SCENE_SHAPES.values())


def scene_values(scene: Scene) -> FloatArray:
    """Every number of ``scene``, flat, in :data:`SCENE_FIELDS` order."""
    return np.concatenate([np.asarray(getattr(scene, f), dtype=float).ravel()
                           for f in SCENE_FIELDS])


def scene_of(values: ArrayLike) -> Scene:
    """The :class:`Scene` of :func:`scene_values`' numbers."""
    flat = np.asarray(values, dtype=float)
    parts, start = {}, 0
    for f in SCENE_FIELDS:
        n = math.prod(SCENE_SHAPES[f])
        parts[f] = flat[start:start + n].reshape(SCENE_SHAPES[f])
        start += n
    return Scene(**parts)


def robot_scene_values(position: ArrayLike, quaternion: ArrayLike, length: float,
                       width: float, *, tilts: ArrayLike, thrusts: ArrayLike,
                       commanded_tilts: ArrayLike, commanded_thrusts: ArrayLike,
                       wrench_cmd: ArrayLike, wrench_achieved: ArrayLike,
                       scales: Scales = Scales()) -> FloatArray:
    """``scene_values(robot_scene(...))``: compiled when the kernels run (one call of
    :func:`~tiltrov_ros.core.visual_kernels.scene_kernel`), else the reference. Raises
    ValueError for a quaternion that is zero or not finite, as :func:`robot_scene`."""
    if not jit.compiled():
        return scene_values(robot_scene(
            position, quaternion, length, width, tilts=tilts, thrusts=thrusts,
            commanded_tilts=commanded_tilts, commanded_thrusts=commanded_thrusts,
            wrench_cmd=wrench_cmd, wrench_achieved=wrench_achieved, scales=scales))
    from tiltrov_ros.core.visual_kernels import IN_SIZE, scene_kernel
    vectors = cast(tuple[Sequence[float], ...], (position, quaternion, tilts, thrusts,
                                                  commanded_tilts, commanded_thrusts,
                                                  wrench_cmd, wrench_achieved))
    inputs = np.array([length, width, *(v for vector in vectors for v in vector),
                       scales.thrust, scales.force, scales.moment], dtype=np.float64)
    if inputs.shape != (IN_SIZE,):
        raise ValueError(f'robot_scene_values: {inputs.shape[0]} numbers; {IN_SIZE} expected')
    norm = math.sqrt(sum(v * v for v in inputs[5:9].tolist()))
    if not math.isfinite(norm) or norm == 0.0:
        raise ValueError(f'not a valid quaternion: {inputs[5:9]!r}')
    out = np.empty(SCENE_SIZE)
    scene_kernel(inputs, out)
    return out
