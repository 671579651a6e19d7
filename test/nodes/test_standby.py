"""A standby at its takeover: its node is destroyed only once the node that takes over is
built (nodes/executors.py stand_by, retire), so the new node's endpoints never take the
place of endpoints just destroyed in the same participant."""

from __future__ import annotations

import threading
from typing import Any

from tiltrov_ros.core.names import ALLOCATOR, CONTROLLER, standby_name
from tiltrov_ros.nodes.executors import retire, stand_by


def test_the_standby_node_lives_until_the_node_that_took_over_is_built(ros: Any) -> None:
    stop, takeover = threading.Event(), threading.Event()
    takeover.set()                              # SIGUSR1 came: no standing by
    standby = stand_by(object(), CONTROLLER, ros.context, stop, takeover)
    assert standby is not None and not standby.handoff
    successor = ros.node('successor')
    assert standby_name(CONTROLLER) in successor.get_node_names()
    retire(standby)
    assert standby_name(CONTROLLER) not in successor.get_node_names()
    assert 'successor' in successor.get_node_names()


def test_a_standby_stopped_without_a_takeover_is_gone(ros: Any) -> None:
    stop, takeover = threading.Event(), threading.Event()
    stop.set()
    assert stand_by(object(), ALLOCATOR, ros.context, stop, takeover) is None
    assert standby_name(ALLOCATOR) not in ros.node('probe').get_node_names()


def test_a_node_built_by_its_standby_states_only_its_own_endpoints(ros: Any) -> None:
    """The successor's graph still holds the killed predecessor's endpoints under the same
    name (until the dead participant's lease ends); the handshake state must not list them,
    or the next standby, which never saw the predecessor, waits for them for ever."""
    import rclpy
    from rclpy.context import Context
    from std_msgs.msg import String

    from tiltrov_ros.nodes.handshake import Handshake

    run = ['twin', 'other']
    predecessor_context = Context()
    rclpy.init(context=predecessor_context)
    try:
        predecessor = rclpy.create_node('twin', context=predecessor_context)
        predecessor.create_publisher(String, 'handed_over', 10)
        Handshake(predecessor, run).start()
        standby = ros.node('twin_standby')          # first in the participant, as a standby
        Handshake(standby, run).start()
        successor = ros.node('twin')
        successor.create_publisher(String, 'handed_over', 10)
        assert ros.spin_until(lambda: sum(
            i.node_name == 'twin' for i in successor.get_publishers_info_by_topic(
                '/handed_over')) == 2, timeout=120.0), 'the predecessor was never discovered'
        handshake = Handshake(successor, run)
        handshake.start()
        state = handshake.own_state()
        own = [gid for topic, gid in state.publishes if topic == '/handed_over']
        assert len(own) == 1 and own[0].startswith(handshake.participant or '-')
    finally:
        rclpy.try_shutdown(context=predecessor_context)
