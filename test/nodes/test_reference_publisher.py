"""reference_publisher: one setpoint per control tick crossed on /clock, stamped exactly."""

from __future__ import annotations

import numpy as np
import pytest
from ros_stack import KEEP_ALL, MS, Probe, finite_outputs, report
from rosgraph_msgs.msg import Clock

from tiltrov_ros.core.scenarios import load_scenario
from tiltrov_ros.nodes.reference_publisher import ReferencePublisher

STEP = 10 * MS
TICK = 50 * MS


@pytest.fixture
def rig(ros):
    node = ros.node('reference_test')
    probe = Probe(node, ['setpoint', 'setpoint_velocity'])
    clock = node.create_publisher(Clock, '/clock', KEEP_ALL)

    def tick_clock(ns: int) -> None:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(ns, 1_000_000_000)
        clock.publish(msg)

    return ros, probe, clock, tick_clock


def _reference(ros, **overrides) -> ReferencePublisher:
    overrides.setdefault('use_sim_time', True)
    return ros.add(ReferencePublisher(context=ros.context, parameter_overrides=overrides))


def test_each_tick_crossed_once_with_the_profile_values(rig) -> None:
    ros, probe, clock, tick_clock = rig
    _reference(ros, scenario='trajectory', duration=0.3)
    assert ros.spin_until(lambda: clock.get_subscription_count() > 0)
    for i in range(13):                       # 0 .. 0.12 s in plant steps
        tick_clock(i * STEP)
    expected = [0, TICK, 2 * TICK]
    assert ros.spin_until(lambda: probe.stamps('setpoint') == expected)
    assert ros.spin_until(lambda: probe.stamps('setpoint_velocity') == expected)
    profile = load_scenario('trajectory').reference
    for ns, sp, vel in zip(expected, probe['setpoint'], probe['setpoint_velocity']):
        ref = profile.at(ns / 1e9)
        assert sp.header.frame_id == vel.header.frame_id == 'odom_ned'
        p, o = sp.pose.position, sp.pose.orientation
        assert [p.x, p.y, p.z] == list(ref.position)
        assert [o.w, o.x, o.y, o.z] == list(ref.quaternion)
        lin, ang = vel.twist.linear, vel.twist.angular
        assert [lin.x, lin.y, lin.z, ang.x, ang.y, ang.z] == list(ref.velocity)
    assert probe['setpoint_velocity'][1].twist.linear.x == pytest.approx(1.0 / 120.0)

    # A jump publishes every tick crossed, but none at or after the duration (0.3 s).
    tick_clock(40 * STEP)
    assert ros.spin_until(lambda: len(probe['setpoint']) == 6)
    ros.spin_for(0.1)
    assert probe.stamps('setpoint') == [0, TICK, 2 * TICK, 3 * TICK, 4 * TICK, 5 * TICK]


def test_a_repeated_tick_is_published_again_and_a_clock_going_back_restarts(rig) -> None:
    ros, probe, clock, tick_clock = rig
    node = _reference(ros)                    # no scenario: hold the origin
    assert ros.spin_until(lambda: clock.get_subscription_count() > 0)
    for ns in (0, STEP, 5 * STEP, 5 * STEP):  # the stalled plant re-publishes 50 ms
        tick_clock(ns)
    assert ros.spin_until(lambda: probe.stamps('setpoint') == [0, TICK, TICK])
    first = probe['setpoint'][0]
    assert (first.pose.orientation.w, first.pose.position.x) == (1.0, 0.0)
    tick_clock(0)                             # a restarted plant
    assert ros.spin_until(lambda: probe.stamps('setpoint') == [0, TICK, TICK, 0])
    assert node.restarts == 1


