"""The transform tree the plant publishes, as the tests check it: the frames' parents,
the REP-105 relations, and composing transforms.

Imported as ``tf_tree`` (test/ is on sys.path: it holds conftest.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tiltrov_ros.core.kinematics import Rquat
from tiltrov_ros.core.names import (
    FRAME_BODY,
    FRAME_BODY_FLU,
    FRAME_EARTH,
    FRAME_EARTH_ENU,
    THRUSTER_LINKS,
)
from tiltrov_ros.nodes.conversions import stamp_ns

Pose = tuple[np.ndarray, np.ndarray]

#: The tree: child -> parent.
TREE = {FRAME_EARTH: FRAME_EARTH_ENU, FRAME_BODY_FLU: FRAME_EARTH_ENU,
        FRAME_BODY: FRAME_BODY_FLU, **dict.fromkeys(THRUSTER_LINKS, FRAME_BODY)}
#: The REP-105 relations: child -> rotation matrix of the child's axes in the parent.
#: NED's north, east, down are ENU's y, x, -z; FRD's forward, starboard, down are
#: FLU's x, -y, -z.
REP105 = {FRAME_EARTH: np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),
          FRAME_BODY: np.diag([1.0, -1.0, -1.0])}


def pose(t: Any) -> Pose:
    """(R, p) of a TransformStamped: the child's axes and origin in the parent."""
    r, v = t.transform.rotation, t.transform.translation
    return Rquat([r.w, r.x, r.y, r.z]), np.array([v.x, v.y, v.z])


def compose(a: Pose, b: Pose) -> Pose:
    return a[0] @ b[0], a[0] @ b[1] + a[1]


def inverse(a: Pose) -> Pose:
    return a[0].T, -a[0].T @ a[1]


def by_child(*messages: Any) -> dict[str, Any]:
    """child frame -> its TransformStamped, over TFMessages."""
    return {t.child_frame_id: t for m in messages for t in m.transforms}


def tf_stamp(message: Any) -> int:
    """The one stamp of a /tf message (every transform in it has it)."""
    stamps = {stamp_ns(t.header.stamp) for t in message.transforms}
    assert len(stamps) == 1, stamps
    return stamps.pop()


def body_in_odom_ned(static: Any, message: Any) -> Pose:
    """odom_ned -> base_link_frd composed from the tree: (odom -> odom_ned)^-1
    (odom -> base_link) (base_link -> base_link_frd)."""
    fixed, moving = by_child(static), by_child(message)
    return compose(compose(inverse(pose(fixed[FRAME_EARTH])), pose(moving[FRAME_BODY_FLU])),
                   pose(fixed[FRAME_BODY]))


def assert_is_the_odometry(composed: Pose, odom: Any) -> None:
    """``composed`` is the pose of an ``odom`` message (position, orientation) to 1e-12."""
    o = odom.pose.pose
    np.testing.assert_allclose(composed[1], [o.position.x, o.position.y, o.position.z],
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(composed[0], Rquat([o.orientation.w, o.orientation.x,
                                                   o.orientation.y, o.orientation.z]),
                               rtol=0, atol=1e-12)


def assert_one_tree(static: Any, message: Any) -> None:
    """/tf_static and one /tf message make :data:`TREE`: every frame once, one parent."""
    transforms = [*static.transforms, *message.transforms]
    assert sorted(t.child_frame_id for t in transforms) == sorted(TREE)
    assert {t.child_frame_id: t.header.frame_id for t in transforms} == TREE
