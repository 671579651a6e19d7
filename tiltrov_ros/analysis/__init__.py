"""Offline analysis of runs: a RunLog (from the headless runner or a bag) to
files, metrics, figures, the results page and re-allocation. No rclpy."""
