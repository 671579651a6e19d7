"""The stack's vocabulary: frames, joints, degrees of freedom, topics, nodes, run modes.

The one definition of each name (docs/nodes.md lists them with their
messages): the nodes, the launcher, the bag tools, the analysis and the tests
import them from here. Pure Python, no ROS.

Topic names are relative (a namespace pushed on the stack applies to them),
except ``/clock`` and ``/diagnostics``, which ROS keeps global, and ``/tf`` and
``/tf_static``, which a namespaced stack remaps into its namespace
(:data:`TF_REMAPPINGS`, as Nav2 does for several robots).
"""

from __future__ import annotations

# --------------------------------------------------------------------------- frames

#: Earth frame, NED (Fossen; the paper), and body frame, FRD.
FRAME_EARTH = 'odom_ned'
FRAME_BODY = 'base_link_frd'
#: Their ENU/FLU siblings (REP-103, REP-105), as a robot's state estimator names them.
FRAME_EARTH_ENU = 'odom'
FRAME_BODY_FLU = 'base_link'
#: The thrusters' links of the URDF (children of base_link_frd through the tilt joints;
#: x along the thrust): thruster_1_link .. thruster_4_link.
THRUSTER_LINKS = tuple(f'thruster_{i}_link' for i in range(1, 5))
#: ``header.frame_id`` of a safety command that answers no wrench_cmd: the allocator's
#: zero thrust (tilts held) while wrench_cmd is stale. Such a command is also stamped
#: off the control-tick grid (ARCHITECTURE.md, "Time and stamps").
FAILSAFE_FRAME = 'failsafe'

# --------------------------------------------------------------------------- joints

#: The four thrusters (eq. (4)): 1 front-left, 2 front-right, 3 rear-right, 4 rear-left.
THRUSTERS = ('thruster_1', 'thruster_2', 'thruster_3', 'thruster_4')
#: The two tilt servos: alpha turns thrusters 1 and 2, beta turns 3 and 4.
TILTS = ('tilt_front', 'tilt_rear')
#: The servos as metrics and tables name them (same order as TILTS).
SERVOS = ('front', 'rear')
#: The URDF's joints of the second thruster of each pair, which mimic its tilt joint.
TILT_MIMICS = ('tilt_front_thruster_2', 'tilt_rear_thruster_4')

# --------------------------------------------------------------------------- DOFs

#: eta: position in NED and ZYX Euler angles.
DOF_NAMES = ('x', 'y', 'z', 'roll', 'pitch', 'yaw')
DOF_UNITS = ('m', 'm', 'm', 'rad', 'rad', 'rad')
#: tau: body force (X Y Z) and moment (K M N), as ``wrench_cmd`` carries it.
WRENCH_DOFS = ('X', 'Y', 'Z', 'K', 'M', 'N')
WRENCH_UNITS = ('N', 'N', 'N', 'N m', 'N m', 'N m')

# --------------------------------------------------------------------------- topics

ODOM = 'odom'
JOINT_STATES = 'joint_states'
SETPOINT = 'setpoint'
SETPOINT_VELOCITY = 'setpoint_velocity'
WRENCH_CMD = 'wrench_cmd'
TILT_REQUEST = 'tilt_request'
THRUST_CMD = 'thrust_cmd'
TILT_CMD = 'tilt_cmd'
WRENCH_ACHIEVED = 'wrench_achieved'
#: The restart handoff (nodes/handoff.py): the pid's integral after each tick; the
#: allocator's servo travel target (no joints when none is under way).
PID_INTEGRAL = 'pid_integral'
TILT_TARGET = 'tilt_target'
HANDOFF_TOPICS = (PID_INTEGRAL, TILT_TARGET)
CLOCK = '/clock'
DIAGNOSTICS = '/diagnostics'
ROBOT_MARKERS = 'robot_markers'
#: Key of a node's last /diagnostics status, sent as it stops (value 'true'): a recording
#: of the whole run without it may lack the node's last messages.
FINAL_STATUS_KEY = 'final'
#: Keys of every stack node's /diagnostics: the implementation running (``numba``: the
#: compiled kernels; ``numpy``: the reference) and the seconds the node's constructor
#: took to compile or load its kernels.
BACKEND_KEY = 'backend'
KERNEL_WARMUP_KEY = 'kernel_warmup_s'

#: The run's handshake (nodes/handshake.py): each node's state, diagnostic_msgs/DiagnosticStatus,
#: transient local. The recorder's progress in a paced lockstep run (rosgraph_msgs/Clock: the
#: sim time up to which every paced topic is written). Neither is recorded; replay and
#: analysis never see them.
HANDSHAKE = 'handshake'
RECORDER_PROGRESS = 'recorder_progress'
HANDSHAKE_TOPICS: dict[str, str] = {HANDSHAKE: 'diagnostic_msgs/msg/DiagnosticStatus',
                                    RECORDER_PROGRESS: 'rosgraph_msgs/msg/Clock'}
