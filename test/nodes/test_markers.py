"""robot_markers: the bytes the plant publishes are the MarkerArray of the scene."""

from __future__ import annotations

import math

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from tiltrov_ros.core.kinematics import quat_from_euler
from tiltrov_ros.core.visual import robot_scene
from tiltrov_ros.nodes.markers import LAYOUT, MarkerBytes, fill_markers, new_marker_array


def _scene(rng: np.random.Generator):
    q = quat_from_euler(*rng.uniform(-math.pi / 2, math.pi / 2, 3))
    return robot_scene(rng.normal(size=3), q, 0.6, 0.4, tilts=rng.uniform(-1.5, 1.5, 2),
                       thrusts=rng.uniform(-40, 40, 4),
                       commanded_tilts=rng.uniform(-1.5, 1.5, 2),
                       commanded_thrusts=rng.uniform(-40, 40, 4),
                       wrench_cmd=rng.normal(size=6) * 20, wrench_achieved=rng.normal(size=6))


@pytest.mark.parametrize('seed', range(5))
def test_the_rewritten_template_decodes_to_the_filled_message(seed: int) -> None:
    rng = np.random.default_rng(seed)
    scene, ns = _scene(rng), int(rng.integers(0, 10**12))
    fast = deserialize_message(MarkerBytes().serialize(ns, scene), MarkerArray)
    slow = deserialize_message(serialize_message(fill_markers(new_marker_array(), ns, scene)),
                               MarkerArray)
    assert fast == slow
    assert [(m.ns, m.id) for m in fast.markers] == [
        (name, i) for name, count, _, _ in LAYOUT for i in range(count)]
    assert {m.header.frame_id for m in fast.markers} == {'odom_ned'}
    assert all(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == ns for m in fast.markers)
    arrows = [m for m in fast.markers if m.type == Marker.ARROW]
    assert len(arrows) == 12 and all(len(m.points) == 2 for m in arrows)


def test_templates_built_again_and_again_find_their_offsets() -> None:
    """rclpy's padding bytes hold whatever memory held before, an earlier template's
    sentinels included: every build still finds unique offsets that decode right."""
    scene = _scene(np.random.default_rng(7))
    first = MarkerBytes().serialize(5, scene)
    for _ in range(10):
        again = MarkerBytes().serialize(5, scene)
        assert (deserialize_message(again, MarkerArray)
                == deserialize_message(first, MarkerArray))
