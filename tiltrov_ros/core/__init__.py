"""Model, allocation and control of the tilting-thruster robot.

Pure numpy/scipy: nothing under ``tiltrov_ros.core`` may import rclpy, so the
headless runner, the analysis and the ROS nodes all share one implementation.
"""
