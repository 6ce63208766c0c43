"""Message <-> numpy conversions and the QoS profiles shared by every node.

Conventions (REP 103/105): metres, radians, planar poses in frame ``map``;
a planar heading theta is the yaw of a quaternion about +z:
    q = (x=0, y=0, z=sin(theta/2), w=cos(theta/2)),  theta = atan2(2(wz + xy), 1 - 2(y^2 + z^2)).
Conversions that read messages validate them and raise ``MessageError`` with the
reason, so a node can log it and keep running.
"""
from __future__ import annotations

import math

import numpy as np
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

from geometry_msgs.msg import Pose, PoseArray, PoseStamped, Quaternion, Twist

MAP_FRAME = 'map'
OBSTACLE_FRAME_PREFIX = 'obstacle_'

# Streams (pose, detections, cmd_vel, cmd_vel_nav, /obstacles): only the newest sample
# matters and a late one is useless, but the loopback link does not drop, so reliable
# keeps tests deterministic. Depth 1 would drop bursts under load; 5 absorbs them.
QOS_STREAM = QoSProfile(depth=5, history=HistoryPolicy.KEEP_LAST,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
# A reader that takes only the newest sample now and then (a filter's tick): one take, nothing
# queued behind it.
QOS_NEWEST = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
# Consumers that must see every sample of a stream (the world counting crashes, the
# supervisor judging every pose) keep a deep queue so a busy moment loses nothing.
QOS_EVERY_SAMPLE = QoSProfile(depth=200, history=HistoryPolicy.KEEP_LAST,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)
# Events that must not be lost (/interventions, /world/intervention_log, decisions).
# A reliable writer drops its oldest unacknowledged sample when its history is full:
# the depth covers a burst of 10,000 sent faster than a busy reader acknowledges.
QOS_EVENTS = QoSProfile(depth=10000, history=HistoryPolicy.KEEP_LAST,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
# Readers that must keep every event even when they fall behind (the learner's
# /interventions): reliable, a queue of 100,000, so a burst is never overwritten
# unread (compatible with QOS_EVENTS writers; history depth is not part of the match).
QOS_EVERY_EVENT = QoSProfile(depth=100000, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
# Logs of records (interventions, trips, crashes): like events, and a late joiner
# (a monitor started with the team) still gets the last 1000 records.
QOS_LOG = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Latched state a late joiner needs at once (obstacle markers, stats, value function).
QOS_LATCHED = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
# /clock: the rosgraph default is best effort depth 1 in some tools; we use reliable
# so a lockstepped clock never loses a tick the robots wait for.
QOS_CLOCK = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)


# Lockstep acknowledgements (step_done): only the newest matters, and a clock that
# matches late must still see it (an observer's 'ready' is sent once).
QOS_ACK = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


class MessageError(ValueError):
    """A message that cannot be used, with the reason why."""


def yaw_to_quaternion(theta: float) -> Quaternion:
    """Quaternion for a rotation of ``theta`` about +z."""
    if not math.isfinite(theta):
        raise MessageError(f'yaw must be finite, got {theta}')
    return Quaternion(x=0.0, y=0.0, z=math.sin(theta / 2.0), w=math.cos(theta / 2.0))


def quaternion_to_yaw(q: Quaternion) -> float:
    """Yaw (rotation about +z) of a quaternion; rejects non-finite or zero quaternions.

    Non-unit quaternions are normalised; the roll/pitch part is ignored (planar robot).
    """
    return yaw_of(q.x, q.y, q.z, q.w)


def yaw_of(x: float, y: float, z: float, w: float) -> float:
    """``quaternion_to_yaw`` of the quaternion (x, y, z, w)."""
    isfinite = math.isfinite      # (four calls and no generator: a fleet reads thousands a second)
    if not (isfinite(x) and isfinite(y) and isfinite(z) and isfinite(w)):
        raise MessageError(f'orientation has non-finite components {(x, y, z, w)}')
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if norm < 1e-9:
        raise MessageError('orientation quaternion has zero norm')
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def pose_to_state(msg: PoseStamped, frame: str | None = MAP_FRAME) -> tuple:
    """(x, y, theta) of a PoseStamped; raises MessageError for NaN/inf or a wrong frame.

    ``frame=None`` skips the frame check (e.g. intervention poses in obstacle frames).
    """
    return header_pose_to_state(msg.header, msg.pose, frame)


def header_pose_to_state(header, pose, frame: str | None = MAP_FRAME) -> tuple:
    """(x, y, theta) of ``pose`` (geometry_msgs/Pose) stamped with ``header`` (nav_msgs/Odometry:
    ``msg.header``, ``msg.pose.pose``; PoseWithCovarianceStamped the same); MessageError for a
    frame other than ``frame`` (None: not checked) or non-finite values."""
    p, q = pose.position, pose.orientation
    return planar_state(header.frame_id, p.x, p.y, q.x, q.y, q.z, q.w, frame)


def planar_state(frame_id: str, x: float, y: float, qx: float, qy: float, qz: float, qw: float,
                 frame: str | None = MAP_FRAME) -> tuple:
    """(x, y, theta) of a pose at (x, y) oriented (qx, qy, qz, qw) in ``frame_id``: the checks of
    ``header_pose_to_state`` (every pose reader's), on the numbers (``cdr.stamped_pose`` reads them
    from a message's bytes without a message object)."""
    if frame is not None and frame_id != frame:
        raise MessageError(f"pose frame is '{frame_id}', expected '{frame}'")
    if not (math.isfinite(x) and math.isfinite(y)):
        raise MessageError(f'pose position is not finite ({x}, {y})')
    return (float(x), float(y), yaw_of(qx, qy, qz, qw))


def state_to_pose(state, stamp=None, frame: str = MAP_FRAME) -> PoseStamped:
    """PoseStamped (z = 0) for a planar state (x, y, theta); ``stamp`` is a builtin Time."""
    x, y, theta = (float(v) for v in state)
    if not (math.isfinite(x) and math.isfinite(y)):
        raise MessageError(f'state is not finite ({x}, {y}, {theta})')
    msg = PoseStamped()
    msg.header.frame_id = frame
    if stamp is not None:
        msg.header.stamp = stamp
    msg.pose.position.x = x
    msg.pose.position.y = y
    msg.pose.orientation = yaw_to_quaternion(theta)
    return msg


def posearray_to_xy(msg: PoseArray, frame: str | None = MAP_FRAME) -> np.ndarray:
    """(N, 2) positions of a PoseArray; raises MessageError for non-finite values or a wrong frame."""
    return checked_xy(msg.header, np.array([(p.position.x, p.position.y) for p in msg.poses],
                                           dtype=float).reshape(-1, 2), frame)


def checked_xy(header, xy, frame: str | None = MAP_FRAME) -> np.ndarray:
    """``xy`` (N, 2) of a pose array with ``header`` (a serialized one: ``cdr.pose_array_xy``),
    checked as ``posearray_to_xy`` checks a message."""
    if frame is not None and header.frame_id != frame:
        raise MessageError(f"pose array frame is '{header.frame_id}', expected '{frame}'")
    if not np.all(np.isfinite(xy)):
        raise MessageError('pose array contains non-finite positions')
    return xy


def xy_to_posearray(xy, stamp=None, frame: str = MAP_FRAME) -> PoseArray:
    """PoseArray with identity orientation at each (x, y) row."""
    pts = np.asarray(xy, dtype=float).reshape(-1, 2)
    if not np.all(np.isfinite(pts)):
        raise MessageError('positions are not finite')
    msg = PoseArray()
    msg.header.frame_id = frame
    if stamp is not None:
        msg.header.stamp = stamp
    for x, y in pts:
        pose = Pose()
        pose.position.x = float(x)
        pose.position.y = float(y)
        pose.orientation.w = 1.0
        msg.poses.append(pose)
    return msg


def twist_turn_rate(msg: Twist) -> float:
    """angular.z of a Twist; raises MessageError if it is not finite."""
    w = msg.angular.z
    if not math.isfinite(w):
        raise MessageError(f'angular.z is not finite ({w})')
    return float(w)


def turn_rate_to_twist(omega: float, speed: float = 0.0) -> Twist:
    """Twist with angular.z = omega (and linear.x = speed, informative only)."""
    msg = Twist()
    msg.linear.x = float(speed)
    msg.angular.z = float(omega)
    return msg


def obstacle_frame(obstacle_id: int) -> str:
    """Frame name of an obstacle (used in /interventions headers)."""
    return f'{OBSTACLE_FRAME_PREFIX}{int(obstacle_id)}'


def parse_obstacle_frame(frame: str) -> int:
    """Obstacle id from 'obstacle_<id>'; raises MessageError otherwise."""
    if not frame.startswith(OBSTACLE_FRAME_PREFIX):
        raise MessageError(f"frame '{frame}' does not name an obstacle (obstacle_<id>)")
    tail = frame[len(OBSTACLE_FRAME_PREFIX):]
    if not tail.isdigit():
        raise MessageError(f"frame '{frame}' does not name an obstacle (obstacle_<id>)")
    return int(tail)


def diagnostic_values(msg) -> dict:
    """Key/value pairs of a diagnostic_msgs/DiagnosticStatus as a dict of strings."""
    return {kv.key: kv.value for kv in msg.values}


def make_diagnostic(name: str, values: dict, message: str = '', level: int = 0):
    """diagnostic_msgs/DiagnosticStatus with every value stringified."""
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    status = DiagnosticStatus()
    status.level = bytes([int(level)])
    status.name = name
    status.message = message
    status.values = [KeyValue(key=str(k), value=str(v)) for k, v in values.items()]
    return status
