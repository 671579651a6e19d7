"""wrench_controller: ticks, stamps, waiting for the setpoint, idempotence, parameters."""

from __future__ import annotations

from dataclasses import replace
import math
from pathlib import Path

from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from ros_stack import (
    KEEP_ALL,
    MS,
    Probe,
    clock_msg,
    finite_outputs,
    odometry,
    pose,
    report,
    twist,
    wrench_rows,
)
from rosgraph_msgs.msg import Clock

from tiltrov_ros.core.controllers import Reference, load_controller_config, make_controller
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.kinematics import quat_from_euler
from tiltrov_ros.core.names import PID_INTEGRAL
from tiltrov_ros.core.params import load_robot_params
from tiltrov_ros.nodes.conversions import stamp_ns
from tiltrov_ros.nodes.handoff import Handoff, pid_integral_message
from tiltrov_ros.nodes.wrench_controller import WrenchController
from tiltrov_ros.paths import config_file

NS_ = 1_000_000_000

TICK = 50 * MS
POSITION = [0.1, -0.05, 0.2]
QUATERNION = list(quat_from_euler(0.02, -0.1, 0.3))
NU = [0.1, 0.0, -0.05, 0.01, 0.02, -0.03]
SETPOINT = ([0.0, 0.0, 0.1], list(quat_from_euler(0.0, -0.2, 0.0)))
VELOCITY = [0.01, 0.0, -0.02, 0.0, -0.01, 0.0]


@pytest.fixture
def rig(ros):
    node = ros.node('controller_test')
    probe = Probe(node, ['wrench_cmd', 'tilt_request', '/diagnostics'])
    pubs = {'odom': node.create_publisher(Odometry, 'odom', KEEP_ALL),
            'setpoint': node.create_publisher(PoseStamped, 'setpoint', KEEP_ALL),
            'velocity': node.create_publisher(TwistStamped, 'setpoint_velocity', KEEP_ALL)}

    def send(what: str, ns: int) -> None:
        if what == 'odom':
            pubs['odom'].publish(odometry(ns, POSITION, QUATERNION, NU))
        elif what == 'setpoint':
            pubs['setpoint'].publish(pose(ns, *SETPOINT))
        else:
            pubs['velocity'].publish(twist(ns, VELOCITY))

    def ready() -> bool:
        return all(p.get_subscription_count() > 0 for p in pubs.values())

    return ros, probe, send, ready


def _controller(ros, **overrides) -> WrenchController:
    return ros.add(WrenchController(context=ros.context, parameter_overrides=overrides))


def _expected(kind: str, t: float = 0.0, velocity=VELOCITY):
    controller = make_controller(load_controller_config().with_kind(kind), load_robot_params())
    reference = Reference(np.array(SETPOINT[0]), np.array(SETPOINT[1]), np.array(velocity))
    return controller, controller.update(t, np.array(POSITION), np.array(QUATERNION),
                                         np.array(NU), reference)


def test_lockstep_tick_waits_for_its_setpoint_and_answers_with_the_odom_stamp(rig) -> None:
    ros, probe, send, ready = rig
    node = _controller(ros, mode='lockstep')
    assert ros.spin_until(ready)
    send('odom', 10 * MS)            # not a control tick: ignored
    send('odom', 0)                  # a tick, but no setpoint yet
    ros.spin_for(0.2)
    assert probe['wrench_cmd'] == []
    send('velocity', 0)
    send('setpoint', TICK)           # another tick's setpoint does not do
    ros.spin_for(0.1)
    assert probe['wrench_cmd'] == []
    send('setpoint', 0)
    assert ros.spin_until(lambda: len(probe['wrench_cmd']) == 1)
    msg = probe['wrench_cmd'][0]
    assert probe.stamps('wrench_cmd') == [0]
    assert msg.header.frame_id == 'base_link_frd'
    _, expected = _expected('pd')
    np.testing.assert_array_equal(wrench_rows([msg])[0], expected.wrench)
    assert probe['tilt_request'] == [] and node.ticks == 1


