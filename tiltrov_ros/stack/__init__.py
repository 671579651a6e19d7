"""Running the ROS stack: which nodes with which parameters, as processes or in
one process (``tiltrov launch``)."""
