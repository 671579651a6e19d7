"""thrust_allocator: answers stamped with the wrench, previous, tilt requests, diagnostics."""

from __future__ import annotations

from pathlib import Path

from geometry_msgs.msg import WrenchStamped
import numpy as np
import pytest
from rclpy.exceptions import InvalidParameterTypeException
from rclpy.parameter import Parameter
from ros_stack import KEEP_ALL, MS, Probe, effort_rows, joint_state, wrench, wrench_rows
from sensor_msgs.msg import JointState

from tiltrov_ros.core.allocation import load_allocator_config
from tiltrov_ros.core.params import load_robot_params
from tiltrov_ros.nodes.thrust_allocator import ThrustAllocatorNode
from tiltrov_ros.paths import config_file

TICK = 50 * MS
W1 = [10.0, -4.0, 30.0, 1.0, -2.0, 0.5]
W2 = [12.0, -3.0, 28.0, 0.5, -2.5, 0.4]


@pytest.fixture
def rig(ros):
    node = ros.node('allocator_test')
    probe = Probe(node, ['thrust_cmd', 'tilt_cmd', 'wrench_achieved', '/diagnostics'])
    wrench_pub = node.create_publisher(WrenchStamped, 'wrench_cmd', KEEP_ALL)
    return ros, node, probe, wrench_pub


def _allocator(ros, **overrides) -> ThrustAllocatorNode:
    return ros.add(ThrustAllocatorNode(context=ros.context, parameter_overrides=overrides))


def _core():
    return load_allocator_config().build(load_robot_params(), 0.05)


def _answered(probe: Probe, n: int):
    return lambda: all(len(probe[t]) == n for t in ('thrust_cmd', 'tilt_cmd',
                                                     'wrench_achieved'))


def test_answers_stamped_with_the_wrench_and_allocated_from_previous(rig) -> None:
    ros, _, probe, pub = rig
    node = _allocator(ros)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(wrench(0, W1))
    assert ros.spin_until(_answered(probe, 1))
    pub.publish(wrench(TICK, W2))
    assert ros.spin_until(_answered(probe, 2))
    for topic in ('thrust_cmd', 'tilt_cmd', 'wrench_achieved'):
        assert probe.stamps(topic) == [0, TICK]
    thrust, tilt = probe['thrust_cmd'][0], probe['tilt_cmd'][0]
    assert list(thrust.name) == ['thruster_1', 'thruster_2', 'thruster_3', 'thruster_4']
    assert list(tilt.name) == ['tilt_front', 'tilt_rear']
    assert probe['wrench_achieved'][0].header.frame_id == 'base_link_frd'

    core = _core()
    r1 = core.allocate(np.array(W1))
    r2 = core.allocate(np.array(W2), previous=r1)
    np.testing.assert_array_equal(effort_rows(probe['thrust_cmd']),
                                  np.array([r1.thrusts, r2.thrusts]))
    assert [tuple(m.position) for m in probe['tilt_cmd']] == [
        (r1.tilt_front, r1.tilt_rear), (r2.tilt_front, r2.tilt_rear)]
    np.testing.assert_array_equal(wrench_rows(probe['wrench_achieved']),
                                  np.array([r1.achieved, r2.achieved]))
    assert node.tilt_request_mode == 'auto' and node.ticks == 2


def test_repeated_stamp_republishes_the_cached_answer(rig) -> None:
    ros, _, probe, pub = rig
    node = _allocator(ros)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(wrench(0, W1))
    assert ros.spin_until(_answered(probe, 1))
    previous = node.previous
    pub.publish(wrench(0, W2))       # same stamp: the answer already given, not W2's
    assert ros.spin_until(_answered(probe, 2))
    assert node.previous is previous and (node.ticks, node.republished) == (1, 1)
    assert list(probe['thrust_cmd'][1].effort) == list(probe['thrust_cmd'][0].effort)


@pytest.mark.parametrize('request_first', [False, True])
def test_required_tilt_request_pairs_by_stamp(rig, request_first: bool) -> None:
    ros, node, probe, pub = rig
    _allocator(ros, tilt_request='required')
    tilt_pub = node.create_publisher(JointState, 'tilt_request', KEEP_ALL)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0
                          and tilt_pub.get_subscription_count() > 0)
    request = joint_state(0, ['tilt_front', 'tilt_rear'], position=[0.0, 0.0])
    if request_first:
        tilt_pub.publish(request)
        ros.spin_for(0.1)
    pub.publish(wrench(0, W1))
    if not request_first:
        ros.spin_for(0.2)
        assert probe['thrust_cmd'] == []        # waits for its tilt request
        tilt_pub.publish(request)
    assert ros.spin_until(_answered(probe, 1))
    expected = _core().allocate_fixed(np.array(W1), 0.0, 0.0)
    assert list(probe['thrust_cmd'][0].effort) == list(expected.thrusts)
    assert list(probe['tilt_cmd'][0].position) == [0.0, 0.0]


