"""Bag tools: the MCAP writer behind ``bag_recorder``, reading a bag into a
:class:`~tiltrov_ros.core.runlog.RunLog`, ``tiltrov bag repair`` and
``tiltrov replay``.

Importing this package does not import rclpy; only :mod:`.qos` and
:mod:`.replay` (and the recorder node) need it.
"""
