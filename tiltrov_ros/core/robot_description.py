"""The robot as a URDF, and the transforms of its thruster links at given tilts.

One description of the robot's kinematics for every viewer, generated from the
robot in use (:class:`~tiltrov_ros.core.params.RobotParams`: the spacings l and
d, the tilt range and rate), so a robot file with other limits gets its own:

* the root link is ``base_link_frd``, the body (the plant publishes ``odom ->
  base_link -> base_link_frd`` itself, REP-105), drawn as the hull box of
  ``robot_markers``;
* each thruster is a link ``thruster_i_link`` at r_i of eq. (4)
  (:func:`~tiltrov_ros.core.thrust_map.thruster_positions`) with its x axis
  along the thrust, drawn as the thruster cylinder of ``robot_markers``;
* ``tilt_front`` turns ``thruster_1_link`` and ``tilt_rear`` ``thruster_3_link``
  (the joints of ``joint_states``); ``tilt_front_thruster_2`` and
  ``tilt_rear_thruster_4`` mimic them, since one servo turns both thrusters of
  a pair but each about its own axis.

Each joint frame sits at r_i, turned about the body's z axis by the yaw of the
thruster's horizontal direction h_i at tilt 0
(:func:`~tiltrov_ros.core.thrust_map.thruster_directions`), so its x axis is h_i
and its z axis the body's z (down). The joint turns about that frame's y axis
(z x h_i): a tilt gamma takes x to ``cos(gamma) h_i + sin(gamma) (0, 0, -1)``,
the thrust direction of eq. (4) (positive tilt: thrust up). The link's
orientation in ``base_link_frd`` is therefore ``q_z(yaw_i) q_y(gamma)``
(:func:`link_quaternions`), which is what robot_state_publisher computes from
the URDF and what the plant publishes where robot_state_publisher is absent.

Pure Python and numpy: text out, no ROS.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
import sys

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core.names import FRAME_BODY, THRUSTER_LINKS, TILT_MIMICS, TILTS
from tiltrov_ros.core.params import RobotParams, load_robot_params
from tiltrov_ros.core.thrust_map import (
    THRUSTER_TILT_INDEX,
    thruster_directions,
    thruster_positions,
)
from tiltrov_ros.core.visual import HULL_RGBA, THRUSTER_RGBA, THRUSTER_SIZE, body_size

FloatArray = NDArray[np.float64]

#: The robot's name in the URDF.
ROBOT_NAME = 'tiltrov'
#: The joint axis in each joint frame (z x h_i: see the module docstring).
TILT_AXIS = (0.0, 1.0, 0.0)
#: The shipped URDF of ``config/robot.yaml`` (``urdf/`` in the package's share).
URDF_FILE = 'tiltrov.urdf'


@dataclass(frozen=True)
class TiltJoint:
    """One thruster's joint: its name, link, the joint it mimics and its frame."""

    name: str                               # tilt_front, tilt_front_thruster_2, ...
    link: str                               # thruster_i_link
    mimic: str | None                       # the tilt joint it follows, or None
    tilt: int                               # 0: tilt_front (alpha), 1: tilt_rear (beta)
    position: tuple[float, float, float]    # r_i in base_link_frd, m
    yaw: float                              # of h_i about the body's z, rad


def tilt_joints(length: float, width: float) -> tuple[TiltJoint, ...]:
    """The four thrusters' joints (thruster_1 .. thruster_4) for spacings l and d."""
    positions = thruster_positions(length, width)
    horizontal = thruster_directions(0.0, 0.0)
    names = (TILTS[0], TILT_MIMICS[0], TILTS[1], TILT_MIMICS[1])
    out = []
    for i, (name, link) in enumerate(zip(names, THRUSTER_LINKS)):
        tilt = int(THRUSTER_TILT_INDEX[i])
        out.append(TiltJoint(
            name=name, link=link, mimic=None if name in TILTS else TILTS[tilt], tilt=tilt,
            position=(float(positions[i, 0]), float(positions[i, 1]), float(positions[i, 2])),
            yaw=math.atan2(float(horizontal[i, 1]), float(horizontal[i, 0]))))
    return tuple(out)


def link_quaternions(joints: tuple[TiltJoint, ...], tilt_front: float, tilt_rear: float
                     ) -> FloatArray:
    """Orientation (w, x, y, z) of each thruster link in ``base_link_frd`` at the tilts,
    shape (4, 4): ``q_z(yaw) q_y(gamma)`` written out (:func:`link_quaternion_values`)."""
    return np.array(link_quaternion_values(joints, tilt_front, tilt_rear)).reshape(-1, 4)


