"""plant_simulator: topics, types, frames, stamps, lockstep waiting, stalls, parameters."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rclpy.exceptions import ParameterException
from rclpy.parameter import Parameter
from ros_stack import KEEP_ALL, MS, NS, Probe, finite_outputs, joint_state, report
from sensor_msgs.msg import JointState

from tiltrov_ros.core import names
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.runner import stack_config
from tiltrov_ros.nodes import plant_simulator
from tiltrov_ros.nodes.plant_simulator import PlantSimulator
from tiltrov_ros.paths import config_file

THRUSTERS = list(names.THRUSTERS)
TILTS = list(names.TILTS)
STEP = 10 * MS


@pytest.fixture
def rig(ros):
    """A command publisher and a probe of the plant's outputs."""
    node = ros.node('plant_test')
    probe = Probe(node, ['odom', 'joint_states', '/clock', '/diagnostics'])
    thrust = node.create_publisher(JointState, 'thrust_cmd', KEEP_ALL)
    tilt = node.create_publisher(JointState, 'tilt_cmd', KEEP_ALL)

    def command(ns: int, thrusts, tilts) -> None:
        tilt.publish(joint_state(ns, TILTS, position=tilts))
        thrust.publish(joint_state(ns, THRUSTERS, effort=thrusts))

    return ros, probe, command, thrust


def _plant(ros, **overrides) -> PlantSimulator:
    return ros.add(PlantSimulator(context=ros.context, parameter_overrides=overrides))


def test_lockstep_initial_state_then_one_control_period_per_command(rig) -> None:
    ros, probe, command, _ = rig
    node = _plant(ros, mode='lockstep', scenario='pitch_hold')
    assert ros.spin_until(lambda: probe.stamps('odom') == [0])
    assert ros.spin_until(lambda: probe.stamps('/clock') == [0])

    first = probe['odom'][0]
    assert (first.header.frame_id, first.child_frame_id) == ('odom_ned', 'base_link_frd')
    o = first.pose.pose.orientation
    assert (o.x, o.y, o.z, o.w) == (0.0, 0.0, 0.0, 1.0)
    joints = probe['joint_states'][0]
    assert list(joints.name) == TILTS + THRUSTERS
    assert list(joints.position[:2]) == [0.0, 0.0] and list(joints.effort[2:]) == [0.0] * 4
    # A field a joint does not have is 0.0: no topic carries NaN.
    assert list((*joints.position[2:], *joints.velocity[2:], *joints.effort[:2])) == [0.0] * 10

    # No command, no step.
    ros.spin_for(0.2)
    assert probe.stamps('odom') == [0]

    thrusts, tilts = [10.0, -5.0, 3.0, 0.5], [0.2, -0.1]
    command(0, thrusts, tilts)
    assert ros.spin_until(lambda: probe.stamps('odom')[-1:] == [5 * STEP])
    ros.spin_for(0.2)   # ... and it waits at the next tick, 50 ms
    assert probe.stamps('odom') == [i * STEP for i in range(6)]
    assert probe.stamps('/clock') == [i * STEP for i in range(6)]
    assert probe.stamps('joint_states') == [i * STEP for i in range(6)]

    # The same as the core plant given the same commands (zero-order hold).
    reference = stack_config('pitch_hold').build_plant()
    reference.command(thrusts, tilts)
    for msg in probe['odom'][1:]:
        reference.step()
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        assert [p.x, p.y, p.z] == list(reference.position)
        assert [q.w, q.x, q.y, q.z] == list(reference.quaternion)
        t = msg.twist.twist
        assert [t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y,
                t.angular.z] == list(reference.nu)
    last = probe['joint_states'][-1]
    assert list(last.position[:2]) == list(reference.tilts)
    assert list(last.velocity[:2]) == list(reference.tilt_velocities)
    assert list(last.effort[2:]) == list(reference.thrusts)

    # A late copy of the tick's commands changes nothing.
    command(0, [40.0] * 4, [1.0, 1.0])
    ros.spin_for(0.2)
    assert node.plant.time_ns == 5 * STEP
    assert probe.stamps('odom')[-1] == 5 * STEP


