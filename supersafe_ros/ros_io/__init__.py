"""ROS message plumbing: conversions and QoS (``rosmsg``), the value-function message
(``vfmsg``), and a background node for in-process helpers (``background_node``)."""