def link_quaternion_values(joints: tuple[TiltJoint, ...], tilt_front: float,
                           tilt_rear: float) -> list[float]:
    """:func:`link_quaternions` as one flat list of plain floats (w, x, y, z of each link
    in turn: what the plant writes into /tf at every step)."""
    out: list[float] = []
    half = (0.5 * tilt_front, 0.5 * tilt_rear)
    for joint in joints:
        cz, sz = math.cos(0.5 * joint.yaw), math.sin(0.5 * joint.yaw)
        cy, sy = math.cos(half[joint.tilt]), math.sin(half[joint.tilt])
        out += (cz * cy, -sz * sy, cz * sy, sz * cy)
    return out


def _numbers(values: tuple[float, ...] | list[float]) -> str:
    """Space-separated floats, exactly (repr: the shortest text that reads back equal)."""
    return ' '.join(repr(float(v)) for v in values)


def robot_urdf(robot: RobotParams, *, source: str = '') -> str:
    """The URDF of ``robot`` (see the module docstring); ``source`` names its file."""
    hull = body_size(robot.length, robot.width)
    radius, length = 0.5 * THRUSTER_SIZE[0], THRUSTER_SIZE[1]
    lines = [
        '<?xml version="1.0"?>',
        '<!-- Generated by tiltrov_ros (tiltrov_ros/core/robot_description.py) from the robot',
        f'     parameters{f" of {source}" if source else ""}: regenerate, do not edit.',
        '     Frames FRD (x forward, y starboard, z down); each thruster link\'s x axis is its',
        '     thrust at the tilt (eq. (4)); a positive tilt points the thrust up. The servos',
        '     are rate-limited position servos: their torque is not modelled (effort 0). -->',
        f'<robot name="{ROBOT_NAME}">',
        f'  <material name="hull"><color rgba="{_numbers(HULL_RGBA)}"/></material>',
        f'  <material name="thruster"><color rgba="{_numbers(THRUSTER_RGBA)}"/></material>',
        f'  <link name="{FRAME_BODY}">',
        '    <visual>',
        f'      <geometry><box size="{_numbers(list(hull))}"/></geometry>',
        '      <material name="hull"/>',
        '    </visual>',
        '  </link>',
    ]
    for joint in tilt_joints(robot.length, robot.width):
        lines += [
            f'  <link name="{joint.link}">',
            '    <visual>',
            f'      <origin xyz="0.0 0.0 0.0" rpy="{_numbers((0.0, 0.5 * math.pi, 0.0))}"/>',
            f'      <geometry><cylinder radius="{radius!r}" length="{length!r}"/></geometry>',
            '      <material name="thruster"/>',
            '    </visual>',
            '  </link>',
            f'  <joint name="{joint.name}" type="revolute">',
            f'    <parent link="{FRAME_BODY}"/>',
            f'    <child link="{joint.link}"/>',
            f'    <origin xyz="{_numbers(joint.position)}" '
            f'rpy="{_numbers((0.0, 0.0, joint.yaw))}"/>',
            f'    <axis xyz="{_numbers(TILT_AXIS)}"/>',
            f'    <limit lower="{robot.tilt_min!r}" upper="{robot.tilt_max!r}" '
            f'velocity="{robot.tilt_rate_limit!r}" effort="0.0"/>',
        ]
        if joint.mimic is not None:
            lines.append(f'    <mimic joint="{joint.mimic}" multiplier="1.0" offset="0.0"/>')
        lines.append('  </joint>')
    lines.append('</robot>')
    return '\n'.join(lines) + '\n'


def main(argv: list[str] | None = None) -> int:
    """``python -m tiltrov_ros.core.robot_description [ROBOT_FILE] OUT``: write the URDF
    of a robot file (default: the shipped ``config/robot.yaml``); ``make docs`` writes
    ``urdf/tiltrov.urdf`` with it."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) not in (1, 2):
        print(main.__doc__, file=sys.stderr)
        return 2
    robot_file = args[0] if len(args) == 2 else None
    text = robot_urdf(load_robot_params(robot_file),
                      source=robot_file or 'config/robot.yaml')
    with open(args[-1], 'w', encoding='utf-8') as stream:
        stream.write(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
