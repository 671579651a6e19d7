"""The ROS stack gives the headless runner's numbers: the wiring adds no error.

Every node of ``tiltrov launch`` (built by the launcher's own ``stack_specs``
and ``build_nodes``, with the shipped parameter files) runs in this process;
a probe records every message. Each odometry sample is compared with the
``RunLog`` plant row of ``run_scenario(stack_config(...))`` at the same time,
each control tick's wrench, thrusts and tilts with the control row.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from ros_stack import (
    MS,
    NS,
    effort_rows,
    odom_rows,
    run_stack,
    wrench_rows,
)

from tiltrov_ros.core.names import ALLOCATOR, CONTROLLER, FAILSAFE_FRAME, PLANT
from tiltrov_ros.core.runner import run_scenario, stack_config
from tiltrov_ros.nodes.conversions import stamp_ns
from tiltrov_ros.nodes.executors import make_executor
from tiltrov_ros.paths import config_file
from tiltrov_ros.stack.specs import LaunchOptions

ATOL = 1e-9
STEP = 10 * MS
TICK = 50 * MS

# (scenario, controller, sim seconds): every scenario and every controller; the
# switching baseline long enough to switch mode once (headless: first switch at
# 5.6 s, 4.15 s and 4.9 s).
CASES = [
    ('pitch_hold', 'pd', 3.0),
    ('pitch_hold', 'pid', 3.0),
    ('pitch_hold', 'switching', 6.0),
    ('pitch_hold_slow_servo', 'pd', 3.0),
    ('pitch_hold_slow_servo', 'switching', 5.0),
    ('trajectory', 'pd', 3.0),
    ('trajectory', 'pid', 3.0),
    ('trajectory', 'switching', 5.5),
]


@pytest.mark.slow
@pytest.mark.parametrize(('scenario', 'controller', 'duration'), CASES)
def test_lockstep_odometry_equals_the_headless_run(ros, scenario: str, controller: str,
                                                   duration: float) -> None:
    options = LaunchOptions(scenario=scenario, controller=controller,
                                     duration=duration)
    run = run_stack(ros.context, ros.executor, options)
    log = run_scenario(stack_config(scenario, controller), duration=duration)
    n_steps = round(duration * NS) // STEP

    # Plant grid: one odometry message per step, t = 0 included, nothing else.
    stamps = run.probe.stamps('odom')
    assert sorted(set(stamps)) == [i * STEP for i in range(n_steps + 1)]
    by_stamp = run.probe.by_stamp('odom')
    messages = [by_stamp[i * STEP] for i in range(n_steps + 1)]
    assert all(m.header.frame_id == 'odom_ned' and m.child_frame_id == 'base_link_frd'
               for m in messages)
    position, quaternion, nu = odom_rows(messages)
    np.testing.assert_allclose(position, log.position, rtol=0, atol=ATOL)
    np.testing.assert_allclose(quaternion, log.quaternion, rtol=0, atol=ATOL)
    np.testing.assert_allclose(nu, log.nu, rtol=0, atol=ATOL)
    np.testing.assert_allclose(np.array([m.header.stamp.sec + m.header.stamp.nanosec / NS
                                         for m in messages]), log.t, rtol=0, atol=1e-12)

    # Control grid: ticks t < duration, answered with the stamp of the odometry.
    ticks = [i * TICK for i in range(round(duration * NS) // TICK)]
    for topic in ('wrench_cmd', 'thrust_cmd', 'tilt_cmd', 'wrench_achieved', 'setpoint'):
        assert sorted(set(run.probe.stamps(topic))) == ticks, topic
    wrench = run.probe.by_stamp('wrench_cmd')
    np.testing.assert_allclose(wrench_rows([wrench[t] for t in ticks]), log.wrench_cmd,
                               rtol=0, atol=ATOL)
    thrust = run.probe.by_stamp('thrust_cmd')
    np.testing.assert_allclose(effort_rows([thrust[t] for t in ticks]), log.thrust_cmd,
                               rtol=0, atol=ATOL)
    tilt = run.probe.by_stamp('tilt_cmd')
    np.testing.assert_allclose(np.array([list(tilt[t].position) for t in ticks]),
                               log.tilt_cmd, rtol=0, atol=ATOL)
    achieved = run.probe.by_stamp('wrench_achieved')
    np.testing.assert_allclose(wrench_rows([achieved[t] for t in ticks]),
                               log.wrench_achieved, rtol=0, atol=ATOL)
    # The switching baseline's tilt requests travel with the same stamps.
    if controller == 'switching':
        assert sorted(set(run.probe.stamps('tilt_request'))) == ticks
        assert run.node(CONTROLLER).controller.switches >= 2
    else:
        assert run.probe['tilt_request'] == []
    # The handshake started the run with every match made: nothing sent twice. (A stall is
    # a wait longer than stall_timeout in wall seconds, a report: a run starved by a loaded
    # machine has some, 1 of 2 x 1.1 s beside two busy loops and a campaign.)
    assert run.extra['republished'] == 0


@pytest.mark.slow
def test_the_pids_anti_windup_keeps_lockstep_equal_to_the_headless_run(ros) -> None:
    """gains.antiwindup on: the pid reads wrench_achieved, one tick late, and each tick
    waits for it; the headless runner passes the previous tick's achieved wrench. In
    current_hold (the current keeps the wrench short) the anti-windup acts: its run
    differs from the one without."""
    duration = 3.0
    options = LaunchOptions(scenario='current_hold', controller='pid', duration=duration,
                            params=('wrench_controller:gains.antiwindup:=1.0',))
    run = run_stack(ros.context, ros.executor, options)
    plain = stack_config('current_hold', 'pid')
    gains = dataclasses.replace(plain.controller.gains, antiwindup=1.0)
    config = dataclasses.replace(plain, controller=dataclasses.replace(plain.controller,
                                                                       gains=gains))
    log = run_scenario(config, duration=duration)
    assert run.node(CONTROLLER).controller.uses_achieved
    ticks = [i * TICK for i in range(round(duration * NS) // TICK)]
    wrench = run.probe.by_stamp('wrench_cmd')
    np.testing.assert_allclose(wrench_rows([wrench[t] for t in ticks]), log.wrench_cmd,
                               rtol=0, atol=ATOL)
    by_stamp = run.probe.by_stamp('odom')
    position, _, _ = odom_rows([by_stamp[i * STEP] for i in range(len(log.t))])
    np.testing.assert_allclose(position, log.position, rtol=0, atol=ATOL)
    assert run.node(CONTROLLER)._waits_for == {'setpoint_velocity', 'wrench_achieved'}
    without = run_scenario(plain, duration=duration)
    assert np.max(np.abs(without.wrench_cmd - log.wrench_cmd)) > 1e-3


@pytest.mark.slow
def test_two_lockstep_runs_record_identical_odometry_on_different_executors(ros) -> None:
    """Determinism does not depend on scheduling: rclpy's SingleThreadedExecutor (a
    Python wait set), then its EventsExecutor (a C++ event queue), bit for bit."""
    options = LaunchOptions(scenario='trajectory', controller='switching',
                                     duration=3.0)
    first = run_stack(ros.context, ros.executor, options)
    executor = make_executor(ros.context, 'events')
    try:
        second = run_stack(ros.context, executor, options)
    finally:
        executor.shutdown()
    for topic in ('odom', 'thrust_cmd', 'tilt_cmd'):
        a, b = first.probe.by_stamp(topic), second.probe.by_stamp(topic)
        assert sorted(a) == sorted(b)
        if topic == 'odom':
            for x, y in zip(odom_rows([a[t] for t in sorted(a)]),
                            odom_rows([b[t] for t in sorted(b)])):
                assert np.array_equal(x, y)
        else:
            field = 'effort' if topic == 'thrust_cmd' else 'position'
            assert all(list(getattr(a[t], field)) == list(getattr(b[t], field)) for t in a)


@pytest.mark.slow
def test_realtime_closed_loop_keeps_the_stamp_contract(ros) -> None:
    """The four nodes in realtime mode (x2): every answer bears the stamp it answers.

    In realtime a node that falls behind (on a loaded machine the controller once
    published nothing for 60 ms of wall time, 0.6 s of sim time at x10) trips its
    downstream watchdog, whose safety output answers no tick: stamped off the
    control-tick grid and, from the allocator, marked ``failsafe`` with zero thrust.
    The contract holds for both kinds, however many safety outputs the load causes
    (under four CPU-bound processes besides the test, 20 of 20 runs at x2 and 40 of
    40 at x10 held it, with safety outputs in 4 and 18 of them)."""
    options = LaunchOptions(scenario='pitch_hold', controller='pd', duration=1.5,
                                     lockstep=False, real_time_factor=2.0)
    run = run_stack(ros.context, ros.executor, options)
    odom = run.probe.stamps('odom')
    assert sorted(set(odom)) == [i * STEP for i in range(151)]
    ticks = {t for t in odom if t % TICK == 0}
    # The controller answers odometry ticks; off the grid only its odom watchdog's zero.
    wrench = run.probe.by_stamp('wrench_cmd')
    answers = {t for t in wrench if t % TICK == 0}
    assert answers and answers <= ticks
    safety_wrenches = [m for t, m in wrench.items() if t % TICK != 0]
    assert all(not np.any(wrench_rows([m])) for m in safety_wrenches)
    assert len(safety_wrenches) <= run.node(CONTROLLER).watchdog_outputs
    # The allocator answers wrench_cmd stamps; anything else is its safety command,
    # marked failsafe, off the grid, zero thrust (its stamp may meet the controller's
    # safety wrench: the mark tells them apart), with no wrench_achieved.
    assert set(run.probe.stamps('wrench_achieved')) <= set(wrench)
    for topic in ('thrust_cmd', 'tilt_cmd'):
        failsafe = [m for m in run.probe[topic] if m.header.frame_id == FAILSAFE_FRAME]
        answered = [m for m in run.probe[topic] if m.header.frame_id != FAILSAFE_FRAME]
        assert all(m.header.frame_id == '' and stamp_ns(m.header.stamp) in wrench
                   for m in answered), topic
        assert all(stamp_ns(m.header.stamp) % TICK != 0 for m in failsafe), topic
        # At most as many as it sent: the last ones, after the plant's end, may not
        # reach the probe before the nodes go.
        assert len(failsafe) <= run.node(ALLOCATOR).watchdog_outputs, topic
        if topic == 'thrust_cmd':
            assert all(not np.any(effort_rows([m])) for m in failsafe)
    assert set(run.probe.stamps('setpoint')) <= ticks
    # How well the loop closes in realtime depends on the machine's load (a starved
    # process answers too late to be applied): the numbers are lockstep's tests.


@pytest.mark.slow
def test_thruster_failure_lockstep_equals_the_headless_run_and_is_reported(
        ros, tmp_path) -> None:
    """A thruster failing mid-run (the plant by the scenario's time, the allocator by
    the wrench stamps): the same numbers as tiltrov sim, and the allocator says what
    it allocates with and what it cannot achieve."""
    scenario = tmp_path / 'failure.yaml'
    text = (config_file('scenarios/thruster_failure.yaml').read_text()
            .replace('at: 40.0', 'at: 1.0'))
    scenario.write_text(text)
    options = LaunchOptions(scenario=str(scenario), controller='pd', duration=2.0)
    run = run_stack(ros.context, ros.executor, options)
    log = run_scenario(stack_config(str(scenario), 'pd'), duration=2.0)
    ticks = [i * TICK for i in range(40)]
    thrust = run.probe.by_stamp('thrust_cmd')
    np.testing.assert_allclose(effort_rows([thrust[t] for t in ticks]), log.thrust_cmd,
                               rtol=0, atol=ATOL)
    odom = run.probe.by_stamp('odom')
    position, _, _ = odom_rows([odom[i * STEP] for i in range(201)])
    np.testing.assert_allclose(position, log.position, rtol=0, atol=ATOL)
    assert all(thrust[t].effort[1] == 0.0 for t in ticks[20:])

    allocator, plant = run.node(ALLOCATOR), run.node(PLANT)
    assert allocator.failed == (1,) and plant.plant.failed_thrusters == (1,)
    _, message, values = allocator.diagnostic_status()
    assert 'failed: thruster_2' in message and 'not achieved (ticks)' in message
    assert values['failed_thrusters'] == [2]
    assert sum(values['unachieved_ticks'].values()) > 0
