"""The constraint table: every row a robot is judged by (the law reads it, ``law.ConstraintTable``).

* ``table``: each robot's rows, in one table of data (``constraint_rows``), and the avoid turns of
  the rows robots avoid by (``avoid_turns``);
* ``pairs``: V at every robot and obstacle pair near enough to matter, now and after the
  lookahead's holds (``pair_values_fast``: a lone robot's few, in Python floats);
* ``discs``: obstacles of their own radius (the value shift V_r = V_R + (R - r), rings of discs);
* ``cluster_rows``: the union value (or the loiter fallback) of each cluster of close obstacles;
* ``nearby``: a robot's many detections narrowed to those within its reach;
* ``map_rows``: a robot judged by its local map, one row for all the map holds.
"""
