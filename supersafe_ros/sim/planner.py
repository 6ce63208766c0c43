"""Nominal goal-seeking planner: steer the heading towards the goal, saturated.

    e = wrap(atan2(gy - y, gx - x) - theta),   u = clip(gain * e, -w_max, w_max)

It knows nothing about obstacles: avoiding them is the safety filter's job (and,
when the robot missed one, the supervisor's).
"""
from __future__ import annotations

import math

import numpy as np

from ..reach.grid import wrap_angle


def goal_seeking_turn_rate(state, goal, gain: float = 2.0, omega_max: float = 1.0) -> float:
    """Turn rate that points a Dubins car at ``goal`` (x, y); 0 when on the goal."""
    x, y, th = (float(v) for v in np.asarray(state, dtype=float).reshape(3))
    gx, gy = (float(v) for v in np.asarray(goal, dtype=float).reshape(2))
    if not all(math.isfinite(v) for v in (x, y, th, gx, gy)):
        raise ValueError('state and goal must be finite')
    if math.hypot(gx - x, gy - y) < 1e-9:
        return 0.0
    error = float(wrap_angle(math.atan2(gy - y, gx - x) - th))
    return float(np.clip(gain * error, -omega_max, omega_max))


def approach_speed(distance: float, speed: float, slow_radius: float, stop_radius: float,
                   least_fraction: float = 0.2) -> float:
    """linear.x of a planner that slows near its goal and stops on it:

        v = 0                                               if distance <= stop_radius
        v = speed * clip(distance / slow_radius, least_fraction, 1)   otherwise

    (slow_radius 0: no slowing). The floor ``least_fraction`` lets the robot reach the stop
    radius in finite time rather than creep towards it."""
    if not all(math.isfinite(v) for v in (distance, speed, slow_radius, stop_radius)):
        raise ValueError('distance, speed and radii must be finite')
    if distance <= stop_radius:
        return 0.0
    if slow_radius <= 0.0:
        return float(speed)
    return float(speed * min(1.0, max(least_fraction, distance / slow_radius)))
