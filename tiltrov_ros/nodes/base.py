"""What the four stack nodes share: names, QoS, message <-> array conversions,
parameter declaration, diagnostics, the callback guard and ``main``.

The nodes are thin adapters over :mod:`tiltrov_ros.core`: they convert messages
to float arrays exactly (float64 fields, quaternions reordered from ROS
(x, y, z, w) to the core's (w, x, y, z)), call the core, and convert back. No
arithmetic happens on the way, so the ROS stack gives the numbers of the
headless runner bit for bit (ARCHITECTURE.md, "Time and stamps").
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
import functools
import math
import os
import sys
import time
from typing import Any, TypeVar

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
from numpy.typing import NDArray
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
import rclpy
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.context import Context
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterException,
)
from rclpy.executors import (
    Executor,
    ExternalShutdownException,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
)
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rclpy.task import Future
from sensor_msgs.msg import JointState
import yaml

from tiltrov_ros.core import validation
from tiltrov_ros.core.errors import ParameterError, TiltrovError
from tiltrov_ros.core.names import (
    DIAGNOSTICS,
    FRAME_BODY,
    FRAME_EARTH,
    LOCKSTEP,
)
from tiltrov_ros.core.params import RobotParams, load_control_period, load_robot_params
from tiltrov_ros.core.timebase import (
    NS_PER_S,
    format_ns,
    ns_to_stamp,
    seconds,
    stamp_to_ns,
    to_ns,
)
from tiltrov_ros.core.validation import InvalidInput, StampBounds

FloatArray = NDArray[np.float64]

#: s: repeated warnings from callbacks are throttled to one per this period.
THROTTLE = 5.0
#: s (wall): period of the /diagnostics messages.
DIAGNOSTICS_PERIOD = 1.0
#: s (wall): how often a node that waits for the recorder checks the graph, and
#: how long it waits at most before it publishes anyway (``wait_for_recorder``).
RECORDER_POLL = 0.02
RECORDER_WAIT = 10.0
#: DiagnosticStatus levels as ints (the message field is a byte).
OK, WARN, ERROR = 0, 1, 2

# --------------------------------------------------------------------------- QoS
#
# Every publisher of the stack offers RELIABLE + VOLATILE with a KEEP_LAST
# history: lockstep needs every command, odometry and clock sample (a lost one
# is a stall), and the bag recorder subscribes RELIABLE to the stack topics
# before their publishers exist (a BEST_EFFORT publisher would leave it
# unmatched until its discovery poll re-subscribes, losing the start of the
# run). A reader that tolerates loss asks for BEST_EFFORT (sensor data), which
# matches a reliable writer: the controller's odometry in realtime mode does.
# See README.md, "Topics and QoS".

#: Commands, setpoints, odometry, joint states: reliable, last 10. In lockstep at
#: most control_period / step_size (5) odometry samples are in flight.
RELIABLE_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE,
                          history=HistoryPolicy.KEEP_LAST, depth=10)
#: The stack's publishers: reliable, with a history deep enough that a sample a
#: slow reader (the bag recorder on a loaded machine) has not acknowledged yet is
#: still there to be resent: a KEEP_LAST writer drops its oldest sample when the
#: history is full, acknowledged or not. In lockstep the plant publishes up to
#: hundreds of steps per wall second; 1000 samples are seconds of them.
PUBLISHER_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE,
                           history=HistoryPolicy.KEEP_LAST, depth=1000)
#: The reference publisher's own /clock reader: reliable, deep enough that a
#: burst of lockstep steps is never overwritten before it is taken.
CLOCK_READER_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE,
                              history=HistoryPolicy.KEEP_LAST, depth=100)
#: Readers that only want the latest sample (realtime odometry).
SENSOR_QOS = qos_profile_sensor_data


def reader_qos(mode: str) -> QoSProfile:
    """Odometry reader profile: reliable in lockstep, sensor data in realtime."""
    return RELIABLE_QOS if mode == LOCKSTEP else SENSOR_QOS


# --------------------------------------------------------------------------- time


def stamp_ns(stamp: Time) -> int:
    """Integer ns of a ``builtin_interfaces/Time``."""
    return stamp_to_ns(stamp.sec, stamp.nanosec)


def set_stamp(stamp: Time, ns: int) -> None:
    """Write integer ns into a ``builtin_interfaces/Time`` in place."""
    stamp.sec, stamp.nanosec = ns_to_stamp(ns)


def steady_clock() -> Clock:
    """A monotonic wall clock for timeouts and diagnostics (independent of sim time)."""
    return Clock(clock_type=ClockType.STEADY_TIME)


# --------------------------------------------------------------------------- conversions


def _finite(values: Iterable[float]) -> bool:
    return all(math.isfinite(v) for v in values)


def odometry_arrays(msg: Odometry) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(position (3), quaternion (w, x, y, z) (4), nu (6)) of an ``odom`` message."""
    pose, twist = msg.pose.pose, msg.twist.twist
    p, o = pose.position, pose.orientation
    lin, ang = twist.linear, twist.angular
    return (np.array([p.x, p.y, p.z]), np.array([o.w, o.x, o.y, o.z]),
            np.array([lin.x, lin.y, lin.z, ang.x, ang.y, ang.z]))


