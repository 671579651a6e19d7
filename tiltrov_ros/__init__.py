"""tiltrov_ros: an underwater robot with four tilting thrusters, for ROS 2 Jazzy.

``tiltrov_ros.core`` holds the model, allocation and control (numpy/scipy only);
``tiltrov_ros.nodes`` the thin rclpy adapters; the rest are the launcher, the bag
tools, the analysis and the ``tiltrov`` command line.
"""

__version__ = '0.1.0'
