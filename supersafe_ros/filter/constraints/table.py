"""Step 2 of a decision: every robot's constraints, the rows of one ``law.ConstraintTable``.

From the columns ``gather`` read (``RobotColumns``: each robot's state now, its detections,
its command, hold, speed and turn bound), per robot:

* the detections within its reach when it has many (``nearby.narrow``: the others cannot
  constrain it);
* one row per detected obstacle near enough to read a value (``pairs``: V now and after the
  planner's hold, +inf for the others, which are no row (``pairs.near_pairs``); a disc of its
  own radius shifted, ``discs.pair_shifts``);
* one row per cluster of close obstacles (``cluster_rows``), its members' rows in its group;
* for a robot judged by its local map, one row for everything the map holds (``map_rows``).

A lone robot's few pairs are read in Python floats (``pairs.pair_values_fast``, the same
values bit for bit: numpy's cost per call would be most of its decision); its table is the
fleet's with one robot's rows.

The table holds data only: its rows' avoid turns are read from ``TurnSources`` by
``avoid_turns``, only for the rows robots avoid by (a pair's turn is a gradient read and two
held arcs' reads: computed for all of a 1,000-robot fleet's pairs it would cost more than the
rest of the table).
"""
from __future__ import annotations

from itertools import repeat
from operator import attrgetter, is_
from typing import NamedTuple

import numpy as np

from .cluster_rows import UnionTurns, cluster_rows, union_turns
from .discs import pair_shifts
from ..law import ConstraintTable
from .map_rows import map_rows
from .nearby import NEAR_QUERY_MIN, narrow
from .pairs import FEW_PAIRS, PairTurns, near_pairs, pair_reads, pair_turns_of, pair_values_fast

_KEPT = attrgetter('kept')

_ONE_ROBOT = np.zeros(1, np.intp)
_ONE_ROBOT.flags.writeable = False


def constraint_rows(cols, safe_set, clusters, derived):
    """(the table of every robot's constraints, per robot row the clusters near it whose union
    value is being solved) from ``gather``'s columns ``cols``; ``clusters``: the ClusterStore
    (None: the process's shared one, ``filter.clusters``); ``derived``: the decision's
    ``filter.derived.Derived`` (what it keeps, written by the recorder)."""
    m = len(cols.robot_index)
    dets, states, lone = cols.detections, cols.states, cols.lone_state
    if lone is not None:       # (a lone robot's count in Python: numpy's max costs more than it)
        counts = None
        many = len(dets[0]) > NEAR_QUERY_MIN
    else:
        counts = np.fromiter(map(len, dets), dtype=np.intp, count=m)
        many = m and counts.max() > NEAR_QUERY_MIN
    narrowed = None
    if many:
        narrowed = narrow(cols.configs, dets, cols.detection_inputs, states, cols.lookahead,
                          cols.max_speed, cols.clear_margin, safe_set, clusters, derived)
        dets = narrowed.dets
        counts = np.fromiter(map(len, dets), dtype=np.intp, count=m)
    vf, alpha = safe_set.vf, float(safe_set.alpha)
    horizon, planned, speed, bang = cols.lookahead, cols.planned_turn, cols.drive_speed, cols.omega_max
    fast = None
    if lone is not None:       # a robot's own filter: its few pairs in Python floats
        centres_list = dets[0].tolist()
        fast = pair_values_fast(vf, *lone, centres_list, float(planned[0]), float(horizon[0]), float(speed[0]),
                                float(bang[0]), FEW_PAIRS)
    if counts is None:
        counts = np.array([len(dets[0])])
    if fast is not None:       # every pair a row
        n_pairs = int(counts[0])
        start, pair_robot, centres = _ONE_ROBOT, np.zeros(n_pairs, np.intp), dets[0]
        pair_index = np.arange(n_pairs)
        position = pair_index if narrowed is None else narrowed.position
        value, value_next = np.array(fast[0], dtype=float), np.array(fast[1], dtype=float)
        shift = pair_shifts(cols.detection_radii, cols.configs, pair_robot, position)
        if shift is not None:        # discs of their own radius (filter.constraints.discs): V_r = V_R + (R - r)
            value += shift
            value_next += shift
        pair_turns = PairTurns(vf, None, fast[0], None, horizon, speed, bang, lone + (centres_list,))
        every_pair = True
    else:       # the pairs near the grid (near_pairs: the others read +inf, no row)
        start = np.concatenate(([0], np.cumsum(counts)[:-1])).astype(np.intp) if m else np.zeros(0, np.intp)
        pair_robot, local, rel, centres = near_pairs(vf.grid, dets, states, horizon, speed, counts, start)
        every_pair = len(pair_robot) == int(counts.sum())
        pair_index = start[pair_robot] + local
        position = local if narrowed is None else narrowed.position[pair_index]
        shift = pair_shifts(cols.detection_radii, cols.configs, pair_robot, position)
        value, value_next = pair_reads(vf, rel, planned[pair_robot], horizon[pair_robot], speed[pair_robot],
                                       bang[pair_robot], alpha if shift is None else alpha - shift)
        if shift is not None:        # discs of their own radius (filter.constraints.discs): V_r = V_R + (R - r)
            value += shift
            value_next += shift
        pair_turns = PairTurns(vf, rel, value, pair_robot, horizon, speed, bang)
    found = cluster_rows(cols.configs, cols.detection_inputs, states, planned, horizon, speed, bang, cols.cluster_alpha,
                         cols.clear_margin, dets, start, (pair_robot, value, alpha), clusters,
                         narrowed.frames if narrowed is not None else None, derived)
    if narrowed is None:
        obstacle = by_message(np.concatenate([position, found['obstacle']]) if len(found['robot']) else position,
                              pair_robot, found['robot'], cols.detection_inputs)
    else:       # (nearby names those it narrowed)
        names = narrowed.names
        obstacle = (np.concatenate([names[pair_index], names[start[found['robot']] + found['obstacle']]])
                    if len(found['robot']) else names[pair_index])
        counts = narrowed.counts
    maps = None
    if cols.map_views is not None:     # robots judged by their local maps' values: one row each
        mapped = [i for i, (v, mv) in enumerate(zip(cols.map_views, cols.map_values))
                  if v is not None and mv is not None]
        if mapped:
            maps = map_rows(cols.map_views, cols.map_values, mapped, states, planned, horizon, speed, bang, safe_set,
                            cols.configs)
    table = constraint_table(pair_robot, pair_index, position, counts, value, value_next, centres, alpha, obstacle,
                             found, maps, pair_turns, every_pair)
    return table, found['solving']


