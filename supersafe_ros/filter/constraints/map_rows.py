"""A robot judged by its local map: one constraint row for everything the map holds.

A robot whose obstacles come from a range sensor or a costmap (``MapView``: a
``filter.sensing.local_map.LocalMap`` of what its sensors saw, the robot's clearance, and the avoid
value of that map, ``filter.sensing.map_value``) is not judged per obstacle: the map's value V_map is
the Hamilton-Jacobi avoid value of the robot's dynamics over the union of the map's occupied
cells in a window around it, so it is one row of the law's table (``law.ConstraintTable``),
read at the robot's state itself (the value's grid is in the map's coordinates: the "obstacle"
is at the origin):

* V now, and V_next after the planner's command held for the lookahead and the better bang
  held once more, and the unit avoid turn (``pairs.pair_values_fast``, ``pair_turn_fast``: every hold
  read, as for a lone robot's pairs; the radial bound of a value solved for a disc at the origin
  means nothing here);
* its level: the learned set's alpha when a learned set is in force and the map's value was
  solved with that set's w_max (the supervisor's model: the learned level applied as to discs),
  else the standard level (``FilterConfig.cluster_alpha``) with the value of the true dynamics;
* sound for its layout (the union's value, as a cluster's): the law lets no other row trade
  its turn away, and a robot that can stop never turns in place on it (there is no loiter
  fallback: the value is the union's);
* what it names: the nearest occupied cell (its centre ``xy``) and the gap to it, the distance
  until the robot's rim touches that cell's disc (``gap``; ``LocalMap.cell_radius``).

Between solves the value is that of the map at its solve time (``MapValue.version``); what the
map learned since is judged by the speed cut (``filter.approach``) on the live map's occupied
cells, each the disc of its cell grown by the robot's clearance (``cut_discs``): the guarantee
between solves, for a robot that can stop. Off the solved window V reads +inf (the row does not
constrain; the cut still does): V is the map's only within ``MapValue.covers`` (near the
window's rim the solver reads l beyond it), so a robot outside that part reads +inf there too,
until the worker's next solve (around the robot: ``MapValueWorker`` recentres the window).
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from ...reach.field import FREE
from .pairs import pair_turn_fast, pair_values_fast

NOTHING_NEAR = FREE / 2.0        # a map's value this high reads no occupied cell (reach.field.FREE)


@dataclass(frozen=True)
class MapView:
    """What a robot judged by its local map gives the decision: the live ``local_map``, the
    robot's ``clearance`` (its radius: an occupied cell's disc is grown by it), where its values
    come from (``values.latest()`` -> the newest ``MapValue`` or None; a
    ``filter.sensing.map_value.MapValueWorker``), and the ``sensor`` word the reasons use ('scan',
    'cloud', 'costmap')."""

    local_map: object
    clearance: float
    values: object
    sensor: str = 'scan'

    def value(self):
        """The newest solved value of the map (None: none yet)."""
        return self.values.latest()


def map_value_level(value, safe_set, cfg) -> float:
    """The level of a map's value: the learned set's alpha where it is in force and the value was
    solved with that set's w_max, else the standard level."""
    set_omega = safe_set.omega_max
    if (safe_set.source == 'learned' and set_omega is not None
            and float(value.omega_max) == float(set_omega)):
        return float(safe_set.alpha)
    return float(cfg.cluster_alpha)


def nearest_cell(view, x, y, reach):
    """(the centre of the occupied cell nearest (x, y) within ``reach`` (NaN, NaN: none), the gap
    from the robot's rim to that cell's disc, inf if none)."""
    m = view.local_map
    centres = m.occupied_centres(x, y, reach)
    if len(centres) == 0:
        return (math.nan, math.nan), math.inf
    d = np.hypot(centres[:, 0] - x, centres[:, 1] - y)
    k = int(np.argmin(d))
    return (float(centres[k, 0]), float(centres[k, 1])), float(d[k]) - m.cell_radius - view.clearance


def map_rows(views, values, rows, states, planned, horizon, speed, bang, safe_set, configs) -> dict:
    """The map rows of the robot rows ``rows`` (each with a view and its solved value, as gathered:
    ``values[i]``): per row its robot, V, V_next, level, the nearest occupied cell and the gap to
    it, and ``turns`` the unit avoid turns of the map rows (read with their values). Each row's
    reads are one robot's few, in Python floats (``pairs.pair_values_fast`` and ``pair_turn_fast``
    of the one "obstacle" at the origin: the same values as ``pair_reads`` and ``pair_turns``, bit
    for bit, at a fifth of their numpy cost here)."""
    k = len(rows)
    out = {'robot': np.asarray(rows, dtype=np.intp), 'value': np.full(k, np.inf), 'value_next': np.full(k, np.inf),
           'level': np.zeros(k), 'xy': np.full((k, 2), np.nan), 'gap': np.full(k, np.inf)}
    turns = np.zeros(k)
    for j, i in enumerate(rows):
        view, mv = views[i], values[i]
        x, y, th = (float(v) for v in states[i])
        if mv.covers(x, y):      # (near the window's rim V reads l beyond it: not the map's value)
            h, v, w = float(horizon[i]), float(speed[i]), float(bang[i])
            (value,), (value_next,) = pair_values_fast(mv.vf, x, y, th, [(0.0, 0.0)], float(planned[i]), h, v, w, 1)
            turn = pair_turn_fast(mv.vf, x - 0.0, y - 0.0, th, value, h, v, w)
            # no occupied cell the value can see: the field's FREE, nothing near (as a pair off its grid)
            out['value'][j] = value if value < NOTHING_NEAR else np.inf
            out['value_next'][j] = value_next if value_next < NOTHING_NEAR else np.inf
            turns[j] = turn
        out['level'][j] = map_value_level(mv, safe_set, configs[i])
        reach = 2.0 * float(speed[i]) * float(horizon[i]) + 2.0 + view.clearance
        out['xy'][j], out['gap'][j] = nearest_cell(view, x, y, reach)
    out['turns'] = turns
    return out


def cut_discs(view, x, y, reach):
    """(centres (K, 2), radius) of the live map's occupied cells that a path from (x, y) of length
    ``reach`` can meet: each cell's disc grown by the robot's clearance (what ``approach`` keeps
    the robot out of)."""
    m = view.local_map
    radius = m.cell_radius + view.clearance
    return m.occupied_centres(x, y, reach + radius), radius
