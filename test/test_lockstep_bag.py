"""Bags recorded from the live stack (``tiltrov launch --lockstep --record``):

* ``tiltrov analyze`` on the bag gives the metrics.json of ``tiltrov sim`` on the
  same scenario, controller and duration;
* replaying the bag's ``wrench_cmd`` (``tiltrov replay --topics wrench_cmd``)
  into a live ``thrust_allocator`` drives it as the live stack did: every
  wrench answered with a ``thrust_cmd`` of the same stamp, equal to the
  offline re-run (``tiltrov replay --through allocator``) and to the recording.
"""

from __future__ import annotations

from dataclasses import replace
import json
import math
from pathlib import Path
import subprocess
import sys
from typing import Any

from harness import TreeProgress, run_while_progressing
import numpy as np
import pytest
from ros_stack import HANG_BOUND, Probe, effort_rows

from tiltrov_ros import cli
from tiltrov_ros.analysis.reallocate import compare, read_control
from tiltrov_ros.bag.bagfile import iter_raw
from tiltrov_ros.bag.cdr import leading_stamp_ns
from tiltrov_ros.bag.reader import read_runlog
from tiltrov_ros.cli.replay import REPLAY_NODE
from tiltrov_ros.core import jit
from tiltrov_ros.core.metrics import metric_differences
from tiltrov_ros.core.names import ALLOCATOR
from tiltrov_ros.core.timebase import to_ns
from tiltrov_ros.nodes.handshake import Handshake
from tiltrov_ros.stack.specs import LaunchOptions, stack_specs
from tiltrov_ros.stack.supervisor import executable

SCENARIO = 'pitch_hold'
DURATION = '5'          # s of sim time: 501 plant steps, 100 control ticks
CONTROLLERS = ('pd', 'switching')


#: Whole launches record this module's bags (the fixture's time counts in the first test
#: that uses it): their waits give up on a hang, not on a slow machine.
pytestmark = pytest.mark.timeout(HANG_BOUND)


