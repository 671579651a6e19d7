"""The vocabulary: names and namespaces."""

from __future__ import annotations

import pytest

from tiltrov_ros.core import names


@pytest.mark.parametrize(('given', 'expected'), [
    ('robot1', '/robot1'), ('/robot1/', '/robot1'), (' a/b ', '/a/b'), ('', ''), ('/', '')])
def test_normalize_namespace(given: str, expected: str) -> None:
    assert names.normalize_namespace(given) == expected


def test_join_namespace_keeps_absolute_names() -> None:
    assert names.join_namespace('/r1', names.ODOM) == '/r1/odom'
    assert names.join_namespace('', names.ODOM) == '/odom'
    assert names.join_namespace('/r1', names.CLOCK) == '/clock'


def test_every_topic_has_a_type_and_the_joints_are_the_contract() -> None:
    topics = [names.ODOM, names.JOINT_STATES, names.SETPOINT, names.SETPOINT_VELOCITY,
              names.WRENCH_CMD, names.TILT_REQUEST, names.THRUST_CMD, names.TILT_CMD,
              names.WRENCH_ACHIEVED, names.CLOCK, names.DIAGNOSTICS, names.ROBOT_MARKERS,
              names.PID_INTEGRAL, names.TILT_TARGET]
    assert sorted(names.STACK_TOPICS) == sorted(topics)
    # The tick topics (a recorded lockstep run is paced on them) are stack topics, the
    # handshake's are not (never recorded).
    assert set(names.TICK_TOPICS) <= set(names.STACK_TOPICS)
    assert not set(names.HANDSHAKE_TOPICS) & set(names.STACK_TOPICS)
    assert all(t.count('/') == 2 for t in names.STACK_TOPICS.values())
    assert names.THRUSTERS == tuple(f'thruster_{i}' for i in range(1, 5))
    assert len(names.TILTS) == len(names.SERVOS) == 2
