"""A robot stack's messages read as the filter's arrays: obstacles from markers, laser scans and
point clouds, the pose from odometry and AMCL's pose, stamped commands.

* ``marker_discs(msg, frame)``: a visualization_msgs/MarkerArray as (N, 3) discs [x, y, r]. A
  message is the full current set of obstacles (as a PoseArray of detections is). CYLINDER and
  SPHERE markers are discs of radius max(scale.x, scale.y) / 2 about their position; a CUBE is
  covered by the disc of its half diagonal, hypot(scale.x, scale.y) / 2; DELETE and DELETEALL
  markers and the other types (arrows, lines, text, meshes...) add no obstacle and are counted
  (``ignored``). Every marker that adds an obstacle must be in ``frame`` with a finite position
  and positive scale, else the whole message is refused (MessageError).
* ``scan_returns(msg)``: a sensor_msgs/LaserScan's returns (M, 2) in its own frame
  (``filter.sensing.scan_points``).
* ``cloud_returns(msg, max_points)``: a sensor_msgs/PointCloud2's x, y (M, 2) in its own frame
  (``filter.sensing.cloud_xy``: FLOAT32 or FLOAT64 fields, any point_step, either byte order,
  malformed sizes refused).
* ``header_pose_to_state(header, pose, frame)``: (x, y, theta) of a pose with a header
  (nav_msgs/Odometry: ``msg.header``, ``msg.pose.pose``; PoseWithCovarianceStamped the same).
"""
from __future__ import annotations

import math

import numpy as np

from ..filter import sensing
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


def scan_returns(msg) -> np.ndarray:
    """(M, 2) returns of a LaserScan in its frame; MessageError if its geometry is not finite."""
    try:
        return sensing.scan_points(msg.ranges, msg.angle_min, msg.angle_increment, msg.range_min,
                                   msg.range_max)
    except ValueError as exc:
        raise MessageError(str(exc)) from None


def cloud_returns(msg, max_points: int) -> np.ndarray:
    """(M, 2) finite x, y of a PointCloud2 in its frame; MessageError with the reason if its
    layout is malformed or it has more than ``max_points`` points."""
    fields = {f.name: (int(f.offset), int(f.datatype), int(f.count)) for f in msg.fields}
    try:
        return sensing.cloud_xy(msg.data, fields, msg.point_step, msg.row_step, msg.width, msg.height,
                                msg.is_bigendian, max_points)
    except (ValueError, TypeError) as exc:
        raise MessageError(f'point cloud refused: {exc}') from None


def header_pose_to_state(header, pose, frame: str) -> tuple:
    """(x, y, theta) of ``pose`` (geometry_msgs/Pose) stamped with ``header``; MessageError for a
    frame other than ``frame`` or non-finite values."""
    if header.frame_id != frame:
        raise MessageError(f"pose frame is '{header.frame_id}', expected '{frame}'")
    p = pose.position
    if not (math.isfinite(p.x) and math.isfinite(p.y)):
        raise MessageError(f'pose position is not finite ({p.x}, {p.y})')
    return (float(p.x), float(p.y), quaternion_to_yaw(pose.orientation))
