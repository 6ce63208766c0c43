"""What a robot's range sensors saw, as the filter judges it (ROS-free).

* ``readings``: a scan's or a cloud's readings, checked (REP 117; the pose at a stamp);
* ``local_map``: what the sensors saw, a rolling window of cells;
* ``map_value``: the map's one avoid value, solved in the background.
"""
