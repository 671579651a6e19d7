"""/tf and /tf_static from the plant: one REP-105 tree, and it agrees with ``odom``.

* A lockstep run of the whole stack (the launcher's nodes, in process): every
  ``odom`` stamp has its ``/tf`` with the same stamp; the tree composed from
  ``/tf`` and ``/tf_static`` gives ``odom_ned -> base_link_frd`` equal to the
  odometry pose and puts each thruster link along eq. (4) at the
  ``joint_states`` tilts; each frame has one parent.
* A subscriber started 5 s of sim time after the plant published ``/tf_static``
  still receives it (transient local), and the URDF on ``robot_description``.
* A namespaced stack's tree is in its namespace; ``tf: false`` publishes none.
"""

from __future__ import annotations

import io
import threading
from typing import Any
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from ros_stack import LATCHED, NS, TOPIC_TYPES, Probe, require_tf2_msgs, run_stack
from std_msgs.msg import String
from tf_tree import (
    REP105,
    TREE,
    assert_is_the_odometry,
    assert_one_tree,
    body_in_odom_ned,
    by_child,
    pose,
    tf_stamp,
)

from tiltrov_ros.core.names import FRAME_BODY, FRAME_BODY_FLU, THRUSTER_LINKS
from tiltrov_ros.core.thrust_map import thruster_directions, thruster_positions
from tiltrov_ros.nodes.conversions import stamp_ns
from tiltrov_ros.nodes.plant_simulator import PlantSimulator
from tiltrov_ros.stack.launch import launch
from tiltrov_ros.stack.specs import LaunchOptions

TFMessage = require_tf2_msgs()
TOPIC_TYPES.setdefault('/tf', TFMessage)
TOPIC_TYPES.setdefault('tf', TFMessage)

def _tf_at(probe: Probe, ns: int) -> bool:
    """The probe has /tf stamped ``ns``."""
    return any(stamp_ns(m.transforms[0].header.stamp) == ns for m in probe['/tf'])


@pytest.fixture(scope='module')
def lockstep_tree() -> dict[str, Any]:
    """One lockstep run (pitch_hold, pd, 2 s): odom, joint_states, every /tf, and
    /tf_static as a late-joining reader gets it."""
    from harness import RosHarness

    ros = RosHarness()
    try:
        static: list[Any] = []
        ros.node('static_probe').create_subscription(TFMessage, '/tf_static', static.append,
                                                     LATCHED)
        run = run_stack(ros.context, ros.executor,
                        LaunchOptions(scenario='pitch_hold', controller='pd', duration=2.0),
                        topics=['odom', 'joint_states', '/tf'], last=_tf_at)
        assert ros.spin_until(lambda: bool(static), timeout=10.0)
        return {'run': run, 'static': static}
    finally:
        ros.close()


@pytest.mark.slow
def test_the_static_relations_are_rep_105s(lockstep_tree: dict[str, Any]) -> None:
    (message,) = lockstep_tree['static']
    static = by_child(message)
    assert sorted(static) == sorted(REP105)
    for child, expected in REP105.items():
        assert static[child].header.frame_id == TREE[child]
        rotation, translation = pose(static[child])
        np.testing.assert_allclose(rotation, expected, rtol=0, atol=1e-15)
        assert translation.tolist() == [0.0, 0.0, 0.0]
        assert stamp_ns(static[child].header.stamp) == 0


@pytest.mark.slow
def test_the_tree_is_complete_at_every_step_and_each_frame_has_one_parent(
        lockstep_tree: dict[str, Any]) -> None:
    run = lockstep_tree['run']
    odom_stamps = sorted(set(run.probe.stamps('odom')))
    assert odom_stamps == [i * 10_000_000 for i in range(201)]
    tf = {tf_stamp(message): message for message in run.probe['/tf']}
    assert sorted(tf) == odom_stamps
    (static,) = lockstep_tree['static']
    for message in tf.values():
        assert_one_tree(static, message)


@pytest.mark.slow
def test_odom_ned_to_base_link_frd_composed_from_the_tree_is_the_odometry(
        lockstep_tree: dict[str, Any]) -> None:
    """odom_ned -> base_link_frd = (odom -> odom_ned)^-1 (odom -> base_link)
    (base_link -> base_link_frd), at every step; and each thruster link at r_i with its
    x axis along eq. (4)'s thrust direction at the joint_states tilts."""
    run, (static,) = lockstep_tree['run'], lockstep_tree['static']
    odom = run.probe.by_stamp('odom')
    joints = run.probe.by_stamp('joint_states')
    config = run.config
    for message in run.probe['/tf']:
        ns = tf_stamp(message)
        assert_is_the_odometry(body_in_odom_ned(static, message), odom[ns])
        moving = by_child(message)
        tilts = list(joints[ns].position[:2])
        directions = thruster_directions(*tilts)
        positions = thruster_positions(config.robot.length, config.robot.width)
        for i, link in enumerate(THRUSTER_LINKS):
            link_rotation, link_position = pose(moving[link])
            np.testing.assert_allclose(link_position, positions[i], rtol=0, atol=1e-15)
            np.testing.assert_allclose(link_rotation[:, 0], directions[i], rtol=0,
                                       atol=1e-12)
    # Nothing sent twice (a stall, a wait over stall_timeout wall seconds, is a report).
    assert run.extra['republished'] == 0


