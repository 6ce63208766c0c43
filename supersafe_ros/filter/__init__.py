"""The safety filter, ROS-free.

Where the decision is made: ``RobotFilter.step`` (one robot) or ``step_many`` (a fleet), in
``filter.decide``; the rule itself, written once, is ``filter.law``. The rooms:

* ``types``: FilterConfig, SafeSet, FilterOutput, the actions;
* ``inputs``: RobotFilter, one robot's inputs and what it sent; batched input updates;
* ``discs``: obstacles of their own radius (the value shift, rings for discs larger than R);
* ``propagation``: a pose propagated to now along the Dubins arcs of the commands sent, each
  at the speed sent with it;
* ``gather``: every robot's inputs read into columns once per decision;
* ``pairs``: V at every (robot, obstacle) pair, now and after the lookahead's holds;
* ``cluster_rows``: the union value (or loiter fallback) of close obstacles, per robot;
* ``law``: the rule over the constraint table (enter, ahead, stay; the command);
* ``outputs``: the commands, the filters' new state, and each robot's explanation;
* ``decide``: the steps above, in order;
* beside them: ``cluster`` (union values solved in the background), ``admissibility``
  (a learned set must contain the standard unsafe set), ``set_selector`` (which learned
  set is in force, checked off the control path), ``lockstep`` (when a lockstepped filter
  answers a pose), ``timebase`` (input ages), ``contours`` (RViz level sets), ``trials``
  (closed-loop collision trials).
"""
from .cluster_rows import default_cluster_store
from .decide import step_many
from .inputs import RobotFilter, update_commands, update_detections_all, update_poses
from .types import FAIL_SAFE, OVERRIDE, PASS, FilterConfig, FilterOutput, SafeSet

__all__ = ['FAIL_SAFE', 'OVERRIDE', 'PASS', 'FilterConfig', 'FilterOutput', 'RobotFilter', 'SafeSet',
           'default_cluster_store', 'step_many', 'update_commands', 'update_detections_all', 'update_poses']