MAP_POSITION = 2 ** 30      # a map row's place in its robot's list: after its pairs and clusters (ties)


class TurnSources(NamedTuple):
    """What the unit avoid turns of a table's rows are read from (``avoid_turns``): rows 0 ..
    ``n_pairs`` - 1 the pairs' (``pairs.PairTurns``), then ``n_clusters`` cluster rows'
    (``cluster_rows.UnionTurns``, None if none), then the map rows' turns (``mapped``, read
    with their values)."""

    n_pairs: int
    pairs: PairTurns
    n_clusters: int
    clusters: UnionTurns | None
    mapped: np.ndarray


def avoid_turns(table, rows) -> np.ndarray:
    """The unit avoid turns (+1 left, -1 right, 0 none) of ``table``'s rows ``rows``: each pair's
    (``pairs.pair_turns``: the law's sign(dV/dtheta), or the better bang held), each cluster's
    (``cluster_rows.union_turns``: the union's better bang, or the loiter circle's), each map
    row's; computed here, for these rows only."""
    src = table.turns
    if not len(rows):       # (no robot avoids: most decisions)
        return _NO_TURNS
    rows = np.asarray(rows, dtype=np.intp)
    out = np.zeros(len(rows))
    n_pairs, after = src.n_pairs, src.n_pairs + src.n_clusters
    pair = rows < n_pairs
    if np.count_nonzero(pair):
        out[pair] = pair_turns_of(src.pairs, rows[pair])
    if not pair.all():
        cluster = ~pair & (rows < after)
        if cluster.any():
            out[cluster] = union_turns(src.clusters, rows[cluster] - n_pairs)
        mapped = rows >= after
        if mapped.any():
            out[mapped] = src.mapped[rows[mapped] - after]
    return out


