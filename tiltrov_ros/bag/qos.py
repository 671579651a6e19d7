"""QoS in the three forms the bag tools meet: rclpy profiles, rosbags ``Qos``
records, and the ``offered_qos_profiles`` YAML of rosbag2 metadata.

Choices (the same as rosbag2's recorder and player):

* The recorder subscribes RELIABLE only when every publisher of the topic is
  reliable, and TRANSIENT_LOCAL only when every publisher is, so it matches
  every publisher; a best-effort reader still receives reliable writers'
  samples, a reliable reader receives nothing from a best-effort writer.
* The bag stores the publishers' profiles as the graph reports them (history
  ``unknown``, depth 0: DDS does not propagate them; infinite durations as
  9223372036 s 854775807 ns, as rosbag2 writes them).
* The player offers the recorded reliability and durability when all
  recorded publishers agree, otherwise RELIABLE/VOLATILE, with a deep
  KEEP_LAST history so a burst of recorded messages is not dropped locally.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSCompatibility,
    QoSProfile,
    ReliabilityPolicy,
    qos_check_compatible,
)
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from tiltrov_ros.core.timebase import ns_to_stamp

_HISTORY = {
    HistoryPolicy.SYSTEM_DEFAULT: QosHistory.SYSTEM_DEFAULT,
    HistoryPolicy.KEEP_LAST: QosHistory.KEEP_LAST,
    HistoryPolicy.KEEP_ALL: QosHistory.KEEP_ALL,
}
_RELIABILITY = {
    ReliabilityPolicy.SYSTEM_DEFAULT: QosReliability.SYSTEM_DEFAULT,
    ReliabilityPolicy.RELIABLE: QosReliability.RELIABLE,
    ReliabilityPolicy.BEST_EFFORT: QosReliability.BEST_EFFORT,
    ReliabilityPolicy.BEST_AVAILABLE: QosReliability.BEST_AVAILABLE,
}
_DURABILITY = {
    DurabilityPolicy.SYSTEM_DEFAULT: QosDurability.SYSTEM_DEFAULT,
    DurabilityPolicy.TRANSIENT_LOCAL: QosDurability.TRANSIENT_LOCAL,
    DurabilityPolicy.VOLATILE: QosDurability.VOLATILE,
    DurabilityPolicy.BEST_AVAILABLE: QosDurability.BEST_AVAILABLE,
}
_LIVELINESS = {
    LivelinessPolicy.SYSTEM_DEFAULT: QosLiveliness.SYSTEM_DEFAULT,
    LivelinessPolicy.AUTOMATIC: QosLiveliness.AUTOMATIC,
    LivelinessPolicy.MANUAL_BY_TOPIC: QosLiveliness.MANUAL_BY_TOPIC,
    LivelinessPolicy.BEST_AVAILABLE: QosLiveliness.BEST_AVAILABLE,
}


def _qos_time(duration: Duration) -> QosTime:
    return QosTime(*ns_to_stamp(duration.nanoseconds))


def to_bag_qos(profile: QoSProfile) -> Qos:
    """rosbags ``Qos`` record of an rclpy profile (e.g. a publisher's, from the graph)."""
    return Qos(
        history=_HISTORY.get(profile.history, QosHistory.UNKNOWN),
        depth=int(profile.depth),
        reliability=_RELIABILITY.get(profile.reliability, QosReliability.UNKNOWN),
        durability=_DURABILITY.get(profile.durability, QosDurability.UNKNOWN),
        deadline=_qos_time(profile.deadline),
        lifespan=_qos_time(profile.lifespan),
        liveliness=_LIVELINESS.get(profile.liveliness, QosLiveliness.UNKNOWN),
        liveliness_lease_duration=_qos_time(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


def _history(depth: int) -> dict[str, object]:
    if depth <= 0:
        return {'history': HistoryPolicy.KEEP_ALL, 'depth': 1}
    return {'history': HistoryPolicy.KEEP_LAST, 'depth': depth}


def subscription_qos(offered: Sequence[QoSProfile], depth: int) -> QoSProfile:
    """A reader profile that matches every offered publisher profile.

    ``depth`` <= 0 means KEEP_ALL. With no publisher known yet, RELIABLE and
    VOLATILE (the ROS 2 default every node of the stack uses).
    """
    reliable = all(p.reliability == ReliabilityPolicy.RELIABLE for p in offered)
    latched = bool(offered) and all(
        p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered)
    return QoSProfile(
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                    else DurabilityPolicy.VOLATILE),
        **_history(depth),
    )


def matches(reader: QoSProfile, offered: Sequence[QoSProfile]) -> bool:
    """True when a reader with ``reader``'s profile receives from every publisher."""
    for writer in offered:
        if (reader.reliability == ReliabilityPolicy.RELIABLE
                and writer.reliability != ReliabilityPolicy.RELIABLE):
            return False
        if (reader.durability == DurabilityPolicy.TRANSIENT_LOCAL
                and writer.durability != DurabilityPolicy.TRANSIENT_LOCAL):
            return False
    return True


def replay_qos(recorded: Sequence[Qos], depth: int = 1000) -> QoSProfile:
    """The profile the player offers for a topic recorded with ``recorded`` profiles."""
    reliabilities = {q.reliability for q in recorded}
    durabilities = {q.durability for q in recorded}
    reliability = ReliabilityPolicy.RELIABLE
    if reliabilities == {QosReliability.BEST_EFFORT}:
        reliability = ReliabilityPolicy.BEST_EFFORT
    durability = DurabilityPolicy.VOLATILE
    if durabilities == {QosDurability.TRANSIENT_LOCAL}:
        durability = DurabilityPolicy.TRANSIENT_LOCAL
    return QoSProfile(reliability=reliability, durability=durability,
                      **_history(depth))


def type_name(msg_type: Any) -> str:
    """``nav_msgs/msg/Odometry`` of the class ``nav_msgs.msg.Odometry``."""
    return f'{msg_type.__module__.split(".")[0]}/msg/{msg_type.__name__}'


def unmatched(node: Any, endpoint: Any, *, publisher: bool) -> tuple[list[Any], int]:
    """The opposite endpoints of ``endpoint`` (a publisher or a subscription of ``node``)
    in ``node``'s graph that it can match (same type, compatible QoS), and how many of
    them it has not matched yet, seen from its own side. The graph and the match come
    from the same discovery data, so an endpoint in the graph and not matched is still
    on its way."""
    topic = endpoint.topic_name
    infos = (node.get_subscriptions_info_by_topic(topic) if publisher
             else node.get_publishers_info_by_topic(topic))
    ours, kind = endpoint.qos_profile, type_name(endpoint.msg_type)
    peers = [i for i in infos if i.topic_type == kind and qos_check_compatible(
        *((ours, i.qos_profile) if publisher else (i.qos_profile, ours)))[0]
        != QoSCompatibility.ERROR]
    matched = (endpoint.get_subscription_count() if publisher
               else endpoint.get_publisher_count())
    return infos, max(len(peers) - matched, 0)
