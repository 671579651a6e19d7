"""``robot_markers``: the robot as a visualization_msgs/MarkerArray, published by the plant.

Every ``markers_period`` of sim time (at the plant steps whose time is a
multiple of it) the plant publishes one MarkerArray in ``odom_ned`` stamped
with the step, so RViz and Foxglove show it with no TF (display frame
``odom_ned``): 17 markers, namespaces ``body`` (a box), ``thrusters`` (4
cylinders along the thrust at the actual tilt), ``thrust_actual`` and
``thrust_commanded`` (4 arrows each: the thrusters' state and the commands in
force), ``force_demanded``, ``force_achieved``, ``moment_demanded`` and
``moment_achieved`` (an arrow each from the body origin: the latest
``wrench_cmd`` and ``wrench_achieved``). The geometry is
:func:`tiltrov_ros.core.visual.robot_scene`'s, its numbers from a compiled kernel
when the kernels run (:func:`~tiltrov_ros.core.visual.robot_scene_values`); a scene
with a number not finite is withheld and counted, as every output is.

In the plant because it holds everything but the two wrenches (read raw, the
latest of each kept as bytes and decoded only when markers are due): a
separate node would read ``odom`` and ``joint_states`` at every step, which
cost lockstep more than building 17 markers ten times per simulated second
(docs/nodes.md, "robot_markers").
"""

from __future__ import annotations

from collections.abc import Callable
import functools
from typing import Any

from geometry_msgs.msg import Point, WrenchStamped
import numpy as np
from visualization_msgs.msg import Marker, MarkerArray

from tiltrov_ros.core.names import FRAME_EARTH, ROBOT_MARKERS, WRENCH_ACHIEVED, WRENCH_CMD
from tiltrov_ros.core.plant import PlantSample
from tiltrov_ros.core.timebase import cdr_stamp_ns
from tiltrov_ros.core.validation import InvalidInput, check_finite
from tiltrov_ros.core.visual import (
    HULL_RGBA,
    SCENE_SIZE,
    THRUSTER_RGBA,
    THRUSTER_SIZE,
    Scales,
    Scene,
    robot_scene_values,
    scene_of,
    scene_values,
)

from .base import TiltrovNode
from .conversions import set_stamp, wrench_array
from .qos import PUBLISHER_QOS, RELIABLE_QOS
from .serialized import SerializedTemplate

#: (namespace, count, type, RGBA) of the markers, in their order in the array.
LAYOUT = (
    ('body', 1, Marker.CUBE, HULL_RGBA),
    ('thrusters', 4, Marker.CYLINDER, THRUSTER_RGBA),
    ('thrust_actual', 4, Marker.ARROW, (1.0, 0.55, 0.0, 1.0)),
    ('thrust_commanded', 4, Marker.ARROW, (0.0, 0.75, 1.0, 0.6)),
    ('force_demanded', 1, Marker.ARROW, (0.9, 0.1, 0.1, 0.8)),
    ('force_achieved', 1, Marker.ARROW, (0.1, 0.8, 0.1, 0.8)),
    ('moment_demanded', 1, Marker.ARROW, (0.8, 0.1, 0.8, 0.8)),
    ('moment_achieved', 1, Marker.ARROW, (0.1, 0.6, 0.6, 0.8)),
)
#: m: arrows (shaft and head diameters).
ARROW_SIZE = (0.02, 0.04)


def new_marker_array() -> MarkerArray:
    """The markers of :data:`LAYOUT`, in ``odom_ned``, ready to be filled."""
    out = MarkerArray()
    for ns, count, kind, rgba in LAYOUT:
        for i in range(count):
            m = Marker(ns=ns, id=i, type=kind, action=Marker.ADD)
            m.header.frame_id = FRAME_EARTH
            m.color.r, m.color.g, m.color.b, m.color.a = rgba
            m.pose.orientation.w = 1.0
            if kind == Marker.ARROW:
                m.scale.x, m.scale.y = ARROW_SIZE
                m.points = [Point(), Point()]
            elif kind == Marker.CYLINDER:
                m.scale.x = m.scale.y = THRUSTER_SIZE[0]
                m.scale.z = THRUSTER_SIZE[1]
            out.markers.append(m)
    return out


def _set_pose(marker: Marker, position: Any, quaternion: Any) -> None:
    p, o = marker.pose.position, marker.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position)
    o.w, o.x, o.y, o.z = (float(v) for v in quaternion)


def _set_arrow(marker: Marker, ends: Any) -> None:
    for point, end in zip(marker.points, ends):
        point.x, point.y, point.z = (float(v) for v in end)