def fill_odometry(msg: Odometry, ns: int, position: Sequence[float],
                  quaternion: Sequence[float], nu: Sequence[float]) -> Odometry:
    """Write a plant state into ``msg`` (reused between steps) and return it."""
    set_stamp(msg.header.stamp, ns)
    pose, twist = msg.pose.pose, msg.twist.twist
    pose.position.x, pose.position.y, pose.position.z = position
    o = pose.orientation
    o.w, o.x, o.y, o.z = quaternion
    twist.linear.x, twist.linear.y, twist.linear.z = nu[0:3]
    twist.angular.x, twist.angular.y, twist.angular.z = nu[3:6]
    return msg


def new_odometry() -> Odometry:
    msg = Odometry()
    msg.header.frame_id = FRAME_EARTH
    msg.child_frame_id = FRAME_BODY
    return msg


def pose_arrays(msg: PoseStamped) -> tuple[FloatArray, FloatArray]:
    """(position (3), quaternion (w, x, y, z) (4)) of a ``setpoint``."""
    p, o = msg.pose.position, msg.pose.orientation
    return np.array([p.x, p.y, p.z]), np.array([o.w, o.x, o.y, o.z])


def fill_pose(msg: PoseStamped, ns: int, position: Sequence[float],
              quaternion: Sequence[float]) -> PoseStamped:
    set_stamp(msg.header.stamp, ns)
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position)
    o.w, o.x, o.y, o.z = (float(v) for v in quaternion)
    return msg


def twist_array(msg: TwistStamped) -> FloatArray:
    """d(eta_d)/dt (6) of a ``setpoint_velocity``: linear then angular."""
    lin, ang = msg.twist.linear, msg.twist.angular
    return np.array([lin.x, lin.y, lin.z, ang.x, ang.y, ang.z])


def fill_twist(msg: TwistStamped, ns: int, velocity: Sequence[float]) -> TwistStamped:
    set_stamp(msg.header.stamp, ns)
    lin, ang = msg.twist.linear, msg.twist.angular
    lin.x, lin.y, lin.z, ang.x, ang.y, ang.z = (float(v) for v in velocity)
    return msg


def wrench_array(msg: WrenchStamped) -> FloatArray:
    """(X, Y, Z, K, M, N) of a ``WrenchStamped``."""
    f, t = msg.wrench.force, msg.wrench.torque
    return np.array([f.x, f.y, f.z, t.x, t.y, t.z])


def fill_wrench(msg: WrenchStamped, ns: int, wrench: Sequence[float]) -> WrenchStamped:
    set_stamp(msg.header.stamp, ns)
    f, t = msg.wrench.force, msg.wrench.torque
    f.x, f.y, f.z, t.x, t.y, t.z = (float(v) for v in wrench)
    return msg


def new_wrench() -> WrenchStamped:
    msg = WrenchStamped()
    msg.header.frame_id = FRAME_BODY
    return msg


def joint_state_values(msg: JointState, required: Sequence[str], field: str,
                       allowed: Sequence[str] | None = None) -> list[float]:
    """Values of ``field`` (position, velocity or effort) for ``required``, by name.

    Checked by :func:`tiltrov_ros.core.validation.joint_values`: raises
    :class:`~tiltrov_ros.core.validation.InvalidInput` for an unknown, missing or
    repeated joint, an array of the wrong length or a non-finite value.
    """
    return validation.joint_values(
        list(msg.name), {'position': msg.position, 'velocity': msg.velocity,
                         'effort': msg.effort}, required, field, allowed)


def fill_joint_state(msg: JointState, ns: int, *, position: Sequence[float] = (),
                     velocity: Sequence[float] = (), effort: Sequence[float] = ()) -> JointState:
    set_stamp(msg.header.stamp, ns)
    msg.position = [float(v) for v in position]
    msg.velocity = [float(v) for v in velocity]
    msg.effort = [float(v) for v in effort]
    return msg


def new_joint_state(names: Sequence[str]) -> JointState:
    msg = JointState()
    msg.name = list(names)
    return msg


# --------------------------------------------------------------------------- outgoing values


def _all_finite(*groups: Iterable[float]) -> bool:
    return all(all(map(math.isfinite, group)) for group in groups)


def _odometry_finite(m: Odometry) -> bool:
    p, o = m.pose.pose.position, m.pose.pose.orientation
    lin, ang = m.twist.twist.linear, m.twist.twist.angular
    return (_all_finite((p.x, p.y, p.z, o.x, o.y, o.z, o.w, lin.x, lin.y, lin.z,
                         ang.x, ang.y, ang.z))
            and bool(np.isfinite(m.pose.covariance).all())
            and bool(np.isfinite(m.twist.covariance).all()))


def _joint_state_finite(m: JointState) -> bool:
    return _all_finite(m.position, m.velocity, m.effort)


def _wrench_finite(m: WrenchStamped) -> bool:
    f, t = m.wrench.force, m.wrench.torque
    return _all_finite((f.x, f.y, f.z, t.x, t.y, t.z))


def _pose_finite(m: PoseStamped) -> bool:
    p, o = m.pose.position, m.pose.orientation
    return _all_finite((p.x, p.y, p.z, o.x, o.y, o.z, o.w))