def test_repeated_odom_stamp_republishes_without_advancing_the_state(rig) -> None:
    ros, probe, send, ready = rig
    node = _controller(ros, mode='lockstep', controller='pid')
    assert ros.spin_until(ready)
    for what in ('odom', 'velocity', 'setpoint'):
        send(what, 0)
    assert ros.spin_until(lambda: len(probe['wrench_cmd']) == 1)
    for what in ('velocity', 'setpoint', 'odom'):
        send(what, TICK)
    assert ros.spin_until(lambda: len(probe['wrench_cmd']) == 2)
    integral = node.controller.integral.copy()
    send('odom', TICK)               # the plant re-publishes a stalled tick
    assert ros.spin_until(lambda: len(probe['wrench_cmd']) == 3)
    assert probe.stamps('wrench_cmd') == [0, TICK, TICK]
    np.testing.assert_array_equal(wrench_rows(probe['wrench_cmd'][1:2]),
                                  wrench_rows(probe['wrench_cmd'][2:3]))
    np.testing.assert_array_equal(node.controller.integral, integral)
    assert (node.ticks, node.republished) == (2, 1)
    # Both ticks as the core PID gives them.
    controller, first = _expected('pid')
    np.testing.assert_array_equal(wrench_rows(probe['wrench_cmd'][:1])[0], first.wrench)
    second = controller.update(0.05, np.array(POSITION), np.array(QUATERNION), np.array(NU),
                               Reference(np.array(SETPOINT[0]), np.array(SETPOINT[1]),
                                         np.array(VELOCITY)))
    np.testing.assert_array_equal(wrench_rows(probe['wrench_cmd'][1:2])[0], second.wrench)


def test_switching_publishes_its_tilt_request_with_the_same_stamp(rig) -> None:
    ros, probe, send, ready = rig
    _controller(ros, mode='lockstep', controller='switching')
    assert ros.spin_until(ready)
    for what in ('velocity', 'setpoint', 'odom'):
        send(what, 0)
    assert ros.spin_until(lambda: probe['wrench_cmd'] and probe['tilt_request'])
    request = probe['tilt_request'][0]
    assert probe.stamps('tilt_request') == probe.stamps('wrench_cmd') == [0]
    assert list(request.name) == ['tilt_front', 'tilt_rear']
    _, expected = _expected('switching')
    assert tuple(request.position) == expected.tilt_request
    np.testing.assert_array_equal(wrench_rows(probe['wrench_cmd'])[0], expected.wrench)


def test_lockstep_waits_for_a_published_setpoint_velocity_however_long(rig) -> None:
    """A node publishes setpoint_velocity at the first tick: every tick waits for it; a
    wait longer than ``input_timeout`` is reported, never replaced by zero."""
    ros, probe, send, ready = rig
    node = _controller(ros, mode='lockstep', input_timeout=0.05)
    assert ros.spin_until(ready)
    send('odom', 0)
    send('setpoint', 0)
    assert ros.spin_until(lambda: node.input_waits == 1)
    assert ros.spin_until(lambda: report(ros, probe, node)['waiting_for'] == 'setpoint_velocity')
    ros.spin_for(0.3)                 # the late velocity is the input: nothing happens before
    assert probe['wrench_cmd'] == []
    send('velocity', 0)
    assert ros.spin_until(lambda: len(probe['wrench_cmd']) == 1)
    _, expected = _expected('pd')
    np.testing.assert_array_equal(wrench_rows(probe['wrench_cmd'])[0], expected.wrench)
    assert node._waits_for == {'setpoint_velocity'}


def test_lockstep_without_a_setpoint_velocity_publisher_uses_zero_for_the_run(ros) -> None:
    """No node publishes setpoint_velocity at the first tick: zero feed-forward for the
    whole run, said once, and no tick waits for it."""
    node = ros.node('controller_test')
    probe = Probe(node, ['wrench_cmd'])
    odom = node.create_publisher(Odometry, 'odom', KEEP_ALL)
    setpoint = node.create_publisher(PoseStamped, 'setpoint', KEEP_ALL)
    controller = _controller(ros, mode='lockstep')
    assert ros.spin_until(lambda: odom.get_subscription_count() > 0
                          and setpoint.get_subscription_count() > 0)
    for count, ns in enumerate((0, TICK), start=1):
        odom.publish(odometry(ns, POSITION, QUATERNION, NU))
        setpoint.publish(pose(ns, *SETPOINT))
        assert ros.spin_until(lambda n=count: len(probe['wrench_cmd']) == n)
    _, expected = _expected('pd', velocity=[0.0] * 6)
    np.testing.assert_array_equal(wrench_rows(probe['wrench_cmd'])[0], expected.wrench)
    assert controller._waits_for == frozenset() and controller.input_waits == 0


