"""A robot stack's messages read as the filter's arrays: obstacles from markers, the pose from
odometry and AMCL's pose (scans, clouds and costmaps go into a local map: ``filter.range_readings``
checks them, ``nodes.filter_inputs.SensorMap`` takes them).

* ``marker_discs(msg, frame)``: a visualization_msgs/MarkerArray as (N, 3) discs [x, y, r]. A
  message is the full current set of obstacles (as a PoseArray of detections is). CYLINDER and
  SPHERE markers are discs of radius max(scale.x, scale.y) / 2 about their position; a CUBE is
  covered by the disc of its half diagonal, hypot(scale.x, scale.y) / 2; DELETE and DELETEALL
  markers and the other types (arrows, lines, text, meshes...) add no obstacle and are counted
  (``ignored``). Every marker that adds an obstacle must be in ``frame`` with a finite position
  and positive scale, else the whole message is refused (MessageError).
* ``header_pose_to_state(header, pose, frame)``: (x, y, theta) of a pose with a header
  (nav_msgs/Odometry: ``msg.header``, ``msg.pose.pose``; PoseWithCovarianceStamped the same).
"""
from __future__ import annotations

import math

import numpy as np

from .rosmsg import MessageError, quaternion_to_yaw

# visualization_msgs/Marker constants (the message's, repeated to keep this module light)
CUBE, SPHERE, CYLINDER = 1, 2, 3
ADD, DELETE, DELETEALL = 0, 2, 3


def marker_discs(msg, frame: str):
    """((N, 3) discs [x, y, r], how many markers added no obstacle) of a MarkerArray (see the
    module); MessageError if a marker that adds an obstacle is not usable."""
    rows, ignored = [], 0
    for m in msg.markers:
        if m.action != ADD or m.type not in (CUBE, SPHERE, CYLINDER):
            ignored += 1
            continue
        if m.header.frame_id != frame:
            raise MessageError(f"marker {m.ns}/{m.id} frame is '{m.header.frame_id}', expected '{frame}'")
        x, y, sx, sy = m.pose.position.x, m.pose.position.y, m.scale.x, m.scale.y
        if not all(math.isfinite(v) for v in (x, y, sx, sy)):
            raise MessageError(f'marker {m.ns}/{m.id} has a non-finite position or scale')
        if sx <= 0.0 or sy <= 0.0:
            raise MessageError(f'marker {m.ns}/{m.id} has scale ({sx}, {sy}): must be > 0')
        r = math.hypot(sx, sy) / 2.0 if m.type == CUBE else max(sx, sy) / 2.0
        rows.append((x, y, r))
    return np.array(rows, dtype=float).reshape(-1, 3), ignored


def header_pose_to_state(header, pose, frame: str) -> tuple:
    """(x, y, theta) of ``pose`` (geometry_msgs/Pose) stamped with ``header``; MessageError for a
    frame other than ``frame`` or non-finite values."""
    if header.frame_id != frame:
        raise MessageError(f"pose frame is '{header.frame_id}', expected '{frame}'")
    p = pose.position
    if not (math.isfinite(p.x) and math.isfinite(p.y)):
        raise MessageError(f'pose position is not finite ({p.x}, {p.y})')
    return (float(p.x), float(p.y), quaternion_to_yaw(pose.orientation))
