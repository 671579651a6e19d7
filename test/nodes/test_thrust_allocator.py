"""thrust_allocator: answers stamped with the wrench, previous, tilt requests, diagnostics."""

from __future__ import annotations

from dataclasses import replace
import math
from pathlib import Path
from typing import Any

from geometry_msgs.msg import WrenchStamped
from harness import run_while_progressing
import numpy as np
import pytest
from rclpy.parameter import Parameter
from ros_stack import (
    KEEP_ALL,
    MS,
    Probe,
    clock_msg,
    effort_rows,
    finite_outputs,
    joint_state,
    report,
    wrench,
    wrench_rows,
)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tiltrov_ros.core.allocation import load_allocator_config
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.names import FAILSAFE_FRAME
from tiltrov_ros.core.params import load_robot_params
from tiltrov_ros.nodes.conversions import stamp_ns
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


def _core(**changes):
    """The core allocator of the shipped configuration, with ``changes`` to it."""
    return replace(load_allocator_config(), **changes).build(load_robot_params(), 0.05)


def _answers(probe: Probe, topic: str) -> list[Any]:
    """The answers to wrench_cmd the probe received on ``topic``: not the failsafe's
    (zero thrust while wrench_cmd is stale, marked and with no wrench_achieved)."""
    return [m for m in probe[topic] if m.header.frame_id != FAILSAFE_FRAME]