def test_lockstep_rejected_command_holds_the_previous_and_advances(rig) -> None:
    ros, probe, command, _thrust = rig
    node = _plant(ros, mode='lockstep')
    assert ros.spin_until(lambda: probe.stamps('odom') == [0])
    command(0, [5.0, 5.0, 5.0, 5.0], [0.0, 0.0])
    assert ros.spin_until(lambda: node.plant.time_ns == 5 * STEP)
    # thruster_4 missing: rejected; the tick still counts as answered, the command holds.
    command(5 * STEP, [1.0, 2.0, 3.0], [0.1, 0.1])
    assert ros.spin_until(lambda: node.plant.time_ns == 10 * STEP)
    assert node.rejected_messages == 1
    assert node.plant.thrusters.command_held == (5.0, 5.0, 5.0, 5.0)
    # A non-finite value is rejected the same way.
    command(10 * STEP, [1.0, math.nan, 0.0, 0.0], [0.0, 0.0])
    assert ros.spin_until(lambda: node.plant.time_ns == 15 * STEP)
    assert node.rejected_messages == 2
    assert node.plant.thrusters.command_held == (5.0, 5.0, 5.0, 5.0)
    assert ros.spin_until(lambda: probe.stamps('odom') == [i * STEP for i in range(16)])


def test_lockstep_a_late_first_answer_gets_the_initial_state_once(rig) -> None:
    """The first commands 1.5 s late (as when the controller holds its outputs until the
    bag recorder reads them): the initial state goes out once, so a recording has one
    state per step (before: again every 0.25 s, each recorded)."""
    ros, probe, command, _ = rig
    node = _plant(ros, mode='lockstep')
    assert ros.spin_until(lambda: probe.stamps('odom') == [0])
    ros.spin_for(1.5)       # the late answer is the input: nothing may happen meanwhile
    command(0, [0.0] * 4, [0.0, 0.0])
    assert ros.spin_until(lambda: node.plant.time_ns == 5 * STEP)
    steps = [i * STEP for i in range(6)]
    assert ros.spin_until(lambda: probe.stamps('/clock') == steps)
    assert probe.stamps('odom') == probe.stamps('joint_states') == steps
    assert node.republished == 0 and node.stalls >= 1      # reported, nothing sent again


def test_lockstep_a_reader_matched_after_the_initial_state_gets_it_again(rig) -> None:
    """Alone (no run nodes), a reader of odom matched on the plant's side once the initial
    state is out (a node started late) cannot have it: the plant publishes it again."""
    ros, probe, _command, _ = rig
    node = _plant(ros, mode='lockstep')
    assert ros.spin_until(lambda: probe.stamps('odom') == [0])
    late = Probe(ros.node('late_reader'), ['odom'])
    # Both readers get the second copy; which one first is up to the executor.
    assert ros.spin_until(lambda: late.stamps('odom') == [0]
                          and probe.stamps('odom') == [0, 0])
    assert node.republished == 1


def test_lockstep_a_command_for_a_tick_not_reached_is_rejected(rig) -> None:
    """Valid commands stamped for a tick ahead (a tool, a replay): rejected as
    ``future_stamp``; they do not stand in for the real answers when the tick comes."""
    ros, probe, command, _ = rig
    node = _plant(ros, mode='lockstep')
    assert ros.spin_until(lambda: probe.stamps('odom') == [0])
    command(5 * STEP, [40.0] * 4, [1.0, 1.0])
    assert ros.spin_until(lambda: node.rejections[('thrust_cmd', 'future_stamp')] == 1
                          and node.rejections[('tilt_cmd', 'future_stamp')] == 1)
    command(0, [1.0] * 4, [0.0, 0.0])
    assert ros.spin_until(lambda: node.plant.time_ns == 5 * STEP)
    ros.spin_for(0.2)       # it waits at 50 ms: nothing answered that tick
    assert node.plant.time_ns == 5 * STEP
    assert node.plant.thrusters.command_held == (1.0, 1.0, 1.0, 1.0)


