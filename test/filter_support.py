"""Helpers of the ROS-free filter tests (not a test module): one robot's filter beside an obstacle.

``robot`` builds a ``RobotFilter`` with a pose, detections and a planner command at time
``t``; ``at`` places a pose relative to ``OBSTACLE``, which is not at the origin, so the
relative frame is exercised. ``pair_values``: every pair's V, avoid turn and V next in one
call (``filter.constraints.pairs``' two reads together), what the pair tests compare against.
"""
import numpy as np

from supersafe_ros.filter import FilterConfig, RobotFilter
from supersafe_ros.filter.constraints.pairs import pair_reads, pair_turns
from supersafe_ros.reach.value_function import ValueFunction

OBSTACLE = (10.0, 5.0)   # obstacle centre in map (not at the origin: exercises the relative frame)


def robot(t=0.0, pose=(0.0, 0.0, 0.0), detections=(OBSTACLE,), cmd=0.3, **cfg):
    f = RobotFilter(FilterConfig(**cfg))
    f.update_pose(pose, t)
    f.update_detections(np.asarray(detections, dtype=float).reshape(-1, 2), t)
    if cmd is not None:
        f.update_command(cmd, t)
    return f


def at(rel_x, rel_y, theta):
    return (OBSTACLE[0] + rel_x, OBSTACLE[1] + rel_y, theta)


class Log:
    """A node's logger that keeps its lines: (level, text)."""

    def __init__(self):
        self.lines = []

    def debug(self, text):
        self.lines.append(('debug', text))

    def info(self, text):
        self.lines.append(('info', text))

    def error(self, text):
        self.lines.append(('error', text))

    def said(self, level, part):
        return any(lv == level and part in text for lv, text in self.lines)


def pair_values(vf: ValueFunction, rel, omega, horizon, speed, bang):
    """V, the avoid turn and the lookahead value of every pair, for commands held over H.

    First the law at the pair's relative state (``law.evaluate_pairs``): V (+inf off the
    grid) and the unit turn sign(dV/dtheta) (ties left; 0 off the grid).

    Per pair: the planner's (clipped) command ``omega``, the hold H (``horizon``, the
    robot's lookahead, >= its control period), the robot's speed and turn bound
    ``bang``; how a hold is judged: ``pairs.pair_reads``.

    A silent planner counts as a zero command (what the filter would forward).
    Translation invariance: the relative state moves like the robot itself.
    ``pair_reads`` reads V and V next of every pair in one call, ``pair_turns`` the turns
    (the fleet path reads turns only for the rows its robots name).
    Returns (V, unit turn, V after the planner's hold and the best bang's).
    """
    value, value_next = pair_reads(vf, rel, omega, horizon, speed, bang)
    return value, pair_turns(vf, rel, value, horizon, speed, bang), value_next
