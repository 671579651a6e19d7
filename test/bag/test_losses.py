"""What a recording lost, from the bag's own evidence (tiltrov_ros.bag.losses)."""

from __future__ import annotations

import json
from pathlib import Path

from test_writer import clock

from tiltrov_ros.bag.bagfile import RUN_INFO_KEY
from tiltrov_ros.bag.losses import WHOLE_RUN_LAUNCHER, losses
from tiltrov_ros.bag.msgdefs import typestore
from tiltrov_ros.bag.writer import BagWriter
from tiltrov_ros.core.names import FINAL_STATUS_KEY

NODES = ['/plant_simulator', '/thrust_allocator', '/wrench_controller']


def diagnostics(node: str, published: dict[str, int], final: bool) -> bytes:
    store = typestore()
    ns = store.types
    values = [ns['diagnostic_msgs/msg/KeyValue'](key=f'published.{topic}', value=str(n))
              for topic, n in published.items()]
    if final:
        values.append(ns['diagnostic_msgs/msg/KeyValue'](key=FINAL_STATUS_KEY, value='true'))
    msg = ns['diagnostic_msgs/msg/DiagnosticArray'](
        header=ns['std_msgs/msg/Header'](stamp=ns['builtin_interfaces/msg/Time'](
            sec=1, nanosec=0), frame_id=''),
        status=[ns['diagnostic_msgs/msg/DiagnosticStatus'](
            level=0, name=node, message='', hardware_id='', values=values)])
    return bytes(store.serialize_cdr(msg, 'diagnostic_msgs/msg/DiagnosticArray'))


def bag(tmp_path: Path, reports: dict[str, bool], *, clocks: int = 3,
        run_info: dict[str, object] | None = None) -> Path:
    """A bag of ``clocks`` /clock messages and one /diagnostics report per node of
    ``reports`` (node -> final?), the plant claiming 3 /clock published."""
    path = tmp_path / 'bag'
    info = {'launcher': WHOLE_RUN_LAUNCHER, 'nodes': NODES} if run_info is None else run_info
    with BagWriter(path, custom_data={RUN_INFO_KEY: json.dumps(info)}) as writer:
        c = writer.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
        d = writer.add_topic('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray')
        for i in range(clocks):
            writer.write(c, 1000 + i, clock(i))
        for node, final in reports.items():
            published = {'/clock': 3} if node == '/plant_simulator' else {'thrust_cmd': 0}
            writer.write(d, 2000, diagnostics(node, published, final))
    return path


def test_a_whole_run_with_every_final_report_and_message_lost_nothing(tmp_path: Path) -> None:
    found = losses(bag(tmp_path, dict.fromkeys(NODES, True)))
    assert found.whole_run and not found and found.lines() == []


def test_a_node_whose_last_report_is_not_final_is_named(tmp_path: Path) -> None:
    found = losses(bag(tmp_path, {**dict.fromkeys(NODES, True), '/wrench_controller': False}))
    assert found.unfinished == ['/wrench_controller']
    assert found.lines() == ['/wrench_controller: its final report is not in the bag: its last '
                             'messages may be lost (the recorder was behind when it stopped)']


def test_a_node_of_the_run_with_no_report_at_all_is_named(tmp_path: Path) -> None:
    """The recorder stopped before a node's first report: the launcher's list of the
    run's nodes says it was there (before, only nodes with a report were checked)."""
    reports = {'/plant_simulator': True, '/wrench_controller': True}
    found = losses(bag(tmp_path, reports))
    assert found.unfinished == ['/thrust_allocator']


def test_fewer_messages_than_published_is_a_loss_per_topic(tmp_path: Path) -> None:
    found = losses(bag(tmp_path, dict.fromkeys(NODES, True), clocks=2))
    assert found.topics == {'/clock': 1}
    assert found.lines() == ['/clock: 1 message(s) published but not recorded']


def test_a_bag_of_no_whole_run_compares_no_counts(tmp_path: Path) -> None:
    found = losses(bag(tmp_path, {'/plant_simulator': False}, clocks=1,
                       run_info={'launcher': 'ros2 launch'}))
    assert not found.whole_run and not found