def constraint_table(pair_robot, pair_index, position, counts, value, value_next, centres, alpha, obstacle, found,
                     maps, pair_turns, every_pair=False) -> ConstraintTable:
    """The ``law.ConstraintTable`` of every robot's constraints: the pair rows first (robot
    ``pair_robot``, ``position`` in the robot's detections, of which it has ``counts``; ``pair_index``
    ascending, its index among all robots' pairs, as ``cluster_rows`` names a cluster's members;
    ``every_pair``: every pair is a row, its index its row),
    then the cluster rows ``found`` (``cluster_rows``; a cluster's members' pair rows join its group), then
    the map rows ``maps`` (``map_rows``, None: none; each sound, a group of its own, naming no
    detection (obstacle -1) but the nearest occupied cell: ``xy``, ``gap``); ``obstacle``: what the
    pair and cluster rows name (``by_message``)."""
    n_pairs = len(pair_robot)
    group = np.arange(n_pairs)          # each obstacle its own group until clustered
    members = found['member_pairs']
    if len(members) and n_pairs:
        if every_pair:          # (a lone robot's)
            group[members] = n_pairs + found['member_groups']
        else:           # (a member's pair that is no row: far from its robot)
            row = np.minimum(np.searchsorted(pair_index, members), n_pairs - 1)
            hit = pair_index[row] == members
            group[row[hit]] = n_pairs + found['member_groups'][hit]
    k = len(found['robot'])
    n_groups = n_pairs + found['n_groups']
    no = np.zeros(n_pairs, bool)        # (not sound, no fallback, not mapped: one array, read only)
    level, members, gap = np.full(n_pairs, alpha), np.ones(n_pairs, np.intp), np.full(n_pairs, np.inf)
    if maps is None:
        if not k:           # the pair rows alone (most lone robots)
            return ConstraintTable(pair_robot, position, value, level, value_next, obstacle, centres, no, group,
                                   members, no, no, gap, n_groups, TurnSources(n_pairs, pair_turns, 0, None, _NO_TURNS))
        cat, yes = np.concatenate, np.ones(k, bool)     # the pair rows, then the cluster rows
        return ConstraintTable(
            cat([pair_robot, found['robot']]), cat([position, counts[found['robot']] + found['index']]),
            cat([value, found['value']]), cat([level, found['level']]), cat([value_next, found['value_next']]),
            obstacle, cat([centres, found['xy']]), cat([no, yes]), cat([group, n_pairs + found['group']]),
            cat([members, found['members']]), cat([no, found['fallback']]), cat([no, ~yes]),
            cat([gap, np.full(k, np.inf)]), n_groups, TurnSources(n_pairs, pair_turns, k, found['turns'], _NO_TURNS))
    # the columns in ConstraintTable's order: the pair rows', the cluster rows', the map rows'
    columns = [[pair_robot], [position], [value], [level], [value_next], [obstacle], [centres], [no], [group],
               [members], [no], [no], [gap]]
    if k:
        for column, part in zip(columns, (
                found['robot'], counts[found['robot']] + found['index'], found['value'], found['level'],
                found['value_next'], None, found['xy'], np.ones(k, bool), n_pairs + found['group'], found['members'],
                found['fallback'], np.zeros(k, bool), np.full(k, np.inf))):
            if part is not None:        # (the obstacles come named: ``obstacle``)
                column.append(part)
    if maps is not None:
        j = len(maps['robot'])
        for column, part in zip(columns, (
                maps['robot'], np.full(j, MAP_POSITION, dtype=np.intp), maps['value'], maps['level'],
                maps['value_next'], np.full(j, -1, dtype=obstacle.dtype), maps['xy'], np.ones(j, bool),
                n_groups + np.arange(j), np.ones(j, np.intp), np.zeros(j, bool), np.ones(j, bool), maps['gap'])):
            column.append(part)
        n_groups += j
        mapped_turns = maps['turns']
    return ConstraintTable(*(c[0] if len(c) == 1 else np.concatenate(c) for c in columns), n_groups,
                           TurnSources(n_pairs, pair_turns, k, found['turns'], mapped_turns))


_NO_TURNS = np.zeros(0)
_NO_TURNS.flags.writeable = False


def by_message(obstacle, pair_robot, cluster_robot, inputs):
    """``obstacle`` (per pair row, then per cluster row: its index in its robot's detections; the
    robots ``pair_robot``, ``cluster_robot``) named by its row in the robot's detections message,
    where a robot's detections are not the message's rows one for one (per robot row, its
    detections' input record's ``kept``: discs split into covering rings, ``filter.constraints.discs``; None:
    row i is row i); a new array if any is renamed. ``filter.constraints.nearby`` names those it narrows
    itself."""
    kept = list(map(_KEPT, inputs))
    if all(map(is_, kept, repeat(None))):      # (most decisions: checked in C)
        return obstacle
    robot = np.concatenate([pair_robot, cluster_robot])
    obstacle = obstacle.copy()
    for i, k in enumerate(kept):
        if k is not None:
            rows = np.flatnonzero(robot == i)
            obstacle[rows] = k[obstacle[rows]]
    return obstacle
