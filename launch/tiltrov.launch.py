"""The tiltrov_ros stack (plant, controller, allocator, reference, and a bag recorder
with record:=DIR), as `tiltrov launch` starts it:

    ros2 launch tiltrov_ros tiltrov.launch.py scenario:=pitch_hold controller:=pid \
        mode:=lockstep record:=runs/x

`ros2 launch tiltrov_ros tiltrov.launch.py --show-args` lists the arguments;
docs/launch.md describes them.
"""

from tiltrov_ros.stack.ros_launch import generate_launch_description

__all__ = ['generate_launch_description']
