"""What a filter node takes from a robot's stack (safety_filter_node; fleet_safety_filter_node per
robot): which message types, read how (``filter_sources``).

``INPUT_PARAMETERS`` (safety_filter_node's, read-only): ``TYPE_PARAMETERS`` (``pose_type``,
``detections_type``, ``cmd_vel_stamped``, ``require_detections``; the fleet node's too) and
``MAP_PARAMETERS``: for a range sensor or a costmap its mount, its local map and the map's
value.

* pose (topic ``pose``): ``pose_stamped`` (geometry_msgs/PoseStamped, read raw from its CDR
  bytes), ``odometry`` (nav_msgs/Odometry: ``pose.pose`` in its header's frame) or
  ``pose_with_covariance`` (geometry_msgs/PoseWithCovarianceStamped, as AMCL publishes). The
  frame must be the filter's ``frame_id`` (for odometry: an odom frame that the filter's
  ``frame_id`` names; the filter does not transform poses).
* detections (topic ``detections``): ``pose_array`` (centres in ``frame_id``, each of the
  node's ``radius``), ``marker_array`` (discs of their own radii, ``ros_io.sensors``),
  ``laser_scan``, ``point_cloud2`` (returns in the sensor's frame) or ``occupancy_grid``
  (nav_msgs/OccupancyGrid in ``frame_id``, e.g. Nav2's local costmap): these three keep a local
  map of what was seen (``SensorMap``). Scans and clouds are subscribed with the sensor-data
  QoS (best effort), which matches best-effort and reliable drivers alike; grids reliable and
  volatile, which matches a costmap's transient-local publisher.
* commands (topics ``cmd_vel_nav`` in, ``cmd_vel`` out): geometry_msgs/Twist, or with
  ``cmd_vel_stamped`` geometry_msgs/TwistStamped both ways.

``SensorMap``: the robot's poses received (``PoseHistory``, stamps on the filter's time base),
its local map (``filter.local_map``: a valid return marks, a valid beam clears what it passes
through, REP 117's NaN, below-minimum and missing returns clear nothing) and the map's avoid
value, re-solved in the background as the map changes (``filter.map_value``); each message is
checked first (``filter.range_readings``: a scan or cloud of invalid geometry is refused with the
fault named, and the map stays as it was).
"""
from __future__ import annotations

from collections import deque
from importlib import import_module
import math

import numpy as np
from rclpy.qos import qos_profile_sensor_data

from ..filter.local_map import LocalMap, MapSettings
from ..filter.map_rows import MapView
from ..filter.map_value import MapValueSettings, MapValueWorker
from ..filter.range_readings import cloud_xy, interpolated_pose, scan_rays
from ..ros_io.rosmsg import QOS_STREAM, MessageError
from .common import ParameterSpec

POSE_TYPES = ('pose_stamped', 'odometry', 'pose_with_covariance')   # (their messages: MESSAGE_TYPES)
DETECTIONS_TYPES = ('pose_array', 'marker_array', 'laser_scan', 'point_cloud2', 'occupancy_grid')
RANGE_SENSORS = ('laser_scan', 'point_cloud2')
MAP_SENSORS = RANGE_SENSORS + ('occupancy_grid',)     # the detections kept in a local map (SensorMap)
SENSOR_WORDS = {'laser_scan': 'scan', 'point_cloud2': 'cloud', 'occupancy_grid': 'costmap'}
POSES_KEPT = 64        # poses remembered to place a scan (at 50 Hz: 1.3 s, more than pose_timeout)

