"""The filter node's inputs, one Source per kind (as Nav2 collision_monitor's Source classes): the
message class a robot's topic carries, the QoS it is taken with, and how its bytes are read and
checked. Every robot of the node (one, or a fleet's) reads its pose, detections and planner
command through these, as ``pose_type``, ``detections_type`` and ``cmd_vel_stamped`` say.

* ``PoseSource(pose_type, frame)``: ``read(data)`` -> ((x, y, theta), the header's stamp), from the
  CDR bytes of a geometry_msgs/PoseStamped, nav_msgs/Odometry (``pose.pose`` in its header's frame)
  or geometry_msgs/PoseWithCovarianceStamped (as AMCL publishes) (``ros_io.cdr``). The frame must be
  the filter's ``frame_id`` (for odometry: an odom frame that ``frame_id`` names; the filter does not
  transform poses);
* ``CommandSource(stamped)``: ``read(data)`` -> (turn rate, linear.x, the header or None), from a
  Twist's or a TwistStamped's bytes (a Twist object is read too); ``take(f, data, t, sink)`` puts
  it into a robot's filter, or refuses it there;
* ``DiscSource(kind, frame)``: ``read(data)`` -> detections rows, from a PoseArray's bytes (centres
  (N, 2), each of the node's ``radius``) or a visualization_msgs/MarkerArray (discs (N, 3) of their
  own radii, ``marker_discs``; bytes are deserialized);
* ``SensorMap``: a sensor_msgs/LaserScan's or PointCloud2's returns (in the sensor's frame, its mount
  ``sensor_x/y/yaw`` on the robot) or a nav_msgs/OccupancyGrid (in ``frame_id``, e.g. Nav2's local
  costmap) kept in the robot's local map (``filter.sensing.local_map``: a valid return marks, a valid beam
  clears what it passes through, REP 117's NaN, below-minimum and missing returns clear nothing),
  and the map's avoid value, solved again in the background as the map changes
  (``filter.sensing.map_value``); each message is checked first (``filter.sensing.readings``: a scan or cloud
  of invalid geometry is refused with the fault named, and the map stays as it was). Scans and
  clouds are subscribed with the sensor-data QoS (best effort: it matches best-effort and
  reliable drivers alike); grids reliable and volatile, which matches a costmap's
  transient-local publisher;
* ``CommandSink(stamped)``: a robot's cmd_vel as bytes, a Twist's or a TwistStamped's (the planner's
  last header kept for it; ``cmd_vel`` of a decision, ``bytes`` of any command).

Each ``read`` (and ``SensorMap.take``) raises ValueError (``MessageError``) naming what is wrong;
the caller rejects the input, fails the robot safe and complains.
"""
from __future__ import annotations

from collections import deque
from importlib import import_module
import math
import re

import numpy as np
from rclpy.qos import qos_profile_sensor_data

from ..filter import FAIL_SAFE
from ..filter.commands import command_fresh
from ..filter.sensing.local_map import LocalMap, MapSettings
from ..filter.constraints.map_rows import MapView
from ..filter.sensing.map_value import MapValueSettings, MapValueWorker
from ..filter.sensing.readings import cloud_xy, interpolated_pose, scan_rays
from ..ros_io import cdr, rosmsg
from ..ros_io.rosmsg import QOS_STREAM, MessageError
from .filter_parameters import RANGE_SENSORS

# each pose_type's raw reader: (frame_id, stamp, pose values) of the bytes (ros_io.cdr.stamped_pose)
POSE_READERS = {'pose_stamped': cdr.pose_stamped, 'odometry': cdr.odometry,
                'pose_with_covariance': cdr.pose_with_covariance}
DISC_TYPES = ('pose_array', 'marker_array')
NO_DETECTIONS = np.zeros((0, 2))      # what a robot without an obstacle sensor sees (require_detections false)
SENSOR_WORDS = {'laser_scan': 'scan', 'point_cloud2': 'cloud', 'occupancy_grid': 'costmap'}
POSES_KEPT = 64        # poses remembered to place a scan (at 50 Hz: 1.3 s, more than pose_timeout)

# each input type's message class, as 'package/Name' (imported when used)
MESSAGE_TYPES = {
    'pose_stamped': 'geometry_msgs/PoseStamped', 'odometry': 'nav_msgs/Odometry',
    'pose_with_covariance': 'geometry_msgs/PoseWithCovarianceStamped',
    'pose_array': 'geometry_msgs/PoseArray', 'marker_array': 'visualization_msgs/MarkerArray',
    'laser_scan': 'sensor_msgs/LaserScan', 'point_cloud2': 'sensor_msgs/PointCloud2',
    'occupancy_grid': 'nav_msgs/OccupancyGrid',
}
# visualization_msgs/Marker constants (the message's, repeated to keep this module light)
CUBE, SPHERE, CYLINDER = 1, 2, 3
ADD = 0


def message_type(kind: str):
    """The message class of a ``pose_type`` or ``detections_type`` value."""
    package, name = MESSAGE_TYPES[kind].split('/')
    return getattr(import_module(f'{package}.msg'), name)