def test_lockstep_a_stall_is_reported_and_changes_nothing(rig, capfd) -> None:
    """A tick nobody answers for longer than ``stall_timeout`` is a stall: logged and on
    /diagnostics (WARN), nothing sent again, and the answer, however late, resumes the run."""
    ros, probe, command, _ = rig
    node = _plant(ros, mode='lockstep', stall_timeout=0.05)
    assert ros.spin_until(lambda: probe.stamps('odom') == [0])
    command(0, [0.0] * 4, [0.0, 0.0])
    assert ros.spin_until(lambda: node.plant.time_ns == 5 * STEP)
    # Tick 0 itself may have waited past 0.05 s wall for its command on a loaded machine.
    before = node.stalls

    def stalled_at_tick_1() -> dict[str, str] | None:
        for msg in probe['/diagnostics']:
            for s in msg.status:
                values = {kv.key: kv.value for kv in s.values}
                if (s.name.endswith('plant_simulator') and s.level == b'\x01'
                        and 'stalled' in s.message
                        and float(values.get('last_stall') or 'nan') == pytest.approx(0.05)):
                    return values
        return None

    assert ros.spin_until(lambda: stalled_at_tick_1() is not None, timeout=10.0)
    values = stalled_at_tick_1()
    assert values is not None
    assert int(values['stalls']) == before + 1 and values['mode'] == 'lockstep'
    assert values['waiting_for'] == 'the commands of the tick'
    assert probe.stamps('odom').count(5 * STEP) == 1 and node.republished == 0
    # The answer resumes the run.
    command(5 * STEP, [0.0] * 4, [0.0, 0.0])
    assert ros.spin_until(lambda: node.plant.time_ns == 10 * STEP)
    # The next tick stalls too, well within the repeats' throttle: told at once.
    assert ros.spin_until(lambda: node.last_stall_ns == 10 * STEP, timeout=5.0)
    assert node.stalls == before + 2
    assert ros.spin_until(lambda: probe.stamps('odom')[-1:] == [10 * STEP])
    assert probe.stamps('odom') == [i * STEP for i in range(11)]
    told = capfd.readouterr().err
    assert told.count('stall at 0.050 s') == 1 and told.count('stall at 0.100 s') == 1, told


def test_lockstep_waits_for_its_peers_before_the_initial_state(ros) -> None:
    probe = Probe(ros.node('plant_probe'), ['odom'])
    _plant(ros, mode='lockstep')
    ros.spin_for(0.3)
    assert probe['odom'] == []          # no command publisher yet
    publisher = ros.node('late_allocator')
    publisher.create_publisher(JointState, 'thrust_cmd', KEEP_ALL)
    publisher.create_publisher(JointState, 'tilt_cmd', KEEP_ALL)
    assert ros.spin_until(lambda: probe.stamps('odom') == [0])


def test_realtime_runs_to_the_end_with_the_latest_command(rig) -> None:
    ros, probe, command, _ = rig
    node = _plant(ros, mode='realtime', real_time_factor=50.0, duration=0.5)
    command(0, [20.0] * 4, [0.3, 0.3])
    assert ros.spin_until(node.finished.done, timeout=20.0)
    assert ros.spin_until(lambda: probe.stamps('odom')[-1:] == [50 * STEP])
    assert sorted(set(probe.stamps('odom'))) == [i * STEP for i in range(51)]
    assert node.finished.result() == 50 * STEP
    last = probe['joint_states'][-1]
    assert last.effort[2] > 10.0 and last.position[0] > 0.2   # the command was applied
    ros.spin_for(0.1)
    assert probe.stamps('odom')[-1] == 50 * STEP               # and it stopped there