def test_realtime_uses_the_latest_setpoint_and_zero_wrench_without_one(rig) -> None:
    ros, probe, send, ready = rig
    node = _controller(ros, mode='realtime')
    assert ros.spin_until(ready)
    send('odom', 0)
    assert ros.spin_until(lambda: len(probe['wrench_cmd']) == 1)
    assert list(wrench_rows(probe['wrench_cmd'])[0]) == [0.0] * 6
    assert node.no_setpoint == 1
    send('velocity', 0)
    send('setpoint', 0)
    assert ros.spin_until(lambda: node._latest_setpoint is not None
                          and node._latest_velocity is not None)
    send('odom', 3 * TICK)           # the latest setpoint (stamped 0) is used
    assert ros.spin_until(lambda: len(probe['wrench_cmd']) == 2)
    _, expected = _expected('pd', t=0.15)
    np.testing.assert_array_equal(wrench_rows(probe['wrench_cmd'])[1], expected.wrench)
    assert probe.stamps('wrench_cmd') == [0, 3 * TICK]


def test_a_respawned_realtime_controller_is_silent_until_its_setpoint_then_resumes(
        rig) -> None:
    """A realtime controller built from a standby's handoff publishes no zero wrench
    before its first setpoint (that would command zero thrust while the plant and the
    allocator hold its predecessor's last one), then resumes the predecessor's integral."""
    ros, probe, send, ready = rig
    integral = [0.01, -0.02, 0.03, 0.0, 0.05, -0.01]
    config = load_controller_config().with_kind('pid')
    handoff = Handoff()
    handoff.keep(PID_INTEGRAL, serialize_message(
        pid_integral_message(17 * NS_, integral, config.gains.ki)))
    node = ros.add(WrenchController(context=ros.context, handoff=handoff,
                                    parameter_overrides={'mode': 'realtime',
                                                         'controller': 'pid'}))
    assert ros.spin_until(ready)
    send('odom', 18 * NS_)
    assert ros.spin_until(lambda: node.no_setpoint == 1)
    assert node.ticks == node.safe_answers == 0          # nothing was published
    send('velocity', 18 * NS_)
    send('setpoint', 18 * NS_)
    assert ros.spin_until(lambda: node._latest_setpoint is not None
                          and node._latest_velocity is not None)
    send('odom', 18 * NS_ + TICK)
    assert ros.spin_until(lambda: len(probe['wrench_cmd']) == 1)
    assert probe.stamps('wrench_cmd') == [18 * NS_ + TICK]
    assert node.resumed_from == 17 * NS_
    controller = make_controller(config, load_robot_params())
    controller.resume(17.0, np.array(integral))
    reference = Reference(np.array(SETPOINT[0]), np.array(SETPOINT[1]), np.array(VELOCITY))
    expected = controller.update(18.05, np.array(POSITION), np.array(QUATERNION), np.array(NU),
                                 reference)
    np.testing.assert_array_equal(wrench_rows(probe['wrench_cmd'])[0], expected.wrench)


def test_setpoint_in_another_frame_is_rejected(rig) -> None:
    ros, _probe, _send, ready = rig
    node = _controller(ros, mode='realtime')
    assert ros.spin_until(ready)
    publisher = ros.nodes[0].create_publisher(PoseStamped, 'setpoint', KEEP_ALL)
    assert ros.spin_until(lambda: publisher.get_subscription_count() > 0)
    publisher.publish(pose(0, *SETPOINT, frame_id='odom'))
    assert ros.spin_until(lambda: node.rejected_messages == 1)


def test_run_time_gain_changes_are_validated_by_the_core(rig) -> None:
    ros, probe, send, ready = rig
    node = _controller(ros, mode='lockstep')
    shipped = load_controller_config()
    result = node.set_parameters([Parameter('gains.kp', value=[-1.0, 1.0, 1.0, 1.0, 1.0, 1.0])])
    assert not result[0].successful
    assert 'gains.kp' in result[0].reason and 'allowed' in result[0].reason
    result = node.set_parameters([Parameter('gains.kd', value=[1.0, 2.0])])
    assert not result[0].successful and 'gains.kd' in result[0].reason
    result = node.set_parameters([Parameter('switching.angle_scale', value=0.0)])
    assert not result[0].successful and 'switching.angle_scale' in result[0].reason
    result = node.set_parameters([Parameter('controller', value='pid')])
    assert not result[0].successful and 'read-only' in result[0].reason
    assert node.controller.gains == shipped.gains      # nothing changed

    doubled = [2.0 * k for k in shipped.gains.kp]
    assert node.set_parameters([Parameter('gains.kp', value=doubled)])[0].successful
    assert node.controller.gains.kp == tuple(doubled)
    assert ros.spin_until(ready)
    for what in ('velocity', 'setpoint', 'odom'):
        send(what, 0)
    assert ros.spin_until(lambda: len(probe['wrench_cmd']) == 1)
    controller = make_controller(replace(shipped, gains=replace(shipped.gains,
                                                                kp=tuple(doubled))),
                                 load_robot_params())
    expected = controller.update(0.0, np.array(POSITION), np.array(QUATERNION), np.array(NU),
                                 Reference(np.array(SETPOINT[0]), np.array(SETPOINT[1]),
                                           np.array(VELOCITY)))
    np.testing.assert_array_equal(wrench_rows(probe['wrench_cmd'])[0], expected.wrench)


