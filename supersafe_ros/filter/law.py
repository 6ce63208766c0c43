"""The filter law: the rule every robot obeys, written once, vectorised over robots.

Per constraint (a row of ``ConstraintTable``: one per robot and detected obstacle near it, one
per robot and cluster of close obstacles), with V its value at the robot's state now, V_next
its value after the planner's command held for the lookahead H and then the better bang
held once more (``filter.constraints.pairs``), and alpha its level:

    enter  = V <= alpha
    ahead  = V_next <= alpha
    stay   = overriding and V <= alpha + clear_margin            (hysteresis)

Within a cluster whose own (sound) row acts, its members' single-obstacle rows are set
aside, so the union's avoid turn is never traded for a single member's. The governing
row (``govern``) is the first kind with a hit, in the order enter, ahead, stay, and within
it the smallest score (V - alpha, or V_next - alpha), the first in the robot's list on
ties (``choose``: the row each robot acts on or names). The command (``command``), s the
planner's speed clipped to [0, speed] (``commands.drive_speed``; 0 for a silent planner):

    fail safe  inputs stale/invalid (``FilterConfig.fail_safe_command``): 'stop': a zero twist
               (v = 0, u = 0); 'stop_turn' (a constant-speed Dubins robot): from the last
               valid state the avoid turn of the row with the smallest V - alpha at speed,
               else the stop-turn (v = 0, u = +w_max)
    override   a governing row: u* = w_max x turn of that row, v = s (a robot that can stop
               turns in place on a cluster's loiter fallback: its circle is drawn at speed)
    pass       the planner's command clipped to +-w_max, v = s; a silent planner: a zero
               twist for a robot that can stop (whatever the rows say), the turn 0 at speed
               for a constant-speed robot, still overridden by the rows

A constant-speed robot's s is its speed (whatever the planner asks).

The avoid turn of a pair is the minimally invasive law's u* = w_max sign(dV/dtheta)
(``avoid_turn``; ties left), and with a hold H the bang whose hold ends at the larger V
(``better_bang``), which tends to sign(dV/dtheta) as H -> 0.

``decide.decide`` calls ``choose``, then reads the avoid turns of the rows chosen
(``constraints.table.avoid_turns``), then ``command``, for a fleet and for a lone robot alike
(``RobotFilter.step`` is ``step_many`` of one): a lone robot's table is the same table with
one robot's rows.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..reach.value_function import ValueFunction


def evaluate_pairs(vf: ValueFunction, rel_states):
    """V and the unit avoid control sign(dV/dtheta) at every relative state (N, 3).

    Pairs outside the grid: V = +inf (never constraining), turn 0. On a ridge of V
    (dV/dtheta = 0, e.g. heading straight at the obstacle) the turn is left (+1)
    rather than straight into it. "Zero" is judged relative to the gradient's
    scale (``tie_tolerance``): on a grid symmetric about the obstacle's axis the
    interpolated dV/dtheta at a head-on state is float32 round-off (-1.4e-8 at
    (-3, 0, 0) on 41 x 41 x 24), whose sign means nothing. Only the theta
    component of the gradient is interpolated. Callers that hold a robot in an
    override band (filter.constraints.pairs) need the turn where V > alpha too, so it is
    evaluated at every pair.
    """
    s = np.asarray(rel_states, dtype=float).reshape(-1, 3)
    value = np.full(len(s), np.inf)
    turn = np.zeros(len(s))
    inside = vf.grid.contains(s)
    if np.any(inside):
        si = s[inside]
        value[inside] = vf.value(si)
        turn[inside] = avoid_turn(vf, si)
    return value, turn


def avoid_turn(vf: ValueFunction, states) -> np.ndarray:
    """sign(dV/dtheta) at states on the grid (N, 3), ties (within ``tie_tolerance``) left: +1."""
    grad_th = vf.grid.interpolate(vf.theta_gradient(), states)
    return np.where(grad_th >= -tie_tolerance(vf), 1.0, -1.0)


def avoid_turn_at(vf: ValueFunction, x: float, y: float, theta: float) -> float:
    """``avoid_turn`` at one state on the grid, in Python floats (the same value bit for bit)."""
    grad_th = vf.grid.interpolate_at(vf.flat_theta_gradient(), x, y, theta)
    return 1.0 if grad_th >= -tie_tolerance(vf) else -1.0


TIE_RELATIVE = 1e-5   # |dV/dtheta| below this fraction of its largest node value is a tie


def tie_tolerance(vf: ValueFunction) -> float:
    """|dV/dtheta| at or below which the avoid turn is a tie (and turns left).

    TIE_RELATIVE x the largest |dV/dtheta| over the grid's nodes: far above float32
    round-off of the values (~1e-7 relative), far below any gradient that means
    a direction (a tie's turn is harmless either way, by definition of a tie).
    """
    return TIE_RELATIVE * vf.theta_gradient_bound()


def better_bang(left, right, tie) -> np.ndarray:
    """The unit turn whose hold ends at the larger V: left (+1) unless V after the right turn
    is larger by more than ``tie`` (the value's tie tolerance: ties turn left)."""
    return np.where(left >= right - tie, 1.0, -1.0)


class ConstraintTable(NamedTuple):
    """Every constraint of every robot, one row each (pairs first, then clusters, then local maps).

    Columns: the robot (its row in ``gather.RobotColumns``), its position in the robot's list (ties go to
    the first), V, level, V after the planner's hold, the obstacle
    it names (index in the robot's detections) and its centre, whether it is sound for
    its layout (a cluster's union value or the loiter fallback), its group (a lone
    obstacle, or the cluster its members belong to), members, for a cluster row whether it
    is the loiter fallback (its source 'cluster-fallback', else 'cluster'), and whether the row is
    a robot's local map's (``mapped``: ``filter.constraints.map_rows``; ``gap`` the distance to the nearest
    occupied cell, inf for the other rows). ``n_groups``: the number of groups; ``turns``: what
    the rows' unit avoid turns are read from (``constraints.table.TurnSources``, read by
    ``constraints.table.avoid_turns`` for the rows robots avoid by).
    """

    robot: np.ndarray
    position: np.ndarray
    value: np.ndarray
    level: np.ndarray
    value_next: np.ndarray
    obstacle: np.ndarray
    xy: np.ndarray
    sound: np.ndarray
    group: np.ndarray
    members: np.ndarray
    fallback: np.ndarray
    mapped: np.ndarray
    gap: np.ndarray
    n_groups: int = 0
    turns: object = None


def first_min(segment, position, score, mask, n, rank=None) -> np.ndarray:
    """Per segment 0..n-1: the row with the smallest ``score`` among ``mask``, the first
    by ``position`` on ties (Python's ``min`` over a list in that order); -1 if none.
    ``rank``: a key before the score (the smallest rank first, then the smallest score).

    Many rows (a fleet's): first each segment's rows of its smallest rank, then of its smallest
    score, found in one pass each (``np.minimum.at``); only those (ties) are sorted (a sort of
    a fleet's thousands of rows would cost more than the rest of the rule)."""
    out = np.full(n, -1, dtype=np.intp)
    idx = np.flatnonzero(mask)
    if len(idx) > FEW_ROWS:
        idx = _smallest_of_segments(idx, segment, score, n, rank)
    if len(idx):
        keys = (position[idx], score[idx], segment[idx]) if rank is None else \
            (position[idx], score[idx], rank[idx], segment[idx])
        order = idx[np.lexsort(keys)]
        seg = segment[order]
        if len(seg) == 1:
            out[seg] = order
        else:
            first = np.flatnonzero(np.concatenate(([True], seg[1:] != seg[:-1])))
            out[seg[first]] = order[first]
    return out


FEW_ROWS = 32       # up to this many rows first_min sorts them all


def _smallest_of_segments(idx, segment, score, n, rank=None) -> np.ndarray:
    """The rows ``idx`` that have their segment's smallest ``rank`` (if given) and, among those, its
    smallest ``score``; all of ``idx`` if a score is NaN (the sort orders those)."""
    seg, s = segment[idx], score[idx]
    if np.isnan(s).any():
        return idx
    keep = np.ones(len(idx), bool)
    if rank is not None:
        r = rank[idx]
        low = np.full(n, r.max(), dtype=r.dtype)
        np.minimum.at(low, seg, r)
        keep = r == low[seg]
    best = np.full(n, np.inf)
    np.minimum.at(best, seg[keep], s[keep])
    return idx[keep & (s == best[seg])]


def first_min_of_runs(score, run, starts) -> np.ndarray:
    """Per run of equal ``run`` labels 0..k-1 (consecutive, each non-empty, beginning at
    ``starts``): the index of its smallest ``score``, the first on ties (``first_min`` over
    rows in run order, without its sort); ``score`` has no NaN."""
    if len(starts) == 0:
        return np.zeros(0, dtype=np.intp)
    at = np.flatnonzero(score == np.minimum.reduceat(score, starts)[run])
    return at[np.concatenate(([True], run[at[1:]] != run[at[:-1]]))]


def govern(table, overriding, margin, n_groups, m):
    """(constraint, why) per robot row that makes the filter override, or (smallest, '') to pass.

    Within a cluster its sound constraint (union value or fallback) comes first: if
    it enters, looks ahead to its level or holds its hysteresis, the cluster's
    members' own constraints are set aside, so the union's avoid turn is never
    traded for a single member's. Between clusters and lone obstacles (farther
    apart than the link distance) the smallest value governs, as per obstacle.
    Checked in order: enter (V <= level), ahead (V after the planner's hold <=
    level), stay (overriding and V <= level + clear margin); within each, the
    smallest V - level (resp. V_next - level), first in the robot's list on ties.
    """
    r = table.robot
    enter = table.value <= table.level
    ahead = table.value_next <= table.level
    stay = overriding[r] & (table.value <= table.level + margin[r])
    acts = enter | ahead | stay
    if not acts.any():          # every robot passes (most decisions): nothing to order
        return np.full(m, -1, dtype=np.intp), np.zeros(m, dtype=np.int8)
    governed = np.zeros(n_groups, bool)
    governed[table.group[table.sound & acts]] = True
    use = table.sound | ~governed[table.group]
    # each acting row by the first kind it has (1 enter, 2 ahead, 3 stay) and that kind's score:
    # a robot's first kind with a hit is its rows' smallest kind, and its rows of that kind are
    # exactly those whose first kind it is, so one ordering by (kind, score, position) finds it
    code = np.where(enter, 1, np.where(ahead, 2, 3)).astype(np.int8)
    score = np.where(code == 2, table.value_next, table.value) - table.level
    k = first_min(r, table.position, score, use & acts, m, rank=code)
    kind = np.zeros(m, dtype=np.int8)      # 0 pass, 1 enter, 2 ahead, 3 stay
    got = k >= 0
    kind[got] = code[k[got]]
    return k, kind


KINDS = ('', 'enter', 'ahead', 'stay')     # why a row governs, by ``govern``'s code


def smallest(table, m) -> np.ndarray:
    """Per robot row: the constraint with the smallest finite V - alpha (the first in the
    robot's list on ties), -1 if none: the one a pass names and a fail safe avoids."""
    return first_min(table.robot, table.position, table.value - table.level, np.isfinite(table.value), m)


class Choice(NamedTuple):
    """Per robot row, what the law acts on (``choose``): the row it names (``row``: the governing
    one where it overrides, else the smallest V - alpha; -1: none), why that row governs (``kind``,
    ``KINDS``; 0: it passes), whether the robot ``overrides``, and whether it turns by the named
    row's avoid turn (``avoiding``: it overrides, or fails safe at constant speed with a row near)."""

    row: np.ndarray
    kind: np.ndarray
    overrides: np.ndarray
    avoiding: np.ndarray


def choose(table, overriding, margin, failing, fresh, constant) -> Choice:
    """The rows the M robot rows of ``table`` act on (``Choice``). Per robot row: ``overriding``,
    ``margin`` (its clear margin), ``failing`` (inputs stale or invalid, its last valid state judged
    instead), ``fresh`` (the planner's command), ``constant`` (a constant-speed robot)."""
    m = len(overriding)
    k_gov, kind = govern(table, overriding, margin, table.n_groups, m)
    k_small = smallest(table, m)
    acts = kind > 0
    # a robot that can stop stops (a zero twist) whenever it fails safe or its planner is silent:
    # nothing to judge, and standing still is safe; a constant-speed robot cannot stop
    silent = ~failing & ~fresh & ~constant
    overrides = ~failing & ~silent & acts
    # failing safe, a constant-speed robot avoids the nearest constraint (the smallest V - alpha)
    # of its last valid state
    named = np.where(overrides, k_gov, k_small)   # the constraint each robot's output names
    avoiding = overrides | (failing & constant & (k_small >= 0))
    return Choice(named, kind, overrides, avoiding)


class Ruling(NamedTuple):
    """The law's answer per robot row (``command``): ``omega``, ``linear``, the action ``code`` (0
    pass, 1 override, 2 fail safe), and from its ``Choice``: ``overrides``, the row it names
    (``named``), why it governs (``kind``)."""

    omega: np.ndarray
    linear: np.ndarray
    code: np.ndarray
    overrides: np.ndarray
    named: np.ndarray
    kind: np.ndarray


def command(table, choice, turns, failing, fresh, constant, planned, bang, drive, held) -> Ruling:
    """The rule's command for the M robot rows: ``choice`` (``choose``'s), ``turns`` the unit avoid
    turns of the rows of the robots that avoid (``choice.avoiding``, in order:
    ``constraints.table.avoid_turns``). Per robot row: ``failing``, ``fresh``, ``constant`` (as
    ``choose``'s), ``planned`` (the planner's turn clipped, 0 if silent), ``bang`` (w_max),
    ``drive`` (the speed of the command judged, ``commands.drive_speed``), ``held`` (the speed last
    sent)."""
    named, overrides, avoiding = choice.row, choice.overrides, choice.avoiding
    turn = np.zeros(len(named))
    turn[avoiding] = turns
    omega = np.where(avoiding, bang * turn, np.where(failing & constant, bang, np.where(failing, 0.0, planned)))
    linear = np.where(failing, np.where(avoiding, held, 0.0), np.where(overrides | fresh, drive, 0.0))
    if np.count_nonzero(overrides) and not constant.all():     # a robot that can stop: in place on a loiter fallback
        loiter = overrides & ~constant
        loiter[loiter] = table.fallback[named[loiter]]
        linear[loiter] = 0.0
    code = np.where(failing, 2, np.where(overrides, 1, 0))
    return Ruling(omega, linear, code, overrides, named, choice.kind)
