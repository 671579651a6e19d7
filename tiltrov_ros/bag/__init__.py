"""The rosbag2/MCAP library: the writer behind ``bag_recorder``, reading a bag into a
:class:`~tiltrov_ros.core.runlog.RunLog`, repair, the replay ``Player`` and
``RunLog`` -> bag. A library: it imports no command and no node.

Importing this package does not import rclpy; only :mod:`.qos` and
:mod:`.replay` (and the recorder node) need it.
"""

from .bagfile import RUN_INFO_KEY, BagInfo, bag_info, iter_raw
from .reader import Decoder, Series, read_runlog, read_series

__all__ = ['RUN_INFO_KEY', 'BagInfo', 'Decoder', 'Series', 'bag_info', 'iter_raw',
           'read_runlog', 'read_series']
