"""Where the decision is made: ``step_many(filters, safe_set, t)`` decides for any number of
robots, a robot's own filter being the case of one (``RobotFilter.step``).

1. the inputs, read once (``gather``; a lone robot's in Python floats, ``gather_one``);
2. each robot's state now: its pose propagated under the commands sent since its stamp
   (``propagation``);
3. its constraints, rows of one ``law.ConstraintTable``: one per detected obstacle
   (``pairs``: V now and after the planner's hold) and one per cluster of close
   obstacles (``cluster_rows``), of the detections within its reach when it has many
   (``nearby``: the others cannot constrain it);
4. the law over the table (``law.decide_rows``) and what it sends and says (``outputs``).

A lone robot's pairs are read in Python floats (numpy's cost per call would be most of its
decision on the path from pose to cmd_vel); its table, its law and its outputs are the
fleet's, with one robot's rows.
"""
from __future__ import annotations

from itertools import repeat
from operator import attrgetter, is_

import numpy as np

from .cluster_rows import cluster_rows
from .discs import pair_shifts
from .gather import gather, gather_one, judged
from .law import ConstraintTable
from .nearby import NEAR_QUERY_MIN, narrow
from .outputs import Decisions, outputs
from .pairs import FEW_PAIRS, pair_reads, pair_turns, pair_values, robot_pair_values
from .propagation import follow
from .types import SafeSet

_DETECTIONS, _KEPT = attrgetter('detections'), attrgetter('kept')


def step_many(filters, safe_set: SafeSet, t, clusters=None) -> Decisions:
    """One decision per robot filter, with one vectorised evaluation of the law.

    Robots that can be judged use their current pose and detections; robots that
    fail safe use their last valid pose and detections if younger than
    ``hold_timeout``, else ``fail_safe_command``. ``clusters``: the ClusterStore
    for obstacles judged together (None: the process's shared store for the
    robots' configuration; see ``filter.cluster``). Returns ``Decisions``: the
    commands as lists, each robot's ``FilterOutput`` built when read.
    """
    if len(filters) == 1:
        problem, usable = judged(filters[0], t)
        if usable:
            return decide_one(filters[0], problem, safe_set, t, clusters)
    rb = gather(filters, t)
    m = len(rb.use)
    states = follow(rb.poses, rb.omega_arcs, rb.dt_arcs, rb.speed_arcs)
    # the holds the law judges are driven at the speed the robot drives under them (gather.drive_speed)
    horizon, planned, speed, bang, dets = rb.horizon, rb.planned, rb.drive, rb.bang, rb.dets
    counts = np.fromiter(map(len, dets), dtype=np.intp, count=m)
    narrowed = None
    if m and counts.max() > NEAR_QUERY_MIN:
        narrowed = narrow(rb.filters, rb.configs, dets, states, horizon, rb.speed, rb.margin, safe_set, clusters)
        dets = narrowed.dets
        counts = np.fromiter(map(len, dets), dtype=np.intp, count=m)
    n_pairs = int(counts.sum())
    start = np.concatenate(([0], np.cumsum(counts)[:-1])).astype(np.intp) if m else np.zeros(0, np.intp)
    pair_robot = np.repeat(np.arange(m), counts)
    if n_pairs:
        centres = np.concatenate([d for d in dets if len(d)])
        rel = np.empty((n_pairs, 3))
        rel[:, 0] = states[pair_robot, 0] - centres[:, 0]
        rel[:, 1] = states[pair_robot, 1] - centres[:, 1]
        rel[:, 2] = states[pair_robot, 2]
    else:
        centres, rel = np.zeros((0, 2)), np.zeros((0, 3))
    alpha = float(safe_set.alpha)
    shift = pair_shifts(rb.radii, rb.configs, counts, narrowed.position if narrowed is not None else None)
    value, value_next = pair_reads(safe_set.vf, rel, planned[pair_robot], horizon[pair_robot], speed[pair_robot],
                                   bang[pair_robot], alpha if shift is None else alpha - shift)
    if shift is not None:        # discs of their own radius (filter.discs): V_r = V_R + (R - r)
        value += shift
        value_next += shift

    def pair_turns_of(p) -> np.ndarray:
        r = pair_robot[p]
        return pair_turns(safe_set.vf, rel[p], value[p], horizon[r], speed[r], bang[r])

    cl = cluster_rows(rb.filters, rb.configs, states, planned, horizon, speed, bang, rb.cluster_alpha, dets, start,
                      clusters, narrowed.frames if narrowed is not None else None)
    if narrowed is None:
        tab, n_groups = constraint_table(pair_robot, np.arange(n_pairs) - start[pair_robot], counts, value,
                                         value_next, centres, float(safe_set.alpha), cl, pair_turns_of)
        name_by_message(tab, rb.filters, rb.dets)
    else:
        tab, n_groups = constraint_table(pair_robot, narrowed.position, narrowed.counts, value, value_next, centres,
                                         float(safe_set.alpha), cl, pair_turns_of)
        narrowed.rename(tab, start, cl)
    return outputs(filters, rb, safe_set, t, tab, n_groups, cl['solving'], states, rb.dets)