def _twist_finite(m: TwistStamped) -> bool:
    lin, ang = m.twist.linear, m.twist.angular
    return _all_finite((lin.x, lin.y, lin.z, ang.x, ang.y, ang.z))


#: Message type -> "every float field is finite" (types without floats are not listed).
FINITE_CHECKS: dict[type, Callable[[Any], bool]] = {
    Odometry: _odometry_finite, JointState: _joint_state_finite,
    WrenchStamped: _wrench_finite, PoseStamped: _pose_finite, TwistStamped: _twist_finite,
}


def message_is_finite(msg: Any) -> bool:
    """True when no float field of ``msg`` is NaN or infinite (types of the stack)."""
    check = FINITE_CHECKS.get(type(msg))
    return True if check is None else check(msg)


# --------------------------------------------------------------------------- parameters


def descriptor(description: str, *, read_only: bool = False,
               floating: tuple[float, float] | None = None,
               integer: tuple[int, int] | None = None,
               constraints: str = '') -> ParameterDescriptor:
    """A ParameterDescriptor with an optional range (shown by ``ros2 param describe``)."""
    d = ParameterDescriptor(description=description, read_only=read_only,
                            additional_constraints=constraints)
    if floating is not None:
        d.floating_point_range = [FloatingPointRange(from_value=float(floating[0]),
                                                     to_value=float(floating[1]), step=0.0)]
    if integer is not None:
        d.integer_range = [IntegerRange(from_value=integer[0], to_value=integer[1], step=1)]
    return d


# robot.* (config/robot.yaml, '/**'): description and range of each scalar. Read-only.
_ROBOT_DOC: dict[str, tuple[str, tuple[float, float] | None]] = {
    'mass_matrix': ('diagonal of M (A.2), rigid body + added mass: kg (surge, sway, heave), '
                    'kg m^2 (roll, pitch, yaw); 6 numbers > 0', None),
    'quadratic_damping': ('quadratic damping d_i of (A.4), D(nu) = diag(d_i |nu_i|): '
                          'N s^2/m^2, N m s^2; 6 numbers >= 0', None),
    'linear_damping': ('linear damping added to (A.4): N s/m, N m s; 6 numbers >= 0', None),
    'weight': ('W = m g, N (> 0)', (0.0, math.inf)),
    'buoyancy': ('B, N (>= 0)', (0.0, math.inf)),
    'center_of_gravity': ('nominal r_g in base_link_frd, m (3 numbers)', None),
    'center_of_buoyancy': ('r_b in base_link_frd, m (3 numbers)', None),
    'length': ('l, thruster spacing along x, m (> 0)', (0.0, math.inf)),
    'width': ('d, thruster spacing along y, m (> 0)', (0.0, math.inf)),
    'max_thrust': ('thrust limit of each thruster in both directions, N (> 0)',
                   (0.0, math.inf)),
    'thruster_time_constant': ('first-order thruster time constant, s (0: ideal)',
                               (0.0, math.inf)),
    'tilt_min': ('lower servo angle limit, rad', (-math.pi, math.pi)),
    'tilt_max': ('upper servo angle limit, rad', (-math.pi, math.pi)),
    'tilt_rate_limit': ('servo rate limit, rad/s (> 0)', (0.0, math.inf)),
}


def allowed_text(d: ParameterDescriptor | None, default: Any) -> str:
    """What a parameter accepts, from its descriptor and default (for error messages)."""
    kind = {bool: 'true or false', int: 'an integer', float: 'a number', str: 'a string',
            list: 'a list'}.get(type(default), 'a value of the declared type')
    parts = [kind]
    if d is not None:
        for r in d.floating_point_range:
            parts.append(f'in [{r.from_value:g}, {r.to_value:g}]')
        for r in d.integer_range:
            parts.append(f'in [{r.from_value}, {r.to_value}]')
        if d.additional_constraints:
            parts.append(f'({d.additional_constraints})')
    return ' '.join(parts)


def _flatten(doc: Any, prefix: str = '') -> set[str]:
    names: set[str] = set()
    if isinstance(doc, Mapping):
        for key, value in doc.items():
            names |= _flatten(value, f'{prefix}{key}.') if isinstance(value, Mapping) else {
                f'{prefix}{key}'}
    return names


def parameter_source(name: str, node_name: str, args: Sequence[str]) -> str | None:
    """The last ``--params-file`` in ``args`` that sets ``name`` (or ``robot.<name>``)
    for ``node_name`` or ``/**``; None when no file does (an override, ``-p``)."""
    files = [args[i + 1] for i, a in enumerate(args[:-1]) if a == '--params-file']
    for path in reversed(files):
        try:
            with open(path, encoding='utf-8') as stream:
                doc = yaml.safe_load(stream)
        except (OSError, yaml.YAMLError):
            continue
        if not isinstance(doc, Mapping):
            continue
        for key, section in doc.items():
            key = str(key)
            if key not in ('/**', '**', node_name) and not key.endswith(f'/{node_name}'):
                continue
            params = section.get('ros__parameters') if isinstance(section, Mapping) else None
            names = _flatten(params)
            if name in names or f'robot.{name}' in names:
                return str(path)
    return None


