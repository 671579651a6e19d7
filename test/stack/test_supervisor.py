"""The process supervisor's status file (the launch tests run the supervisor itself)."""

from __future__ import annotations

import json
from pathlib import Path

from tiltrov_ros.stack.supervisor import StatusFile


def test_status_file_is_replaced_whole_at_each_write(tmp_path: Path) -> None:
    path = tmp_path / 'status.json'
    status = StatusFile(path)
    status.write('starting', {})
    assert json.loads(path.read_text()) == {'state': 'starting', 'exit_code': None, 'nodes': {}}
    nodes = {'plant_simulator': {'pid': 42, 'starts': 1, 'running': True}}
    status.write('ended', nodes, 0)
    assert json.loads(path.read_text()) == {'state': 'ended', 'exit_code': 0, 'nodes': nodes}
    assert sorted(p.name for p in tmp_path.iterdir()) == ['status.json']   # no temporary left


def test_no_status_file_without_a_path(tmp_path: Path) -> None:
    StatusFile(None).write('running', {})
    assert list(tmp_path.iterdir()) == []


def test_a_stopping_node_has_time_to_wait_for_its_readers_before_sigterm() -> None:
    from tiltrov_ros.nodes.base import DELIVERY_WAIT
    from tiltrov_ros.stack.supervisor import STOP_TIMEOUTS

    assert STOP_TIMEOUTS[0] > DELIVERY_WAIT + 1.0
