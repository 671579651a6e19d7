"""The QoS profiles of the stack's publishers and readers (docs/nodes.md, "Topics and QoS")."""

from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from tiltrov_ros.core.names import LOCKSTEP

#
# Every publisher of the stack offers RELIABLE + VOLATILE with a KEEP_LAST
# history: lockstep needs every command, odometry and clock sample (a lost one
# is a stall), and the bag recorder subscribes RELIABLE to the stack topics
# before their publishers exist (a BEST_EFFORT publisher would leave it
# unmatched until its discovery poll re-subscribes, losing the start of the
# run). A reader that tolerates loss asks for BEST_EFFORT (sensor data), which
# matches a reliable writer: the controller's odometry in realtime mode does.
# See docs/nodes.md, "Topics and QoS".

#: Commands, setpoints, odometry, joint states: reliable, last 10. In lockstep at
#: most control_period / step_size (5) odometry samples are in flight.
RELIABLE_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE,
                          history=HistoryPolicy.KEEP_LAST, depth=10)
#: Inputs a node answers one by one (the allocator's ``wrench_cmd`` and ``tilt_request``):
#: reliable, KEEP_ALL. A KEEP_LAST reader overwrites its oldest sample, unannounced, when
#: the node falls that many behind (a replay at the stamps' pace into an allocator slowed
#: at its start lost the second wrench from a 10-deep queue); a KEEP_ALL reader refuses
#: a sample it has no room for, so the writer keeps it and sends it again.
ANSWERED_READER_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.VOLATILE,
                                 history=HistoryPolicy.KEEP_ALL)
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
#: The plant's per-step topics (``/clock``, ``joint_states``, ``odom``, ``/tf``): as
#: :data:`PUBLISHER_QOS`, ten times deeper. In a recorded lockstep run no depth decides
#: what is kept: the recorder paces the plant (``recorder_window``, 1 s of sim time: 100
#: steps), far inside it; in realtime a recorder behind by more than the depth loses
#: samples, and says so. Fast DDS frees what every reader acknowledged: a reader that
#: keeps up costs no memory.
STATE_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE,
                       history=HistoryPolicy.KEEP_LAST, depth=10000)
#: Written once and kept for every reader, late ones too (``/tf_static``,
#: ``robot_description``): reliable, transient local, the last sample, as tf2's static
#: broadcaster and robot_state_publisher offer them.
LATCHED_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         history=HistoryPolicy.KEEP_LAST, depth=1)
#: ``recorder_progress``: the recorder's latest progress for the plant of a paced run, kept
#: for a reader matched later (reliable, transient local, the last sample).
PROGRESS_QOS = LATCHED_QOS
#: The run's handshake (nodes/handshake.py): each node's latest state (:data:`LATCHED_QOS`),
#: read by every node of the run, every writer's latest kept (a topic without keys keeps
#: one queue for all its writers).
HANDSHAKE_READER_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                                  durability=DurabilityPolicy.TRANSIENT_LOCAL,
                                  history=HistoryPolicy.KEEP_LAST, depth=100)
#: The restart handoff (nodes/handoff.py): reliable, transient local (a standby that
#: starts after the node still gets the state in force), as deep as :data:`PUBLISHER_QOS`:
#: the bag records it, and a paced recorder may be ``recorder_window`` of ticks behind
#: (10 deep lost a sample of ``tilt_target`` with the recorder stopped for a 1 s window of
#: 20 ticks).
HANDOFF_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         history=HistoryPolicy.KEEP_LAST, depth=PUBLISHER_QOS.depth)
#: Readers that only want the latest sample (realtime odometry).
SENSOR_QOS = qos_profile_sensor_data


def paced_window_limit_ns(step_ns: int, period_ns: int, markers_ns: int) -> int:
    """The longest ``recorder_window`` whose samples every recorded writer keeps.

    A paced plant runs at most the window plus a control period ahead of what the
    recorder has written; a KEEP_LAST writer drops its oldest sample once its history is
    full, acknowledged or not. So what a window lets by must fit the shallowest history:
    steps (:data:`STATE_QOS`), ticks (:data:`PUBLISHER_QOS`, :data:`HANDOFF_QOS`),
    markers (:data:`PUBLISHER_QOS`), two samples to spare.
    """
    limits = [(STATE_QOS.depth - 2) * step_ns - period_ns,
              (min(PUBLISHER_QOS.depth, HANDOFF_QOS.depth) - 2) * period_ns - period_ns]
    if markers_ns:
        limits.append((PUBLISHER_QOS.depth - 2) * markers_ns - period_ns)
    return max(0, min(limits))


def reader_qos(mode: str) -> QoSProfile:
    """Odometry reader profile: reliable in lockstep, sensor data in realtime."""
    return RELIABLE_QOS if mode == LOCKSTEP else SENSOR_QOS
