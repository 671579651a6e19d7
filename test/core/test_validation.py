"""core/validation.py: the checks every node applies to what it receives and sends."""

from __future__ import annotations

import math

import pytest

from tiltrov_ros.core import validation as v
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.timebase import NS_PER_S as NS

BOUNDS = v.StampBounds.from_seconds(0.5, 5.0)


def _reason(call) -> str:
    with pytest.raises(v.InvalidInput) as info:
        call()
    return info.value.reason


def test_stamps_against_the_clock() -> None:
    assert v.check_stamp(20, 0, 20 * NS, BOUNDS) == 20 * NS
    assert v.check_stamp(20, 400_000_000, 20 * NS, BOUNDS) == 20_400_000_000
    assert _reason(lambda: v.check_stamp(21, 0, 20 * NS, BOUNDS)) == v.FUTURE_STAMP
    assert _reason(lambda: v.check_stamp(14, 0, 20 * NS, BOUNDS)) == v.OLD_STAMP
    assert _reason(lambda: v.check_stamp(1, NS, 20 * NS, BOUNDS)) == v.BAD_STAMP
    assert _reason(lambda: v.check_stamp(-1, 0, None, BOUNDS)) == v.BAD_STAMP
    assert v.check_stamp(10**6, 0, None, BOUNDS) == 10**6 * NS       # no clock: unchecked
    assert v.check_stamp(10**6, 0, 0, v.StampBounds()) == 10**6 * NS  # bounds 0: off


def test_joint_values_by_name_with_every_rejection() -> None:
    names, req = ['b', 'a'], ['a', 'b']
    assert v.joint_values(names, {'position': [1.0, 2.0], 'effort': []}, req,
                          'position') == [2.0, 1.0]
    cases = [
        (['a', 'b', 'c'], {'position': [1, 2, 3]}, v.UNKNOWN_JOINT),
        (['a'], {'position': [1]}, v.MISSING_JOINT),
        (['a', 'a', 'b'], {'position': [1, 2, 3]}, v.DUPLICATE_JOINT),
        (['a', 'b'], {'position': [1]}, v.WRONG_LENGTH),
        (['a', 'b'], {'position': [1, 2], 'velocity': [0.0]}, v.WRONG_LENGTH),
        (['a', 'b'], {'position': [1, math.nan]}, v.NON_FINITE),
    ]
    for joint_names, arrays, reason in cases:
        assert _reason(lambda n=joint_names, a=arrays: v.joint_values(n, a, req, 'position')) \
            == reason


def test_frames_finite_and_quaternions() -> None:
    v.check_frame('odom_ned', 'odom_ned')
    assert _reason(lambda: v.check_frame('map', 'odom_ned')) == v.WRONG_FRAME
    assert _reason(lambda: v.check_finite([0.0, math.inf], 'x')) == v.NON_FINITE
    v.check_quaternion([1.0, 0.0, 0.0, 0.0])
    assert _reason(lambda: v.check_quaternion([0.0] * 4)) == v.BAD_QUATERNION
    assert _reason(lambda: v.check_quaternion([math.nan, 0, 0, 1])) == v.NON_FINITE


def test_commands_are_limited_or_refused() -> None:
    lim = (40.0, -1.5, 1.5)
    assert v.limit_command([40.0 * (1 + 1e-12), -3.0], [1.5 + 1e-12], *lim) == (
        [40.0, -3.0], [1.5])
    assert v.limit_command([41.0], [0.0], *lim) is None
    assert v.limit_command([0.0], [1.6], *lim) is None
    assert v.limit_command([math.nan], [0.0], *lim) is None
    assert v.clip_wrench([1e300, -2.0]) == ([v.MAX_WRENCH, -2.0], True)
    assert v.clip_wrench([1.0, -2.0]) == ([1.0, -2.0], False)


def test_failed_thruster_numbers() -> None:
    assert v.failed_thruster_indices([4, 2]) == (1, 3)
    assert v.failed_thruster_indices([]) == v.failed_thruster_indices(None) == ()
    for bad in ([0], [5], [2, 2], ['2'], [True], 2):
        with pytest.raises(ParameterError, match='failed_thrusters'):
            v.failed_thruster_indices(bad)