def fill_markers(msg: MarkerArray, ns: int, scene: Scene) -> MarkerArray:
    """Write ``scene`` into ``msg`` (from :func:`new_marker_array`) stamped ``ns``."""
    markers = iter(msg.markers)
    body = next(markers)
    _set_pose(body, scene.body_position, scene.body_quaternion)
    body.scale.x, body.scale.y, body.scale.z = (float(v) for v in scene.body_size)
    for position, quaternion in zip(scene.thruster_positions, scene.thruster_quaternions):
        _set_pose(next(markers), position, quaternion)
    for arrows in (scene.thrust_actual, scene.thrust_commanded):
        for ends in arrows:
            _set_arrow(next(markers), ends)
    for ends in (scene.force_demanded, scene.force_achieved, scene.moment_demanded,
                 scene.moment_achieved):
        _set_arrow(next(markers), ends)
    for m in msg.markers:
        set_stamp(m.header.stamp, ns)
    return msg


class MarkerBytes:
    """The serialized MarkerArray, rewritten in place for each scene
    (:class:`~tiltrov_ros.nodes.serialized.SerializedTemplate`: a few microseconds
    where rclpy's conversion of 17 Marker objects takes about 0.5 ms)."""

    def __init__(self) -> None:
        self.template = SerializedTemplate(
            MarkerArray, lambda values, ns: fill_markers(new_marker_array(), ns,
                                                         scene_of(values)),
            lambda msg: [m.header.stamp for m in msg.markers], SCENE_SIZE)

    def serialize(self, ns: int, scene: Scene) -> bytes:
        """The MarkerArray of ``scene`` stamped ``ns``, serialized."""
        return self.template.serialize(ns, scene_values(scene))


class RobotMarkers:
    """The plant's ``robot_markers`` publisher (see the module docstring)."""

    def __init__(self, node: TiltrovNode, length: float, width: float, period_ns: int,
                 scales: Scales) -> None:
        self.node = node
        self.length, self.width = length, width
        self.period_ns = period_ns
        self.scales = scales
        self.publisher = node.create_safe_publisher(MarkerArray, ROBOT_MARKERS, PUBLISHER_QOS)
        self._bytes = MarkerBytes()
        self._last_ns = -1
        self._wrenches = {WRENCH_CMD: np.zeros(6), WRENCH_ACHIEVED: np.zeros(6)}
        self._latest: dict[str, bytes] = {}
        #: Lockstep (set by the plant at the start): each tick's wrenches come through
        #: ``on_wrench`` and the plant hands the tick's pair over (:meth:`use`) when it
        #: applies the tick's commands; otherwise the latest received are drawn.
        self.by_stamp = False
        self.on_wrench: Callable[[int, int, bytes], None] | None = None
        for slot, topic in enumerate(self._wrenches, start=2):
            node.create_subscription(WrenchStamped, topic,
                                     functools.partial(self._keep, topic, slot),
                                     RELIABLE_QOS, raw=True)

    def _keep(self, topic: str, slot: int, data: bytes) -> None:
        if self.by_stamp and self.on_wrench is not None:
            try:
                stamp = cdr_stamp_ns(data)
            except ValueError:
                self.node.reject_malformed(topic, WrenchStamped, data)
                return
            self.on_wrench(stamp, slot, data)
            return
        self._latest[topic] = data

    def use(self, wrench: bytes, achieved: bytes) -> None:
        """Draw these wrenches (those stamped with the tick whose commands are in force)
        from now on."""
        self._latest = {WRENCH_CMD: wrench, WRENCH_ACHIEVED: achieved}

    def due(self, ns: int) -> bool:
        """Markers are due at ``ns`` (a multiple of the period, not yet published)."""
        return ns % self.period_ns == 0 and ns != self._last_ns

    def publish(self, sample: PlantSample, commanded_thrusts: Any,
                commanded_tilts: Any) -> None:
        """The markers of ``sample`` and the commands in force, stamped with its time."""
        self._update_wrenches()
        values = robot_scene_values(
            sample.position, sample.quaternion, self.length, self.width, tilts=sample.tilts,
            thrusts=sample.thrusts, commanded_tilts=commanded_tilts,
            commanded_thrusts=commanded_thrusts, wrench_cmd=self._wrenches[WRENCH_CMD],
            wrench_achieved=self._wrenches[WRENCH_ACHIEVED], scales=self.scales)
        self._last_ns = sample.t_ns
        self.publisher.publish_serialized(self._bytes.template, sample.t_ns, values)

    def _update_wrenches(self) -> None:
        """Decode the latest wrenches; a bad one (bytes that do not decode, a value
        not finite) is rejected (counted on /diagnostics) and the one before it stays."""
        latest, self._latest = self._latest, {}
        for topic, data in latest.items():
            msg = self.node.decode(WrenchStamped, topic, data)
            if msg is None:
                continue
            wrench = wrench_array(msg)
            try:
                check_finite(wrench, 'wrench')
            except InvalidInput as bad:
                self.node.reject_input(topic, bad)
                continue
            self._wrenches[topic] = wrench