def decide_one(f, problem, safe_set: SafeSet, t, clusters) -> Decisions:
    """``step_many`` for one robot with a state to judge (a robot's own filter node): the same
    table, law and outputs, its few pairs read in Python floats (``pairs.robot_pair_values``,
    the same values bit for bit), or with numpy when more than FEW_PAIRS are near."""
    rb, (x, y, th) = gather_one(f, problem, t)
    horizon, planned, speed, bang = (float(a[0]) for a in (rb.horizon, rb.planned, rb.drive, rb.bang))
    det = f.detections.value
    narrowed = None
    if len(det) > NEAR_QUERY_MIN:
        narrowed = narrow(rb.filters, rb.configs, [det], np.array([[x, y, th]]), rb.horizon, rb.speed, rb.margin,
                          safe_set, clusters)
        det = narrowed.dets[0]
    n_pairs = len(det)
    pairs = robot_pair_values(safe_set.vf, x, y, th, det.tolist(), planned, horizon, speed, bang, FEW_PAIRS)
    if pairs is None:
        rel = np.empty((n_pairs, 3))
        rel[:, 0] = x - det[:, 0]
        rel[:, 1] = y - det[:, 1]
        rel[:, 2] = th
        value, turn, value_next = pair_values(safe_set.vf, rel, np.full(n_pairs, planned), np.full(n_pairs, horizon),
                                              np.full(n_pairs, speed), np.full(n_pairs, bang))
    else:
        value, turn, value_next = (np.array(a, dtype=float) for a in pairs)
    shift = pair_shifts(rb.radii, rb.configs, [n_pairs], narrowed.position if narrowed is not None else None)
    if shift is not None:        # discs of their own radius (filter.discs): V_r = V_R + (R - r)
        value += shift
        value_next += shift
    start = np.zeros(1, np.intp)
    cl = cluster_rows([f], rb.configs, np.array([[x, y, th]]), rb.planned, rb.horizon, rb.drive, rb.bang,
                      rb.cluster_alpha, [det], start, clusters, narrowed.frames if narrowed is not None else None)
    if narrowed is None:
        tab, n_groups = constraint_table(np.zeros(n_pairs, np.intp), np.arange(n_pairs), np.array([n_pairs]), value,
                                         value_next, det, float(safe_set.alpha), cl, lambda p: turn[p])
        name_by_message(tab, [f], [det])
    else:
        tab, n_groups = constraint_table(np.zeros(n_pairs, np.intp), narrowed.position, narrowed.counts, value,
                                         value_next, det, float(safe_set.alpha), cl, lambda p: turn[p])
        narrowed.rename(tab, start, cl)
    return outputs([f], rb, safe_set, t, tab, n_groups, cl['solving'], np.array([[x, y, th]]), [f.detections.value])


def constraint_table(pair_robot, position, counts, value, value_next, centres, alpha, cl, pair_turns_of):
    """(the ``law.ConstraintTable`` of every robot's constraints, its number of groups): the
    pair rows first (robot ``pair_robot``, ``position`` in the robot's detections), then the
    cluster rows ``cl`` (``cluster_rows``); a cluster's members' pair rows join its group."""
    n_pairs = len(pair_robot)
    group = np.arange(n_pairs)          # each obstacle its own group until clustered
    group[cl['member_pairs']] = n_pairs + cl['member_groups']
    tab = ConstraintTable()
    k = len(cl['robot'])
    cat = (lambda a, b: np.concatenate([a, b])) if k else (lambda a, b: a)   # noqa: E731
    tab.robot = cat(pair_robot, cl['robot'])
    tab.position = cat(position, counts[cl['robot']] + cl['index'])
    tab.value = cat(value, cl['value'])
    tab.level = cat(np.full(n_pairs, alpha), cl['level'])
    tab.value_next = cat(value_next, cl['value_next'])
    tab.obstacle = cat(position, cl['obstacle'])
    tab.xy = cat(centres, cl['xy'])
    tab.sound = cat(np.zeros(n_pairs, bool), np.ones(k, bool))
    tab.group = cat(group, n_pairs + cl['group'])
    tab.members = cat(np.ones(n_pairs, np.intp), cl['members'])
    tab.fallback = cat(np.zeros(n_pairs, bool), cl['fallback'])

    def turns_of(rows) -> np.ndarray:
        """The unit avoid turns of table ``rows`` (read only for the rows robots avoid by)."""
        out = np.zeros(len(rows))
        pair = rows < n_pairs
        out[pair] = pair_turns_of(rows[pair])
        out[~pair] = cl['turns_of'](rows[~pair] - n_pairs)
        return out

    tab.turns_of = turns_of
    return tab, n_pairs + cl['n_groups']


def name_by_message(tab, filters, dets) -> None:
    """The table's obstacles named by their rows in the robots' detections messages, where a
    robot's detections are not the message's rows one for one (``detections.kept``: discs split
    into covering rings, ``filter.discs``); ``filter.nearby`` names those it narrows itself."""
    inputs = list(map(_DETECTIONS, filters))
    if all(map(is_, map(_KEPT, inputs), repeat(None))):      # (most decisions: checked in C)
        return
    for i, (inp, det) in enumerate(zip(inputs, dets)):
        kept = inp.kept
        if kept is not None and inp.value is det:
            rows = np.flatnonzero(tab.robot == i)
            tab.obstacle[rows] = kept[tab.obstacle[rows]]
