"""ENU/FLU <-> NED/FRD at the boundary: golden values, meaning, and the round trip."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st
import numpy as np
import pytest

from tiltrov_ros.core.frames import enu_to_ned, ned_to_enu
from tiltrov_ros.core.kinematics import Rquat, euler_from_quat, quat_from_euler

S = math.sqrt(0.5)

# (ENU position, ENU/FLU quaternion (w, x, y, z), FLU twist) -> the NED/FRD ones,
# written out by hand from the axes: x_ned = y_enu, y_ned = x_enu, z_ned = -z_enu;
# forward stays forward, left becomes -right, up becomes -down.
GOLDEN = [
    # At the origin facing east (ENU yaw 0) = NED yaw +90 deg; surging forward at 1 m/s.
    (([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
     ([0.0, 0.0, 0.0], [S, 0.0, 0.0, S], [1.0, 0.0, 0.0, 0.0, 0.0, 0.0])),
    # 1 m east, 2 m north, 3 m up, facing north (ENU yaw +90 deg) = NED yaw 0; moving
    # left (+v), up (+w), turning left (+r) = right -v, down -w, turning right -r.
    (([1.0, 2.0, 3.0], [S, 0.0, 0.0, S], [0.0, 0.5, 0.25, 0.0, 0.0, 0.1]),
     ([2.0, 1.0, -3.0], [1.0, 0.0, 0.0, 0.0], [0.0, -0.5, -0.25, 0.0, 0.0, -0.1])),
    # Facing north, nose down 90 deg in FLU (pitch +90 deg about y left) = nose down in
    # NED/FRD too, which is pitch -90 deg there; roll rate p keeps its sign, q flips.
    (([0.0, 0.0, -1.0], [0.5, -0.5, 0.5, 0.5], [0.0, 0.0, 0.0, 0.3, 0.2, 0.0]),
     ([0.0, 0.0, 1.0], [S, 0.0, -S, 0.0], [0.0, 0.0, 0.0, 0.3, -0.2, 0.0])),
]


@pytest.mark.parametrize(('enu', 'ned'), GOLDEN)
def test_golden_values_both_ways(enu, ned) -> None:
    p, q, nu = enu_to_ned(*enu)
    np.testing.assert_allclose(p, ned[0], atol=1e-15)
    np.testing.assert_allclose(q, ned[1], atol=1e-15)
    np.testing.assert_allclose(nu, ned[2], atol=1e-15)
    p, q, nu = ned_to_enu(*ned)
    np.testing.assert_allclose(p, enu[0], atol=1e-15)
    np.testing.assert_allclose(q * np.sign(q @ enu[1]), enu[1], atol=1e-15)
    np.testing.assert_allclose(nu, enu[2], atol=1e-15)


def test_euler_angles_roll_kept_pitch_negated_yaw_from_north() -> None:
    _, q, _ = enu_to_ned([0, 0, 0], quat_from_euler(0.2, 0.3, 0.4), [0.0] * 6)
    np.testing.assert_allclose(euler_from_quat(q), [0.2, -0.3, math.pi / 2 - 0.4], atol=1e-12)


angles = st.floats(-3.0, 3.0)
values = st.lists(st.floats(-100.0, 100.0), min_size=9, max_size=9)


@given(angles, st.floats(-1.5, 1.5), angles, values)
def test_the_body_axes_point_the_same_way_in_the_world(roll, pitch, yaw, v) -> None:
    """R_ned_frd's columns are the FLU axes (x, -y, -z) expressed in NED, and the
    twist's velocity seen in the world is the same vector; a round trip is exact
    to rounding."""
    q_enu = quat_from_euler(roll, pitch, yaw)
    p, q, nu = enu_to_ned(v[:3], q_enu, v[3:])
    to_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    R_enu, R_ned = Rquat(q_enu), Rquat(q)
    np.testing.assert_allclose(R_ned, to_ned @ R_enu @ np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(R_ned @ nu[:3], to_ned @ (R_enu @ np.array(v[3:6])),
                               atol=1e-9)
    np.testing.assert_allclose(R_ned @ nu[3:], to_ned @ (R_enu @ np.array(v[6:9])),
                               atol=1e-9)
    back = ned_to_enu(p, q, nu)
    np.testing.assert_allclose(back[0], v[:3], atol=1e-12)
    np.testing.assert_allclose(back[1] * np.sign(back[1] @ q_enu), q_enu, atol=1e-12)
    np.testing.assert_allclose(back[2], v[3:], atol=1e-12)


def test_the_static_relations_are_rep_105s() -> None:
    """``odom -> odom_ned``: the NED axes north, east, down are ENU's y, x and -z;
    ``base_link -> base_link_frd``: forward stays, starboard is FLU's -y, down is -z."""
    from tiltrov_ros.core.frames import BODY_RELATION, EARTH_RELATION

    np.testing.assert_allclose(Rquat(EARTH_RELATION),
                               [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]], atol=1e-15)
    np.testing.assert_allclose(Rquat(BODY_RELATION), np.diag([1.0, -1.0, -1.0]), atol=1e-15)


@given(st.lists(st.floats(-5.0, 5.0), min_size=3, max_size=3),
       st.lists(st.floats(-2.0, 2.0), min_size=4, max_size=4).filter(
           lambda q: sum(v * v for v in q) > 1e-6))
def test_the_plain_float_pose_is_the_matrix_one(position: list[float],
                                                quaternion: list[float]) -> None:
    """pose_ned_to_enu_values (what the plant writes into /tf) is the pose the derivation
    gives: R_ned_enu^T p, and the normalized quaternion times _TO_ENU, w >= 0."""
    from tiltrov_ros.core.frames import _NED_ENU, _TO_ENU, pose_ned_to_enu_values
    from tiltrov_ros.core.kinematics import quat_normalize
    values = pose_ned_to_enu_values(position, quaternion)
    q = _TO_ENU @ quat_normalize(quaternion)
    q = -q if q[0] < 0 else q
    np.testing.assert_allclose(values[:3], _NED_ENU.T @ position, rtol=0, atol=0)
    np.testing.assert_allclose(values[3:], q, rtol=0, atol=1e-15)
    assert values[3] >= 0.0


@pytest.mark.parametrize('quaternion', [[0.0] * 4, [math.nan, 0.0, 0.0, 1.0],
                                        [math.inf, 0.0, 0.0, 0.0]])
def test_the_plain_float_pose_refuses_a_quaternion_that_is_none(quaternion) -> None:
    from tiltrov_ros.core.frames import pose_ned_to_enu, pose_ned_to_enu_values
    with pytest.raises(ValueError, match='not a valid quaternion'):
        pose_ned_to_enu_values([0.0, 0.0, 0.0], quaternion)
    with pytest.raises(ValueError, match='not a valid quaternion'):
        pose_ned_to_enu([0.0, 0.0, 0.0], quaternion)
