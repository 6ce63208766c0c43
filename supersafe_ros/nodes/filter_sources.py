"""A filter node's inputs, one Source per kind (as Nav2 collision_monitor's Source classes): the
message class a robot's topic carries, the QoS it is taken with, and how its bytes are read and
checked. safety_filter_node and fleet_safety_filter_node read every robot's pose, detections and
planner command through these, so a fleet's robot takes what a lone robot takes
(``pose_type``, ``detections_type``, ``cmd_vel_stamped``; ``filter_inputs``).

* ``PoseSource(pose_type, frame)``: ``read(data)`` -> ((x, y, theta), the header's stamp), from the
  CDR bytes of a PoseStamped, Odometry or PoseWithCovarianceStamped (``ros_io.cdr``);
* ``CommandSource(stamped)``: ``read(data)`` -> (turn rate, linear.x, the header or None), from a
  Twist's or a TwistStamped's bytes (a Twist object is read too); ``take(f, data, t, sink)`` puts
  it into a robot's filter, or refuses it there;
* ``DiscSource(kind, frame)``: ``read(data)`` -> detections rows, from a PoseArray's bytes (centres
  (N, 2)) or a MarkerArray (discs (N, 3) of their own radii; bytes are deserialized);
* ``CommandSink(stamped)``: a robot's cmd_vel as bytes, a Twist's or a TwistStamped's (the planner's
  last header kept for it; ``cmd_vel`` of a decision, ``bytes`` of any command).

Each ``read`` raises ValueError (``MessageError``) naming what is wrong; the caller rejects the
input, fails safe and complains. The range sensors' and the costmap's Source is
``filter_inputs.SensorMap`` (a local map per robot, its value solved in the background).
"""
from __future__ import annotations

import numpy as np

from ..filter import FAIL_SAFE
from ..filter.commands import command_fresh
from ..ros_io import cdr, rosmsg, sensors
from .filter_inputs import command_message_type, message_type

# each pose_type's raw reader: a PoseStamped view of the bytes (ros_io.cdr)
POSE_READERS = {'pose_stamped': cdr.pose_stamped, 'odometry': cdr.odometry,
                'pose_with_covariance': cdr.pose_with_covariance}
DISC_TYPES = ('pose_array', 'marker_array')
NO_DETECTIONS = np.zeros((0, 2))      # what a robot without an obstacle sensor sees (require_detections false)


class PoseSource:
    """A robot's pose topic as ``pose_type`` says (taken raw)."""

    topic, raw, qos = 'pose', True, rosmsg.QOS_STREAM

    def __init__(self, pose_type: str, frame: str):
        self.msg_type = message_type(pose_type)
        self._read, self.frame = POSE_READERS[pose_type], frame

    def read(self, data):
        """((x, y, theta), the header's stamp) of a serialized pose message."""
        msg = self._read(data)
        return rosmsg.pose_to_state(msg, self.frame), msg.header.stamp


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
        return sensors.marker_discs(data, self.frame)[0]


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
