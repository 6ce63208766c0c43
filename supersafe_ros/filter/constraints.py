"""Step 2 of a decision: every robot's constraints, the rows of one ``law.ConstraintTable``.

From the columns ``gather`` read (``RobotColumns``: each robot's state now, its detections,
its command, hold, speed and turn bound), per robot:

* the detections within its reach when it has many (``nearby.narrow``: the others cannot
  constrain it);
* one row per detected obstacle (``pairs``: V now and after the planner's hold; a disc of its
  own radius shifted, ``discs.pair_shifts``);
* one row per cluster of close obstacles (``cluster_rows``), its members' rows in its group;
* for a robot judged by its local map, one row for everything the map holds (``map_rows``).

A lone robot's few pairs are read in Python floats (``pairs.pair_values_fast``, the same
values bit for bit: numpy's cost per call would be most of its decision); its table is the
fleet's with one robot's rows.
"""
from __future__ import annotations

from itertools import repeat
from operator import attrgetter, is_

import numpy as np

from .cluster_rows import cluster_rows
from .discs import pair_shifts
from .law import ConstraintTable
from .map_rows import map_rows
from .nearby import NEAR_QUERY_MIN, narrow
from .pairs import FEW_PAIRS, pair_reads, pair_turns, pair_values_fast

_DETECTIONS, _KEPT = attrgetter('detections'), attrgetter('kept')
_ONE_ROBOT = np.zeros(1, np.intp)
_ONE_ROBOT.flags.writeable = False


def constraint_rows(cols, safe_set, clusters, derived=None):
    """(the table of every robot's constraints, its number of groups, per robot row the
    clusters near it whose union value is being solved) from ``gather``'s columns ``cols``;
    ``clusters``: the ClusterStore (None: the process's shared one, ``filter.cluster``);
    ``derived``: the decision's ``filter.derived.Derived`` (what it keeps, written by the recorder)."""
    m = len(cols.use)
    dets, states, lone = cols.dets, cols.states, cols.lone
    if lone is not None:       # (a lone robot's count in Python: numpy's max costs more than it)
        counts = None
        many = len(dets[0]) > NEAR_QUERY_MIN
    else:
        counts = np.fromiter(map(len, dets), dtype=np.intp, count=m)
        many = m and counts.max() > NEAR_QUERY_MIN
    narrowed = None
    if many:
        narrowed = narrow(cols.filters, cols.configs, dets, states, cols.horizon, cols.speed, cols.margin, safe_set,
                          clusters, derived)
        dets = narrowed.dets
        counts = np.fromiter(map(len, dets), dtype=np.intp, count=m)
    vf, alpha = safe_set.vf, float(safe_set.alpha)
    horizon, planned, speed, bang = cols.horizon, cols.planned, cols.drive, cols.bang
    fast = None
    if lone is not None:       # a robot's own filter: its few pairs in Python floats
        fast = pair_values_fast(vf, *lone, dets[0].tolist(), float(planned[0]), float(horizon[0]), float(speed[0]),
                                float(bang[0]), FEW_PAIRS)
    if counts is None:
        counts = np.array([len(dets[0])])
    if fast is not None:
        n_pairs = int(counts[0])
        start, pair_robot, centres = _ONE_ROBOT, np.zeros(n_pairs, np.intp), dets[0]
        position = np.arange(n_pairs)
        value, turn, value_next = (np.array(a, dtype=float) for a in fast)
        shift = pair_shifts(cols.radii, cols.configs, [n_pairs], narrowed.position if narrowed is not None else None)
        if shift is not None:        # discs of their own radius (filter.discs): V_r = V_R + (R - r)
            value += shift
            value_next += shift

        def pair_turns_of(p) -> np.ndarray:
            return turn[p]
    else:
        n_pairs = int(counts.sum())
        start = np.concatenate(([0], np.cumsum(counts)[:-1])).astype(np.intp) if m else np.zeros(0, np.intp)
        pair_robot = np.repeat(np.arange(m), counts)
        position = np.arange(n_pairs) - start[pair_robot]
        if n_pairs:
            centres = np.concatenate([d for d in dets if len(d)])
            rel = np.empty((n_pairs, 3))
            rel[:, 0] = states[pair_robot, 0] - centres[:, 0]
            rel[:, 1] = states[pair_robot, 1] - centres[:, 1]
            rel[:, 2] = states[pair_robot, 2]
        else:
            centres, rel = np.zeros((0, 2)), np.zeros((0, 3))
        shift = pair_shifts(cols.radii, cols.configs, counts, narrowed.position if narrowed is not None else None)
        value, value_next = pair_reads(vf, rel, planned[pair_robot], horizon[pair_robot], speed[pair_robot],
                                       bang[pair_robot], alpha if shift is None else alpha - shift)
        if shift is not None:        # discs of their own radius (filter.discs): V_r = V_R + (R - r)
            value += shift
            value_next += shift

        def pair_turns_of(p) -> np.ndarray:
            r = pair_robot[p]
            return pair_turns(vf, rel[p], value[p], horizon[r], speed[r], bang[r])

    clusters_found = cluster_rows(cols.filters, cols.configs, states, planned, horizon, speed, bang, cols.cluster_alpha,
                                  dets, start, clusters, narrowed.frames if narrowed is not None else None, derived)
    if narrowed is None:
        table, n_groups = constraint_table(pair_robot, position, counts, value, value_next, centres, alpha,
                                           clusters_found, pair_turns_of)
        name_by_message(table, cols.filters, cols.dets)
    else:
        table, n_groups = constraint_table(pair_robot, narrowed.position, narrowed.counts, value, value_next, centres,
                                           alpha, clusters_found, pair_turns_of)
        narrowed.rename(table, start, clusters_found)
    if cols.views is not None:     # robots judged by their local maps' values: one row each
        mapped = [i for i, (v, mv) in enumerate(zip(cols.views, cols.map_values)) if v is not None and mv is not None]
        if mapped:
            n_groups = add_map_rows(table, n_groups, map_rows(cols.views, cols.map_values, mapped, states, planned,
                                                              horizon, speed, bang, safe_set, cols.configs))
    return table, n_groups, clusters_found['solving']


