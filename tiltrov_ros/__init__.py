"""tiltrov_ros: an underwater robot with four tilting thrusters, for ROS 2 Jazzy.

Layers, each importing only those below it (ARCHITECTURE.md): ``cli`` (the
``tiltrov`` command), ``stack`` (starting the nodes) and ``analysis`` (runs and
bags to metrics and figures), ``nodes`` (the rclpy adapters), ``bag`` (the
rosbag2/MCAP library), ``core`` (model, allocation, control; numpy/scipy only),
and at the bottom ``paths`` and ``progress``.
"""

__version__ = '0.1.0'
