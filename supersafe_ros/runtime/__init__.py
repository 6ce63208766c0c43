"""The filter nodes' run time, ROS-free, beside the decision (``filter``) and below the nodes:

* ``lockstep``: when a lockstepped filter answers a pose (skipped, held, given up);
* ``set_selector``: which learned set is in force, each one checked off the control path;
* ``timebase``: the time base of input ages (sim time while /clock advances, else steady);
* ``contours``: the level set in force around a detection, for RViz.
"""
