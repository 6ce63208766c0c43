"""Values of clusters of detected obstacles: the union's avoid value, not the min.

The smallest of the per-obstacle values is not the value of their union: two discs
closer than a turning diameter can each be avoidable while their union is not (the
turn away from one leads into the other). Obstacles close enough to interact are
therefore judged together:

* ``geometry.components``: obstacles whose centres lie within ``link`` of each other
  (transitively) form a cluster;
* ``geometry.canonical``: a cluster's geometry up to translation and rotation, rounded to
  ``key_resolution`` - the cache key (the same cup seen by another robot, or
  anywhere else on the map, is solved once);
* ``store.ClusterStore``: solves each new key with the core's union solver
  (``reach.solver.solve_avoid`` on ``sets.Union``) in a background thread, so
  control never waits, and keeps the values (LRU);
* ``geometry.ClusterValue.evaluate``: V and the avoid turn of robot states relative to a
  cluster, in its canonical frame.

Soundness margins. The solve uses discs inflated by ``margin`` >= the key's
rounding error (the rounded disc contains the true one) plus an allowance for the
solver's error. The value between grid nodes is read as a Lipschitz lower bound
(``geometry.lower_bound``): V is 1-Lipschitz in position (l is, and the flow commutes with
translation) and L_theta-Lipschitz in heading (L_theta = the largest |dV/dtheta| of
the nodes), so V(x) >= V(node) - |dp| - L_theta |dtheta| for each of the 8
corners of the cell, and the largest of those is kept. Trilinear interpolation
would instead overestimate V in the valley of head-on states by up to
L_theta dtheta / 2 - exactly where the filter must not act late.

Fallback while a cluster is being solved: ``geometry.orbit_value``, the clearance of the
best loiter circle. A Dubins robot that turns at +-w_max forever stays on a circle
of radius r = v / w_max; if that circle clears every disc of the cluster by
c > 0, holding that turn keeps the robot out of all of them forever, and the
circle stays the same as long as the turn is held. The filter keeps "some loiter
circle is clear" invariant: it passes the planner's command only if a circle is
still clear at the end of the hold, and otherwise turns onto the clearer circle.
That is sound for any layout and needs no grid (it is conservative: it wants a
whole clear circle of diameter 2r, so it is only a stop-gap until the union's
value is in force).
"""
