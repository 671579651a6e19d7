"""Thin rclpy adapters over :mod:`tiltrov_ros.core`, one module per node."""
