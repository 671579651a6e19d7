"""``/tf`` and ``/tf_static`` from the plant: the robot's transform tree, the ROS way.

One tree (each frame one parent), REP-105's frames with the model's NED/FRD
siblings hung off them, as MAVROS does::

    odom ----------> base_link ----------> base_link_frd --> thruster_i_link (x4)
     |  (/tf, every step)   (/tf_static)          (/tf, every step: the tilts)
     +--> odom_ned (/tf_static)

* ``odom -> base_link`` (ENU/FLU) on ``/tf`` at every plant step, stamped with
  the step, as ``odom`` (the same state; :func:`~tiltrov_ros.core.frames.pose_ned_to_enu`);
* ``odom -> odom_ned`` and ``base_link -> base_link_frd`` on ``/tf_static``,
  once, transient local (:data:`~tiltrov_ros.nodes.qos.LATCHED_QOS`: a reader
  started late still gets them); the rotations of :mod:`tiltrov_ros.core.frames`;
* with ``tf_thrusters`` (where robot_state_publisher is absent, the venv): the
  thruster links at the actual tilts in the same ``/tf`` message, as
  robot_state_publisher computes them from the URDF and ``joint_states``
  (:func:`~tiltrov_ros.core.robot_description.link_quaternion_values`), and the URDF on
  ``robot_description`` (transient local), so a viewer or a bag shows the
  thrusters tilt.

So every frame a message of the stack names resolves, and ``odom_ned ->
base_link_frd`` composed from the tree is the ``odom`` pose. The ``/tf``
message is one serialized template rewritten in place
(:class:`~tiltrov_ros.nodes.serialized.SerializedTemplate`): a few microseconds
per step. The type is tf2_msgs/msg/TFMessage: a ROS install has it; in the venv
``make install`` builds it (tools/tf2_msgs); without it there is no tree and the
plant says so once (:data:`TFMessage` is None).
"""

from __future__ import annotations

import math
from typing import Any

from geometry_msgs.msg import TransformStamped
import numpy as np
from std_msgs.msg import String

from tiltrov_ros.core.frames import BODY_RELATION, EARTH_RELATION, pose_ned_to_enu_values
from tiltrov_ros.core.names import (
    FRAME_BODY,
    FRAME_BODY_FLU,
    FRAME_EARTH,
    FRAME_EARTH_ENU,
    ROBOT_DESCRIPTION,
    TF,
    TF_STATIC,
)
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.plant import PlantSample
from tiltrov_ros.core.robot_description import link_quaternion_values, robot_urdf, tilt_joints

from .base import TiltrovNode
from .conversions import set_stamp
from .qos import LATCHED_QOS, STATE_QOS
from .serialized import SerializedTemplate

try:
    from tf2_msgs.msg import TFMessage
except ImportError:         # the venv before (or without) make install's tf2_msgs build
    TFMessage = None

#: What the plant says, once, when it cannot publish the tree.
NO_TF2_MSGS = ('tf2_msgs is not importable: no /tf and /tf_static (in the venv, `make '
               'install` builds it: docs/nodes.md, "The transform tree")')
#: The values of the /tf template: odom -> base_link's translation and rotation (w, x, y,
#: z), then each thruster link's rotation (w, x, y, z).
_POSE = 7


def transform(parent: str, child: str, ns: int, translation: Any = (0.0, 0.0, 0.0),
              quaternion: Any = (1.0, 0.0, 0.0, 0.0)) -> TransformStamped:
    """``parent -> child`` stamped ``ns``: ``translation`` (3) and ``quaternion``
    (w, x, y, z), the child's pose in the parent."""
    t = TransformStamped()
    set_stamp(t.header.stamp, ns)
    t.header.frame_id, t.child_frame_id = parent, child
    v, r = t.transform.translation, t.transform.rotation
    v.x, v.y, v.z = (float(x) for x in translation)
    r.w, r.x, r.y, r.z = (float(x) for x in quaternion)
    return t


def static_message(ns: int) -> Any:
    """``/tf_static``: the REP-105 relations, stamped ``ns``."""
    return TFMessage(transforms=[
        transform(FRAME_EARTH_ENU, FRAME_EARTH, ns, quaternion=EARTH_RELATION),
        transform(FRAME_BODY_FLU, FRAME_BODY, ns, quaternion=BODY_RELATION)])


class RobotTransforms:
    """The plant's ``/tf`` and ``/tf_static`` (see the module docstring); ``thrusters``:
    also the thruster links and ``robot_description``."""

    def __init__(self, node: TiltrovNode, robot: RobotParams, ns: int, *,
                 thrusters: bool) -> None:
        self.publisher = node.create_safe_publisher(TFMessage, TF, STATE_QOS)
        self.static = node.create_safe_publisher(TFMessage, TF_STATIC, LATCHED_QOS)
        self.static.publish(static_message(ns))
        self._joints = tilt_joints(robot.length, robot.width) if thrusters else ()
        if thrusters:
            self.description = node.create_publisher(String, ROBOT_DESCRIPTION, LATCHED_QOS)
            self.description.publish(String(data=robot_urdf(robot)))
        self._links: list[float] = []         # the thruster links' quaternions, flat
        self._tilts: tuple[float, ...] = ()
        self._template = SerializedTemplate(TFMessage, self._message, self._stamps,
                                            _POSE + 4 * len(self._joints))

    def _message(self, values: np.ndarray, ns: int) -> Any:
        """The /tf message of ``values`` (:data:`_POSE`), stamped ``ns``: the template's
        fill."""
        transforms = [transform(FRAME_EARTH_ENU, FRAME_BODY_FLU, ns, values[0:3],
                                values[3:_POSE])]
        for i, joint in enumerate(self._joints):
            transforms.append(transform(FRAME_BODY, joint.link, ns, joint.position,
                                        values[_POSE + 4 * i:_POSE + 4 * i + 4]))
        return TFMessage(transforms=transforms)

    @staticmethod
    def _stamps(msg: Any) -> list[Any]:
        return [t.header.stamp for t in msg.transforms]

    def publish(self, sample: PlantSample) -> None:
        """The tree at ``sample`` (its stamp); nothing for a state not finite (its odom
        is withheld too)."""
        values = self.values(sample)
        if values is not None:
            self.publisher.publish(self._template.serialize(sample.t_ns, values))

    def values(self, sample: PlantSample) -> list[float] | None:
        """The template's values at ``sample`` (plain floats); None if they are not all
        finite."""
        try:
            pose = pose_ned_to_enu_values(sample.position, sample.quaternion)
        except ValueError:      # a quaternion not finite: a diverged state
            return None
        if self._joints and sample.tilts != self._tilts:
            self._tilts = sample.tilts
            self._links = link_quaternion_values(self._joints, *sample.tilts)
        values = [*pose, *self._links]
        return values if all(map(math.isfinite, values)) else None


def robot_transforms(node: TiltrovNode, robot: RobotParams, ns: int, *, tf: bool,
                     thrusters: bool) -> RobotTransforms | None:
    """The plant's :class:`RobotTransforms` (parameters ``tf``, ``tf_thrusters``), or None:
    ``tf`` off, or no tf2_msgs (said once)."""
    if tf and TFMessage is None:
        node.get_logger().warning(NO_TF2_MSGS)
    if not tf or TFMessage is None:
        return None
    return RobotTransforms(node, robot, ns, thrusters=thrusters)
