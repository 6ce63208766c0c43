"""The safety filter, ROS-free.

Where the decision is made: ``RobotFilter.step`` (one robot) or ``step_many`` (a fleet), in
``filter.decide``; the rule itself, written once, is ``filter.law``. A decision goes one way,
each step a function of what the steps before it made (docs/filter_learner.md, "How a decision
is made"):

* ``inputs``: RobotFilter, one robot's inputs (batched updates for a fleet's);
* ``gather``: every robot's inputs read once into columns (``RobotColumns``, frozen: what the rest
  of the decision reads of the robots), with which are judged (``problem``) and their states now
  (``propagation``: a pose propagated along the Dubins arcs of the commands sent) and commands
  (``commands``: the planner's command within the robot's limits);
* ``constraints``: each robot's rows of the constraint table (data: ``law.ConstraintTable``),
  a package: ``table`` (the rows, and ``avoid_turns``, the avoid turns of the rows robots avoid
  by), ``pairs`` (V at every robot and obstacle pair, now and after the lookahead's holds),
  ``discs`` (obstacles of their own radius), ``cluster_rows`` (the union value or loiter fallback
  of close obstacles), ``nearby`` (a robot's many detections narrowed to those within its reach),
  ``map_rows`` (a robot judged by its local map: one row for all the map holds);
* ``law``: the rule over the constraint table (``choose``: enter, ahead, stay; ``command``);
  ``approach``: the speed cut of a robot that can stop, so that each command's path enters
  nothing detected;
* ``outputs``: the commands and each robot's explanation;
* ``sent``: what was sent, the one writer of a filter's ``sent``, ``overriding`` and the caches a
  decision updates (``derived``);
* ``decide``: the steps above, in order (``decide(columns, safe_set, clusters)`` -> (decisions,
  updates); ``decide_many``: ``gather`` then ``decide``; ``step_many`` records them too);
* beside them: ``types`` (FilterConfig, SafeSet, FilterOutput, the actions), ``clusters``
  (union values of close obstacles: ``geometry``, and the ``store`` that solves them in the
  background), ``admissibility`` (a learned set must contain the standard unsafe set),
  ``sensing`` (``readings``: a scan's or a cloud's readings, checked; ``local_map``: what the
  sensors saw, a rolling window of cells; ``map_value``: the map's one avoid value, solved in
  the background), ``derived`` (the caches a decision fills, applied by ``sent``),
  ``elementwise`` (max and min of Python floats).

The nodes' run time around it (lockstep answers, the set in force, the time base, RViz level
sets) is ``supersafe_ros.runtime``; the closed-loop collision trials that count the filter's
collisions are a simulation, ``sim.trials``.
"""
from .clusters.store import default_cluster_store
from .decide import step_many
from .inputs import RobotFilter, update_commands, update_detections_all, update_poses
from .types import FAIL_SAFE, OVERRIDE, PASS, FilterConfig, FilterOutput, SafeSet

__all__ = ['FAIL_SAFE', 'OVERRIDE', 'PASS', 'FilterConfig', 'FilterOutput', 'RobotFilter', 'SafeSet',
           'default_cluster_store', 'step_many', 'update_commands', 'update_detections_all', 'update_poses']
