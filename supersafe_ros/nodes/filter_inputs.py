"""What safety_filter_node takes from a robot's stack: which message types, read how.

``INPUT_PARAMETERS`` (the node's, read-only): ``pose_type``, ``detections_type``,
``cmd_vel_stamped``, and for a range sensor its mount and how its returns become discs.

* pose (topic ``pose``): ``pose_stamped`` (geometry_msgs/PoseStamped, read raw from its CDR
  bytes), ``odometry`` (nav_msgs/Odometry: ``pose.pose`` in its header's frame) or
  ``pose_with_covariance`` (geometry_msgs/PoseWithCovarianceStamped, as AMCL publishes). The
  frame must be the filter's ``frame_id`` (for odometry: an odom frame that the filter's
  ``frame_id`` names; the filter does not transform poses).
* detections (topic ``detections``): ``pose_array`` (centres in ``frame_id``, each of the
  node's ``radius``), ``marker_array`` (discs of their own radii, ``ros_io.sensors``),
  ``laser_scan`` or ``point_cloud2`` (returns in the sensor's frame, made covering discs by
  ``SensorDiscs``). Scans and clouds are subscribed with the sensor-data QoS (best effort),
  which matches best-effort and reliable drivers alike.
* commands (topics ``cmd_vel_nav`` in, ``cmd_vel`` out): geometry_msgs/Twist, or with
  ``cmd_vel_stamped`` geometry_msgs/TwistStamped both ways.

``SensorDiscs``: the robot's poses received (``PoseHistory``, stamps on the filter's time
base) and a scan or cloud -> discs (x, y, r) in map (``filter.sensing``: the pose nearest the
message's stamp, its distance in time covered by a slack; returns inflated by
``robot_radius``; groups of close returns covered by one disc).
"""
from __future__ import annotations

from collections import deque
from importlib import import_module

import numpy as np

from ..filter import sensing
from ..ros_io import sensors
from ..ros_io.rosmsg import MessageError
from .common import ParameterSpec

POSE_TYPES = ('pose_stamped', 'odometry', 'pose_with_covariance')   # (their messages: MESSAGE_TYPES)
DETECTIONS_TYPES = ('pose_array', 'marker_array', 'laser_scan', 'point_cloud2')
RANGE_SENSORS = ('laser_scan', 'point_cloud2')
POSES_KEPT = 64        # poses remembered to place a scan (at 50 Hz: 1.3 s, more than pose_timeout)

INPUT_PARAMETERS = (
    ParameterSpec('pose_type', 'pose_stamped', f'message on pose: one of {POSE_TYPES}'),
    ParameterSpec('detections_type', 'pose_array', f'message on detections: one of {DETECTIONS_TYPES} '
                  '(pose_array: centres of radius; marker_array: CYLINDER discs of their own radius; '
                  'laser_scan / point_cloud2: returns in the sensor\'s frame, each a point obstacle)'),
    ParameterSpec('cmd_vel_stamped', False, 'cmd_vel_nav and cmd_vel are geometry_msgs/TwistStamped (false: '
                  'Twist)'),
    ParameterSpec('robot_radius', 0.3, 'laser_scan / point_cloud2: each return is inflated by this (the '
                  'robot\'s own radius) [m]', 0.0, 100.0),
    ParameterSpec('sensor_x', 0.0, 'laser_scan / point_cloud2: the sensor\'s x in the robot\'s frame [m]',
                  -100.0, 100.0),
    ParameterSpec('sensor_y', 0.0, 'laser_scan / point_cloud2: the sensor\'s y in the robot\'s frame [m]',
                  -100.0, 100.0),
    ParameterSpec('sensor_yaw', 0.0, 'laser_scan / point_cloud2: the sensor\'s yaw in the robot\'s frame '
                  '[rad]', -7.0, 7.0),
    ParameterSpec('obstacle_depth', 0.0, 'laser_scan / point_cloud2: each return stands for this much of its '
                  'beam behind it too (the far side the sensor cannot see: at least the diameter of the '
                  'objects about; 0 = the surface alone) [m]', 0.0, 100.0),
    ParameterSpec('sensor_cell', 0.5, 'laser_scan / point_cloud2: returns in touching cells of this size '
                  'are one group, covered by one disc [m]', 0.01, 100.0),
    ParameterSpec('sensor_max_disc_radius', 2.5, 'laser_scan / point_cloud2: a group whose disc would be '
                  'wider is covered in pieces of at most this radius (walls, large objects) [m]', 0.01, 1000.0),
    ParameterSpec('max_sensor_points', 1_000_000, 'laser_scan / point_cloud2: a message with more beams or '
                  'points is refused unread (failing safe) [points]', 1, 100_000_000),
)


