"""Helpers of the ROS-free filter tests (not a test module): one robot's filter beside an obstacle.

``robot`` builds a ``RobotFilter`` with a pose, detections and a planner command at time
``t``; ``at`` places a pose relative to ``OBSTACLE``, which is not at the origin, so the
relative frame is exercised.
"""
import numpy as np

from supersafe_ros.filter import FilterConfig, RobotFilter

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