def test_parameters_scenario_overrides_and_defaults(ros) -> None:
    default = _plant(ros)
    assert default.config.mode == 'realtime' and default.config.step_ns == STEP
    assert default.config.disturbances.com_error == (0.0, 0.0, 0.0)

    slow = ros.add(PlantSimulator(node_name='slow', context=ros.context, parameter_overrides={
        'scenario': 'pitch_hold_slow_servo', 'com_error': [0.0, 0.0, 0.0],
        'current': [0.1, -0.2, 0.0], 'mode': 'lockstep'}))
    assert slow.config.robot.tilt_rate_limit == pytest.approx(math.radians(60.0))
    assert slow.config.disturbances.com_error == (0.0, 0.0, 0.0)    # explicit zero wins
    assert slow.config.disturbances.current == (0.1, -0.2, 0.0)
    scenario = ros.add(PlantSimulator(node_name='scn', context=ros.context,
                                      parameter_overrides={'scenario': 'pitch_hold',
                                                           'mode': 'lockstep'}))
    assert scenario.config.disturbances.com_error == (0.01, 0.0, 0.005)

    # Run-time: real_time_factor is checked against its range; geometry is read-only.
    result = default.set_parameters([Parameter('real_time_factor', value=-1.0)])[0]
    assert not result.successful and 'real_time_factor' in result.reason
    assert default.set_parameters([Parameter('real_time_factor', value=5.0)])[0].successful
    assert default.config.real_time_factor == 5.0
    result = default.set_parameters([Parameter('robot.length', value=1.0)])[0]
    assert not result.successful and 'read-only' in result.reason


@pytest.mark.parametrize(('overrides', 'name'), [
    ({'mode': 'fast'}, 'mode'),
    ({'duration': 0.015}, 'duration'),
    ({'control_period': 0.055}, 'control_period'),
    ({'com_error': [0.1, 0.0]}, 'com_error'),
    ({'robot.length': -0.6}, 'robot.length'),
    ({'recorder_window': 49.9}, 'recorder_window'),
    ({'recorder_window': 10.0, 'markers_period': 0.01}, 'recorder_window'),
])
def test_invalid_parameters_name_themselves(ros, overrides, name) -> None:
    with pytest.raises((ParameterError, ParameterException)) as info:
        PlantSimulator(context=ros.context, parameter_overrides=overrides)
    assert name in str(info.value)


def test_shipped_yaml_and_a_wrong_type_yaml(ros, tmp_path: Path) -> None:
    files = ['--ros-args', '--params-file', str(config_file('robot.yaml')),
             '--params-file', str(config_file('plant_simulator.yaml'))]
    node = ros.add(PlantSimulator(context=ros.context, cli_args=files))
    assert node.config.step_ns == STEP and node.config.mode == 'realtime'
    assert node.get_parameter('robot.max_thrust').value == 40.0

    bad = tmp_path / 'plant_simulator.yaml'
    bad.write_text('plant_simulator:\n  ros__parameters:\n    step_size: 1\n')
    with pytest.raises(ParameterError, match=f"'step_size' \\(in {bad}\\): got 1; allowed: "):
        PlantSimulator(context=ros.context, cli_args=['--ros-args', '--params-file', str(bad)])


def test_main_reports_a_bad_parameter_and_exits_1(capsys: pytest.CaptureFixture[str]) -> None:
    code = plant_simulator.main(['plant_simulator', '--ros-args', '-p', 'mode:=fast'])
    assert code == 1
    err = capsys.readouterr().err
    assert 'plant_simulator' in err and "'mode'" in err and 'lockstep' in err


def test_joint_states_values_are_the_plant_sample(rig) -> None:
    ros, probe, command, _ = rig
    node = _plant(ros, mode='lockstep')
    assert ros.spin_until(lambda: probe.stamps('odom') == [0])
    command(0, [40.0, -40.0, 12.0, 0.0], [1.2, -0.7])
    assert ros.spin_until(lambda: node.plant.time_ns == 5 * STEP)
    assert ros.spin_until(lambda: len(probe['joint_states']) == 6)
    sample = node.plant.sample()
    msg = probe['joint_states'][-1]
    np.testing.assert_array_equal(msg.position[:2], sample.tilts)
    np.testing.assert_array_equal(msg.velocity[:2], sample.tilt_velocities)
    np.testing.assert_array_equal(msg.effort[2:], sample.thrusts)


# --------------------------------------------------------------------------- reliability

TICK = 5 * STEP
GOOD_THRUSTS, GOOD_TILTS = [5.0, 5.0, 5.0, 5.0], [0.1, 0.1]


