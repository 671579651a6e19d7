"""The run's handshake (nodes/handshake.py): the plant starts when every node of the run
has matched every other, seen from both sides; a node outside the run is never waited
for; a restarted node is matched again before the tick it must answer is sent again."""

from __future__ import annotations

from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_stack import MS, NS, Probe, odom_rows

from tiltrov_ros.core.names import ALLOCATOR, CONTROLLER, PLANT, REFERENCE
from tiltrov_ros.core.runner import run_scenario, stack_config
from tiltrov_ros.nodes.handshake import NodeState
from tiltrov_ros.stack.inprocess import build_node
from tiltrov_ros.stack.specs import LaunchOptions, stack_specs

RUN = (ALLOCATOR, CONTROLLER, REFERENCE, PLANT)
STEP_NS = 10 * MS


def _specs(duration: float = 2.0) -> dict[str, Any]:
    specs, _, _ = stack_specs(LaunchOptions(scenario='pitch_hold', controller='pd',
                                            duration=duration), extra_odom_readers=1)
    return {spec.name: spec for spec in specs}


def test_a_state_survives_its_message() -> None:
    state = NodeState('plant_simulator', '17.42', True,
                      frozenset({('/odom', 'ab'), ('/clock', 'cd')}),
                      frozenset({('/thrust_cmd', 'ef')}),
                      (('plant_simulator', '17.42'), ('wrench_controller', '3.1')),
                      '', {'mode': 'lockstep'})
    msg = state.to_message('/plant_simulator')
    assert isinstance(msg, DiagnosticStatus) and msg.hardware_id == '17.42'
    assert NodeState.from_message(msg) == state


def test_the_plant_waits_for_every_run_node_and_starts_once_they_are_matched(ros) -> None:
    """Without the controller the plant says what it waits for and publishes nothing;
    started, the controller joins, and the initial state goes out once, to everyone."""
    specs = _specs()
    probe = Probe(ros.node('probe'), ['odom', '/clock'])
    nodes = {name: ros.add(build_node(specs[name], ros.context))
             for name in (PLANT, ALLOCATOR, REFERENCE)}
    plant = nodes[PLANT]
    # Every started node's state is known, and the controller is what the run waits for.
    assert ros.spin_until(lambda: set(plant.handshake.states) == {PLANT, ALLOCATOR, REFERENCE}
                          and plant.handshake.state_of(ALLOCATOR).waiting_for != '')
    assert f'{CONTROLLER} (not started)' in plant.handshake.run_waiting_for()
    assert not plant._started and probe['odom'] == []
    assert 'wrench_controller (not started)' in plant.lockstep_status()['waiting_for']
    ros.add(build_node(specs[CONTROLLER], ros.context))
    assert ros.spin_until(lambda: plant.plant.time_ns > 0)
    assert plant.handshake.run_ready() and plant.republished == 0
    assert ros.spin_until(lambda: probe.stamps('odom')[:2] == [0, STEP_NS])
    assert probe.stamps('odom').count(0) == 1


def test_an_unmatchable_reader_outside_the_run_is_not_waited_for(ros) -> None:
    """A reader of odom that can never match the plant's writer (it asks for transient
    local durability, the plant offers volatile) is in the graph, but outside the run:
    the run starts and ends as if it were not there."""
    specs = _specs(duration=0.5)
    outsider = ros.node('outsider')
    asks_more = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
    from nav_msgs.msg import Odometry
    outsider.create_subscription(Odometry, 'odom', lambda msg: None, asks_more)
    # startup_subscribers counts readers on the plant's side: the controller alone here.
    spec = specs[PLANT]
    spec = type(spec)(spec.name, spec.module, spec.class_name, spec.params_files,
                      {**spec.overrides, 'startup_subscribers': 1}, spec.raw_params)
    plant = ros.add(build_node(spec, ros.context))
    for name in (ALLOCATOR, CONTROLLER, REFERENCE):
        ros.add(build_node(specs[name], ros.context))
    assert ros.spin_until(lambda: plant.finished.done(), timeout=30.0)
    # Nothing sent twice (a stall, a wait over stall_timeout wall seconds, is a report).
    assert plant.republished == 0


def test_a_node_replaced_mid_run_is_matched_again_before_its_tick_is_sent_again(ros) -> None:
    """The controller destroyed mid-run (a crash) and started again: the plant waits at its
    tick, and once the new instance has matched every node and every node has matched it,
    publishes that tick's state once more; the run ends with the headless numbers (the pd
    law keeps no state between ticks)."""
    duration = 2.0
    specs = _specs(duration)
    probe = Probe(ros.node('stack_probe'), ['odom'])
    nodes = {name: ros.add(build_node(specs[name], ros.context)) for name in RUN}
    plant = nodes[PLANT]
    assert ros.spin_until(lambda: plant.plant.time_ns >= NS // 2, timeout=30.0)
    old = nodes[CONTROLLER]
    ros.executor.remove_node(old)
    ros.nodes.remove(old)
    old.destroy_node()
    assert ros.spin_until(lambda: plant._waiting_since is not None)
    waited_at = plant.plant.time_ns
    generation = plant.handshake.generation
    new = ros.add(build_node(specs[CONTROLLER], ros.context))
    assert new.handshake.instance != old.handshake.instance
    assert ros.spin_until(lambda: plant.finished.done(), timeout=30.0)
    end = plant.plant.time_ns
    assert ros.spin_until(lambda: probe.stamps('odom')[-1] == end)    # the last state too
    assert plant.handshake.generation == generation + 1
    assert plant.republished == 1
    assert probe.stamps('odom').count(waited_at) == 2
    log = run_scenario(stack_config('pitch_hold', 'pd'), duration=duration)
    by_stamp = probe.by_stamp('odom')
    position, _, _ = odom_rows([by_stamp[i * STEP_NS] for i in range(len(log.t))])
    np.testing.assert_allclose(position, log.position, rtol=0, atol=1e-9)