# each input type's message class, as 'package/Name' (imported when used)
MESSAGE_TYPES = {
    'pose_stamped': 'geometry_msgs/PoseStamped', 'odometry': 'nav_msgs/Odometry',
    'pose_with_covariance': 'geometry_msgs/PoseWithCovarianceStamped',
    'pose_array': 'geometry_msgs/PoseArray', 'marker_array': 'visualization_msgs/MarkerArray',
    'laser_scan': 'sensor_msgs/LaserScan', 'point_cloud2': 'sensor_msgs/PointCloud2',
}


def message_type(kind: str):
    """The message class of a ``pose_type`` or ``detections_type`` value."""
    package, name = MESSAGE_TYPES[kind].split('/')
    return getattr(import_module(f'{package}.msg'), name)


def command_message_type(stamped: bool):
    from geometry_msgs.msg import Twist, TwistStamped
    return TwistStamped if stamped else Twist


def check_types(p: dict) -> None:
    """ValueError if a type parameter names no type this node reads."""
    if p['pose_type'] not in POSE_TYPES:
        raise ValueError(f"pose_type {p['pose_type']!r} is not one of {POSE_TYPES}")
    if p['detections_type'] not in DETECTIONS_TYPES:
        raise ValueError(f"detections_type {p['detections_type']!r} is not one of {DETECTIONS_TYPES}")


def pose_of(msg, frame: str) -> tuple:
    """(x, y, theta) of an Odometry or PoseWithCovarianceStamped (both: header, pose.pose)."""
    return sensors.header_pose_to_state(msg.header, msg.pose.pose, frame)


class PoseHistory:
    """The last POSES_KEPT poses received: (stamp on the filter's time base, (x, y, theta))."""

    def __init__(self, kept: int = POSES_KEPT):
        self.stamps = deque(maxlen=kept)
        self.states = deque(maxlen=kept)

    def add(self, stamp: float, state) -> None:
        self.stamps.append(float(stamp))
        self.states.append(tuple(state))

    def nearest(self, stamp: float):
        return sensing.nearest_pose(np.fromiter(self.stamps, float, len(self.stamps)), self.states, stamp)


class SensorDiscs:
    """Scans and clouds -> covering discs in map (see the module)."""

    def __init__(self, p: dict, history: PoseHistory):
        self.kind = p['detections_type']
        self.history = history
        self.mount = (p['sensor_x'], p['sensor_y'], p['sensor_yaw'])
        self.robot_radius = p['robot_radius']
        self.cell = p['sensor_cell']
        self.max_disc_radius = p['sensor_max_disc_radius']
        self.max_points = p['max_sensor_points']
        self.depth = p['obstacle_depth']

    def returns(self, msg) -> np.ndarray:
        """(M, 2) returns of a scan or cloud in its frame; MessageError if refused."""
        if self.kind == 'laser_scan':
            if len(msg.ranges) > self.max_points:
                raise MessageError(f'scan of {len(msg.ranges)} beams exceeds max_sensor_points={self.max_points}')
            return sensors.scan_returns(msg)
        return sensors.cloud_returns(msg, self.max_points)

    def discs(self, msg, stamp: float, config, max_pose_gap: float) -> np.ndarray:
        """(K, 3) discs [x, y, r] in map of a scan or cloud describing ``stamp`` (the filter's
        time base); MessageError if refused or if no pose is within ``max_pose_gap`` of it."""
        points = self.returns(msg)
        pose, gap = self.history.nearest(stamp)
        if pose is None:
            raise MessageError('no pose received yet to place the returns with')
        if gap > max_pose_gap:
            raise MessageError(f'no pose within {max_pose_gap:g} s of the scan\'s stamp (nearest {gap:.3g} s '
                               'away)')
        return sensing.range_discs(points, pose, gap, self.mount, self.robot_radius, self.depth, self.cell,
                                   self.max_disc_radius, config.speed, config.omega_max)