def _thrust_msg(ns, names=THRUSTERS, **fields):
    return joint_state(ns, names, **(fields or {'effort': GOOD_THRUSTS}))


BAD_COMMANDS = {
    'thrust_nan': ('thrust_cmd', 'non_finite', lambda: _thrust_msg(
        0, effort=[1.0, math.nan, 0.0, 0.0])),
    'thrust_inf': ('thrust_cmd', 'non_finite', lambda: _thrust_msg(
        0, effort=[1.0, 0.0, -math.inf, 0.0])),
    'thrust_wrong_length': ('thrust_cmd', 'wrong_length', lambda: _thrust_msg(
        0, effort=[1.0, 2.0, 3.0])),
    'thrust_wrong_velocity_length': ('thrust_cmd', 'wrong_length', lambda: _thrust_msg(
        0, effort=GOOD_THRUSTS, velocity=[0.0])),
    'thrust_unknown_joint': ('thrust_cmd', 'unknown_joint', lambda: _thrust_msg(
        0, [*THRUSTERS[:3], 'thruster_9'], effort=GOOD_THRUSTS)),
    'thrust_missing_joint': ('thrust_cmd', 'missing_joint', lambda: _thrust_msg(
        0, THRUSTERS[:3], effort=GOOD_THRUSTS[:3])),
    'thrust_duplicate_joint': ('thrust_cmd', 'duplicate_joint', lambda: _thrust_msg(
        0, [*THRUSTERS, 'thruster_1'], effort=[*GOOD_THRUSTS, 1.0])),
    'thrust_future_stamp': ('thrust_cmd', 'future_stamp', lambda: _thrust_msg(10 * NS)),
    'tilt_nan': ('tilt_cmd', 'non_finite', lambda: joint_state(
        0, TILTS, position=[math.nan, 0.0])),
    'tilt_unknown_joint': ('tilt_cmd', 'unknown_joint', lambda: joint_state(
        0, ['tilt_front', 'tilt_middle'], position=GOOD_TILTS)),
}


@pytest.mark.parametrize('case', sorted(BAD_COMMANDS))
def test_bad_command_is_rejected_counted_and_the_run_goes_on(ros, case) -> None:
    topic, reason, build = BAD_COMMANDS[case]
    node = ros.node('plant_bad_test')
    probe = Probe(node, ['odom', 'joint_states', '/clock', '/diagnostics'])
    pubs = {'thrust_cmd': node.create_publisher(JointState, 'thrust_cmd', KEEP_ALL),
            'tilt_cmd': node.create_publisher(JointState, 'tilt_cmd', KEEP_ALL)}
    plant = _plant(ros, mode='lockstep', scenario='pitch_hold')
    assert ros.spin_until(lambda: probe.stamps('odom') == [0])
    assert ros.spin_until(lambda: all(p.get_subscription_count() > 0 for p in pubs.values()))
    pubs[topic].publish(build())
    assert ros.spin_until(lambda: plant.rejections[(topic, reason)] == 1)
    # Valid commands for the present tick (the plant still waits there after a bad
    # stamp; after bad content the tick counts as answered, the previous command
    # holding), then for the next: the run goes on.
    pubs['tilt_cmd'].publish(joint_state(0, TILTS, position=GOOD_TILTS))
    pubs['thrust_cmd'].publish(_thrust_msg(0))
    assert ros.spin_until(lambda: plant.plant.time_ns >= TICK)
    pubs['tilt_cmd'].publish(joint_state(TICK, TILTS, position=GOOD_TILTS))
    pubs['thrust_cmd'].publish(_thrust_msg(TICK))
    assert ros.spin_until(lambda: probe.stamps('odom')[-1:] == [2 * TICK])
    assert finite_outputs(probe)
    assert plant.plant.thrusters.command_held == tuple(GOOD_THRUSTS)
    values = report(ros, probe, plant)
    assert values[f'rejected.{topic}.{reason}'] == '1' and values['callback_errors'] == '0'


