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