@pytest.fixture(scope='module')
def lockstep_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One bag per controller, recorded by ``tiltrov launch`` (separate processes)."""
    root = tmp_path_factory.mktemp('lockstep')
    bags = {}
    for controller in CONTROLLERS:
        bag = root / controller / 'bag'
        result = run_while_progressing(
            [sys.executable, '-m', 'tiltrov_ros.cli', 'launch', '--scenario', SCENARIO,
             '--controller', controller, '--duration', DURATION, '--record', str(bag)],
            cwd=root)
        assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
        bags[controller] = bag
    return bags


@pytest.mark.slow
@pytest.mark.parametrize('controller', CONTROLLERS)
def test_analyze_of_a_lockstep_bag_gives_the_metrics_of_tiltrov_sim(
        lockstep_bags: dict[str, Path], tmp_path: Path, controller: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    bag = lockstep_bags[controller]
    assert cli.main(['analyze', str(bag), '--out', str(tmp_path / 'analyze'),
                     '--no-figures']) == 0
    assert cli.main(['sim', '--scenario', SCENARIO, '--controller', controller,
                     '--duration', DURATION, '--out', str(tmp_path / 'sim'),
                     '--no-figures']) == 0
    capsys.readouterr()
    analyzed = json.loads((tmp_path / 'analyze' / 'metrics.json').read_text())
    simulated = json.loads((tmp_path / 'sim' / 'metrics.json').read_text())
    assert analyzed['ticks'] == 100 and analyzed['unmatched_ticks'] == 0
    assert analyzed['run'] == {'scenario': SCENARIO, 'controller': controller,
                               'allocator_mode': 'robust', 'backend': jit.backend()}
    assert metric_differences(analyzed, simulated) == []
    # Nothing was missing from the bag: every value came from a message; and every
    # message DDS delivered was read by its CDR layout, none needed rosbags' decoder.
    meta = read_runlog(bag).meta['bag']
    assert meta['missing'] == {} and meta['decoded_one_by_one'] == {}


@pytest.mark.slow
def test_the_bag_shows_the_robot_markers_of_every_tenth_of_a_second(
        lockstep_bags: dict[str, Path]) -> None:
    """What Foxglove's 3D panel draws from a demo bag: one MarkerArray per 0.1 s of sim
    time (t = 0 to the end), 17 markers each, in odom_ned, every pose and point finite,
    the body where odom puts it."""
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message
    from visualization_msgs.msg import Marker, MarkerArray

    bag = lockstep_bags['pd']
    odom = {}
    for raw in iter_raw(bag, ['/odom']):
        msg = deserialize_message(raw.data, Odometry)
        odom[leading_stamp_ns(raw.data, raw.msgtype)] = msg.pose.pose
    arrays = [deserialize_message(raw.data, MarkerArray)
              for raw in iter_raw(bag, ['/robot_markers'])]
    stamps = [a.markers[0].header.stamp.sec * 10**9 + a.markers[0].header.stamp.nanosec
              for a in arrays]
    end = to_ns(float(DURATION))
    assert sorted(set(stamps)) == list(range(0, end + 1, to_ns(0.1)))
    for array, stamp in zip(arrays, stamps):
        markers = array.markers
        assert len(markers) == 17
        assert {m.header.frame_id for m in markers} == {'odom_ned'}
        numbers = [v for m in markers for v in (
            m.pose.position.x, m.pose.position.y, m.pose.position.z, m.pose.orientation.w,
            m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z,
            *(c for p in m.points for c in (p.x, p.y, p.z)))]
        assert all(math.isfinite(v) for v in numbers)
        body = markers[0]
        assert body.ns == 'body' and body.type == Marker.CUBE
        assert body.pose.position == odom[stamp].position
        got, want = body.pose.orientation, odom[stamp].orientation
        np.testing.assert_allclose([got.w, got.x, got.y, got.z],
                                   [want.w, want.x, want.y, want.z], rtol=0, atol=1e-12)
        assert sum(m.type == Marker.ARROW for m in markers) == 12


@pytest.mark.slow
def test_every_node_stamps_its_diagnostics_on_the_sim_time_it_runs_on(
        lockstep_bags: dict[str, Path]) -> None:
    """The plant on its own sim time, the others on /clock: one time axis in the bag,
    going forward for each node (not wall time for one node and sim time for the rest)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message

    stamps: dict[str, list[int]] = {}
    for raw in iter_raw(lockstep_bags['pd'], ['/diagnostics']):
        msg = deserialize_message(raw.data, DiagnosticArray)
        for status in msg.status:
            stamps.setdefault(status.name, []).append(
                msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
    assert {'/plant_simulator', '/wrench_controller', '/thrust_allocator',
            '/reference_publisher'} <= set(stamps)
    end = to_ns(float(DURATION))
    for name, values in stamps.items():
        assert all(0 <= ns <= end for ns in values), (name, values)
        assert values == sorted(values), name
    assert stamps['/plant_simulator'][-1] == end      # the final counts, at the end


@pytest.mark.slow
@pytest.mark.parametrize('controller', CONTROLLERS)
def test_offline_allocator_reproduces_the_lockstep_recording(
        lockstep_bags: dict[str, Path], controller: str) -> None:
    control = read_control(lockstep_bags[controller])
    comparison = compare(control)
    assert comparison.summary['tilt_requests'] is (controller == 'switching')
    assert comparison.summary['reproduction'] == {
        'mode': 'robust', 'ticks': 100, 'max_thrust_difference': 0.0,
        'max_tilt_difference': 0.0, 'reproduced': True}


@pytest.mark.slow
def test_replayed_wrench_cmd_drives_the_allocator_like_the_live_stack(
        ros: Any, lockstep_bags: dict[str, Path], tmp_path: Path) -> None:
    """The allocator runs as ``tiltrov launch`` runs it (own process, same parameter
    files and overrides), in a run with the player and the probe; the replay is
    ``tiltrov replay BAG --topics wrench_cmd --by-stamp --join ...`` (at the stamps'
    pace: a lockstep bag's log times bunch up; its first message once the player, the
    allocator and the probe have matched each other from both sides: before that, a
    loaded machine lost the first wrenches or their answers)."""
    bag = lockstep_bags['pd']
    control = read_control(bag)
    offline = compare(control)          # the --through allocator re-run
    n = len(control.stamps)
    assert n == 100
    # Every wrench_cmd message in replay order; a stalled lockstep tick may have
    # been published twice (same stamp, same wrench).
    replayed = sorted(leading_stamp_ns(m.data, m.msgtype) for m in iter_raw(bag, ['/wrench_cmd']))
    assert sorted(set(replayed)) == [int(ns) for ns in control.stamps]
    probe_node = ros.node('replay_probe')
    probe = Probe(probe_node, ['thrust_cmd', 'tilt_cmd', 'wrench_achieved'])
    specs, _, _ = stack_specs(LaunchOptions(scenario=SCENARIO, controller='pd',
                                                     duration=float(DURATION)))
    run = [ALLOCATOR, REPLAY_NODE, 'replay_probe']
    spec = next(s for s in specs if s.name == ALLOCATOR)
    spec = replace(spec, overrides={**spec.overrides, 'run_nodes': run})
    Handshake(probe_node, run).start()
    allocator = subprocess.Popen(executable(spec)
                                 + spec.ros_args(spec.write_overrides(tmp_path)),
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    player = None
    try:
        player = subprocess.Popen(
            [sys.executable, '-m', 'tiltrov_ros.cli', 'replay', str(bag), '--topics',
             'wrench_cmd', '--by-stamp', '--join', f'{ALLOCATOR},replay_probe'],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        cpu = TreeProgress(allocator.pid, player.pid)
        assert ros.spin_while_progressing(
            lambda: player.poll() is not None
            and all(len(probe[t]) >= len(replayed) for t in probe.messages),
            lambda: (sum(len(probe[t]) for t in probe.messages), cpu())), \
            sorted(set(replayed) - set(probe.stamps('thrust_cmd')))
        ros.spin_for(0.2)               # nothing more comes
        output = player.communicate()[0]
    finally:
        for process in (player, allocator):
            if process is not None and process.poll() is None:
                process.terminate()
        allocator_log = allocator.communicate()[0]
    assert player.returncode == 0, output
    assert f'published {len(replayed)} messages: /wrench_cmd {len(replayed)}' in output
    for topic in probe.messages:
        assert probe.stamps(topic) == replayed, topic   # each wrench answered, in order
    assert [int(ns) for ns in control.stamps] == [to_ns(k * 0.05) for k in range(n)]
    answers = probe.by_stamp('thrust_cmd')
    thrusts = effort_rows([answers[int(ns)] for ns in control.stamps])
    tilt_answers = probe.by_stamp('tilt_cmd')
    tilts = np.array([list(tilt_answers[int(ns)].position) for ns in control.stamps])
    np.testing.assert_allclose(thrusts, offline.thrusts['robust'], rtol=0, atol=1e-9)
    np.testing.assert_allclose(tilts, offline.tilts['robust'], rtol=0, atol=1e-9)
    # ... and to what the live stack's allocator answered during the recording.
    np.testing.assert_allclose(thrusts, control.thrust_cmd, rtol=0, atol=1e-9)
    np.testing.assert_allclose(tilts, control.tilt_cmd, rtol=0, atol=1e-9)
    # A repeated stamp is answered again with the same message (the node's cache).
    for stamp, msg in zip(probe.stamps('thrust_cmd'), probe['thrust_cmd']):
        assert list(msg.effort) == list(answers[stamp].effort)
    assert 'robust allocation' in allocator_log


@pytest.mark.slow
def test_a_120_s_lockstep_run_is_recorded_without_losing_a_message(tmp_path: Path) -> None:
    """The sizing check: the 120 s trajectory (the busiest shipped scenario)
    in separate processes; every message each node publishes is in the bag.

    The publishers' side is what each node reports it published (its final
    /diagnostics, ``published.<topic>``): the plant publishes odom, joint_states
    and /clock at t = 0, 0.01, ..., 120 s (12 001 each), the reference, the
    controller and the allocator once per 50 ms control tick (2 400 each), plus the
    state a stall published again and the answers to it (a loaded machine: one
    stall in a run of the suite). The bag holds exactly what was published, and the
    RunLog read from it misses no value, so no message is lost or duplicated.
    """
    from tiltrov_ros.bag.losses import final_diagnostics, message_counts
    bag = tmp_path / 'bag'
    result = run_while_progressing(
        [sys.executable, '-m', 'tiltrov_ros.cli', 'launch', '--scenario', 'trajectory',
         '--controller', 'pid', '--record', str(bag)], cwd=tmp_path)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    finals = final_diagnostics(bag)[0]
    again = int(finals['/plant_simulator']['republished_states'])
    counts = message_counts(bag, finals)
    plant = dict.fromkeys(('/odom', '/joint_states', '/clock'), 12001)
    control = dict.fromkeys(('/setpoint', '/setpoint_velocity', '/wrench_cmd',
                             '/thrust_cmd', '/tilt_cmd', '/wrench_achieved'), 2400)
    for topic, grid in (plant | control).items():
        assert counts[topic]['recorded'] == counts[topic]['published'], (topic, counts[topic])
        assert grid <= counts[topic]['published'] <= grid + again, (topic, counts[topic], again)
    recorded = read_runlog(bag)
    assert recorded.meta['bag']['missing'] == {}
    assert recorded.t.shape == (12001,) and recorded.tc.shape == (2400,)
