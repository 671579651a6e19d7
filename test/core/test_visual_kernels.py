"""robot_markers' scene compiled (core/visual_kernels.py) against its numpy reference
(core/visual.robot_scene), on seeded random states, tilts straight up and down included."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tiltrov_ros.core import jit
from tiltrov_ros.core.kinematics import quat_from_euler
from tiltrov_ros.core.visual import (
    SCENE_SIZE,
    Scales,
    robot_scene,
    robot_scene_values,
    scene_of,
    scene_values,
)

needs_kernels = pytest.mark.skipif(not jit.compiled(), reason='the numpy backend has no kernels')
RTOL = 1e-12


def _state(rng: np.random.Generator, tilts: tuple[float, float] | None = None
           ) -> tuple[tuple, dict]:
    """Any attitude and position, non-unit quaternions, tilts across +-pi, thrusts and
    wrenches of the stack's size."""
    q = quat_from_euler(*rng.uniform(-math.pi, math.pi, 3)) * rng.uniform(0.5, 2.0)
    args = (rng.normal(scale=5.0, size=3), q, rng.uniform(0.3, 1.2), rng.uniform(0.2, 0.8))
    kwargs = dict(tilts=rng.uniform(-math.pi, math.pi, 2) if tilts is None else tilts,
                  thrusts=rng.uniform(-40, 40, 4), commanded_tilts=rng.uniform(-3, 3, 2),
                  commanded_thrusts=rng.uniform(-40, 40, 4),
                  wrench_cmd=rng.normal(scale=30.0, size=6),
                  wrench_achieved=rng.normal(scale=30.0, size=6),
                  scales=Scales(*rng.uniform(0.001, 0.05, 3)))
    return args, kwargs


@needs_kernels
@pytest.mark.parametrize('seed', range(4))
def test_the_kernel_gives_the_reference_scene(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(250):
        args, kwargs = _state(rng)
        expected = scene_values(robot_scene(*args, **kwargs))
        got = robot_scene_values(*args, **kwargs)
        assert got.shape == (SCENE_SIZE,)
        np.testing.assert_allclose(got, expected, rtol=RTOL,
                                   atol=RTOL * max(1.0, float(np.max(np.abs(expected)))))


@needs_kernels
@pytest.mark.parametrize('tilts', [(math.pi / 2, -math.pi / 2), (-math.pi / 2, 0.0)])
def test_thrust_straight_down_or_up_at_a_level_body(tilts: tuple[float, float]) -> None:
    """A level body with a thruster along +-z of odom_ned: quat_from_z's half turn (the
    direction opposite to z) and its regular branch."""
    rng = np.random.default_rng(9)
    args, kwargs = _state(rng, tilts)
    args = (args[0], np.array([1.0, 0.0, 0.0, 0.0]), *args[2:])
    expected = scene_values(robot_scene(*args, **kwargs))
    np.testing.assert_allclose(robot_scene_values(*args, **kwargs), expected, rtol=RTOL,
                               atol=RTOL * float(np.max(np.abs(expected))))
    front = scene_of(expected).thruster_quaternions[:2]
    if tilts[0] > 0:        # thrust up = along -z (NED): the half turn
        assert (front == [0.0, 1.0, 0.0, 0.0]).all()
    else:                   # along +z: (almost) no turn
        np.testing.assert_allclose(front, [[1.0, 0.0, 0.0, 0.0]] * 2, atol=1e-15)


@pytest.mark.parametrize('quaternion', [[0.0] * 4, [math.nan, 1.0, 0.0, 0.0]])
def test_a_quaternion_that_is_none_is_refused_either_way(quaternion: list[float]) -> None:
    args, kwargs = _state(np.random.default_rng(1))
    with pytest.raises(ValueError, match='not a valid quaternion'):
        robot_scene_values(args[0], quaternion, *args[2:], **kwargs)


def test_scene_values_and_scene_of_are_inverse() -> None:
    args, kwargs = _state(np.random.default_rng(2))
    scene = robot_scene(*args, **kwargs)
    values = scene_values(scene)
    again = scene_of(values)
    for name in scene.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(again, name), getattr(scene, name))
    assert values.shape == (SCENE_SIZE,) == (110,)
