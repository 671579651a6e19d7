"""The stack's topic names and types (README.md and ARCHITECTURE.md), and name helpers.

The recorder subscribes to these before their publishers exist, so the first
message of a run is recorded; the bag reader looks them up by these names.
Names without a leading ``/`` are relative to the stack's namespace.
"""

from __future__ import annotations

# relative name (or absolute, with a leading '/') -> ROS 2 type name
STACK_TOPICS: dict[str, str] = {
    'odom': 'nav_msgs/msg/Odometry',
    'joint_states': 'sensor_msgs/msg/JointState',
    'setpoint': 'geometry_msgs/msg/PoseStamped',
    'setpoint_velocity': 'geometry_msgs/msg/TwistStamped',
    'wrench_cmd': 'geometry_msgs/msg/WrenchStamped',
    'thrust_cmd': 'sensor_msgs/msg/JointState',
    'tilt_cmd': 'sensor_msgs/msg/JointState',
    'tilt_request': 'sensor_msgs/msg/JointState',
    'wrench_achieved': 'geometry_msgs/msg/WrenchStamped',
    '/clock': 'rosgraph_msgs/msg/Clock',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
}

CLOCK_TOPIC = '/clock'


def join_namespace(namespace: str, name: str) -> str:
    """Absolute name of ``name`` in ``namespace`` (absolute names are kept)."""
    if name.startswith('/'):
        return name
    namespace = namespace.rstrip('/')
    return f'{namespace}/{name}' if namespace else f'/{name}'


def is_hidden(name: str) -> bool:
    """True for names with a token starting with ``_`` (ROS 2 hidden topics)."""
    return any(token.startswith('_') for token in name.split('/'))


def normalize_type(msgtype: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type``; ``pkg/msg/Type`` is kept."""
    parts = msgtype.split('/')
    if len(parts) == 2:
        return f'{parts[0]}/msg/{parts[1]}'
    return msgtype