def declare_failed_thrusters(node: Node) -> tuple[int, ...]:
    """Declare ``failed_thrusters`` (thruster numbers 1..4, run-time changeable) and
    return the core indices (0..3). Validated by
    :func:`tiltrov_ros.core.validation.failed_thruster_indices`."""
    d = descriptor('thrusters that give no thrust, by number: 1..4 = thruster_1..thruster_4 '
                   '(e.g. [2]); [] none; settable at run time',
                   constraints='distinct integers 1..4')
    d.dynamic_typing = True     # [] has no element type
    value = node.declare_parameter('failed_thrusters', [], d).value
    return validation.failed_thruster_indices(value)


def declare_robot(node: Node) -> tuple[RobotParams, float]:
    """Declare ``robot.*`` and ``control_period`` (the shared robot.yaml) and return them.

    Defaults are the shipped ``config/robot.yaml``, so a node started without a
    parameter file runs the shipped robot. All read-only: the geometry and the
    control period of a running stack do not change. Validated by the core
    (:class:`~tiltrov_ros.core.params.RobotParams`); an invalid value raises
    :class:`~tiltrov_ros.core.errors.ParameterError` naming it.
    """
    shipped = load_robot_params().as_dict()
    values: dict[str, Any] = {}
    for name, (text, rng) in _ROBOT_DOC.items():
        default = shipped[name]
        if isinstance(default, list):
            default = [float(v) for v in default]
        else:
            default = float(default)
        param = node.declare_parameter(f'robot.{name}', default,
                                       descriptor(text, read_only=True, floating=rng))
        values[name] = list(param.value) if isinstance(default, list) else param.value
    period = node.declare_parameter(
        'control_period', load_control_period(),
        descriptor('control period T of the stack, s (a multiple of the plant step); '
                   'control ticks are the sim times that are multiples of T',
                   read_only=True, floating=(0.0, 60.0))).value
    robot = RobotParams.from_mapping(values)
    if not period > 0:
        raise ParameterError('control_period', f'got {period!r}; allowed: a number of '
                             'seconds > 0')
    return robot, float(period)


Overrides = Mapping[str, Any] | Sequence[Parameter] | None


def as_parameters(overrides: Overrides) -> list[Parameter]:
    """Parameter overrides from a mapping (name -> value) or a list of Parameters."""
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        return [Parameter(name, value=value) for name, value in overrides.items()]
    return list(overrides)


# --------------------------------------------------------------------------- the base node

F = TypeVar('F', bound=Callable[..., Any])


def _callback_failed(node: TiltrovNode, name: str, exc: Exception) -> None:
    node.callback_errors += 1
    try:
        node.on_callback_error(name, exc)
    except Exception as inner:  # even the error handler must not escape
        node.get_logger().error(f'error handler failed: {inner!r}',
                                throttle_duration_sec=THROTTLE)


def guarded(method: F) -> F:
    """Wrap a callback so an exception is logged and counted, never raised.

    An exception escaping a callback would stop the executor (and, in the
    single-process launcher, every node with it). The node's
    :meth:`TiltrovNode.on_callback_error` decides what safe thing to do.
    """

    @functools.wraps(method)
    def wrapper(self: TiltrovNode, *args: Any) -> Any:
        try:
            return method(self, *args)
        except Exception as exc:  # the executor must survive anything a callback does
            _callback_failed(self, method.__name__, exc)
            return None

    return wrapper  # type: ignore[return-value]


def input_callback(topic: str) -> Callable[[F], F]:
    """Decorate the subscription callback of ``topic``: validation plus :func:`guarded`.

    An :class:`~tiltrov_ros.core.validation.InvalidInput` raised inside is a
    rejection of the message (:meth:`TiltrovNode.reject_input`: counted per
    topic and reason, logged, and :meth:`TiltrovNode.on_rejected` may publish a
    safe answer); any other exception is a callback error, as in :func:`guarded`.
    """

    def decorate(method: F) -> F:
        @functools.wraps(method)
        def wrapper(self: TiltrovNode, msg: Any) -> Any:
            self._input_stamp = None
            try:
                return method(self, msg)
            except InvalidInput as bad:
                try:
                    self.reject_input(topic, bad, self._input_stamp)
                except Exception as exc:
                    _callback_failed(self, method.__name__, exc)
            except Exception as exc:  # the executor must survive anything a callback does
                _callback_failed(self, method.__name__, exc)
            return None

        return wrapper  # type: ignore[return-value]

    return decorate


