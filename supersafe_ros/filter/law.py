"""The minimally invasive filter law, as a pure function over many robots.

For robot states expressed relative to each detected obstacle (obstacle at the
origin, axes as the map), with avoid value V:

    override  = V(x) <= alpha
    u*        = omega_max * sign(dV/dtheta)       (the control that raises V fastest)

A robot with several obstacles is governed by the smallest V (see
``most_constraining``). Pairs outside the value function's grid are far from the
obstacle and never constrain (V = +inf there).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..reach.value_function import ValueFunction


@dataclass
class FilterDecision:
    override: np.ndarray   # bool[N]: apply u* instead of the planner's command
    control: np.ndarray    # float[N]: u* (turn rate), meaningful where override
    value: np.ndarray      # float[N]: V at each state (+inf outside the grid)


def evaluate_pairs(vf: ValueFunction, rel_states):
    """V and the unit avoid control sign(dV/dtheta) at every relative state (N, 3).

    Pairs outside the grid: V = +inf (never constraining), turn 0. On a ridge of V
    (dV/dtheta = 0, e.g. heading straight at the obstacle) the turn is left (+1)
    rather than straight into it. "Zero" is judged relative to the gradient's
    scale (``tie_tolerance``): on a grid symmetric about the obstacle's axis the
    interpolated dV/dtheta at a head-on state is float32 round-off (-1.4e-8 at
    (-3, 0, 0) on 41 x 41 x 24), whose sign means nothing. Only the theta
    component of the gradient is interpolated. Callers that hold a robot in an
    override band (filter.core) need the turn where V > alpha too, so it is
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
    Cached on the value function.
    """
    tol = getattr(vf, '_tie_tolerance', None)
    if tol is None:
        tol = TIE_RELATIVE * float(np.max(np.abs(vf.node_gradient()[..., 2])))
        vf._tie_tolerance = tol
    return tol


def filter_law(vf: ValueFunction, alpha: float, rel_states, omega_max: float) -> FilterDecision:
    """Decide, for N relative states (N, 3), whether to override and with which turn rate."""
    s = np.asarray(rel_states, dtype=float).reshape(-1, 3)
    if not np.isfinite(alpha):
        raise ValueError(f'alpha must be finite, got {alpha}')
    if not np.all(np.isfinite(s)):
        raise ValueError('relative states contain NaN or infinite values')
    value, turn = evaluate_pairs(vf, s)
    override = value <= alpha
    return FilterDecision(override, np.where(override, omega_max * turn, 0.0), value)


def most_constraining(robot_index, decision: FilterDecision, n_robots: int):
    """Reduce pair decisions to one per robot: the pair with the smallest V wins.

    Returns (override bool[n], control float[n], value float[n], pair index int[n] or -1).
    """
    robot_index = np.asarray(robot_index, dtype=int)
    value = np.full(n_robots, np.inf)
    pair = np.full(n_robots, -1)
    order = np.argsort(decision.value, kind='stable')[::-1]  # largest first, smallest written last
    value[robot_index[order]] = decision.value[order]
    pair[robot_index[order]] = order
    has = pair >= 0
    override = np.zeros(n_robots, dtype=bool)
    control = np.zeros(n_robots)
    override[has] = decision.override[pair[has]]
    control[has] = decision.control[pair[has]]
    return override, control, value, pair