def test_tilt_request_timeout_uses_the_latest(rig) -> None:
    ros, node, probe, pub = rig
    alloc = _allocator(ros, tilt_request='required', input_timeout=0.05)
    tilt_pub = node.create_publisher(JointState, 'tilt_request', KEEP_ALL)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0
                          and tilt_pub.get_subscription_count() > 0)
    tilt_pub.publish(joint_state(0, ['tilt_front', 'tilt_rear'], position=[0.1, 0.1]))
    pub.publish(wrench(0, W1))
    assert ros.spin_until(_answered(probe, 1))
    pub.publish(wrench(TICK, W1))           # its tilt request never comes
    assert ros.spin_until(_answered(probe, 2))
    assert alloc.stale_requests == 1
    assert list(probe['tilt_cmd'][1].position) == [0.1, 0.1]


def test_auto_mode_follows_the_graph(rig) -> None:
    ros, node, probe, pub = rig
    alloc = _allocator(ros)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(wrench(0, W1))
    assert ros.spin_until(_answered(probe, 1))          # no tilt_request publisher: free
    tilt_pub = node.create_publisher(JointState, 'tilt_request', KEEP_ALL)
    assert ros.spin_until(lambda: alloc.count_publishers('tilt_request') > 0)
    pub.publish(wrench(TICK, W1))
    ros.spin_for(0.2)
    assert len(probe['thrust_cmd']) == 1                 # now it waits for the request
    tilt_pub.publish(joint_state(TICK, ['tilt_front', 'tilt_rear'], position=[0.0, 0.0]))
    assert ros.spin_until(_answered(probe, 2))


def test_diagnostics_count_feasible_infeasible_and_saturated(rig) -> None:
    ros, _, probe, pub = rig
    node = _allocator(ros)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(wrench(0, [500.0, 0.0, 0.0, 0.0, 0.0, 0.0]))   # beyond 4 x 40 N
    pub.publish(wrench(TICK, [0.0] * 6))
    assert ros.spin_until(_answered(probe, 2))
    assert (node.feasible, node.infeasible, node.saturated) == (1, 1, 1)

    def status():
        return next((s for m in reversed(probe['/diagnostics']) for s in m.status
                     if s.name.endswith('thrust_allocator')), None)

    assert ros.spin_until(lambda: status() is not None, timeout=5.0)
    values = {kv.key: kv.value for kv in status().values}
    assert (values['feasible'], values['infeasible'], values['saturated']) == ('1', '1', '1')
    assert status().level == b'\x01'


def test_run_time_parameters_are_validated(rig) -> None:
    ros, _, _, _ = rig
    node = _allocator(ros)
    result = node.set_parameters([Parameter('weights', value=[1.0, 2.0])])[0]
    assert not result.successful and 'weights' in result.reason and '6' in result.reason
    result = node.set_parameters([Parameter('mode', value='fancy')])[0]
    assert not result.successful and 'mode' in result.reason and 'paper' in result.reason
    result = node.set_parameters([Parameter('tilt_request', value='ignored')])[0]
    assert not result.successful and 'read-only' in result.reason
    assert node.set_parameters([Parameter('mode', value='paper')])[0].successful
    assert node.allocator.mode == 'paper'
    assert node.set_parameters([Parameter('max_tilt_step', value=0.05)])[0].successful
    assert node.allocator.max_tilt_step == 0.05


def test_shipped_yaml_and_a_wrong_type_yaml(ros, tmp_path: Path) -> None:
    files = ['--ros-args', '--params-file', str(config_file('robot.yaml')),
             '--params-file', str(config_file('thrust_allocator.yaml'))]
    node = ros.add(ThrustAllocatorNode(context=ros.context, cli_args=files))
    assert node.allocator_config == load_allocator_config()
    bad = tmp_path / 'thrust_allocator.yaml'
    bad.write_text('thrust_allocator:\n  ros__parameters:\n    weights: [1, 1, 10, 10, 10, 1]\n')
    with pytest.raises(InvalidParameterTypeException, match='weights'):
        ThrustAllocatorNode(context=ros.context,
                            cli_args=['--ros-args', '--params-file', str(bad)])