class SafePublisher:
    """A publisher that never sends NaN or infinity (README.md, "Reliability").

    A message with a non-finite float is not published: the node counts it
    (``unsafe_outputs`` on /diagnostics, ERROR level), logs it, and publishes
    what ``safe(msg)`` returns instead (the node's safe command), if anything.
    ``published`` counts the messages sent.
    """

    def __init__(self, node: TiltrovNode, msg_type: Any, topic: str, qos: QoSProfile,
                 safe: Callable[[Any], Any | None] | None = None) -> None:
        self.node = node
        self.topic = topic
        self.publisher = node.create_publisher(msg_type, topic, qos)
        self._safe = safe
        self.published = 0

    def publish(self, msg: Any) -> bool:
        """Publish ``msg`` if it is finite, else its safe replacement; True if ``msg`` went
        (or is held until the recorder reads this topic, see ``wait_for_recorder``)."""
        if self.node.hold_output(self, msg):
            return True
        if message_is_finite(msg):
            self.publisher.publish(msg)
            self.published += 1
            return True
        self.node.unsafe_output(self.topic)
        replacement = self._safe(msg) if self._safe is not None else None
        if replacement is not None and message_is_finite(replacement):
            self.publisher.publish(replacement)
            self.published += 1
        return False

    def get_subscription_count(self) -> int:
        return int(self.publisher.get_subscription_count())

    def wait_for_all_acked(self, timeout: Any) -> bool:
        return bool(self.publisher.wait_for_all_acked(timeout))


class InputWatchdog:
    """One input's freshness against a timeout (README.md, "Reliability"): the newest
    message's stamp and arrival, whether it is stale, how often it went stale; each
    transition logged once. The controller watches ``odom`` with it, the allocator
    ``wrench_cmd``.
    """

    def __init__(self, node: TiltrovNode, topic: str, timeout_name: str, safe_action: str,
                 resumes: str) -> None:
        self.node = node
        self.topic = topic
        self.timeout_name = timeout_name
        self.safe_action = safe_action      # what the node does while stale (for the log)
        self.resumes = resumes              # what resumes with fresh input (for the log)
        self.seen: tuple[int, int] | None = None     # (stamp, steady ns) of the newest
        self.stale = False
        self.events = 0

    def fresh(self, stamp: int, received: int | None = None) -> None:
        """A valid input stamped ``stamp`` arrived (at steady time ``received``, now if None)."""
        self.seen = (stamp, self.node.steady_ns() if received is None else received)
        if self.stale:
            self.stale = False
            self.node.get_logger().info(f'{self.topic} fresh again (stamped '
                                        f'{format_ns(stamp)}): {self.resumes}')

    def expired(self, timeout: float) -> tuple[int, int] | None:
        """(stamp, arrival) of the newest input when it is older than ``timeout`` s
        (0: off), else None; the first expiry of a stale spell is counted and logged."""
        seen = self.seen
        if seen is None or timeout <= 0:
            return None
        age = self.node.input_age_ns(*seen)
        if age <= to_ns(timeout):
            return None
        if not self.stale:
            self.stale = True
            self.events += 1
            self.node.get_logger().warning(
                f'{self.topic} is stale: the newest (stamped {format_ns(seen[0])}) is '
                f'{seconds(age):.3f} s old ({self.timeout_name} {timeout:g} s); '
                f'{self.safe_action}')
        return seen