def _plant(ros: Any, **overrides: Any) -> PlantSimulator:
    """A plant alone in realtime, 20 x the wall clock, its time starting at once."""
    return ros.add(PlantSimulator(context=ros.context, parameter_overrides={
        'mode': 'realtime', 'real_time_factor': 20.0, 'startup_subscribers': 0,
        'scenario': 'pitch_hold', **overrides}))


@pytest.mark.slow
def test_a_subscriber_started_5_s_late_still_receives_tf_static(ros: Any) -> None:
    """Late by sim time (the plant's own clock, not the machine's speed): the reader is
    created once the plant is past 5 s, long after /tf_static went out, once."""
    plant = _plant(ros)
    assert ros.spin_until(lambda: plant.plant.time_ns >= 5 * NS, timeout=120.0)
    late = ros.node('late_reader')
    static: list[Any] = []
    description: list[Any] = []
    late.create_subscription(TFMessage, '/tf_static', static.append, LATCHED)
    late.create_subscription(String, 'robot_description', description.append, LATCHED)
    assert ros.spin_until(lambda: bool(static) and bool(description), timeout=30.0)
    assert sorted(by_child(*static)) == sorted(REP105)
    assert plant.published_counts()['/tf_static'] == 1
    robot = ET.fromstring(description[0].data)
    assert sorted(link.get('name') for link in robot.iter('link')) == sorted(
        [FRAME_BODY, *THRUSTER_LINKS])


@pytest.mark.slow
def test_tf_false_publishes_no_tree(ros: Any) -> None:
    plant = _plant(ros, tf=False)
    assert plant.transforms is None
    assert ros.spin_until(lambda: plant.plant.time_ns >= NS, timeout=60.0)
    assert plant.count_publishers('/tf') == plant.count_publishers('/tf_static') == 0
    assert '/tf' not in plant.published_counts()


@pytest.mark.slow
def test_a_namespaced_stack_has_its_own_tree(ros: Any) -> None:
    """``--namespace r1`` (the launcher's remappings, one process): /r1/tf and
    /r1/tf_static; no publisher of the root tree."""
    probe = Probe(ros.node('tree_probe', namespace='/r1'), ['odom', 'tf'])
    mine: list[Any] = []
    root: list[Any] = []
    probe.node.create_subscription(TFMessage, 'tf_static', mine.append, LATCHED)
    ros.node('root_probe').create_subscription(TFMessage, '/tf_static', root.append, LATCHED)
    publishers: dict[str, int] = {}

    def graph() -> None:
        for topic in ('/tf', '/tf_static', '/r1/tf', '/r1/tf_static'):
            publishers[topic] = max(publishers.get(topic, 0),
                                    probe.node.count_publishers(topic))

    probe.node.create_timer(0.05, graph)
    stream = io.StringIO()
    result: list[int] = []
    options = LaunchOptions(scenario='pitch_hold', duration=1.0, single_process=True,
                            namespace='r1', params=('plant_simulator:startup_subscribers:=2',))
    thread = threading.Thread(target=lambda: result.append(launch(options, stream)))
    thread.start()
    try:
        ros.spin_until(lambda: not thread.is_alive(), timeout=120.0)
    finally:
        thread.join(timeout=120.0)
    assert result == [0], stream.getvalue()
    end = NS

    def tf_stamps() -> set[int]:
        return {stamp_ns(m.transforms[0].header.stamp) for m in probe['tf']}

    # Every message reached the probe before the launch ended (the plant waits for its
    # readers' acknowledgements); the last odom and /tf may still wait to be taken.
    assert ros.spin_until(lambda: end in probe.stamps('odom') and end in tf_stamps())
    assert tf_stamps() <= set(probe.stamps('odom'))
    assert sorted(by_child(*mine)) == sorted(REP105)
    assert root == []
    assert publishers == {'/tf': 0, '/tf_static': 0, '/r1/tf': 1, '/r1/tf_static': 1}


def test_without_tf2_msgs_the_plant_runs_without_the_tree_and_says_so_once(
        ros: Any, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]) -> None:
    """A venv where tf2_msgs could not be built: the stack runs, with one line."""
    import tiltrov_ros.nodes.transforms as transforms

    monkeypatch.setattr(transforms, 'TFMessage', None)
    plant = _plant(ros)
    assert plant.transforms is None
    assert ros.spin_until(lambda: plant.plant.time_ns >= NS // 10, timeout=60.0)
    assert plant.count_publishers('/tf') == plant.count_publishers('/tf_static') == 0
    assert capfd.readouterr().err.count('tf2_msgs is not importable') == 1


@pytest.mark.slow
def test_with_robot_state_publisher_the_plant_leaves_it_the_thruster_links(ros: Any) -> None:
    """``tf_thrusters: false`` (ros2 launch where robot_state_publisher runs): /tf carries
    odom -> base_link alone, and the plant publishes no robot_description."""
    plant = _plant(ros, tf_thrusters=False)
    tf: list[Any] = []
    ros.node('tf_reader').create_subscription(TFMessage, '/tf', tf.append, 100)
    assert ros.spin_until(lambda: len(tf) >= 5, timeout=60.0)
    assert {tuple(t.child_frame_id for t in m.transforms) for m in tf} == {(FRAME_BODY_FLU,)}
    assert plant.count_publishers('robot_description') == 0