def test_shipped_yaml_defaults_and_a_wrong_type_yaml(ros, tmp_path: Path) -> None:
    files = ['--ros-args', '--params-file', str(config_file('robot.yaml')),
             '--params-file', str(config_file('wrench_controller.yaml'))]
    node = ros.add(WrenchController(context=ros.context, cli_args=files))
    assert node.controller_config == load_controller_config()
    assert node.kind == 'pd' and node.mode == 'realtime'
    bare = ros.add(WrenchController(node_name='bare', context=ros.context))
    assert bare.controller_config == load_controller_config()

    bad = tmp_path / 'wrench_controller.yaml'
    bad.write_text('wrench_controller:\n  ros__parameters:\n    switching:\n'
                   '      dwell_time: 1\n')
    with pytest.raises(ParameterError, match=rf"'switching\.dwell_time' \(in {bad}\): got 1; "
                       r'allowed: a number in \[0, 1e\+06\]'):
        WrenchController(context=ros.context, cli_args=['--ros-args', '--params-file', str(bad)])
    with pytest.raises(Exception, match='controller'):
        WrenchController(context=ros.context, parameter_overrides={'controller': 'lqr'})


def test_diagnostics_report_the_ticks(rig) -> None:
    ros, probe, send, ready = rig
    _controller(ros, mode='lockstep')
    assert ros.spin_until(ready)
    for what in ('velocity', 'setpoint', 'odom'):
        send(what, 0)

    def reported() -> bool:
        return any(s.name.endswith('wrench_controller')
                   and {kv.key: kv.value for kv in s.values}.get('ticks') == '1'
                   for m in probe['/diagnostics'] for s in m.status)

    assert ros.spin_until(reported, timeout=5.0)


# --------------------------------------------------------------------------- reliability

T0 = 20 * NS_
INF, NAN = math.inf, math.nan


def _sim_rig(ros, **overrides):
    """A realtime controller on sim time, its inputs, /clock at T0 and a probe."""
    node = ros.node('controller_sim_test')
    probe = Probe(node, ['wrench_cmd', '/diagnostics'])
    pubs = {'odom': node.create_publisher(Odometry, 'odom', KEEP_ALL),
            'setpoint': node.create_publisher(PoseStamped, 'setpoint', KEEP_ALL),
            'setpoint_velocity': node.create_publisher(TwistStamped, 'setpoint_velocity',
                                                       KEEP_ALL),
            '/clock': node.create_publisher(Clock, '/clock', KEEP_ALL)}
    controller = ros.add(WrenchController(context=ros.context, parameter_overrides={
        'mode': 'realtime', 'use_sim_time': True, **overrides}))
    assert ros.spin_until(lambda: all(p.get_subscription_count() > 0 for p in pubs.values()))
    pubs['/clock'].publish(clock_msg(T0))
    assert ros.spin_until(lambda: controller.clock_ns() == T0)
    pubs['setpoint'].publish(pose(T0, *SETPOINT))
    pubs['setpoint_velocity'].publish(twist(T0, VELOCITY))
    assert ros.spin_until(lambda: controller._latest_velocity is not None)
    return controller, probe, pubs


def _odom(ns, frame='odom_ned', child='base_link_frd', position=POSITION,
          quaternion=QUATERNION, nu=NU):
    msg = odometry(ns, position, quaternion, nu)
    msg.header.frame_id, msg.child_frame_id = frame, child
    return msg


BAD_INPUTS = {
    'odom_nan_position': ('odom', 'non_finite', lambda: _odom(T0, position=[NAN, 0, 0])),
    'odom_inf_twist': ('odom', 'non_finite', lambda: _odom(T0, nu=[0, 0, 0, 0, INF, 0])),
    'odom_wrong_frame': ('odom', 'wrong_frame', lambda: _odom(T0, frame='map')),
    'odom_wrong_child_frame': ('odom', 'wrong_frame', lambda: _odom(T0, child='base_link')),
    'odom_zero_quaternion': ('odom', 'bad_quaternion', lambda: _odom(T0, quaternion=[0] * 4)),
    'odom_future_stamp': ('odom', 'future_stamp', lambda: _odom(T0 + 10 * NS_)),
    'odom_old_stamp': ('odom', 'old_stamp', lambda: _odom(T0 - 10 * NS_)),
    'setpoint_nan': ('setpoint', 'non_finite', lambda: pose(T0, [0, NAN, 0], SETPOINT[1])),
    'setpoint_wrong_frame': ('setpoint', 'wrong_frame',
                             lambda: pose(T0, *SETPOINT, frame_id='map')),
    'setpoint_velocity_inf': ('setpoint_velocity', 'non_finite',
                              lambda: twist(T0, [INF, 0, 0, 0, 0, 0])),
}