class TiltrovNode(Node):
    """Base of the stack nodes: construction options, diagnostics, error handling,
    input validation and guarded publishers.

    Parameters
    ----------
    node_name : str
        Default name of the node.
    namespace : str, optional
        Pushed on every relative topic name.
    context : rclpy Context, optional
        For in-process tests and the single-process launcher.
    cli_args : list of str, optional
        Node-local ROS arguments, e.g. ``['--ros-args', '--params-file', path]``.
    parameter_overrides : mapping or list of Parameter, optional
        Values that win over parameter files.
    """

    def __init__(self, node_name: str, *, namespace: str | None = None,
                 context: Context | None = None, cli_args: Sequence[str] | None = None,
                 parameter_overrides: Overrides = None) -> None:
        super().__init__(node_name, namespace=namespace, context=context,
                         cli_args=list(cli_args) if cli_args is not None else None,
                         parameter_overrides=as_parameters(parameter_overrides))
        #: Where parameter files are named (error messages say which file set a value).
        self._source_args = [*(cli_args or ()), *sys.argv]
        self.callback_errors = 0
        self.steady = steady_clock()
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS,
                                                      RELIABLE_QOS)
        self._diagnostics_msg = DiagnosticArray()
        #: (topic, reason) -> messages rejected (see core/validation.py).
        self.rejections: Counter[tuple[str, str]] = Counter()
        #: topic -> outgoing messages withheld for a non-finite value.
        self.unsafe: Counter[str] = Counter()
        self.stamp_bounds = StampBounds()
        self._input_stamp: int | None = None
        self._reject_log: dict[tuple[str, str], tuple[int, int]] = {}
        self._rejected_at_last_report = 0
        self._safe_publishers: list[SafePublisher] = []
        # Lockstep with a recorder (the launcher sets it with --record): hold this
        # node's outputs, in order, until the recorder reads every one of its topics.
        # The stack's writers are VOLATILE, so what goes out before the recorder has
        # matched a writer is not recorded; a node started again mid-run (--respawn)
        # is otherwise discovered by the plant first and by the recorder up to
        # seconds later (no multicast), while lockstep runs on.
        self.recorder_node = str(self.declare_parameter('wait_for_recorder', '', descriptor(
            'name of the bag recorder node: publish nothing until it reads every topic of '
            'this node (at most RECORDER_WAIT s); empty: do not wait. tiltrov launch '
            '--record sets it in lockstep.', read_only=True)).value)
        self._held: list[tuple[SafePublisher, Any]] = []
        self._holding = bool(self.recorder_node)
        self._hold_since = time.monotonic()
        self._hold_timer = (self.create_timer(RECORDER_POLL, self._check_recorder,
                                              clock=self.steady)
                            if self._holding else None)

    def declare_parameter(self, name: str, value: Any = None,
                          descriptor: ParameterDescriptor | None = None,
                          ignore_override: bool = False) -> Parameter:
        """rclpy's, but a value of the wrong type or out of range (from a parameter
        file or an override) raises :class:`ParameterError` naming the parameter, the
        value, the allowed range and the file it came from."""
        try:
            return super().declare_parameter(name, value, descriptor, ignore_override)
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            given = getattr(self, '_parameter_overrides', {}).get(name)
            got = given.value if given is not None else value
            raise ParameterError(
                name, f'got {got!r}; allowed: {allowed_text(descriptor, value)}',
                source=parameter_source(name, self.get_name(), self._source_args)) from exc

    # -- hooks for subclasses ---------------------------------------------------

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, key values) for /diagnostics; subclasses extend it."""
        return OK, 'ok', {}

    def on_callback_error(self, callback: str, exc: Exception) -> None:
        """Called when a callback raised; subclasses publish a safe command too."""
        self.get_logger().error(f'{callback} failed: {exc!r}', throttle_duration_sec=THROTTLE)

    def on_rejected(self, topic: str, bad: InvalidInput, stamp: int | None) -> None:
        """Called after a message of ``topic`` was rejected; ``stamp`` is its stamp (ns)
        when the stamp itself was valid, else None. Subclasses answer a rejected
        tick with their safe command here."""

    # -- input validation -------------------------------------------------------

    def declare_stamp_bounds(self) -> None:
        """Declare ``stamp_max_future`` and ``stamp_max_age`` (s, run-time changeable)."""
        future = self.declare_parameter('stamp_max_future', 0.5, descriptor(
            'input stamps more than this ahead of the node\'s clock are rejected, s (sim time: '
            '/clock, the plant its own; not checked on system time); 0: not checked',
            floating=(0.0, 1e6))).value
        age = self.declare_parameter('stamp_max_age', 5.0, descriptor(
            'input stamps more than this behind the node\'s clock are rejected, s; '
            '0: not checked', floating=(0.0, 1e9))).value
        self.stamp_bounds = StampBounds.from_seconds(future, age)
        self.add_post_set_parameters_callback(self._apply_stamp_bounds)

    def _apply_stamp_bounds(self, parameters: list[Parameter]) -> None:
        if any(p.name in ('stamp_max_future', 'stamp_max_age') for p in parameters):
            self.stamp_bounds = StampBounds.from_seconds(
                self.get_parameter('stamp_max_future').value,
                self.get_parameter('stamp_max_age').value)

    # -- watchdogs ---------------------------------------------------------------

    def declare_timeout(self, name: str, default: float, text: str) -> float:
        """Declare a watchdog timeout ``name`` (s, run-time changeable, 0: off)."""
        value = self.declare_parameter(name, default, descriptor(
            f'{text}, s; on sim time measured on /clock, else wall time since the message '
            'arrived; 0: off', floating=(0.0, 3600.0))).value
        return float(value)

    def input_age_ns(self, stamp: int, received: int) -> int:
        """How old an input stamped ``stamp`` that arrived at steady time ``received`` is:
        on sim time, by ``/clock`` (0 before the first one: sim time is not running);
        on system time, the wall time since it arrived."""
        if self.on_sim_time():
            now = self.clock_ns()
            return 0 if now is None else now - stamp
        return self.steady_ns() - received

    def on_sim_time(self) -> bool:
        return bool(getattr(self.get_clock(), 'ros_time_is_active', False))

    def estimated_now_ns(self, stamp: int, received: int, period: int) -> int:
        """The stamp for a watchdog's output: sim time now on /clock, else ``stamp``
        plus the wall time since it arrived; after ``stamp``, and never a multiple of
        ``period`` (a control tick), so that no answer to a real tick, which downstream
        nodes cache by stamp, is ever confused with it."""
        now = self.clock_ns()
        if now is None:
            now = stamp + self.steady_ns() - received
        now = max(now, stamp + 1)
        return now + 1 if now % period == 0 else now

    def clock_ns(self) -> int | None:
        """The clock input stamps are checked against, ns: sim time when the node
        runs on ``/clock`` (``use_sim_time``, as ``tiltrov launch`` starts it).

        None (stamps not checked against a clock) on system time, and on sim time
        before the first ``/clock`` message (ROS time 0 means "not initialised"):
        the stack stamps with sim time, which the wall clock says nothing about.
        """
        clock = self.get_clock()
        if not getattr(clock, 'ros_time_is_active', False):
            return None
        ns = int(clock.now().nanoseconds)
        return ns if ns > 0 else None

    def check_header(self, header: Any, frame: str | None) -> int:
        """The header's stamp (ns), checked against :meth:`clock_ns` and
        :attr:`stamp_bounds`, then its ``frame_id`` against ``frame`` (None: any).

        Raises InvalidInput. Once the stamp is known to be valid, a later
        rejection of the same message passes it to :meth:`on_rejected`.
        """
        ns = validation.check_stamp(header.stamp.sec, header.stamp.nanosec, self.clock_ns(),
                                    self.stamp_bounds)
        self._input_stamp = ns
        if frame is not None:
            validation.check_frame(header.frame_id, frame)
        return ns

    def reject_input(self, topic: str, bad: InvalidInput, stamp: int | None = None) -> None:
        """Count a rejected message of ``topic``, log it (at most once per THROTTLE
        seconds per topic and reason, with the number left unlogged), and call
        :meth:`on_rejected`."""
        key = (topic, bad.reason)
        self.rejections[key] += 1
        now = self.steady_ns()
        last, quiet = self._reject_log.get(key, (None, 0))
        if last is None or now - last >= THROTTLE * NS_PER_S:
            more = f' ({quiet} more since the last report)' if quiet else ''
            self.get_logger().warning(f'rejected a {topic} message ({bad.reason}): '
                                      f'{bad.detail}{more}')
            self._reject_log[key] = (now, 0)
        else:
            self._reject_log[key] = (last, quiet + 1)
        self.on_rejected(topic, bad, stamp)

    @property
    def rejected_messages(self) -> int:
        """Messages rejected so far, every topic and reason."""
        return sum(self.rejections.values())

    # -- output guard -----------------------------------------------------------

    def create_safe_publisher(self, msg_type: Any, topic: str, qos: QoSProfile,
                              safe: Callable[[Any], Any | None] | None = None
                              ) -> SafePublisher:
        """A :class:`SafePublisher`: never NaN or infinity on ``topic``."""
        pub = SafePublisher(self, msg_type, topic, qos, safe)
        self._safe_publishers.append(pub)
        return pub

    def hold_output(self, publisher: SafePublisher, msg: Any) -> bool:
        """Keep ``msg`` for later while waiting for the recorder; True if kept."""
        if self._holding:
            self._held.append((publisher, msg))
        return self._holding

    def recorder_reads_every_topic(self) -> bool:
        """The recorder's subscription is in the graph on every guarded topic of this
        node, and every subscription there is matched with this node's writer."""
        for pub in self._safe_publishers:
            infos = self.get_subscriptions_info_by_topic(pub.publisher.topic_name)
            if not any(info.node_name == self.recorder_node for info in infos):
                return False
            if pub.get_subscription_count() < len(infos):
                return False
        return True

    def _check_recorder(self) -> None:
        waited = time.monotonic() - self._hold_since
        ready = self.recorder_reads_every_topic()
        if not ready and waited < RECORDER_WAIT:
            return
        if self._hold_timer is not None:
            self._hold_timer.cancel()
            self.destroy_timer(self._hold_timer)
            self._hold_timer = None
        self._holding = False
        held, self._held = self._held, []
        if ready:
            self.get_logger().info(f'{self.recorder_node} reads every topic of this node '
                                   f'after {waited:.2f} s; publishing {len(held)} held '
                                   'messages')
        else:
            self.get_logger().warning(f'{self.recorder_node} does not read every topic of '
                                      f'this node after {waited:.0f} s; publishing anyway '
                                      f'({len(held)} held messages)')
        for pub, msg in held:
            pub.publish(msg)

    def unsafe_output(self, topic: str) -> None:
        """Count and log an outgoing message withheld for a non-finite value."""
        self.unsafe[topic] += 1
        self.get_logger().error(f'withheld a {topic} message with a non-finite value '
                                f'({self.unsafe[topic]} so far); publishing the safe command',
                                throttle_duration_sec=THROTTLE)

    def published_counts(self) -> dict[str, int]:
        """Messages published per topic by the guarded publishers."""
        return {pub.topic: pub.published for pub in self._safe_publishers}

    # -- helpers ----------------------------------------------------------------

    def start_diagnostics(self) -> None:
        """Publish /diagnostics every DIAGNOSTICS_PERIOD wall seconds (call last in __init__)."""
        self.create_timer(DIAGNOSTICS_PERIOD, self.publish_diagnostics, clock=self.steady)

    def steady_ns(self) -> int:
        return int(self.steady.now().nanoseconds)

    @guarded
    def publish_diagnostics(self) -> None:
        level, message, values = self.diagnostic_status()
        rejected = self.rejected_messages
        if rejected > self._rejected_at_last_report:
            level = max(level, WARN)
            message = (f'{message}; {rejected - self._rejected_at_last_report} input '
                       'message(s) rejected')
        self._rejected_at_last_report = rejected
        unsafe = sum(self.unsafe.values())
        if self.callback_errors or unsafe:
            level = max(level, ERROR)
        if self.callback_errors:
            message = f'{message}; {self.callback_errors} callback error(s)'
        if unsafe:
            message = f'{message}; {unsafe} non-finite output(s) withheld'
        values = {**values, 'callback_errors': self.callback_errors,
                  'rejected_messages': rejected}
        values.update({f'rejected.{topic}.{reason}': n
                       for (topic, reason), n in sorted(self.rejections.items())})
        values.update({f'unsafe_outputs.{topic}': n for topic, n in sorted(self.unsafe.items())})
        values.update({f'published.{topic}': n for topic, n in self.published_counts().items()})
        status = DiagnosticStatus(
            level=bytes([level]), name=f'{self.get_fully_qualified_name()}',
            message=message, hardware_id='tiltrov',
            values=[KeyValue(key=str(k), value=_text(v)) for k, v in values.items()])
        msg = self._diagnostics_msg
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [status]
        self._diagnostics_pub.publish(msg)

    def check_overrides(self) -> None:
        """Warn about parameters given (file or -p) that this node does not have.

        rclpy ignores them silently; a typo in a YAML file would otherwise go
        unnoticed. Call after every parameter is declared.
        """
        given = getattr(self, '_parameter_overrides', {}) or {}
        unknown = sorted(name for name in given if not self.has_parameter(name))
        if unknown:
            self.get_logger().warning(f'ignoring unknown parameter(s): {", ".join(unknown)}')

    def reject(self, reason: str) -> SetParametersResult:
        self.get_logger().warning(f'parameter change rejected: {reason}')
        return SetParametersResult(successful=False, reason=reason)

    def check_failed_thrusters(self, parameters: list[Parameter]) -> SetParametersResult:
        """The verdict on a change that may set ``failed_thrusters`` (plant, allocator)."""
        for p in parameters:
            if p.name == 'failed_thrusters':
                try:
                    validation.failed_thruster_indices(p.value)
                except ParameterError as exc:
                    return self.reject(str(exc))
        return SetParametersResult(successful=True)