# the input types (both filter nodes'), then the local map's (safety_filter_node's alone)
TYPE_PARAMETERS = (
    ParameterSpec('pose_type', 'pose_stamped', f'message on pose: one of {POSE_TYPES}'),
    ParameterSpec('detections_type', 'pose_array', f'message on detections: one of {DETECTIONS_TYPES} '
                  '(pose_array: centres of radius; marker_array: CYLINDER discs of their own radius; '
                  'laser_scan / point_cloud2: returns in the sensor\'s frame, kept in a local map; '
                  'occupancy_grid: a costmap in frame_id, kept in the local map)'),
    ParameterSpec('cmd_vel_stamped', False, 'cmd_vel_nav and cmd_vel are geometry_msgs/TwistStamped (false: '
                  'Twist)'),
    ParameterSpec('require_detections', True, 'fail safe until detections arrive and whenever they are stale; '
                  'false = a robot without an obstacle sensor: every pose comes with "no obstacle" and '
                  'detections is not subscribed'),
)
MAP_PARAMETERS = (
    ParameterSpec('robot_radius', 0.3, 'laser_scan / point_cloud2 / occupancy_grid: the robot\'s own radius: it '
                  'keeps this far from every occupied cell of its local map [m]', 0.0, 100.0),
    ParameterSpec('sensor_x', 0.0, 'laser_scan / point_cloud2: the sensor\'s x in the robot\'s frame [m]',
                  -100.0, 100.0),
    ParameterSpec('sensor_y', 0.0, 'laser_scan / point_cloud2: the sensor\'s y in the robot\'s frame [m]',
                  -100.0, 100.0),
    ParameterSpec('sensor_yaw', 0.0, 'laser_scan / point_cloud2: the sensor\'s yaw in the robot\'s frame '
                  '[rad]', -7.0, 7.0),
    ParameterSpec('obstacle_depth', 0.0, 'laser_scan / point_cloud2: each return also marks its beam this far '
                  'behind it in the local map (the far side the sensor cannot see; a beam that later passes '
                  'there clears it; 0 = the surface alone) [m]', 0.0, 100.0),
    ParameterSpec('inf_is_valid', False, 'laser_scan: a +inf range is a beam that saw nothing up to range_max '
                  'and clears its cells (as Nav2\'s obstacle layer); false: it clears nothing (REP 117 leaves '
                  'it to the driver)'),
    ParameterSpec('map_cell', 0.05, 'laser_scan / point_cloud2 / occupancy_grid: the local map\'s cell side [m]',
                  0.005, 10.0),
    ParameterSpec('map_size', 10.0, 'the local map\'s window side, centred on the robot and moved with it '
                  '(what leaves it is forgotten) [m]', 0.5, 1000.0),
    ParameterSpec('value_cell', 0.0, 'the local map\'s value: its grid\'s spacing [m]; 0 = (value_reach + speed '
                  'x horizon) / 28 in whole map cells, about 60 x 60 nodes a heading (0.1 m for 0.5 m/s over 3 s)',
                  0.0, 10.0),
    ParameterSpec('value_headings', 32, 'the local map\'s value: headings of its grid', 8, 256),
    ParameterSpec('value_horizon', 0.0, 'the local map\'s value: its horizon [s] (0 = standard_horizon; a fast '
                  'robot\'s window grows with speed x horizon)', 0.0, 60.0),
    ParameterSpec('value_reach', 1.0, 'the local map\'s value: how far the robot may go from the solved window\'s '
                  'centre with its value sound (it is solved around the robot again once 0.5 m away) [m]', 0.1, 100.0),
    ParameterSpec('value_period', 0.5, 'the local map\'s value is solved again (in the background) at most every '
                  'this many seconds of the filter\'s time while the map changes, and not while inactive', 0.0, 60.0),
    ParameterSpec('occupied_threshold', 100, 'occupancy_grid: a cell of at least this value is occupied, 0 .. '
                  'this - 1 free, -1 unknown (leaves what the map held; Nav2\'s costmap: 100 lethal, 99 '
                  'inscribed)', 1, 100),
    ParameterSpec('max_sensor_points', 1_000_000, 'laser_scan / point_cloud2 / occupancy_grid: a message with more '
                  'beams, points or cells is refused unread (the map stays as it was) [points]', 1, 100_000_000),
)
INPUT_PARAMETERS = TYPE_PARAMETERS + MAP_PARAMETERS


