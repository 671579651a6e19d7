"""The launcher's wiring of the transform tree: a namespaced stack remaps /tf and
/tf_static into its namespace (processes and one process alike); where
robot_state_publisher publishes the thruster links the plant is told not to."""

from __future__ import annotations

from tiltrov_ros.core.names import PLANT
from tiltrov_ros.stack.specs import LaunchOptions, remap_args, stack_specs


def test_a_namespaced_node_remaps_the_tree_into_its_namespace() -> None:
    specs, _, _ = stack_specs(LaunchOptions(duration=1.0))
    for spec in specs:
        args = spec.ros_args(None, '/r1')
        assert args[:3] == ['--ros-args', '-r', '__ns:=/r1']
        assert args[3:7] == ['-r', '/tf:=tf', '-r', '/tf_static:=tf_static']
        assert '/tf:=tf' not in spec.ros_args(None)
    assert remap_args('') == []


def test_the_plant_leaves_the_thruster_links_to_robot_state_publisher() -> None:
    def plant(options: LaunchOptions) -> dict[str, object]:
        specs, _, _ = stack_specs(options)
        return next(s for s in specs if s.name == PLANT).all_overrides()

    assert 'tf_thrusters' not in plant(LaunchOptions(duration=1.0))
    assert plant(LaunchOptions(duration=1.0, tf_thrusters=False))['tf_thrusters'] is False
