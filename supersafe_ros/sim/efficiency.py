"""What the paper's H2 is about: how much path the safe set costs, per robot, without ROS.

Fed one pose at a time (with its sim time, the robot's goal and the obstacles), and the
safety filter's action in force over the segment that ends at that pose:

* ``path_length``: every segment between consecutive poses;
* ``trip_path``: the segments of *completed* trips (``trip_completed`` closes one), so
  ``trip_path / trips`` is the path per completed trip;
* ``override_time`` / ``robot_time``: sim seconds of segments driven while the filter was
  overriding / all segments: the fraction of robot time overriding;
* avoidance arcs: a run of overriding segments is one arc. Its extra length over the
  nominal path is what the robot drove during the arc minus the progress it made towards
  its goal (the planner's nominal path is the straight line to the goal point):
  ``extra = arc length - (|start - goal| - |end - goal|)`` >= 0 by the triangle inequality.
  An arc ends at the first non-overriding segment, at a completed trip (the goal
  changes), or at a reset;
* ``min_clearance``: the least (distance to the nearest obstacle centre - radius) over
  the poses; negative inside a disc.

A segment longer than ``jump`` metres (a teleport) or not forward in time is not driven:
it only moves the robot and closes an open arc.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

OVERRIDE = 'override'


@dataclass
class EfficiencyMeter:
    jump: float = 5.0
    path_length: float = 0.0
    trip_path: float = 0.0
    current_trip: float = 0.0
    override_time: float = 0.0
    robot_time: float = 0.0
    arcs: int = 0
    avoidance_extra: float = 0.0
    min_clearance: float = math.inf
    _last: tuple | None = None           # (x, y, t)
    _arc: list | None = None             # [start_xy, goal_xy, length]
    _arc_end: object = None              # xy of the arc's last overriding pose

    def pose(self, state, time: float, goal, overriding: bool, obstacles_xy=None,
             radius: float = 0.0) -> None:
        """Account the segment from the previous pose to ``state`` (x, y, theta) at ``time``.

        ``overriding``: the filter's action over this segment was an override.
        ``goal``: the robot's goal point (x, y) over this segment, or None.
        """
        x, y = float(state[0]), float(state[1])
        t = float(time)
        xy = np.array([x, y])
        if obstacles_xy is not None and len(obstacles_xy):
            d = np.hypot(*(np.asarray(obstacles_xy, dtype=float).reshape(-1, 2) - xy).T)
            self.min_clearance = min(self.min_clearance, float((d - radius).min()))   # (radius: one, or each's)
        if self._last is None:
            self._last = (x, y, t)
            return
        lx, ly, lt = self._last
        self._last = (x, y, t)
        seg = math.hypot(x - lx, y - ly)
        dt = t - lt
        if seg > self.jump or dt <= 0:
            self.close_arc(None)
            return
        self.path_length += seg
        self.current_trip += seg
        self.robot_time += dt
        if overriding:
            self.override_time += dt
            if self._arc is None and goal is not None:
                self._arc = [np.array([lx, ly]), np.asarray(goal, dtype=float).reshape(2), 0.0]
            if self._arc is not None:
                self._arc[2] += seg
            self._arc_end = xy
        else:
            self.close_arc(np.array([lx, ly]))

    def close_arc(self, end_xy) -> None:
        """End the open arc at ``end_xy`` (None: at the last overriding pose)."""
        if self._arc is None:
            return
        start, goal, length = self._arc
        end = end_xy if end_xy is not None else self._arc_end
        progress = float(np.hypot(*(start - goal)) - np.hypot(*(end - goal)))
        self.avoidance_extra += max(0.0, length - progress)
        self.arcs += 1
        self._arc = None

    def trip_completed(self) -> None:
        """The last pose crossed the goal line: the trip's path is complete."""
        if self._last is not None:
            self.close_arc(np.array(self._last[:2]))
        self.trip_path += self.current_trip
        self.current_trip = 0.0

    def values(self) -> dict:
        """The counters so far; an open arc counts as ended at the last pose."""
        extra, arcs = self.avoidance_extra, self.arcs
        if self._arc is not None:
            start, goal, length = self._arc
            end = self._arc_end
            extra += max(0.0, length - float(np.hypot(*(start - goal)) - np.hypot(*(end - goal))))
            arcs += 1
        return {'path_length': self.path_length, 'trip_path': self.trip_path,
                'override_time': self.override_time, 'robot_time': self.robot_time,
                'avoidance_arcs': arcs, 'avoidance_extra': extra,
                'min_clearance': self.min_clearance}


def team_efficiency(meters, trips: int) -> dict:
    """Team-level H2 measures of one game from the robots' meters and completed trips.

    path_per_trip [m], avoidance_length (mean extra length per avoidance arc [m]),
    avoidance_total [m], avoidance_arcs, override_fraction, min_clearance [m] (NaN when
    unknown: no trip, no arc, no time, no obstacle seen).
    """
    vals = [m.values() for m in meters]
    s = {k: sum(v[k] for v in vals) for k in ('path_length', 'trip_path', 'override_time',
                                              'robot_time', 'avoidance_arcs', 'avoidance_extra')}
    clearance = min((v['min_clearance'] for v in vals), default=math.inf)
    nan = float('nan')
    return {
        'path_per_trip': s['trip_path'] / trips if trips else nan,
        'avoidance_length': s['avoidance_extra'] / s['avoidance_arcs'] if s['avoidance_arcs'] else nan,
        'avoidance_total': s['avoidance_extra'],
        'avoidance_arcs': s['avoidance_arcs'],
        'override_fraction': s['override_time'] / s['robot_time'] if s['robot_time'] else nan,
        'min_clearance': clearance if math.isfinite(clearance) else nan,
        'path_length': s['path_length'],
    }
