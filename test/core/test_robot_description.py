"""The URDF against eq. (4): forward kinematics through the URDF's text at non-zero
tilts gives each thruster's position and thrust axis of the core's thrust map.

The kinematics here read the XML as robot_state_publisher does (joint origin
xyz and fixed-axis rpy, then the revolute axis by the joint's angle, mimic
joints by their multiplier and offset) and share no code with the generator;
the sign of the tilt axis in FRD is where a hand-written URDF goes wrong.
"""

from __future__ import annotations

from dataclasses import replace
import math
from pathlib import Path
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from tiltrov_ros.core.kinematics import Rquat
from tiltrov_ros.core.names import FRAME_BODY, THRUSTER_LINKS, TILTS
from tiltrov_ros.core.params import load_robot_params
from tiltrov_ros.core.robot_description import (
    URDF_FILE,
    link_quaternions,
    main,
    robot_urdf,
    tilt_joints,
)
from tiltrov_ros.core.thrust_map import thruster_directions, thruster_positions
from tiltrov_ros.paths import share_dir

#: (tilt_front, tilt_rear), rad: non-zero, unequal, both signs, past vertical for the
#: +-180 deg servos.
TILT_CASES = [(0.3, -1.1), (-0.7, 1.4), (1.5707963267948966, -0.2), (2.6, -3.0)]


def _rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF's rpy: fixed axes x, then y, then z (R = Rz Ry Rx)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: the rotation by ``angle`` about the unit ``axis``."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def _floats(text: str) -> list[float]:
    return [float(v) for v in text.split()]


def urdf_forward_kinematics(text: str, positions: dict[str, float]
                            ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Child link -> (origin, rotation) in the root link, for the actuated joints'
    ``positions`` (mimic joints follow theirs); every joint must hang off the root."""
    robot = ET.fromstring(text)
    joints = {j.get('name'): j for j in robot.iter('joint')}
    out = {}
    for name, joint in joints.items():
        assert joint.find('parent').get('link') == FRAME_BODY, name
        origin = joint.find('origin')
        xyz = np.array(_floats(origin.get('xyz')))
        rotation = _rpy(*_floats(origin.get('rpy')))
        mimic = joint.find('mimic')
        if mimic is None:
            angle = positions[name]
        else:
            angle = (float(mimic.get('multiplier', '1')) * positions[mimic.get('joint')]
                     + float(mimic.get('offset', '0')))
        axis = np.array(_floats(joint.find('axis').get('xyz')))
        out[joint.find('child').get('link')] = (xyz, rotation @ _about(axis, angle))
    return out


@pytest.fixture(scope='module')
def robot():
    return load_robot_params()


@pytest.mark.parametrize(('tilt_front', 'tilt_rear'), TILT_CASES)
def test_forward_kinematics_of_the_urdf_is_eq_4(robot, tilt_front: float,
                                                tilt_rear: float) -> None:
    """Each thruster link at r_i, its x axis along the thrust direction of eq. (4)."""
    robot = replace(robot, tilt_min=-math.pi, tilt_max=math.pi)
    links = urdf_forward_kinematics(robot_urdf(robot),
                                    {TILTS[0]: tilt_front, TILTS[1]: tilt_rear})
    assert sorted(links) == sorted(THRUSTER_LINKS)
    positions = thruster_positions(robot.length, robot.width)
    directions = thruster_directions(tilt_front, tilt_rear)
    for i, link in enumerate(THRUSTER_LINKS):
        origin, rotation = links[link]
        np.testing.assert_allclose(origin, positions[i], rtol=0, atol=1e-15, err_msg=link)
        np.testing.assert_allclose(rotation[:, 0], directions[i], rtol=0, atol=1e-12,
                                   err_msg=link)
        # the tilt turns the thrust about an axis that stays horizontal
        assert abs(rotation[2, 1]) < 1e-12, link


def test_a_positive_tilt_points_the_thrust_up(robot) -> None:
    """FRD: up is -z. At +90 deg every thruster's x axis is (0, 0, -1)."""
    links = urdf_forward_kinematics(robot_urdf(robot), dict.fromkeys(TILTS, math.pi / 2))
    for link in THRUSTER_LINKS:
        np.testing.assert_allclose(links[link][1][:, 0], [0.0, 0.0, -1.0], atol=1e-15)


@pytest.mark.parametrize(('tilt_front', 'tilt_rear'), TILT_CASES)
def test_the_plants_link_transforms_are_the_urdfs(robot, tilt_front: float,
                                                  tilt_rear: float) -> None:
    """What the plant publishes without robot_state_publisher (link_quaternions) is what
    robot_state_publisher computes from the URDF."""
    robot = replace(robot, tilt_min=-math.pi, tilt_max=math.pi)
    links = urdf_forward_kinematics(robot_urdf(robot),
                                    {TILTS[0]: tilt_front, TILTS[1]: tilt_rear})
    joints = tilt_joints(robot.length, robot.width)
    quaternions = link_quaternions(joints, tilt_front, tilt_rear)
    for joint, q in zip(joints, quaternions):
        origin, rotation = links[joint.link]
        np.testing.assert_allclose(joint.position, origin, rtol=0, atol=0)
        np.testing.assert_allclose(Rquat(q), rotation, rtol=0, atol=1e-12)
        assert abs(np.linalg.norm(q) - 1.0) < 1e-15


def test_the_urdf_names_the_joints_of_joint_states_and_the_robots_limits(robot) -> None:
    wide = replace(robot, tilt_min=-math.pi, tilt_max=math.pi, tilt_rate_limit=1.25)
    for params in (robot, wide):
        tree = ET.fromstring(robot_urdf(params))
        joints = {j.get('name'): j for j in tree.iter('joint')}
        actuated = [name for name, j in joints.items() if j.find('mimic') is None]
        assert actuated == list(TILTS)
        for joint in joints.values():
            assert joint.get('type') == 'revolute'
            limit = joint.find('limit')
            assert float(limit.get('lower')) == params.tilt_min
            assert float(limit.get('upper')) == params.tilt_max
            assert float(limit.get('velocity')) == params.tilt_rate_limit
        links = [link.get('name') for link in tree.iter('link')]
        assert links[0] == FRAME_BODY and sorted(links[1:]) == sorted(THRUSTER_LINKS)


def test_the_shipped_urdf_is_the_generators(tmp_path: Path) -> None:
    """urdf/tiltrov.urdf is config/robot.yaml's URDF (`make docs` writes it)."""
    out = tmp_path / URDF_FILE
    assert main([str(out)]) == 0
    assert (share_dir() / 'urdf' / URDF_FILE).read_text(encoding='utf-8') == out.read_text(
        encoding='utf-8')