def test_realtime_command_watchdog_zero_thrust_and_recovery(rig) -> None:
    ros, probe, command, _ = rig
    # The thrust needs 0.3 s of sim time (3 time constants) to pass 19 N: the timeout
    # leaves it 0.7 s more, so the check below never races the watchdog.
    plant = _plant(ros, mode='realtime', real_time_factor=5.0, command_timeout=1.0)
    assert ros.spin_until(lambda: len(probe['odom']) > 0)
    command(plant.plant.time_ns, [20.0] * 4, [0.0, 0.0])
    # Read from joint_states, every step's: one timer callback may step up to 1 s of sim
    # time when the process was starved, past the rise and into the watchdog's zero.
    assert ros.spin_until(lambda: any(m.effort[2] > 19.0 for m in probe['joint_states']))
    # No more commands: after 1 s of sim time the thrusters are commanded to zero.
    assert ros.spin_until(lambda: plant.commands_stale, timeout=5.0)
    assert plant.plant.thrusters.command_held == (0.0,) * 4
    assert ros.spin_until(lambda: abs(probe['joint_states'][-1].effort[2]) < 0.1)
    values = report(ros, probe, plant)
    assert values['commands_stale'] == 'True' and 'thrusters at zero' in values['_message']
    # Commands again: applied at once.
    seen = len(probe['joint_states'])
    command(plant.plant.time_ns, [10.0] * 4, [0.0, 0.0])
    assert ros.spin_until(lambda: any(m.effort[2] > 9.0 for m in probe['joint_states'][seen:]))
    assert finite_outputs(probe)


def test_failed_thruster_parameter_at_start_and_at_run_time(rig) -> None:
    ros, probe, command, _ = rig
    plant = _plant(ros, mode='lockstep', failed_thrusters=[3])
    assert plant.plant.failed_thrusters == (2,)
    assert not plant.set_parameters([Parameter('failed_thrusters', value=[0])])[0].successful
    assert plant.set_parameters([Parameter('failed_thrusters', value=[1, 4])])[0].successful
    assert plant.plant.failed_thrusters == (0, 3)
    assert ros.spin_until(lambda: probe.stamps('odom') == [0])
    command(0, [10.0] * 4, [0.0, 0.0])
    assert ros.spin_until(lambda: plant.plant.time_ns == TICK)
    assert plant.plant.thrusts[0] == 0.0 and plant.plant.thrusts[3] == 0.0
    assert plant.plant.thrusts[1] > 3.0      # working: toward 10 N with its 0.1 s lag
    values = report(ros, probe, plant)
    assert values['failed_thrusters'] == '[1, 4]'


def test_the_per_step_topics_keep_seconds_of_a_readers_lag(ros) -> None:
    """odom, joint_states, /clock and /tf keep 10000 samples for a reader behind (a
    recorder on a loaded machine): 100 s of sim time, seconds of lockstep."""
    node = _plant(ros, mode='lockstep')
    topics = ['odom', 'joint_states', '/clock'] + (['/tf'] if node.transforms else [])
    depths = {pub.topic_name: pub.qos_profile.depth for pub in node.publishers}
    for topic in topics:
        assert depths[node.resolve_topic_name(topic)] == 10000, topic
    assert depths[node.resolve_topic_name('robot_markers')] == 1000


def test_a_paced_window_fits_every_recorded_writers_history() -> None:
    """What a recorder_window lets the plant run ahead of the bag (plus a control period)
    fits the shallowest recorded history: steps, ticks, markers; the default window does
    with room, the longest allowed one with two samples to spare."""
    from tiltrov_ros.nodes.qos import HANDOFF_QOS, PUBLISHER_QOS, STATE_QOS, paced_window_limit_ns
    step, period, markers = 10_000_000, 50_000_000, 100_000_000
    limit = paced_window_limit_ns(step, period, markers)
    assert limit == 49_850_000_000
    assert (limit + period) // step + 2 <= STATE_QOS.depth
    assert (limit + period) // period + 2 <= min(PUBLISHER_QOS.depth, HANDOFF_QOS.depth)
    assert paced_window_limit_ns(step, period, step) < paced_window_limit_ns(step, period, 0)
    assert paced_window_limit_ns(step, 10 * STATE_QOS.depth * step, 0) == 0