def test_its_own_clock_reader_sets_the_nodes_clock(rig) -> None:
    """The node takes each /clock sample once: its reader (reliable, every sample)
    sets the node's clock too, so its time source subscribes to nothing."""
    ros, _, clock, tick_clock = rig
    node = _reference(ros)
    assert ros.spin_until(lambda: clock.get_subscription_count() > 0)
    readers = [i for i in node.get_subscriptions_info_by_topic('/clock')
               if i.node_name == node.get_name()]
    assert len(readers) == 1
    for ns in (0, STEP, 7 * STEP, 3 * STEP):  # the last one goes back: time starts over
        tick_clock(ns)
    assert ros.spin_until(lambda: node.get_clock().now().nanoseconds == 3 * STEP)
    assert node.time_source.jumps_back == 1 and node.clock_ns() == 3 * STEP


def test_joining_late_starts_at_the_current_tick(rig) -> None:
    ros, probe, clock, tick_clock = rig
    _reference(ros, scenario='pitch_hold')
    assert ros.spin_until(lambda: clock.get_subscription_count() > 0)
    tick_clock(1234 * STEP)
    assert ros.spin_until(lambda: probe.stamps('setpoint') == [1230 * STEP])
    pitch = load_scenario('pitch_hold').reference.at(12.3).quaternion
    o = probe['setpoint'][0].pose.orientation
    np.testing.assert_array_equal([o.w, o.x, o.y, o.z], pitch)


def test_wall_time_without_sim_time(ros) -> None:
    probe = Probe(ros.node('reference_wall'), ['setpoint'])
    _reference(ros, use_sim_time=False)
    assert ros.spin_until(lambda: len(probe['setpoint']) >= 3, timeout=10.0)
    assert all(s.header.frame_id == 'odom_ned' for s in probe['setpoint'])
    stamps = probe.stamps('setpoint')
    assert stamps == sorted(stamps) and stamps[0] > 0



def test_a_malformed_clock_is_rejected_counted_and_the_next_answered(rig) -> None:
    ros, probe, clock, tick_clock = rig
    node = _reference(ros, scenario='pitch_hold')
    diag = Probe(ros.node('reference_diag'), ['/diagnostics'])
    assert ros.spin_until(lambda: clock.get_subscription_count() > 0)
    bad = Clock()
    bad.clock.sec, bad.clock.nanosec = 1, 1_500_000_000      # nanosec >= 1e9: not a time
    clock.publish(bad)
    assert ros.spin_until(lambda: node.rejections[('/clock', 'bad_stamp')] == 1)
    tick_clock(TICK)
    assert ros.spin_until(lambda: probe.stamps('setpoint') == [TICK])
    assert finite_outputs(probe)
    values = report(ros, diag, node)
    assert values['rejected./clock.bad_stamp'] == '1' and values['callback_errors'] == '0'


def test_a_reference_not_finite_goes_out_as_the_last_good_setpoint(rig) -> None:
    """A reference with a NaN (a broken scenario) is withheld and counted: the last good
    setpoint goes out instead, held, with zero feed-forward."""
    ros, probe, clock, tick_clock = rig
    node = _reference(ros, scenario='trajectory')
    profile = node.profile

    class Broken:
        def at(self, t: float):
            ref = profile.at(t)
            return ref if t < 0.075 else ref._replace(position=ref.position * np.nan,
                                                       velocity=ref.velocity * np.nan)

    node.profile = Broken()
    assert ros.spin_until(lambda: clock.get_subscription_count() > 0)
    for ns in (0, TICK, 2 * TICK):
        tick_clock(ns)
    assert ros.spin_until(lambda: probe.stamps('setpoint') == [0, TICK, 2 * TICK])
    assert ros.spin_until(lambda: probe.stamps('setpoint_velocity') == [0, TICK, 2 * TICK])
    assert finite_outputs(probe)
    good, held = probe['setpoint'][1], probe['setpoint'][2]
    assert held.pose == good.pose
    v = probe['setpoint_velocity'][2].twist
    assert [v.linear.x, v.linear.y, v.angular.z] == [0.0, 0.0, 0.0]
    assert node.unsafe == {'setpoint': 1, 'setpoint_velocity': 1}
