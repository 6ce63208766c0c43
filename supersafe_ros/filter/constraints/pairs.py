"""V at every (robot, obstacle) pair: now, and after the holds the lookahead judges.

A pair is a robot's state relative to one detected obstacle (the obstacle at the origin,
axes as the map): translation invariance lets one value function, solved for a disc at the
origin, serve every obstacle (the relative state moves like the robot itself). Per pair, with
the planner's (clipped) command, the hold H (the robot's lookahead, >= its control period),
the robot's speed and turn bound w_max (a silent planner counts as a zero command):

* V at the state now (+inf off the grid: far from the obstacle, never constraining);
* the unit avoid turn: the law's sign(dV/dtheta), or with a hold H the better bang
  (``filter.law``);
* V_next = min(V(end of the planner's command held for H), max over +-w_max of V(that end,
  then the bang held for H)): what the filter can still do after letting the command pass.
  A pass therefore never leaves the robot below the level, nor where no held turn keeps V
  above it (the filter acts one hold early rather than one hold late).

``near_pairs`` finds the pairs near enough to the grid to read anything but +inf (a fleet's
robots among 30 obstacles over 80 x 80 m: about 5 % of its pairs; only they are rows of the
constraint table), ``pair_reads`` reads V and V_next of many pairs in one call (skipping the
hold reads of pairs whose radial bound keeps V_next above the level), ``pair_turns`` the turns
(read only for the rows robots avoid by, from ``PairTurns``: ``pair_turns_of``);
``pair_values_fast`` and ``pair_turn_fast`` are the same for one robot's few pairs, in Python
floats (the same bits).
"""
from __future__ import annotations

from itertools import repeat
import math
from operator import is_
from typing import NamedTuple

import numpy as np

from ...reach.value_function import ValueFunction
from ..law import avoid_turn, avoid_turn_at, better_bang, tie_tolerance
from ..propagation import arc, arc_flow, bang_ends


def pair_reads(vf: ValueFunction, rel, omega, horizon, speed, bang, level=math.inf):
    """(V, V next) of the pairs (see the module): V at the pair's state and where the planner's hold and
    both bangs after it end, in one read; V next only where it can be at or below ``level``
    (the pairs' alpha, or per pair (N,): the level less the pair's ``discs.value_shift``;
    +inf: everywhere), else a lower bound above it (so the row never looks ahead: the same
    decisions).

    The holds end within 2 speed H of the pair's state, so no read there can be below
    ``vf.radial_minimum`` over that band of radii: a pair whose bound is above the level
    needs no hold read (most pairs on the grid, away from their obstacle)."""
    n = len(rel)
    value, value_next = np.full(n, np.inf), np.full(n, np.inf)
    if n == 0:
        return value, value_next
    holds = bool(np.any(horizon > 0))
    # pairs too far from the grid for any hold to reach it: every V below is +inf, so V and V_next
    # stay +inf (two holds move the robot at most 2 speed H; +1 m for round-off); without holds,
    # the pairs on the grid
    g = vf.grid
    reach = 2.0 * speed * horizon + 1.0 if holds else 0.0
    near = np.flatnonzero((rel[:, 0] >= g.lo[0] - reach) & (rel[:, 0] <= g.hi[0] + reach)
                          & (rel[:, 1] >= g.lo[1] - reach) & (rel[:, 1] <= g.hi[1] + reach))
    if len(near) == 0:
        return value, value_next
    rel = rel[near]
    k = len(rel)
    if not holds:
        value[near] = vf.value(rel, outside=np.inf)
        return value, value_next
    horizon, speed = horizon[near], speed[near]
    per_pair = np.ndim(level) > 0
    if per_pair or level < math.inf:
        if per_pair:
            level = level[near]
        radius, travel = np.hypot(rel[:, 0], rel[:, 1]), 2.0 * speed * horizon
        bound = vf.radial_minimum(radius - travel, radius + travel)
        held = np.flatnonzero((horizon > 0) & ~(bound > level + 1e-6))     # read unless above the level
    else:           # every hold read (a lone robot's many pairs: no bound to compute)
        bound = np.full(k, np.inf)
        held = np.flatnonzero(horizon > 0)
    h = len(held)
    ahead = arc_flow(rel[held], speed[held], omega[near][held], horizon[held])
    v = vf.value(np.concatenate([rel, bang_ends(ahead, speed[held], bang[near][held], horizon[held]), ahead]),
                 outside=np.inf)
    value[near] = v[:k]
    later = np.where(horizon > 0, bound, np.inf)
    later[held] = np.minimum(v[k + 2 * h:], np.maximum(v[k:k + h], v[k + h:k + 2 * h]))
    value_next[near] = later
    return value, value_next