def _answered(probe: Probe, n: int):
    return lambda: all(len(_answers(probe, t)) == n for t in ('thrust_cmd', 'tilt_cmd',
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


def test_auto_mode_pairs_once_a_request_carries_a_wrench_stamp(rig) -> None:
    ros, node, probe, pub = rig
    alloc = _allocator(ros)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    pub.publish(wrench(0, W1))
    assert ros.spin_until(_answered(probe, 1))          # no tilt_request: free
    tilt_pub = node.create_publisher(JointState, 'tilt_request', KEEP_ALL)
    assert ros.spin_until(lambda: alloc.count_publishers('tilt_request') > 0)
    # A publisher, and a request with a stamp no wrench carries: still free.
    tilt_pub.publish(joint_state(9 * TICK, ['tilt_front', 'tilt_rear'], position=[0.3, 0.3]))
    assert ros.spin_until(lambda: alloc.requests_received == 1)
    pub.publish(wrench(TICK, W1))
    assert ros.spin_until(_answered(probe, 2))
    assert alloc.requests_matched == 0 and list(probe['tilt_cmd'][1].position) != [0.3, 0.3]
    # A request with the next wrench's stamp: the tilts are fixed by it, and from now
    # on each wrench waits for its request.
    tilt_pub.publish(joint_state(2 * TICK, ['tilt_front', 'tilt_rear'], position=[0.1, 0.1]))
    assert ros.spin_until(lambda: alloc.requests_received == 2)
    pub.publish(wrench(2 * TICK, W1))
    assert ros.spin_until(_answered(probe, 3))
    assert alloc.requests_matched == 1
    pub.publish(wrench(3 * TICK, W1))
    assert ros.spin_until(lambda: alloc._waiting is not None)
    assert len(probe['thrust_cmd']) == 3
    tilt_pub.publish(joint_state(3 * TICK, ['tilt_front', 'tilt_rear'], position=[0.0, 0.0]))
    assert ros.spin_until(_answered(probe, 4))
    assert alloc.requests_matched == 2


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


def test_hovering_is_ok_and_quiet_and_a_real_shortfall_warns(rig) -> None:
    """Hovering with a small sideways correction: the robust mode gives up 1.6 mN
    of X for less servo motion (not exact, but far below wrench_tolerance: no log, no
    WARN, nothing counted per component); a 5 N surge from the hover attitude is
    short by 4.5 N at the servo rate: counted, WARN."""
    ros, _, probe, pub = rig
    node = _allocator(ros)
    np.testing.assert_allclose(node.tolerances, [0.4, 0.4, 0.4, 0.08, 0.08, 0.08])
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    hover = [0.0, 0.0, 5.0, 0.0, 0.0, 0.0]
    for i, values in enumerate([hover, [0.0, 0.05, 5.0, 0.0, 0.0, 0.0], hover]):
        pub.publish(wrench(i * TICK, values))
    assert ros.spin_until(_answered(probe, 3))
    assert node.infeasible >= 1 and node.short == 0 and not node.unachieved
    level, message, values = node.diagnostic_status()
    assert level == 0 and '(0 short beyond tolerance)' in message

    pub.publish(wrench(3 * TICK, [5.0, 0.0, 5.0, 0.0, 0.0, 0.0]))
    assert ros.spin_until(_answered(probe, 4))
    assert node.short == 1 and dict(node.unachieved) == {'X': 1}
    assert node.last_shortfall[0] > 4.0
    assert node.diagnostic_status()[0] == 1        # WARN: short since the last report
    assert node.diagnostic_status()[0] == 0        # ... and OK again once reported


def test_a_steady_demand_no_tilt_produces_is_reported_live(rig) -> None:
    """Two seconds of the steady wrench of a hole in the attainable set (a pitched
    setpoint in a current across: no tilt produces its surge, core/steady.py): WARN,
    "steady demand out of the servo range's reach", with the demand and its shortfall;
    a thruster failing forgets it."""
    ros, _, _, pub = rig
    node = _allocator(ros)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    hole = [-1.78855, -4.30930, 5.20989, 1.40107, 6.74503, 0.06609]
    ticks = node.hold_monitor.size
    for i in range(ticks):
        pub.publish(wrench(i * TICK, hole))
        assert ros.spin_until(lambda n=i + 1: node.ticks == n)
    level, message, values = node.diagnostic_status()
    assert level == 1 and message.startswith("steady demand out of the servo range's reach: "
                                             'short by X ')
    assert values['out_of_reach'] and values['steady_demand'] == pytest.approx(hole)
    assert abs(values['steady_shortfall'][0]) > 1.0
    node.set_parameters([Parameter('failed_thrusters', value=[2])])
    assert not node.diagnostic_status()[2]['out_of_reach']


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
    with pytest.raises(ParameterError, match=f"'weights' \\(in {bad}\\): got \\[1, 1,"):
        ThrustAllocatorNode(context=ros.context,
                            cli_args=['--ros-args', '--params-file', str(bad)])


# --------------------------------------------------------------------------- reliability

T0 = 20 * 1_000_000_000
NAN, INF = math.nan, math.inf
ROBOT = load_robot_params()


def _sim_rig(ros, **overrides):
    """An allocator on sim time (/clock at T0), its inputs and a probe."""
    node = ros.node('allocator_sim_test')
    probe = Probe(node, ['thrust_cmd', 'tilt_cmd', 'wrench_achieved', '/diagnostics'])
    pubs = {'wrench_cmd': node.create_publisher(WrenchStamped, 'wrench_cmd', KEEP_ALL),
            'tilt_request': node.create_publisher(JointState, 'tilt_request', KEEP_ALL),
            '/clock': node.create_publisher(Clock, '/clock', KEEP_ALL)}
    overrides.setdefault('tilt_request', 'ignored')
    allocator = _allocator(ros, use_sim_time=True, **overrides)
    subscribed = [p for name, p in pubs.items()
                  if name != 'tilt_request' or allocator.tilt_request_mode != 'ignored']
    assert ros.spin_until(lambda: all(p.get_subscription_count() > 0 for p in subscribed))
    pubs['/clock'].publish(clock_msg(T0))
    assert ros.spin_until(lambda: allocator.clock_ns() == T0)
    return allocator, probe, pubs


def _within_limits(probe: Probe) -> bool:
    thrusts = [v for m in probe['thrust_cmd'] for v in m.effort]
    tilts = [v for m in probe['tilt_cmd'] for v in m.position]
    return (all(abs(f) <= ROBOT.max_thrust for f in thrusts)
            and all(ROBOT.tilt_min <= a <= ROBOT.tilt_max for a in tilts))


def _framed(msg, frame):
    msg.header.frame_id = frame
    return msg


BAD_INPUTS = {
    'wrench_nan': ('wrench_cmd', 'non_finite', lambda: wrench(T0, [NAN, 0, 0, 0, 0, 0])),
    'wrench_inf': ('wrench_cmd', 'non_finite', lambda: wrench(T0, [0, 0, 0, 0, -INF, 0])),
    'wrench_wrong_frame': ('wrench_cmd', 'wrong_frame',
                           lambda: _framed(wrench(T0, W1), 'odom_ned')),
    'wrench_future_stamp': ('wrench_cmd', 'future_stamp', lambda: wrench(T0 + 10**10, W1)),
    'wrench_old_stamp': ('wrench_cmd', 'old_stamp', lambda: wrench(T0 - 10**10, W1)),
    'tilt_request_unknown_joint': ('tilt_request', 'unknown_joint', lambda: joint_state(
        T0, ['tilt_front', 'tilt_middle'], position=[0.1, 0.2])),
    'tilt_request_wrong_length': ('tilt_request', 'wrong_length', lambda: joint_state(
        T0, ['tilt_front', 'tilt_rear'], position=[0.1])),
    'tilt_request_missing_joint': ('tilt_request', 'missing_joint', lambda: joint_state(
        T0, ['tilt_front'], position=[0.1])),
    'tilt_request_nan': ('tilt_request', 'non_finite', lambda: joint_state(
        T0, ['tilt_front', 'tilt_rear'], position=[NAN, 0.0])),
}


@pytest.mark.parametrize('case', sorted(BAD_INPUTS))
def test_bad_input_is_rejected_counted_and_the_next_valid_one_answered(ros, case) -> None:
    topic, reason, build = BAD_INPUTS[case]
    request = topic == 'tilt_request'
    allocator, probe, pubs = _sim_rig(ros, tilt_request='required' if request else 'ignored')
    pubs[topic].publish(build())
    assert ros.spin_until(lambda: allocator.rejections[(topic, reason)] == 1)
    if request:
        pubs['tilt_request'].publish(joint_state(T0 + TICK, ['tilt_front', 'tilt_rear'],
                                                 position=[0.1, 0.2]))
    pubs['wrench_cmd'].publish(wrench(T0 + TICK, W1))        # valid: answered as usual
    assert ros.spin_until(lambda: T0 + TICK in probe.stamps('thrust_cmd'))
    assert finite_outputs(probe) and _within_limits(probe)
    assert np.any(effort_rows([probe.by_stamp('thrust_cmd')[T0 + TICK]]) != 0.0)
    if topic == 'wrench_cmd' and 'stamp' not in reason:   # a bad tick: zero thrust
        assert np.all(effort_rows([probe.by_stamp('thrust_cmd')[T0]]) == 0.0)
    values = report(ros, probe, allocator)
    assert values[f'rejected.{topic}.{reason}'] == '1'
    assert values['rejected_messages'] == '1' and values['callback_errors'] == '0'


def test_never_beyond_the_thrust_limit_or_tilt_range_whatever_it_receives(ros) -> None:
    allocator, probe, pubs = _sim_rig(ros, max_tilt_step=10.0)
    wrenches = [[1e12, -1e12, 1e12, 1e9, -1e9, 1e9], [0, 0, 1e300, 0, 0, 0],
                [-1e-300, 5e-324, 0, 0, 0, 0], [400, 400, -400, 100, 100, -100]]
    for i, values in enumerate(wrenches):
        pubs['wrench_cmd'].publish(wrench(T0 + i * TICK, values))
    assert ros.spin_until(lambda: len(probe['thrust_cmd']) == len(wrenches))
    assert finite_outputs(probe) and _within_limits(probe)
    assert allocator.callback_errors == 0


def test_wrench_watchdog_zero_thrust_when_stale_and_recovery(ros) -> None:
    allocator, probe, pubs = _sim_rig(ros, wrench_timeout=0.2)
    pubs['wrench_cmd'].publish(wrench(T0, W1))
    assert ros.spin_until(_answered(probe, 1))
    held = list(probe['tilt_cmd'][-1].position)
    pubs['/clock'].publish(clock_msg(T0 + 300 * MS))
    assert ros.spin_until(lambda: allocator.wrench_watchdog.stale and len(probe['thrust_cmd']) > 1
                          and len(probe['tilt_cmd']) > 1)
    zero, tilts = probe['thrust_cmd'][-1], probe['tilt_cmd'][-1]
    assert list(zero.effort) == [0.0] * 4 and list(tilts.position) == held
    # The safety command answers no wrench_cmd: stamped after the last one, off the
    # control-tick grid, and marked.
    stamp = stamp_ns(zero.header.stamp)
    assert stamp > T0 and stamp % TICK != 0 and stamp_ns(tilts.header.stamp) == stamp
    assert zero.header.frame_id == tilts.header.frame_id == FAILSAFE_FRAME
    assert probe['thrust_cmd'][0].header.frame_id == ''      # an answer is not marked
    values = report(ros, probe, allocator)
    assert values['wrench_stale'] == 'True' and 'wrench_cmd stale' in values['_message']
    pubs['wrench_cmd'].publish(wrench(T0 + 300 * MS, W2))
    assert ros.spin_until(lambda: not allocator.wrench_watchdog.stale)
    assert ros.spin_until(lambda: np.any(effort_rows(probe['thrust_cmd'][-1:]) != 0.0))
    count = len(probe['thrust_cmd'])
    ros.spin_for(0.15)
    assert len(probe['thrust_cmd']) == count and finite_outputs(probe)


def test_failed_thruster_set_at_run_time_is_never_used_and_reported(ros) -> None:
    allocator, probe, pubs = _sim_rig(ros)
    hover = [0.0, 0.0, 5.0, 0.0, 0.0, 0.0]
    pubs['wrench_cmd'].publish(wrench(T0, hover))
    assert ros.spin_until(lambda: len(probe['thrust_cmd']) == 1)
    assert allocator.set_parameters([Parameter('failed_thrusters', value=[7])])[0].successful \
        is False
    assert allocator.set_parameters([Parameter('failed_thrusters', value=[2])])[0].successful
    assert allocator.failed == (1,) and allocator.allocator.failed_thrusters == (1,)
    # Hovering with three thrusters is still exact; a yaw moment as well is not.
    demands = [hover, [0.0, 0.0, 5.0, 0.0, 0.0, 30.0]]
    for i, values in enumerate(demands, start=1):
        pubs['wrench_cmd'].publish(wrench(T0 + i * TICK, values))
    assert ros.spin_until(_answered(probe, 3))
    assert all(m.effort[1] == 0.0 for m in probe['thrust_cmd'][1:])
    assert finite_outputs(probe) and _within_limits(probe)
    achieved = wrench_rows(probe['wrench_achieved'][1:])
    np.testing.assert_allclose(achieved[0], hover, atol=1e-6)
    values = report(ros, probe, allocator)
    assert values['failed_thrusters'] == '[2]' and 'failed: thruster_2' in values['_message']
    assert "'N': 1" in values['unachieved_ticks']
    shortfall = [float(v) for v in values['last_shortfall'].strip('[]').split(',')]
    # Depth and attitude first: the heave force is met to 0.2 %, roll and pitch to
    # 0.03 N m; the yaw moment is what is given up.
    assert achieved[1][2] == pytest.approx(5.0, rel=2e-3)
    assert max(abs(shortfall[3]), abs(shortfall[4])) < 0.03
    assert shortfall[5] > 25.0


@pytest.mark.parametrize(('line', 'message'), [
    ('wrench_timeout: -1.0', "'wrench_timeout' (in {file}): got -1.0; allowed: a number in "
                             '[0, 3600]'),
    ('wrench_timeout: soon', "'wrench_timeout' (in {file}): got 'soon'; allowed: a number"),
    ('weights: [1.0, 2.0]', "'weights' (in {file}): got [1.0, 2.0]; allowed: 6 finite"),
])
def test_a_broken_yaml_stops_the_process_naming_file_parameter_and_range(
        tmp_path: Path, line: str, message: str) -> None:
    import sys

    bad = tmp_path / 'thrust_allocator.yaml'
    bad.write_text(f'thrust_allocator:\n  ros__parameters:\n    {line}\n')
    result = run_while_progressing(
        [sys.executable, '-m', 'tiltrov_ros.nodes.thrust_allocator', '--ros-args',
         '--params-file', str(config_file('robot.yaml')), '--params-file', str(bad)])
    assert result.returncode == 1
    assert f"thrust_allocator: parameter {message.format(file=bad)}" in result.stderr


def test_measured_tilts_from_joint_states_are_the_starting_point(rig) -> None:
    """tilt_source measured: the servos lag their commands, so the next allocation
    starts (and moves at most max_tilt_step) from the tilts joint_states reports, the
    one with the wrench's stamp, else the latest before it."""
    from tiltrov_ros.core.allocation import from_tilts

    ros, node, probe, pub = rig
    step = 0.05
    alloc = _allocator(ros, tilt_source='measured', max_tilt_step=step)
    joints = node.create_publisher(JointState, 'joint_states', KEEP_ALL)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0
                          and joints.get_subscription_count() > 0)
    measured = (0.3, -0.2)
    joints.publish(joint_state(0, ['tilt_front', 'tilt_rear', 'thruster_1', 'thruster_2',
                                   'thruster_3', 'thruster_4'],
                               position=[*measured, 0.0, 0.0, 0.0, 0.0]))
    assert ros.spin_until(lambda: alloc._latest_measured is not None)
    pub.publish(wrench(0, W1))
    assert ros.spin_until(_answered(probe, 1))
    pub.publish(wrench(TICK, W2))               # no joint_states at TICK: the latest
    assert ros.spin_until(_answered(probe, 2))

    core = _core(max_tilt_step=step)
    r1 = core.allocate(np.array(W1), previous=from_tilts(None, measured))
    r2 = core.allocate(np.array(W2), previous=from_tilts(r1, measured))
    got = [tuple(m.position) for m in probe['tilt_cmd']]
    assert got == [(r1.tilt_front, r1.tilt_rear), (r2.tilt_front, r2.tilt_rear)]
    assert all(abs(a - m) <= step + 1e-12 for tilts in got for a, m in zip(tilts, measured))
    commanded = core.allocate(np.array(W2), previous=r1)
    assert (commanded.tilt_front, commanded.tilt_rear) != got[1]
    assert alloc.measured_late == 1
    assert alloc.diagnostic_status()[2]['tilt_source'] == 'measured'


def test_every_wrench_sent_while_the_allocator_was_busy_is_answered_in_order(rig) -> None:
    """30 wrenches stored by DDS while the allocator's callbacks do not run (a node slowed
    at its start, a replay at the stamps' pace): each is answered, in order. Its reader
    keeps all: a 10-deep one answered the last 10 and dropped the rest unannounced."""
    from rclpy.duration import Duration

    ros, _, probe, pub = rig
    _allocator(ros)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0)
    stamps = [k * TICK for k in range(30)]
    for ns in stamps:
        pub.publish(wrench(ns, W1 if ns % (2 * TICK) else W2))
    # Stored on the allocator's side (acknowledged) before a callback of it ran.
    assert pub.wait_for_all_acked(Duration(seconds=60))
    assert ros.spin_until(_answered(probe, len(stamps)))
    for topic in ('thrust_cmd', 'tilt_cmd', 'wrench_achieved'):
        assert [stamp_ns(m.header.stamp) for m in _answers(probe, topic)] == stamps, topic