#: The topics stamped with the control tick they answer or serve, published by the nodes
#: other than the plant: a recorded lockstep run is paced on them and on ``/clock``.
TICK_TOPICS = (SETPOINT_VELOCITY, SETPOINT, TILT_REQUEST, PID_INTEGRAL, WRENCH_CMD,
               TILT_TARGET, WRENCH_ACHIEVED, TILT_CMD, THRUST_CMD)

#: Every topic of the stack -> its ROS 2 type, in the order the stack publishes
#: them within a step and a tick.
STACK_TOPICS: dict[str, str] = {
    ODOM: 'nav_msgs/msg/Odometry',
    JOINT_STATES: 'sensor_msgs/msg/JointState',
    CLOCK: 'rosgraph_msgs/msg/Clock',
    SETPOINT_VELOCITY: 'geometry_msgs/msg/TwistStamped',
    SETPOINT: 'geometry_msgs/msg/PoseStamped',
    TILT_REQUEST: 'sensor_msgs/msg/JointState',
    PID_INTEGRAL: 'sensor_msgs/msg/JointState',
    WRENCH_CMD: 'geometry_msgs/msg/WrenchStamped',
    TILT_TARGET: 'sensor_msgs/msg/JointState',
    WRENCH_ACHIEVED: 'geometry_msgs/msg/WrenchStamped',
    TILT_CMD: 'sensor_msgs/msg/JointState',
    THRUST_CMD: 'sensor_msgs/msg/JointState',
    DIAGNOSTICS: 'diagnostic_msgs/msg/DiagnosticArray',
    ROBOT_MARKERS: 'visualization_msgs/msg/MarkerArray',
}

#: The transform tree (REP-105), tf2_msgs/msg/TFMessage: odom -> base_link (and the
#: thruster links) at every plant step, and the static relations, transient local.
TF = '/tf'
TF_STATIC = '/tf_static'
TF_TOPICS: dict[str, str] = {TF: 'tf2_msgs/msg/TFMessage', TF_STATIC: 'tf2_msgs/msg/TFMessage'}
#: ``-r`` remappings that keep a namespaced stack's tree in its namespace.
TF_REMAPPINGS = ((TF, TF.lstrip('/')), (TF_STATIC, TF_STATIC.lstrip('/')))
#: The URDF as robot_state_publisher publishes it (std_msgs/String, transient local).
ROBOT_DESCRIPTION = 'robot_description'
#: Topics written once for every reader (transient local) that a bag holds from the run's
#: start: topic -> type (the tree's static relations and the URDF).
LATCHED_TOPICS: dict[str, str] = {TF_STATIC: TF_TOPICS[TF_STATIC],
                                  ROBOT_DESCRIPTION: 'std_msgs/msg/String'}

# --------------------------------------------------------------------------- nodes

#: Node names, which are also the executables' names.
PLANT = 'plant_simulator'
CONTROLLER = 'wrench_controller'
ALLOCATOR = 'thrust_allocator'
REFERENCE = 'reference_publisher'
RECORDER = 'bag_recorder'
#: Environment variable (value 1) that makes a node's process a standby: it keeps the
#: node's restart handoff and builds the node on SIGUSR1 (nodes/handoff.py).
STANDBY_ENV = 'TILTROV_STANDBY'


def standby_name(node: str) -> str:
    """The node name of ``node``'s standby until it takes over (a run node of its own
    in a run with a respawn: the run starts once it keeps the handoff)."""
    return f'{node}_standby'


#: Every node of the package (a parameter file section naming none of them is reported).
NODES = (PLANT, CONTROLLER, ALLOCATOR, REFERENCE, RECORDER)
#: The stack's nodes: each reports what it published on /diagnostics, finally as it stops.
STACK_NODES = (PLANT, CONTROLLER, ALLOCATOR, REFERENCE)

# --------------------------------------------------------------------------- modes

#: The stack's timing: deterministic and as fast as possible, or on the wall clock.
LOCKSTEP = 'lockstep'
REALTIME = 'realtime'
MODES = (LOCKSTEP, REALTIME)
#: The allocator's modes (``ThrustAllocator(mode=...)``); robust is the default.
ALLOCATOR_MODES = ('robust', 'paper')


def normalize_namespace(namespace: str) -> str:
    """``robot1``, ``/robot1/`` -> ``/robot1``; ``''`` and ``/`` -> ``''`` (none)."""
    namespace = namespace.strip().strip('/')
    return f'/{namespace}' if namespace else ''


def join_namespace(namespace: str, name: str) -> str:
    """Absolute name of ``name`` in ``namespace`` (absolute names are kept)."""
    if name.startswith('/'):
        return name
    namespace = namespace.rstrip('/')
    return f'{namespace}/{name}' if namespace else f'/{name}'