def near_pairs(grid, dets, states, horizon, speed, counts, start):
    """The pairs that can constrain their robots, robot-major: (robot row, index in its detections,
    relative state (P, 3), the obstacle's centre (P, 2)) of every pair within two holds (2 speed H)
    and a metre of ``grid`` on both axes, as ``pair_reads`` reaches (a superset of the pairs it
    reads: those with H = 0 are kept within the metre too). Every other pair reads V = V next =
    +inf: it never acts, nor has a smallest value, so it is no row. Per robot row: ``dets`` its
    detections (K_i, 2) (``counts`` of them, the first its ``start``-th pair of all), ``states``,
    ``horizon``, ``speed``. Robots given one detections array
    (the batched fleet) are tested at once over (robots x detections), without the pairs of
    every robot laid out; robots given arrays of their own keep every pair (such an array holds
    what is near its robot: its own sensor's, or narrowed to its reach, ``filter.constraints.nearby``; testing
    them costs more than the rows it saves: bench_core.py's dense-1000 fleets, 6 %)."""
    m = len(dets)
    det = dets[0] if m else None
    if m > 1 and all(map(is_, dets, repeat(det))):       # one array for all (checked in C)
        reach = 2.0 * speed * horizon + 1.0
        lo0, hi0, lo1, hi1 = grid.lo[0] - reach, grid.hi[0] + reach, grid.lo[1] - reach, grid.hi[1] + reach
        dx = states[:, 0:1] - det[:, 0]
        dy = states[:, 1:2] - det[:, 1]
        near = ((dx >= lo0[:, None]) & (dx <= hi0[:, None]) & (dy >= lo1[:, None]) & (dy <= hi1[:, None]))
        robot, index = np.nonzero(near)
        rel = np.empty((len(robot), 3))
        rel[:, 0], rel[:, 1], rel[:, 2] = dx[near], dy[near], states[robot, 2]
        return robot, index, rel, det[index]
    robot = np.repeat(np.arange(m), counts)       # arrays of their own: every pair
    index = np.arange(len(robot)) - start[robot]
    if not len(robot):
        return robot, index, np.zeros((0, 3)), np.zeros((0, 2))
    centres = np.concatenate([d for d in dets if len(d)])
    rel = np.empty((len(robot), 3))
    rel[:, 0] = states[robot, 0] - centres[:, 0]
    rel[:, 1] = states[robot, 1] - centres[:, 1]
    rel[:, 2] = states[robot, 2]
    return robot, index, rel, centres


def pair_turns(vf: ValueFunction, rel, value, horizon, speed, bang):
    """The unit avoid turns of pairs at ``rel`` with V ``value``: the
    law's sign(dV/dtheta) where V is finite (on the grid), else 0; with a hold, the bang whose
    hold ends at the larger V (ties left) wherever either end is on the grid. (A pair
    ``pair_reads`` left out as beyond any hold's reach has both ends off the grid: 0.)"""
    turn = np.zeros(len(rel))
    inside = np.isfinite(value)
    if np.any(inside):
        turn[inside] = avoid_turn(vf, rel[inside])
    held = np.flatnonzero(horizon > 0)
    if len(held):
        ends = bang_ends(rel[held], speed[held], bang[held], horizon[held])
        left, right = vf.value(ends, outside=np.inf).reshape(2, len(held))
        use = np.isfinite(left) | np.isfinite(right)
        turn[held] = np.where(use, better_bang(left, right, tie_tolerance(vf)), turn[held])
    return turn


class PairTurns(NamedTuple):
    """What the unit avoid turns of pair rows are read from (``pair_turns_of``): the safe set's ``vf``;
    per pair row its relative state ``rel`` (P, 3), V (``value``) and robot row (``robot``); per robot
    row its lookahead, speed and turn bound. A lone robot's few pairs read in Python floats
    (``pair_values_fast``): ``lone`` its state (x, y, theta) and the pairs' centres [(cx, cy)], ``value``
    a list, ``rel`` and ``robot`` None (its turns are read as its values were: ``pair_turn_fast``)."""

    vf: ValueFunction
    rel: np.ndarray | None
    value: object
    robot: np.ndarray | None
    lookahead: np.ndarray
    speed: np.ndarray
    omega_max: np.ndarray
    lone: tuple | None = None


