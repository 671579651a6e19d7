"""What the four stack nodes share: names, QoS, message <-> array conversions,
parameter declaration, diagnostics, the callback guard and ``main``.

The nodes are thin adapters over :mod:`tiltrov_ros.core`: they convert messages
to float arrays exactly (float64 fields, quaternions reordered from ROS
(x, y, z, w) to the core's (w, x, y, z)), call the core, and convert back. No
arithmetic happens on the way, so the ROS stack gives the numbers of the
headless runner bit for bit (ARCHITECTURE.md, "Time and stamps").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
import functools
import math
import os
import struct
import sys
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
from rclpy.exceptions import ParameterException
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

from tiltrov_ros.core.errors import ParameterError, TiltrovError
from tiltrov_ros.core.params import RobotParams, load_control_period, load_robot_params
from tiltrov_ros.core.timebase import NS_PER_S, ns_to_stamp

FloatArray = NDArray[np.float64]

# --------------------------------------------------------------------------- names

FRAME_EARTH = 'odom_ned'
FRAME_BODY = 'base_link_frd'
THRUSTERS = ('thruster_1', 'thruster_2', 'thruster_3', 'thruster_4')
TILTS = ('tilt_front', 'tilt_rear')

# Relative topic names (a namespace pushed on the stack applies to them).
ODOM = 'odom'
JOINT_STATES = 'joint_states'
SETPOINT = 'setpoint'
SETPOINT_VELOCITY = 'setpoint_velocity'
WRENCH_CMD = 'wrench_cmd'
TILT_REQUEST = 'tilt_request'
THRUST_CMD = 'thrust_cmd'
TILT_CMD = 'tilt_cmd'
WRENCH_ACHIEVED = 'wrench_achieved'
CLOCK = '/clock'
DIAGNOSTICS = '/diagnostics'

LOCKSTEP = 'lockstep'
REALTIME = 'realtime'
MODES = (LOCKSTEP, REALTIME)

#: s: repeated warnings from callbacks are throttled to one per this period.
THROTTLE = 5.0
#: s (wall): period of the /diagnostics messages.
DIAGNOSTICS_PERIOD = 1.0
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
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def cdr_stamp_ns(data: bytes) -> int:
    """Header stamp (ns) of a serialized message that starts with a ``std_msgs/Header``.

    CDR: a 4-byte encapsulation (byte 1: 1 = little endian), then the stamp's
    int32 sec and uint32 nanosec. Lets a raw subscription skip deserializing
    the messages it does not need (the controller's odometry between ticks).
    """
    if len(data) < 12:
        raise ValueError(f'a serialized message of {len(data)} bytes has no header')
    sec, nanosec = struct.unpack_from('<iI' if data[1] == 1 else '>iI', data, 4)
    return int(sec) * NS_PER_S + int(nanosec)


def set_stamp(stamp: Time, ns: int) -> None:
    """Write integer ns into a ``builtin_interfaces/Time`` in place."""
    stamp.sec, stamp.nanosec = ns_to_stamp(ns)


def steady_clock() -> Clock:
    """A monotonic wall clock for timeouts and diagnostics (independent of sim time)."""
    return Clock(clock_type=ClockType.STEADY_TIME)


def format_ns(ns: int) -> str:
    """``12.345 s``-style text of a sim time, for logs."""
    return f'{ns / NS_PER_S:.3f} s'


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


def joint_values(msg: JointState, names: Sequence[str], field: str) -> list[float] | None:
    """Values of ``field`` (position, velocity or effort) for ``names``, by name.

    None when a name is missing, the array is too short or a value is not
    finite: the caller rejects the whole message.
    """
    values = getattr(msg, field)
    index = {name: i for i, name in enumerate(msg.name)}
    out = []
    for name in names:
        i = index.get(name)
        if i is None or i >= len(values):
            return None
        out.append(float(values[i]))
    return out if _finite(out) else None


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
            self.callback_errors += 1
            try:
                self.on_callback_error(method.__name__, exc)
            except Exception as inner:  # even the error handler must not escape
                self.get_logger().error(f'error handler failed: {inner!r}',
                                        throttle_duration_sec=THROTTLE)
            return None

    return wrapper  # type: ignore[return-value]


class TiltrovNode(Node):
    """Base of the stack nodes: construction options, diagnostics, error handling.

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
        self.callback_errors = 0
        self.steady = steady_clock()
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS,
                                                      RELIABLE_QOS)
        self._diagnostics_msg = DiagnosticArray()

    # -- hooks for subclasses ---------------------------------------------------

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, key values) for /diagnostics; subclasses extend it."""
        return OK, 'ok', {}

    def on_callback_error(self, callback: str, exc: Exception) -> None:
        """Called when a callback raised; subclasses publish a safe command too."""
        self.get_logger().error(f'{callback} failed: {exc!r}', throttle_duration_sec=THROTTLE)

    # -- helpers ----------------------------------------------------------------

    def start_diagnostics(self) -> None:
        """Publish /diagnostics every DIAGNOSTICS_PERIOD wall seconds (call last in __init__)."""
        self.create_timer(DIAGNOSTICS_PERIOD, self.publish_diagnostics, clock=self.steady)

    def steady_ns(self) -> int:
        return int(self.steady.now().nanoseconds)

    @guarded
    def publish_diagnostics(self) -> None:
        level, message, values = self.diagnostic_status()
        if self.callback_errors:
            level = max(level, ERROR)
            message = f'{message}; {self.callback_errors} callback error(s)'
        values = {**values, 'callback_errors': self.callback_errors}
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
        print(f'{name}: {exc}', file=sys.stderr, flush=True)
        code = 1
    finally:
        if executor is not None:
            executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code