MAP_POSITION = 2 ** 30      # a map row's place in its robot's list: after its pairs and clusters (ties)


def add_map_rows(table, n_groups, mp) -> int:
    """``mp`` (``map_rows.map_rows``) appended to ``table``: each map row sound, a group of its own,
    naming no detection (obstacle -1) but the nearest occupied cell (``xy``, ``gap``); the
    table's number of groups after them."""
    k, n = len(mp['robot']), len(table.robot)
    cat = np.concatenate
    table.robot = cat([table.robot, mp['robot']])
    table.position = cat([table.position, np.full(k, MAP_POSITION, dtype=np.intp)])
    table.value, table.level, table.value_next = (cat([getattr(table, a), mp[b]]) for a, b in (
        ('value', 'value'), ('level', 'level'), ('value_next', 'value_next')))
    table.obstacle = cat([table.obstacle, np.full(k, -1, dtype=table.obstacle.dtype)])
    table.xy = cat([np.asarray(table.xy, dtype=float).reshape(-1, 2), mp['xy']])
    table.sound = cat([table.sound, np.ones(k, bool)])
    table.group = cat([table.group, n_groups + np.arange(k)])
    table.members = cat([table.members, np.ones(k, np.intp)])
    table.fallback = cat([table.fallback, np.zeros(k, bool)])
    table.mapped = cat([table.mapped, np.ones(k, bool)])
    table.gap = cat([table.gap, mp['gap']])
    table.turns_of = joined_turns(table.turns_of, n, mp['turns_of'])
    return n_groups + k


def joined_turns(first, n_first: int, rest):
    """``turns_of`` of a table whose first ``n_first`` rows are read by ``first`` and the others
    by ``rest`` (indexed from 0): the unit avoid turns of any rows of it."""
    def turns_of(rows) -> np.ndarray:
        out = np.zeros(len(rows))
        head = rows < n_first
        out[head] = first(rows[head])
        out[~head] = rest(rows[~head] - n_first)
        return out
    return turns_of


def constraint_table(pair_robot, position, counts, value, value_next, centres, alpha, clusters_found, pair_turns_of):
    """(the ``law.ConstraintTable`` of every robot's constraints, its number of groups): the
    pair rows first (robot ``pair_robot``, ``position`` in the robot's detections), then the
    cluster rows ``clusters_found`` (``cluster_rows``); a cluster's members' pair rows join its group."""
    n_pairs = len(pair_robot)
    group = np.arange(n_pairs)          # each obstacle its own group until clustered
    group[clusters_found['member_pairs']] = n_pairs + clusters_found['member_groups']
    table = ConstraintTable()
    k = len(clusters_found['robot'])
    cat = (lambda a, b: np.concatenate([a, b])) if k else (lambda a, b: a)   # noqa: E731
    table.robot = cat(pair_robot, clusters_found['robot'])
    table.position = cat(position, counts[clusters_found['robot']] + clusters_found['index'])
    table.value = cat(value, clusters_found['value'])
    table.level = cat(np.full(n_pairs, alpha), clusters_found['level'])
    table.value_next = cat(value_next, clusters_found['value_next'])
    table.obstacle = cat(position, clusters_found['obstacle'])
    table.xy = cat(centres, clusters_found['xy'])
    table.sound = cat(np.zeros(n_pairs, bool), np.ones(k, bool))
    table.group = cat(group, n_pairs + clusters_found['group'])
    table.members = cat(np.ones(n_pairs, np.intp), clusters_found['members'])
    table.fallback = cat(np.zeros(n_pairs, bool), clusters_found['fallback'])
    table.mapped = np.zeros(n_pairs + k, bool)          # map rows (add_map_rows)
    table.gap = np.full(n_pairs + k, np.inf)
    # read only for the rows avoided by
    table.turns_of = joined_turns(pair_turns_of, n_pairs, clusters_found['turns_of'])
    return table, n_pairs + clusters_found['n_groups']


def name_by_message(table, filters, dets) -> None:
    """The table's obstacles named by their rows in the robots' detections messages, where a
    robot's detections are not the message's rows one for one (``detections.kept``: discs split
    into covering rings, ``filter.discs``); ``filter.nearby`` names those it narrows itself."""
    inputs = list(map(_DETECTIONS, filters))
    if all(map(is_, map(_KEPT, inputs), repeat(None))):      # (most decisions: checked in C)
        return
    for i, (inp, det) in enumerate(zip(inputs, dets)):
        kept = inp.kept
        if kept is not None and inp.value is det:
            rows = np.flatnonzero(table.robot == i)
            table.obstacle[rows] = kept[table.obstacle[rows]]