@pytest.mark.parametrize('case', sorted(BAD_INPUTS))
def test_bad_input_is_rejected_counted_and_the_next_valid_one_answered(ros, case) -> None:
    topic, reason, build = BAD_INPUTS[case]
    controller, probe, pubs = _sim_rig(ros)
    pubs[topic].publish(build())
    assert ros.spin_until(lambda: controller.rejections[(topic, reason)] == 1)
    pubs['odom'].publish(_odom(T0 + TICK))            # valid: answered as usual
    assert ros.spin_until(lambda: T0 + TICK in probe.stamps('wrench_cmd'))
    assert finite_outputs(probe)
    answer = probe.by_stamp('wrench_cmd')[T0 + TICK]
    assert np.any(wrench_rows([answer]) != 0.0)
    if topic == 'odom' and 'stamp' not in reason:     # a tick with bad content: zero wrench
        assert np.all(wrench_rows([probe.by_stamp('wrench_cmd')[T0]]) == 0.0)
    values = report(ros, probe, controller)
    assert values[f'rejected.{topic}.{reason}'] == '1'
    assert values['rejected_messages'] == '1' and values['callback_errors'] == '0'


def test_odom_watchdog_zero_wrench_when_stale_and_recovery(ros) -> None:
    controller, probe, pubs = _sim_rig(ros, odom_timeout=0.2)
    pubs['odom'].publish(_odom(T0))
    assert ros.spin_until(lambda: T0 in probe.stamps('wrench_cmd'))
    # Sim time runs on without odometry: within one control period past the timeout
    # the controller publishes a zero wrench and says so.
    pubs['/clock'].publish(clock_msg(T0 + 300 * MS))
    assert ros.spin_until(lambda: controller.odom_watchdog.stale and len(probe['wrench_cmd']) > 1)
    zero = probe['wrench_cmd'][-1]
    assert stamp_ns(zero.header.stamp) > T0 and np.all(wrench_rows([zero]) == 0.0)
    values = report(ros, probe, controller)
    assert values['odom_stale'] == 'True' and 'odom stale' in values['_message']
    # Fresh odometry: the control law again, the watchdog quiet.
    pubs['odom'].publish(_odom(T0 + 300 * MS))
    assert ros.spin_until(lambda: T0 + 300 * MS in probe.stamps('wrench_cmd'))
    assert not controller.odom_watchdog.stale
    assert np.any(wrench_rows([probe.by_stamp('wrench_cmd')[T0 + 300 * MS]]) != 0.0)
    count = len(probe['wrench_cmd'])
    ros.spin_for(0.15)
    assert len(probe['wrench_cmd']) == count and finite_outputs(probe)
    assert report(ros, probe, controller)['odom_stale'] == 'False'


def test_enu_flu_odometry_is_converted_at_the_boundary(rig) -> None:
    """odom_frame_convention: enu: the controller takes REP-105 odometry (odom ->
    base_link, FLU twist) and computes the wrench of the same state in NED/FRD; NED
    frames are then refused."""
    from tiltrov_ros.core.frames import ned_to_enu

    ros, probe, send, ready = rig
    node = _controller(ros, mode='lockstep', odom_frame_convention='enu')
    assert ros.spin_until(ready)
    position, quaternion, nu = ned_to_enu(POSITION, QUATERNION, NU)
    enu = odometry(0, list(position), list(quaternion), list(nu))
    enu.header.frame_id, enu.child_frame_id = 'odom', 'base_link'
    send('velocity', 0)
    send('setpoint', 0)
    next(p for p in ros.nodes[0].publishers if p.topic_name == '/odom').publish(enu)
    assert ros.spin_until(lambda: len(probe['wrench_cmd']) == 1)
    _, expected = _expected('pd')
    np.testing.assert_allclose(wrench_rows(probe['wrench_cmd'])[0], expected.wrench,
                               rtol=0, atol=1e-9)
    send('odom', TICK)                          # odom_ned: not this node's convention
    assert ros.spin_until(lambda: node.rejected_messages == 1)
    assert list(node.rejections) == [('odom', 'wrong_frame')]
