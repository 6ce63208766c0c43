"""The safety filter, ROS-free: the law (``law``) and the per-robot state machine (``core``)."""