def pair_turns_of(p: PairTurns, rows) -> np.ndarray:
    """``pair_turns`` of pair rows ``rows`` (a lone robot's: ``pair_turn_fast``, the same bits)."""
    if p.lone is not None:
        x, y, th, centres = p.lone
        horizon, speed, bang = float(p.lookahead[0]), float(p.speed[0]), float(p.omega_max[0])
        return np.array([pair_turn_fast(p.vf, x - centres[j][0], y - centres[j][1], th, p.value[j], horizon, speed,
                                        bang) for j in rows.tolist()], dtype=float)
    r = p.robot[rows]
    return pair_turns(p.vf, p.rel[rows], p.value[rows], p.lookahead[r], p.speed[r], p.omega_max[r])


FEW_PAIRS = 3     # a robot decided alone reads V in Python floats up to this many pairs near the grid


def pair_values_fast(vf: ValueFunction, x, y, th, centres, planned, horizon, speed, bang, few):
    """(V, V next) of ``pair_reads`` (every hold read: level +inf) for one robot's pairs (its state
    x, y, th; ``centres`` a list of (cx, cy); its command, hold, speed and bound), as lists; None if
    more than ``few`` pairs are near the grid (then numpy's evaluation is the cheaper). Their
    turns: ``pair_turn_fast``, read only for the rows the robot avoids by (as ``pair_turns``).

    V is read state by state in Python floats (``ValueFunction.value_at``): a robot's own
    filter has one or two obstacles near, and numpy's cost per call (some 150 calls) is
    most of its decision. The same operations in the same order, so the same values bit
    for bit (test_filter_vectorised: each robot decided alone decides as in a fleet).
    Kept for: 66-68 us against 156 us for ``pair_reads`` of the same three pairs near the grid
    (2.4x; timeit, 2026-12-06, the 2-core development machine, load 1.5); and a turn
    (``pair_turn_fast``) 15 us against 141-155 us for ``pair_turns`` of one pair.
    """
    g = vf.grid
    inf = math.inf
    reach = 2.0 * speed * horizon + 1.0 if horizon > 0 else 0.0
    rel = [(x - cx, y - cy) for cx, cy in centres]
    near = [j for j, (rx, ry) in enumerate(rel) if g.lo[0] - reach <= rx <= g.hi[0] + reach
            and g.lo[1] - reach <= ry <= g.hi[1] + reach]
    if len(near) > few:
        return None
    n = len(rel)
    value, value_next = [inf] * n, [inf] * n
    for j in near:
        rx, ry = rel[j]
        value[j] = vf.value_at(rx, ry, th, outside=inf)
        if horizon > 0:     # (without a hold: V_next = +inf)
            ax, ay, ath = arc(rx, ry, th, speed, planned, horizon)
            end_left = vf.value_at(*arc(ax, ay, ath, speed, bang, horizon), outside=inf)
            end_right = vf.value_at(*arc(ax, ay, ath, speed, -bang, horizon), outside=inf)
            v_ahead = vf.value_at(ax, ay, ath, outside=inf)
            better = end_left if end_left > end_right else end_right       # np.maximum
            value_next[j] = v_ahead if v_ahead < better else better          # np.minimum
    return value, value_next


def pair_turn_fast(vf: ValueFunction, rx, ry, th, value, horizon, speed, bang) -> float:
    """``pair_turns`` of one pair in Python floats (its relative state rx, ry, th, its V ``value``;
    the robot's hold, speed and bound): with a hold, the bang whose hold ends at the larger V (ties
    left) wherever either end is on the grid, else the law's sign(dV/dtheta) where V is finite, else
    0 (the same operations as ``pair_turns``, so the same bits; test_filter_vectorised compares
    them). Kept for: 15 us against 141-155 us for ``pair_turns`` of one pair (``pair_values_fast``'
    figures)."""
    inf = math.inf
    if horizon > 0:
        left = vf.value_at(*arc(rx, ry, th, speed, bang, horizon), outside=inf)
        right = vf.value_at(*arc(rx, ry, th, speed, -bang, horizon), outside=inf)
        if left != inf or right != inf:
            return 1.0 if left >= right - tie_tolerance(vf) else -1.0
    return avoid_turn_at(vf, rx, ry, th) if value != inf else 0.0