def _text(value: Any) -> str:
    if isinstance(value, float):
        return f'{value:.6g}'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_text(v) for v in value) + ']'
    return str(value)


# --------------------------------------------------------------------------- main

#: Errors that stop a node at start-up with a message and exit code 1.
STARTUP_ERRORS = (TiltrovError, ParameterException, ValueError, FileNotFoundError)


#: Executors the nodes can spin on (environment variable TILTROV_EXECUTOR).
EXECUTORS = ('events', 'single', 'multi')
DEFAULT_EXECUTOR = 'events'


def make_executor(context: Context | None = None, kind: str | None = None) -> Executor:
    """The executor the stack spins on.

    ``events`` (default): rclpy's EventsExecutor (C++, shipped with Jazzy's rclpy
    as ``rclpy.experimental``), several times faster per callback than the
    Python executors, which rebuild a wait set over every entity of every node
    (parameter services included) for each callback taken. ``single`` and
    ``multi`` are rclpy's SingleThreadedExecutor and MultiThreadedExecutor.
    ``kind`` None reads ``TILTROV_EXECUTOR``.
    """
    kind = kind or os.environ.get('TILTROV_EXECUTOR', DEFAULT_EXECUTOR)
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind == 'single':
        return SingleThreadedExecutor(context=context)
    if kind == 'multi':
        return MultiThreadedExecutor(context=context)
    raise ValueError(f'TILTROV_EXECUTOR={kind!r}; allowed: {", ".join(EXECUTORS)}')


