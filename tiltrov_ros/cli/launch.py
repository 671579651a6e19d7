"""``tiltrov launch``: start the ROS stack (plant, controller, allocator, reference,
and with ``--record`` the recorder) for a scenario, lockstep or realtime
(:func:`tiltrov_ros.stack.launch.launch`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from tiltrov_ros.core.controllers import CONTROLLER_KINDS
from tiltrov_ros.core.names import ALLOCATOR_MODES
from tiltrov_ros.core.scenarios import scenario_names
from tiltrov_ros.stack.launch import launch
from tiltrov_ros.stack.specs import RESPAWNABLE, LaunchOptions


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--scenario', default='pitch_hold', metavar='NAME|FILE',
                        help=f'shipped scenario ({", ".join(scenario_names())}) or a scenario '
                             'YAML file (default: pitch_hold)')
    parser.add_argument('--controller', choices=CONTROLLER_KINDS, default=None,
                        help="control law (default: config/wrench_controller.yaml's, pd)")
    parser.add_argument('--allocator', choices=ALLOCATOR_MODES, default=None,
                        help="allocation mode (default: config/thrust_allocator.yaml's, robust)")
    parser.add_argument('--duration', type=float, default=None, metavar='SEC',
                        help="sim time to run, s (default: the scenario's)")
    parser.add_argument('--robot', default=None, metavar='NAME|FILE',
                        help='robot parameter file, or the name of a shipped one '
                             '(robot_past_vertical: servos past vertical; default: '
                             'config/robot.yaml, the paper\'s +-90 deg)')
    timing = parser.add_mutually_exclusive_group()
    timing.add_argument('--lockstep', dest='lockstep', action='store_true', default=True,
                        help='deterministic, as fast as possible (default)')
    timing.add_argument('--realtime', dest='lockstep', action='store_false',
                        help='wall-clock stepping at --real-time-factor')
    parser.add_argument('--real-time-factor', type=float, default=1.0, metavar='X',
                        help='--realtime: sim seconds per wall second (default 1.0)')
    parser.add_argument('--record', type=Path, default=None, metavar='DIR',
                        help='record every topic into the bag directory DIR (bag_recorder)')
    parser.add_argument('--no-markers', dest='markers', action='store_false',
                        help='the plant publishes no robot_markers (for RViz and Foxglove)')
    parser.add_argument('--single-process', action='store_true',
                        help='run every node in this process on one executor')
    parser.add_argument('--executor', choices=('events', 'single', 'multi'), default=None,
                        help="executor of every node: rclpy's EventsExecutor (default), "
                             'SingleThreadedExecutor or MultiThreadedExecutor (one shared '
                             'by all nodes with --single-process)')
    parser.add_argument('--namespace', default='', metavar='NS',
                        help='push the whole stack into namespace NS (topics become /NS/odom, '
                             '...; /clock and /diagnostics stay global)')
    parser.add_argument('--param', action='append', default=[], metavar='NODE:NAME:=VALUE',
                        help='extra parameter for one node, e.g. '
                             "wrench_controller:gains.kp:='[100.0, 100.0, 100.0, 30.0, 60.0, "
                             "50.0]' (repeatable)")
    parser.add_argument('--stall-timeout', type=float, default=None, metavar='SEC',
                        help='lockstep: wall seconds before the plant reports a stall')
    parser.add_argument('--status-file', type=Path, default=None, metavar='FILE',
                        help='keep FILE up to date with the state of the launch (JSON: '
                             'state, each node\'s pid and starts, the exit code), for '
                             'scripts that wait on it')
    parser.add_argument('--respawn', action='append', default=[], choices=RESPAWNABLE,
                        metavar='NODE',
                        help='start NODE again when its process dies mid-run '
                             f'({", ".join(RESPAWNABLE)}; repeatable)')
    parser.add_argument('--join', action='append', default=[], metavar='NAME',
                        help="a node outside the package that joins the run's handshake "
                             '(tiltrov_ros.nodes.handshake.Handshake): the run starts once '
                             'it has matched every node too (repeatable)')


def options_from_args(args: argparse.Namespace) -> LaunchOptions:
    return LaunchOptions(
        scenario=args.scenario, controller=args.controller, allocator=args.allocator,
        duration=args.duration, robot=args.robot, lockstep=args.lockstep,
        real_time_factor=args.real_time_factor, record=args.record,
        single_process=args.single_process, namespace=args.namespace,
        params=tuple(args.param), stall_timeout=args.stall_timeout, executor=args.executor,
        respawn=tuple(args.respawn), status_file=args.status_file, markers=args.markers,
        join=tuple(args.join))


def run(args: argparse.Namespace) -> int:
    return launch(options_from_args(args))
