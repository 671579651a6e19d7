"""The wander oracle (core/wander.py): can the servos follow the demand as the current
wanders?

Hand-built cases whose answer is known without the oracle: a fixed current is a
single demand (followable exactly when it is attainable within the range); a
strong mean current whose fluctuation only scales the drag is followed by the
branch of exact solutions without a flip; a current that swings across the
robot while a center-of-mass error asks for a roll moment needs the front pair
to lean either way of vertical, which the paper's servos (+-90 deg) reach only
through a flip and servos turning all the way round reach directly; a servo
far too slow for the branch cannot follow it; a hole in the attainable set
somewhere in the wander box leaves nothing to follow.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tiltrov_ros.core.kinematics import quat_from_euler
from tiltrov_ros.core.params import load_robot_params
from tiltrov_ros.core.steady import FULL_CIRCLE, judge, steady_wrench
from tiltrov_ros.core.wander import WANDER_POINTS, from_meta, wander_reach

ROBOT = load_robot_params()
LEVEL = (1.0, 0.0, 0.0, 0.0)
# The steady oracle's hole (test/core/test_steady.py).
HOLE_COM = (0.000547, -0.003493, 0.003178)
HOLE_CURRENT = (-0.15582, 0.20317, 0.0)
HOLE_Q = tuple(quat_from_euler(0.0, 0.507370, 0.0))


def _true(com: tuple[float, float, float]) -> object:
    return replace(ROBOT, center_of_gravity=tuple(
        g + e for g, e in zip(ROBOT.center_of_gravity, com)))


def test_a_fixed_current_is_one_demand_followed_when_attainable() -> None:
    robot = _true((0.01, 0.0, 0.005))
    answer = wander_reach(robot, LEVEL, (0.2, 0.1, 0.0))
    assert answer.followable and answer.points == 1 and answer.reason == ''
    assert answer.tilts is not None
    tau = steady_wrench(robot, LEVEL, (0.2, 0.1, 0.0))
    assert judge(robot, tau).in_range.attainable


def test_a_hole_in_the_attainable_set_leaves_nothing_to_follow() -> None:
    """The steady oracle's hole (test_steady.py): a setpoint pitched 29 deg in a current
    across it, short at every tilt on the full circle, at the mean current already."""
    robot = _true(HOLE_COM)
    assert not judge(robot, steady_wrench(robot, HOLE_Q, HOLE_CURRENT)).full_circle.attainable
    answer = wander_reach(robot, HOLE_Q, HOLE_CURRENT, (0.02, 0.02, 0.02), limits=FULL_CIRCLE)
    assert not answer.followable and answer.reason == 'unattainable'
    assert answer.worst is not None and answer.tilts is None


def test_a_strong_current_is_followed_without_a_flip() -> None:
    """0.25 m/s along x and its 0.02 m/s fluctuation, a center-of-mass error that
    asks for a pitch moment only: the drag grows and shrinks, the configurations
    follow it on their side of vertical."""
    robot = _true((0.005, 0.0, 0.002))
    for limits in (None, FULL_CIRCLE):
        answer = wander_reach(robot, LEVEL, (0.25, 0.0, 0.0), (0.02, 0.02, 0.02),
                              limits=limits)
        assert answer.followable, answer
        assert answer.points == WANDER_POINTS ** 3


def test_a_swing_across_vertical_is_followed_only_past_vertical() -> None:
    """A mean current along x with a fluctuation across it, and a roll moment from the
    center of mass: with the sway demand near zero, the roll moment needs a pair
    near vertical, and its thrust line turns through vertical as the sway and yaw
    demands change sign. Servos turning all the way round follow it; the paper's
    servos would need a flip, during which the demand is not met. With the mean
    current at 45 deg the sway demand keeps its sign and the paper's servos follow."""
    robot = _true((0.0, 0.006, 0.0))
    args = (robot, LEVEL, (0.25, 0.0, 0.0), (0.02, 0.02, 0.02))
    assert wander_reach(robot, LEVEL, (0.15, 0.15, 0.0), (0.02, 0.02, 0.02)).followable
    narrow = wander_reach(*args)
    full = wander_reach(*args, limits=FULL_CIRCLE)
    assert full.followable, full
    assert not narrow.followable and narrow.reason == 'no path', narrow
    assert narrow.worst is not None


def test_a_servo_too_slow_for_the_branch_cannot_follow_it() -> None:
    robot = _true((0.005, 0.0, 0.002))
    args = (LEVEL, (0.25, 0.0, 0.0), (0.02, 0.02, 0.02))
    assert wander_reach(robot, *args).followable
    crawling = replace(robot, tilt_rate_limit=0.01)     # rad/s, the robot file's least
    slow = wander_reach(crawling, *args)
    fast = wander_reach(replace(robot, tilt_rate_limit=10.0), *args)
    assert fast.followable
    # What moves with the current faster than the servo is lost; a configuration that
    # stays within tolerance of every demand needs no travel and is kept.
    assert slow.followable == (slow.tilts is not None)
    if slow.followable:
        assert slow.viable <= fast.viable


def test_from_meta_needs_the_robot_and_the_disturbances() -> None:
    assert from_meta({}, LEVEL) is None
    meta = {'robot': ROBOT.as_dict(), 'allocator_weights': [1, 1, 10, 10, 10, 10],
            'disturbances': {'com_error': [0.005, 0.0, 0.002], 'current': [0.25, 0, 0],
                             'current_std': [0.02, 0.02, 0.02],
                             'current_time_constant': [60, 60, 60],
                             'external_wrench_lasting': [0.0] * 6}}
    answer = from_meta(meta, LEVEL)
    assert answer is not None and answer.followable
    unknown = {**meta, 'disturbances': {**meta['disturbances'],
                                        'external_wrench_lasting': None}}
    assert from_meta(unknown, LEVEL) is None


def test_the_answer_does_not_depend_on_the_order_of_evaluation() -> None:
    robot = _true((0.0, 0.006, 0.0))
    first = wander_reach(robot, LEVEL, (0.2, 0.0, 0.0), (0.05, 0.05, 0.0))
    again = wander_reach(robot, LEVEL, (0.2, 0.0, 0.0), (0.05, 0.05, 0.0))
    assert first == again
    assert np.isfinite(first.points)