def spin_until(executor: Executor, context: Context, future: Future | None = None,
               step: float = 0.5) -> None:
    """Spin until ``future`` is done (None: for ever) or the context shuts down (Ctrl-C).

    The wait is handed to the executor in slices of ``step`` seconds
    (``spin_until_future_complete``), never event by event from Python: the
    EventsExecutor then runs its loop in C++ (a ``None`` timeout does not
    return there when the future completes, hence the slices).
    """
    while context.ok() and (future is None or not future.done()):
        if future is None:
            executor.spin_once(timeout_sec=step)
        else:
            executor.spin_until_future_complete(future, timeout_sec=step)


def main_loop(factory: Callable[[], TiltrovNode], args: list[str] | None, name: str, *,
              until: Callable[[TiltrovNode], Future | None] | None = None,
              before_exit: Callable[[TiltrovNode], None] | None = None) -> int:
    """The Jazzy ``main``: init, spin, and always destroy the node and shut down.

    ``until`` returns a future that ends the spin when done (the plant's end of
    run); ``before_exit`` runs after a normal end (flush deliveries). A start-up
    error (an invalid parameter, a wrong-type YAML value) is printed as one line
    naming the node and gives exit code 1; Ctrl-C (the context shut down by
    rclpy's signal handler) gives 0.
    """
    rclpy.init(args=args)
    context = rclpy.get_default_context()
    node: TiltrovNode | None = None
    executor: Executor | None = None
    code = 0
    try:
        node = factory()
        executor = make_executor(context)
        executor.add_node(node)
        future = until(node) if until is not None else None
        # Not executor.spin(): the EventsExecutor's does not return when Ctrl-C shuts
        # the context down; spin_until checks the context between slices.
        spin_until(executor, context, future if future is not None else Future())
        if future is not None and future.done() and before_exit is not None:
            before_exit(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except STARTUP_ERRORS as exc:
        text = str(exc)
        if isinstance(exc, ParameterError) and exc.source is None:
            source = parameter_source(exc.name, name, list(args or sys.argv))
            prefix = f'parameter {exc.name!r}'
            if source and text.startswith(prefix):
                text = f'{prefix} (in {source}){text[len(prefix):]}'
        print(f'{name}: {text}', file=sys.stderr, flush=True)
        code = 1
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code

