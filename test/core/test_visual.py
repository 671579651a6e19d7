"""The geometry of robot_markers: where the body, thrusters and arrows are in odom_ned."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tiltrov_ros.core.kinematics import Rquat, quat_from_euler
from tiltrov_ros.core.thrust_map import thrust_wrench
from tiltrov_ros.core.visual import Scales, quat_from_z, robot_scene

L, D = 0.6, 0.4


@pytest.mark.parametrize('direction', [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 1, 0],
                                       [0.6, -0.8, 0.0], [0.36, 0.48, -0.8]])
def test_quat_from_z_turns_the_z_axis_onto_the_direction(direction) -> None:
    d = np.array(direction, dtype=float)
    np.testing.assert_allclose(Rquat(quat_from_z(d)) @ [0.0, 0.0, 1.0], d, atol=1e-12)


def _scene(**changes):
    values = dict(tilts=[math.pi / 2, -0.3], thrusts=[10.0, 20.0, -5.0, 0.0],
                  commanded_tilts=[0.2, 0.1], commanded_thrusts=[1.0, 2.0, 3.0, 4.0],
                  wrench_cmd=[1.0, 2.0, 3.0, 0.1, 0.2, 0.3],
                  wrench_achieved=[1.0, 2.0, 2.5, 0.1, 0.2, 0.0])
    values.update(changes)
    q = quat_from_euler(0.1, -0.2, 0.7)
    return q, robot_scene([1.0, -2.0, 3.0], q, L, D, scales=Scales(0.01, 0.005, 0.02),
                          **values)


def test_body_and_thrusters_sit_where_the_pose_puts_them() -> None:
    q, scene = _scene()
    R = Rquat(q)
    np.testing.assert_allclose(scene.body_position, [1.0, -2.0, 3.0])
    np.testing.assert_allclose(scene.body_size, [L + 0.2, D + 0.1, 0.25])
    # thruster_1 front-left (+l/2, -d/2, 0) in the body, rotated and moved.
    np.testing.assert_allclose(scene.thruster_positions[0],
                               [1.0, -2.0, 3.0] + R @ [L / 2, -D / 2, 0.0], atol=1e-12)
    # At +90 deg the front thrusters push up: -z of the body.
    axis = Rquat(scene.thruster_quaternions[0]) @ [0.0, 0.0, 1.0]
    np.testing.assert_allclose(axis, R @ [0.0, 0.0, -1.0], atol=1e-12)


def test_thrust_arrows_sum_to_the_force_of_eq_4() -> None:
    """Each arrow is scale x thrust along the thruster's direction, so the arrows,
    rotated back into the body, add up to the force part of eq. (4)."""
    q, scene = _scene()
    R = Rquat(q)
    for arrows, thrusts, tilts in ((scene.thrust_actual, [10.0, 20.0, -5.0, 0.0],
                                    (math.pi / 2, -0.3)),
                                   (scene.thrust_commanded, [1.0, 2.0, 3.0, 4.0], (0.2, 0.1))):
        np.testing.assert_allclose(arrows[:, 0], scene.thruster_positions)
        body_force = R.T @ (arrows[:, 1] - arrows[:, 0]).sum(axis=0) / 0.01
        np.testing.assert_allclose(body_force, thrust_wrench(thrusts, *tilts, L, D)[:3],
                                   atol=1e-9)


def test_wrench_arrows_start_at_the_body_and_point_as_the_body_wrench() -> None:
    q, scene = _scene()
    R = Rquat(q)
    for ends, vector, scale in ((scene.force_demanded, [1.0, 2.0, 3.0], 0.005),
                                (scene.force_achieved, [1.0, 2.0, 2.5], 0.005),
                                (scene.moment_demanded, [0.1, 0.2, 0.3], 0.02),
                                (scene.moment_achieved, [0.1, 0.2, 0.0], 0.02)):
        np.testing.assert_allclose(ends[0], [1.0, -2.0, 3.0])
        np.testing.assert_allclose(ends[1] - ends[0], scale * (R @ vector), atol=1e-12)