def command_message_type(stamped: bool):
    from geometry_msgs.msg import Twist, TwistStamped
    return TwistStamped if stamped else Twist


def marker_discs(msg, frame: str):
    """((N, 3) discs [x, y, r], how many markers added no obstacle) of a MarkerArray, the full current
    set of obstacles (as a PoseArray of detections is). CYLINDER and SPHERE markers are discs of radius
    max(scale.x, scale.y) / 2 about their position; a CUBE is covered by the disc of its half diagonal,
    hypot(scale.x, scale.y) / 2; DELETE and DELETEALL markers and the other types (arrows, lines, text,
    meshes...) add no obstacle and are counted. Every marker that adds an obstacle must be in ``frame``
    with a finite position and positive scale, else the whole message is refused (MessageError)."""
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


class PoseSource:
    """A robot's pose topic as ``pose_type`` says (taken raw)."""

    topic, raw, qos = 'pose', True, rosmsg.QOS_STREAM

    def __init__(self, pose_type: str, frame: str):
        self.msg_type = message_type(pose_type)
        self._read, self.frame = POSE_READERS[pose_type], frame

    def read(self, data):
        """((x, y, theta), the header's stamp) of a serialized pose message."""
        frame_id, stamp, v = self._read(data)
        return rosmsg.planar_state(frame_id, v[0], v[1], v[3], v[4], v[5], v[6], self.frame), stamp


class CommandSource:
    """A robot's planner command (``cmd_vel_nav``), a Twist or, ``stamped``, a TwistStamped (raw)."""

    topic, raw, qos = 'cmd_vel_nav', True, rosmsg.QOS_STREAM

    def __init__(self, stamped: bool):
        self.stamped = bool(stamped)
        self.msg_type = command_message_type(self.stamped)

    def read(self, data):
        """(angular.z, linear.x, the header or None) of a serialized command (or a Twist); the values
        as given (the filter checks them: ``RobotFilter.update_command``)."""
        header = None
        if not isinstance(data, (bytes, bytearray, memoryview)):
            twist = data
        elif self.stamped:
            header, twist = cdr.twist_stamped(data)
        else:
            twist = cdr.twist(data)
        return twist.angular.z, twist.linear.x, header

    def take(self, f, data, t, sink) -> bool:
        """The command in ``data`` as robot filter ``f``'s newest, at ``t`` (its header kept by
        ``sink``); False if refused, not finite or unreadable: a robot that can stop then stops
        until a valid command comes (``RobotFilter.refuse_command``). ``f.command.note`` says why,
        or what was beyond the robot's limits."""
        try:
            turn, linear, header = self.read(data)
            sink.heard(header)
            f.update_command(turn, t, linear)
        except ValueError as exc:       # not finite (update_command, which refuses it), or unreadable
            if not f.command.rejected:
                f.refuse_command(f'unreadable ({exc})', t)
            return False
        return True


class DiscSource:
    """A robot's detections of objects: a PoseArray of centres (raw) or a MarkerArray of discs."""

    topic, qos = 'detections', rosmsg.QOS_STREAM

    def __init__(self, kind: str, frame: str):
        if kind not in DISC_TYPES:
            raise ValueError(f'{kind!r} is not a detections type of discs ({DISC_TYPES})')
        self.kind, self.frame = kind, frame
        self.msg_type = message_type(kind)
        self.raw = kind == 'pose_array'

    def read(self, data):
        """Detections rows: centres (N, 2) of a PoseArray's bytes, discs (N, 3) of a MarkerArray
        (a message object, or its bytes)."""
        if self.kind == 'pose_array':
            return rosmsg.checked_xy(*cdr.pose_array_xy(data, 'detections'), self.frame)
        if isinstance(data, (bytes, bytearray, memoryview)):
            from rclpy.serialization import deserialize_message
            data = deserialize_message(bytes(data), self.msg_type)
        return marker_discs(data, self.frame)[0]