# each input type's message class, as 'package/Name' (imported when used)
MESSAGE_TYPES = {
    'pose_stamped': 'geometry_msgs/PoseStamped', 'odometry': 'nav_msgs/Odometry',
    'pose_with_covariance': 'geometry_msgs/PoseWithCovarianceStamped',
    'pose_array': 'geometry_msgs/PoseArray', 'marker_array': 'visualization_msgs/MarkerArray',
    'laser_scan': 'sensor_msgs/LaserScan', 'point_cloud2': 'sensor_msgs/PointCloud2',
    'occupancy_grid': 'nav_msgs/OccupancyGrid',
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


class PoseHistory:
    """The last POSES_KEPT poses received: (stamp on the filter's time base, (x, y, theta))."""

    def __init__(self, kept: int = POSES_KEPT):
        self.stamps = deque(maxlen=kept)
        self.states = deque(maxlen=kept)

    def add(self, stamp: float, state) -> None:
        if self.stamps and stamp < self.stamps[-1]:     # a pose older than the newest: kept in order
            order = sorted(zip([*self.stamps, float(stamp)], [*self.states, tuple(state)]))
            self.stamps.clear(), self.states.clear()
            for s, x in order[-self.stamps.maxlen:]:
                self.stamps.append(s)
                self.states.append(x)
            return
        self.stamps.append(float(stamp))
        self.states.append(tuple(state))

    def at(self, stamp: float, max_gap: float):
        """(the pose at ``stamp``, its gap in time: 0 when interpolated between two poses that bracket it
        within ``max_gap``; ``range_readings.interpolated_pose``)."""
        return interpolated_pose(np.fromiter(self.stamps, float, len(self.stamps)), list(self.states), stamp,
                                 max_gap)

    @property
    def newest(self):
        return self.states[-1] if self.states else None


VALUE_NODES_HALF = 28       # value_cell 0: about this many nodes from the window's centre to its edge


def value_cell(p: dict, speed: float, horizon: float) -> float:
    """The map value's grid spacing: ``value_cell``, or with 0 (value_reach + speed horizon) / VALUE_NODES_HALF
    rounded to whole map cells (at least one): the window's half-width is about value_reach + speed horizon,
    so its grid has about 2 x 28 + 1 nodes a side whatever the robot's speed (a 40 ms solve here)."""
    if p['value_cell'] > 0.0:
        return float(p['value_cell'])
    cell = p['map_cell']
    return cell * max(1, round((p['value_reach'] + speed * horizon) / VALUE_NODES_HALF / cell))


def mounted(pose, mount) -> tuple:
    """The sensor's pose in the map: the robot at ``pose`` (x, y, theta) carrying it at ``mount``
    (x_m, y_m, yaw_m) in its own frame."""
    x, y, th = (float(v) for v in pose)
    mx, my, myaw = (float(v) for v in mount)
    c, s = math.cos(th), math.sin(th)
    return x + c * mx - s * my, y + s * mx + c * my, th + myaw


class SensorMap:
    """A range sensor's or a costmap's messages -> the robot's local map and its value (see the module).

    ``take(msg, stamp, config, pose_timeout)`` checks a message, places it with the robot's pose at
    its stamp and puts it into the map (``MessageError`` naming the fault if refused: the map stays as
    it was); ``solve(omega_max, now)`` asks for the map's value again (in the background, at most
    every ``value_period``, latest wins); ``view`` is what the filter judges by. ``note`` is the last
    message's problem in plain words ('' if none: e.g. every beam NaN), for /diagnostics. It is the
    detections' Source too (``filter_sources``): ``msg_type``, ``topic``, ``raw``, ``qos`` (scans and
    clouds with the sensor-data QoS; a costmap's transient-local publisher matches the reliable,
    volatile stream)."""

    topic, raw = 'detections', False

    def __init__(self, p: dict, history: PoseHistory, config, horizon: float, frame: str, inline: bool = False):
        self.kind = p['detections_type']
        self.msg_type = message_type(self.kind)
        self.qos = qos_profile_sensor_data if self.kind in RANGE_SENSORS else QOS_STREAM
        self.history = history
        self.frame = frame
        self.mount = (p['sensor_x'], p['sensor_y'], p['sensor_yaw'])
        self.max_points = p['max_sensor_points']
        self.inf_is_valid = p['inf_is_valid']
        self.threshold = p['occupied_threshold']
        self.period = p['value_period']
        self.map = LocalMap(MapSettings(cell=p['map_cell'], size=p['map_size'], depth=p['obstacle_depth']))
        value_horizon = p['value_horizon'] or horizon or 3.0
        self.value_settings = MapValueSettings(cell=value_cell(p, config.speed, value_horizon),
                                               headings=p['value_headings'], horizon=value_horizon,
                                               reach=p['value_reach'], recentre=min(0.5, p['value_reach']))
        # inline (a lockstepped simulation): solved in the caller's thread, so that the value's latency is none
        # in sim time (the clock waits for the answer), as a background solve's is next to value_period on a robot
        # in the background: a worker process of its own (its solves hold nothing of the control path here)
        self.worker = MapValueWorker(config.speed, config.omega_max, p['robot_radius'], self.value_settings,
                                     inline=inline, process=not inline)
        self.view = MapView(self.map, p['robot_radius'], self.worker, SENSOR_WORDS[self.kind])
        self.note = ''
        self.last = None            # the last message's ViewSummary
        self._dropped = 0           # a cloud's points not finite
        self._asked = -math.inf     # steady time of the last solve asked for

    def take(self, msg, stamp: float, config, pose_timeout: float):
        """Put one message into the map (see the class); (the view's summary, whether the sensor looked:
        not a scan of no beam or of only erroneous ones (NaN, below range_min), not a cloud of points none
        of them finite, not a costmap of unknown cells only; one that did not look leaves the view to go
        stale: blind)."""
        if self.kind == 'occupancy_grid':
            summary = self._take_grid(msg)
            learned = bool(np.any(np.frombuffer(memoryview(msg.data).cast('B'), dtype=np.int8) != -1)) \
                if len(msg.data) else False
        else:
            readings = self._scan(msg) if self.kind == 'laser_scan' else self._cloud(msg)   # checked first
            pose, gap = self.history.at(stamp, pose_timeout)
            if pose is None:
                raise MessageError('no pose received yet to place the returns with')
            if gap > pose_timeout:
                raise MessageError(f'no pose within {pose_timeout:g} s of its stamp (the nearest {gap:.2g} s away)')
            sensor = mounted(pose, self.mount)
            self.map.follow(float(pose[0]), float(pose[1]))
            # placed with a pose gap s from the stamp: a return rho from the robot may lie v gap + rho w gap
            # from where it is put (the robot moved at most that since); 0 when interpolated
            reach = math.hypot(self.mount[0], self.mount[1])
            if self.kind == 'laser_scan':
                slack = 0.0 if gap == 0.0 else (config.speed * gap
                                                + (readings.mark_range + reach) * config.omega_max * gap)
                summary = self.map.integrate_rays(sensor, readings, slack)
                learned = not readings.faulty
            else:
                slack = 0.0 if gap == 0.0 else (config.speed * gap + (np.hypot(readings[:, 0], readings[:, 1])
                                                                      + reach) * config.omega_max * gap)
                summary = self.map.integrate_points(sensor, readings, slack)
                learned = len(readings) > 0 or int(msg.width) * int(msg.height) == 0
            # the robot's own disc holds nothing but the robot (its own parts seen, a return closer than
            # range_min marked inside it): cleared, as Nav2's footprint clearing
            self.map.clear_footprint(float(pose[0]), float(pose[1]), self.view.clearance)
        self.last = summary
        if summary.problem or learned:
            self.note = summary.problem
        elif self.kind == 'point_cloud2':
            self.note = f'{self._dropped} of {self._dropped} points not finite: the cloud says nothing'
        else:
            self.note = 'every cell unknown (-1): the costmap says nothing'
        return summary, learned

    def _scan(self, msg):
        try:
            return scan_rays(msg.ranges, msg.angle_min, msg.angle_max, msg.angle_increment, msg.range_min,
                             msg.range_max, inf_is_valid=self.inf_is_valid, max_beams=self.max_points)
        except ValueError as exc:
            raise MessageError(str(exc)) from None

    def _cloud(self, msg):
        fields = {f.name: (int(f.offset), int(f.datatype), int(f.count)) for f in msg.fields}
        try:
            xy, self._dropped = cloud_xy(msg.data, fields, msg.point_step, msg.row_step, msg.width, msg.height,
                                         msg.is_bigendian, self.max_points)
        except (ValueError, TypeError) as exc:
            raise MessageError(str(exc)) from None
        return xy

    def _take_grid(self, msg):
        from ..ros_io.rosmsg import quaternion_to_yaw
        if msg.header.frame_id != self.frame:
            raise MessageError(f"costmap frame is '{msg.header.frame_id}', expected '{self.frame}'")
        info = msg.info
        if int(info.width) * int(info.height) > self.max_points:
            raise MessageError(f'costmap of {int(info.width)} x {int(info.height)} cells exceeds max_sensor_points='
                               f'{self.max_points}')
        o = info.origin
        origin = (float(o.position.x), float(o.position.y), quaternion_to_yaw(o.orientation))
        newest = self.history.newest
        if newest is not None:
            self.map.follow(float(newest[0]), float(newest[1]))
        try:
            return self.map.integrate_grid(origin, float(info.resolution), int(info.width), int(info.height),
                                           msg.data, self.threshold)
        except ValueError as exc:
            raise MessageError(f'costmap refused: {exc}') from None

    def solve(self, omega_max: float, now: float, x: float, y: float) -> bool:
        """Ask for the map's value around (x, y) with turn bound ``omega_max`` (the set in force's), at most
        every ``value_period`` seconds of ``now`` (the filter's time; True if asked). The worker solves in
        the background (inline: at once), the newest request replacing one not yet started, and solves
        nothing when neither the map nor the window changed (``filter.map_value``)."""
        if now - self._asked < self.period:
            return False
        self._asked = now
        self.worker.submit(self.map.snapshot(), (x, y), omega_max=omega_max, stamp=now)
        return True

    def problem(self, detections) -> str:
        """The sensor's problem in words ('' if none): the newest messages' refusal (``detections``: the filter's
        input, which counts them) or the last message's own (every beam NaN, ...)."""
        if detections.refused:
            return f'{detections.refusals} {self.view.sensor} message(s) unusable since the last valid one: ' \
                   f'{detections.refused}'
        return f'{self.view.sensor}: {self.note}' if self.note else ''

    def state_values(self, detections) -> dict:
        """The map's and its value's values for the state topic."""
        value, last = self.worker.latest(), self.last
        return {
            'map_version': str(self.map.version),
            'map_value_version': '' if value is None else str(value.version),
            'map_value_solve_s': '' if value is None else f'{value.solve_s:.3g}',
            'map_value_errors': str(len(self.worker.errors)),
            'view': '' if last is None else f'{last.kind}: {last.marked} cells marked, {last.cleared} cleared',
            'view_problem': self.problem(detections),
        }

    def close(self):
        self.worker.close()