class CommandSink:
    """A robot's cmd_vel, serialized (no message built): a Twist, or with ``stamped`` a TwistStamped
    that carries the planner's header on what was judged from its command (as Nav2's
    collision_monitor keeps it) and the node clock's stamp, in the planner's last frame, on what
    was not (a fail safe, a silent planner's zero twist, a managed node going quiet)."""

    __slots__ = ('stamped', 'msg_type', 'frame', 'stamp')

    def __init__(self, stamped: bool):
        self.stamped = bool(stamped)
        self.msg_type = command_message_type(self.stamped)
        self.frame, self.stamp = '', None       # the planner's last header

    def heard(self, header) -> None:
        """The header of a planner command read (None: a Twist's, nothing to keep)."""
        if header is not None:
            self.frame, self.stamp = header.frame_id, header.stamp

    def cmd_vel(self, f, t, action: str, linear: float, omega: float, clock_ns) -> bytes:
        """The bytes of robot filter ``f``'s decision at ``t`` (``action``, ``linear``, ``omega``): it
        was judged from the planner's command when it is no fail safe and that command is fresh."""
        judged = self.stamped and action != FAIL_SAFE and command_fresh(f, t)
        return self.bytes(linear, omega, judged, clock_ns)

    def bytes(self, linear: float, omega: float, judged: bool, clock_ns) -> bytes:
        """The cmd_vel's bytes; ``judged``: the command came from the planner's, fresh;
        ``clock_ns()``: the node clock's time [ns], read only when it stamps."""
        if not self.stamped:
            return cdr.twist_bytes(float(linear), float(omega))
        if judged and self.stamp is not None:
            sec, nanosec = self.stamp.sec, self.stamp.nanosec
        else:
            sec, nanosec = divmod(clock_ns(), 1_000_000_000)
        return cdr.twist_stamped_bytes(sec, nanosec, self.frame, float(linear), float(omega))


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
        within ``max_gap``; ``readings.interpolated_pose``)."""
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
        self._first_told = False    # the map's first value said

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

    def say_settings(self, p: dict, config, log) -> None:
        """The map's settings in one log line (and a WARN where nothing stops the robot before what the
        map learned since its value was last solved)."""
        s = self.value_settings
        log.info(f"{self.view.sensor}: a local map of {p['map_size']:g} m at {p['map_cell']:g} m cells per robot, "
                 f'judged by its avoid value (speed {config.speed:g}, w_max {config.omega_max:g}, clearance '
                 f'{p["robot_radius"]:g} m, horizon {s.horizon:g} s, {s.cell:g} m x {s.headings} headings), solved '
                 f'again in the background at most every {p["value_period"]:g} s while the map changes')
        if config.time_before_collision <= 0.0 and not config.constant_speed:
            # the map's value is that of the map at its solve time; what the map learns between
            # solves is judged only by the speed cut, for a robot that can stop
            log.warning(f"detections_type {self.kind}: time_before_collision is 0, so nothing stops this robot "
                        'before an obstacle the map learned since its value was last solved; set it > 0 '
                        '(config/nav2_safety_filter.yaml: 0.5; docs/filter_node.md, "Stop before collision")')

    def take_into(self, f, msg, t, wiring, complain):
        """One message into robot filter ``f``'s view at filter time ``t`` (``take``; its stamp on
        ``wiring``'s time base): refused with the fault named (the view stays as it was: the robot fails
        safe once its last valid view is detections_timeout old), or the view updated, or, where the sensor
        did not look, blind; each said through ``complain(kind, text, level)``. (whether it was placed:
        not before the first pose; whether the sensor looked)."""
        kind, timeout = self.view.sensor, wiring.config.detections_timeout
        if not self.history.stamps and self.kind != 'occupancy_grid':
            # starting: the scan came before the first pose (said once, not an error)
            complain('detections before pose', f'a {kind} before the first pose: waiting for a pose to place its '
                     'returns with (failing safe until then)', level='info')
            return False, False
        try:
            stamp = wiring.stamp(msg.header.stamp, t)
            summary, learned = self.take(msg, t if stamp is None else stamp, wiring.config,
                                         wiring.config.pose_timeout)
        except ValueError as exc:     # MessageError: the fault named; the view stays as it was
            why = str(exc) if str(exc).startswith(f'{kind} refused') else f'{kind} refused: {exc}'
            f.refuse_view(why, t)
            # each kind of fault logged (throttled per kind: its words with the numbers masked)
            complain(re.sub(r'[-+0-9.eE]+', '#', why), f'{why}; the map stays as it was (failing safe once its '
                     f'last valid view is detections_timeout {timeout:g} s old)', level='error')
            return True, False
        if learned:
            f.update_view(self.view, t)
            if summary.problem:
                complain(f'{kind} note', f'{kind}: {summary.problem}')
        else:           # it did not look: blind, not "looked, nothing seen" (the map keeps what was seen)
            f.refuse_view(f'{kind} did not look: {self.note}', t)
            complain(f'{kind} note', f'{kind}: {self.note}; the map keeps what was seen (failing safe once its last '
                     f'view is detections_timeout {timeout:g} s old)')
        return True, learned

    def ask_value(self, wiring, complain) -> None:
        """The map's value solved again around the robot (at most every value_period) for the set in force:
        the learned w_max where a learned set is, the robot's own otherwise; its first value said once."""
        newest = self.history.newest
        if newest is None:
            return
        safe = wiring.safe_set
        learned = safe.source == 'learned' and safe.omega_max is not None
        omega = safe.omega_max if learned else wiring.config.omega_max
        self.solve(float(omega), wiring.now(), float(newest[0]), float(newest[1]))
        value = self.worker.latest()
        if value is not None and not self._first_told:
            self._first_told = True
            g = value.vf.grid
            complain('first value', f'{self.view.sensor} map: its first value solved in {value.solve_s:.3g} s (a '
                     f'window of {g.hi[0] - g.lo[0]:.3g} m, grid {g.shape})', level='info')

    def solve(self, omega_max: float, now: float, x: float, y: float) -> bool:
        """Ask for the map's value around (x, y) with turn bound ``omega_max`` (the set in force's), at most
        every ``value_period`` seconds of ``now`` (the filter's time; True if asked). The worker solves in
        the background (inline: at once), the newest request replacing one not yet started, and solves
        nothing when neither the map nor the window changed (``filter.sensing.map_value``)."""
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
