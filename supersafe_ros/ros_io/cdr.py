"""A few standard messages read from and written to their serialized (CDR) bytes.

rclpy builds a Python object per nested message when it deserializes (a PoseStamped is
six objects, ~15 us; a fleet node of N robots takes up to three messages per robot per
tick). The fleet node's per-robot topics are taken raw instead, and only the newest
sample of each is decoded, into light views with the message's attribute names
(``header.stamp.sec``, ``pose.position.x``, ``angular.z``, ...), so the validators of
``rosmsg`` read them exactly as they read the messages (same values bit for bit, same
errors). ``pose_array_xy`` reads a PoseArray's positions as one numpy array (detections of
any size: bounded work, no object per pose). ``pose_array_bytes``, ``twist_bytes`` and
``twist_stamped_bytes`` serialize a PoseArray of positions, a Twist and a TwistStamped; a robot
stack's Odometry, AMCL's PoseWithCovarianceStamped and a TwistStamped are read the same way
(``odometry``, ``pose_with_covariance``, ``twist_stamped``: the parts the filter reads).
``diagnostic_status_bytes`` and ``diagnostic_array_bytes`` write the filters' state messages
(a fleet's hundreds a tick) without a typed message and its KeyValues.

``serialized_to_value_function`` reads a /safe_set/value_function message: rclpy's
``deserialize_message`` copies a 50 MB Float32MultiArray into a Python array in one C call
that holds the GIL for 0.3 s or more, stalling every other thread of the process (the
filter's control path), so the header is read here and the values are a zero-copy numpy
view of the bytes; the checks are ``vfmsg.msg_to_value_function``'s own.

Layout (little-endian CDR, ``encapsulation`` = 00 01 00 00; offsets count from the end
of those 4 bytes, each primitive aligned to its size): Header = int32 sec, uint32
nanosec, string frame_id (uint32 length with its NUL, the bytes); Pose = 7 float64
[position x y z, orientation x y z w]; PoseArray = Header, uint32 count, count Poses;
Twist = 6 float64 [linear x y z, angular x y z]; Float32MultiArray = uint32 dim count,
per dim (string label, uint32 size, uint32 stride), uint32 data_offset, uint32 count,
count float32; DiagnosticStatus = octet level, strings name, message, hardware_id, uint32
count, count (string key, string value); DiagnosticArray = Header, uint32 count, the statuses
one after another (each string aligned from where the one before ended). Any other
encapsulation (big-endian, XCDR2) is deserialized by rclpy.
"""
from __future__ import annotations

import struct
from types import SimpleNamespace

import numpy as np
from rclpy.serialization import deserialize_message

from .rosmsg import MessageError

_LE = b'\x00\x01'
_STAMP_LEN = struct.Struct('<iII')
_COUNT = struct.Struct('<I')
_POSE = struct.Struct('<7d')
_TWIST = struct.Struct('<6d')
_TWO = struct.Struct('<II')
MAX_DIMENSIONS = 16     # a value function's layout has 3; more is not one
ENCAPSULATION = b'\x00\x01\x00\x00'


class Stamp:
    __slots__ = ('sec', 'nanosec')

    def __init__(self, sec, nanosec):
        self.sec, self.nanosec = sec, nanosec


class Header:
    __slots__ = ('stamp', 'frame_id')

    def __init__(self, stamp, frame_id):
        self.stamp, self.frame_id = stamp, frame_id


class Vector:
    __slots__ = ('x', 'y', 'z')

    def __init__(self, x, y, z):
        self.x, self.y, self.z = x, y, z


class Quaternion:
    __slots__ = ('x', 'y', 'z', 'w')

    def __init__(self, x, y, z, w):
        self.x, self.y, self.z, self.w = x, y, z, w


class Pose:
    __slots__ = ('position', 'orientation')

    def __init__(self, v):
        self.position = Vector(v[0], v[1], v[2])
        self.orientation = Quaternion(v[3], v[4], v[5], v[6])


class PoseArray:
    __slots__ = ('header', 'poses')

    def __init__(self, header, poses):
        self.header, self.poses = header, poses


class Twist:
    __slots__ = ('linear', 'angular')

    def __init__(self, v):
        self.linear = Vector(v[0], v[1], v[2])
        self.angular = Vector(v[3], v[4], v[5])


def body(data):
    """The CDR body after a little-endian encapsulation header, or None (another encoding)."""
    buf = memoryview(data)
    if len(buf) >= 4 and bytes(buf[:2]) == _LE:
        return buf[4:]
    return None


def _header(body):
    """(Header, offset after it); struct.error or ValueError if the bytes are not one."""
    sec, nanosec, length = _STAMP_LEN.unpack_from(body, 0)
    if 12 + length > len(body):
        raise ValueError('truncated frame_id')
    frame_id = bytes(body[12:12 + max(0, length - 1)]).decode('utf-8')
    return Header(Stamp(sec, nanosec), frame_id), 12 + length


def _align(offset, size):
    return (offset + size - 1) & ~(size - 1)


def stamped_pose(data, type_name: str, skip_strings: int, message_type):
    """(frame_id, Stamp, (x, y, z, qx, qy, qz, qw)) of the serialized bytes of a ``type_name`` whose
    Header is followed by ``skip_strings`` strings and then a Pose (no object per field: a fleet
    reads one per robot and tick; ``rosmsg.planar_state`` checks it as every pose reader does);
    another encoding is deserialized by rclpy as ``message_type`` (its pose: ``pose``, or
    ``pose.pose``); MessageError naming ``type_name`` if the bytes are not one."""
    b = body(data)
    if b is None:
        msg = deserialize_message(bytes(data), message_type)
        pose = msg.pose.pose if hasattr(msg.pose, 'pose') else msg.pose
        p, q = pose.position, pose.orientation
        return msg.header.frame_id, msg.header.stamp, (p.x, p.y, p.z, q.x, q.y, q.z, q.w)
    try:
        header, off = _header(b)
        for _ in range(skip_strings):
            _, off = _string(b, off)
        values = _POSE.unpack_from(b, _align(off, 8))
    except (struct.error, ValueError) as exc:
        raise MessageError(f'pose is not a serialized {type_name} ({exc})') from None
    return header.frame_id, header.stamp, values


def pose_stamped(data):
    """``stamped_pose`` of a serialized geometry_msgs/PoseStamped."""
    from geometry_msgs.msg import PoseStamped as Msg
    return stamped_pose(data, 'PoseStamped', 0, Msg)


def odometry(data):
    """``stamped_pose`` of a serialized nav_msgs/Odometry (its ``pose.pose``): Header, string
    child_frame_id, PoseWithCovariance (Pose, 36 float64), TwistWithCovariance; the covariances
    are not read."""
    from nav_msgs.msg import Odometry as Msg
    return stamped_pose(data, 'Odometry', 1, Msg)


def pose_with_covariance(data):
    """``stamped_pose`` of a serialized geometry_msgs/PoseWithCovarianceStamped (AMCL's; its ``pose.pose``)."""
    from geometry_msgs.msg import PoseWithCovarianceStamped as Msg
    return stamped_pose(data, 'PoseWithCovarianceStamped', 0, Msg)


def pose_array_layout(b, what: str):
    """(Header, pose count, offset of the first pose's 7 float64) of a PoseArray's CDR body
    ``b``; MessageError naming ``what`` if the bytes are not one (truncated included)."""
    try:
        header, off = _header(b)
        off = _align(off, 4)
        (count,) = _COUNT.unpack_from(b, off)
        off = _align(off + 4, 8)         # (no padding is written when count is 0)
        if count and len(b) < off + _POSE.size * count:
            raise ValueError(f'truncated: {count} poses')
    except (struct.error, ValueError) as exc:
        raise MessageError(f'{what} is not a serialized PoseArray ({exc})') from None
    return header, count, off


def pose_array(data):
    """A PoseArray view of serialized bytes (MessageError if they are not one)."""
    b = body(data)
    if b is None:
        from geometry_msgs.msg import PoseArray as Msg
        return deserialize_message(bytes(data), Msg)
    header, count, off = pose_array_layout(b, 'pose array')
    return PoseArray(header, [Pose(v) for v in _POSE.iter_unpack(b[off:off + _POSE.size * count])])


def pose_array_xy(data, what: str = 'pose array'):
    """(Header view, (N, 2) float64 positions) of a serialized PoseArray: the positions are
    read as one strided numpy view of the buffer and copied once (16 bytes a pose), no
    object per pose (rclpy builds five per pose: 100,000 detections took seconds).
    MessageError naming ``what`` if the bytes are not one; another encapsulation is
    deserialized by rclpy."""
    b = body(data)
    if b is None:
        from geometry_msgs.msg import PoseArray as Msg
        msg = deserialize_message(bytes(data), Msg)
        xy = np.array([(p.position.x, p.position.y) for p in msg.poses], dtype=float).reshape(-1, 2)
        return msg.header, xy
    header, count, off = pose_array_layout(b, what)
    if not count:
        return header, np.zeros((0, 2))
    poses = np.frombuffer(b, dtype='<f8', count=7 * count, offset=off).reshape(count, 7)
    return header, poses[:, :2].astype(float)


def twist(data):
    """A Twist view of serialized bytes (MessageError if they are not one)."""
    b = body(data)
    if b is None:
        from geometry_msgs.msg import Twist as Msg
        return deserialize_message(bytes(data), Msg)
    try:
        return Twist(_TWIST.unpack_from(b, 0))
    except struct.error as exc:
        raise MessageError(f'command is not a serialized Twist ({exc})') from None


def twist_stamped(data):
    """(Header view, Twist view) of a serialized TwistStamped (MessageError if the bytes are not one)."""
    b = body(data)
    if b is None:
        from geometry_msgs.msg import TwistStamped as Msg
        msg = deserialize_message(bytes(data), Msg)
        return msg.header, msg.twist
    try:
        header, off = _header(b)
        return header, Twist(_TWIST.unpack_from(b, _align(off, 8)))
    except (struct.error, ValueError) as exc:
        raise MessageError(f'command is not a serialized TwistStamped ({exc})') from None


def _string(b, off):
    """(str, offset after it) of a CDR string at ``off`` (aligned to 4 first); ValueError
    if its length is 0 (no NUL) or runs past the end."""
    off = _align(off, 4)
    (length,) = _COUNT.unpack_from(b, off)
    if length == 0 or off + 4 + length > len(b):
        raise ValueError('bad string')
    return bytes(b[off + 4:off + 3 + length]).decode('utf-8', errors='replace'), off + 4 + length


def serialized_to_value_function(data):
    """ValueFunction from the serialized bytes of a /safe_set/value_function message (bytes, or
    a numpy uint8 array as ``ros_io.gil_free_take`` gives; the values are a view of it).
    ValueFunctionMessageError if the bytes are not one."""
    from .vfmsg import ValueFunctionMessageError, msg_to_value_function
    if len(data) < 8:
        raise ValueFunctionMessageError(f'serialized value function of {len(data)} bytes is too short')
    b = body(data)
    if b is None:
        from std_msgs.msg import Float32MultiArray
        return msg_to_value_function(deserialize_message(bytes(data), Float32MultiArray))
    try:
        (n_dims,) = _COUNT.unpack_from(b, 0)
        if n_dims > MAX_DIMENSIONS:
            raise ValueFunctionMessageError(f'{n_dims} layout dimensions')
        dims, off = [], 4
        for _ in range(n_dims):
            label, off = _string(b, off)
            off = _align(off, 4)
            size, stride = _TWO.unpack_from(b, off)
            dims.append(SimpleNamespace(label=label, size=size, stride=stride))
            off += 8
        off = _align(off, 4)
        data_offset, count = _TWO.unpack_from(b, off)
        off += 8
    except (struct.error, ValueError) as exc:
        raise ValueFunctionMessageError(f'serialized value function is truncated ({exc})') from None
    if off + 4 * count > len(b):
        raise ValueFunctionMessageError(f'serialized value function is truncated: {count} values announced')
    values = np.frombuffer(b, dtype='<f4', count=count, offset=off)
    msg = SimpleNamespace(layout=SimpleNamespace(dim=dims, data_offset=data_offset), data=values)
    return msg_to_value_function(msg)


def pose_array_bytes(xy, frame_id: str = 'map', sec: int = 0, nanosec: int = 0) -> bytes:
    """A serialized PoseArray of positions ``xy`` (N, 2) (z 0, identity orientations), for
    ``publish``: written from one numpy array (a detector's thousands of points, or a test's
    100,000, without an object per pose)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    name = frame_id.encode('utf-8') + b'\0'
    out = bytearray(_STAMP_LEN.pack(sec, nanosec, len(name)) + name)
    out += bytes(_align(len(out), 4) - len(out)) + _COUNT.pack(len(xy))
    if len(xy):
        out += bytes(_align(len(out), 8) - len(out))
        poses = np.zeros((len(xy), 7), dtype='<f8')
        poses[:, :2], poses[:, 6] = xy, 1.0
        out += poses.tobytes()
    return ENCAPSULATION + bytes(out)


def twist_bytes(linear_x: float, angular_z: float) -> bytes:
    """A serialized Twist with linear.x and angular.z (the rest 0), for ``publish``."""
    return ENCAPSULATION + _TWIST.pack(linear_x, 0.0, 0.0, 0.0, 0.0, angular_z)


def twist_stamped_bytes(sec: int, nanosec: int, frame_id: str, linear_x: float, angular_z: float) -> bytes:
    """A serialized TwistStamped with linear.x and angular.z (the rest 0), for ``publish``."""
    name = frame_id.encode('utf-8') + b'\0'
    out = _STAMP_LEN.pack(sec, nanosec, len(name)) + name
    out += bytes(_align(len(out), 8) - len(out))
    return ENCAPSULATION + out + _TWIST.pack(linear_x, 0.0, 0.0, 0.0, 0.0, angular_z)


_PAD = (b'', b'\0', b'\0\0', b'\0\0\0')


# each string's CDR form (its length, bytes, NUL), kept for the strings that recur: a state's keys,
# its actions and words, every robot's name (a status costs about half as much with them kept)
_ENCODED: dict = {}
_ENCODED_KEPT = 1 << 14       # then it is emptied and filled again (bounded memory, whatever the values)


def _encoded(s: str) -> bytes:
    b = s.encode('utf-8')
    got = _COUNT.pack(len(b) + 1) + b + b'\0'
    if len(_ENCODED) >= _ENCODED_KEPT:
        _ENCODED.clear()
    _ENCODED[s] = got
    return got


def _strings_into(parts: list, offset: int, strings) -> int:
    """Each of ``strings`` appended to ``parts`` as CDR strings from ``offset`` (its length 4-aligned,
    then the bytes and their NUL); the offset after them."""
    get, append = _ENCODED.get, parts.append
    for s in strings:
        got = get(s) or _encoded(s)
        pad = -offset & 3
        if pad:
            append(_PAD[pad])
        append(got)
        offset += pad + len(got)
    return offset


def _status_into(parts: list, offset: int, status) -> int:
    """A diagnostic_msgs/DiagnosticStatus (``status``: ``level`` an int, ``name``, ``message``,
    ``hardware_id``, ``values`` a dict of str; ``encoded``, if it has one, a dict that keeps its
    values' bytes) appended from ``offset``; the offset after it. A status's values are written
    once for each of the four alignments they can start at: a robot's state goes out on its topic,
    in the batched array and on /diagnostics, the same values each time."""
    parts.append(bytes((status.level,)))
    offset = _strings_into(parts, offset + 1, (status.name, status.message, status.hardware_id))
    kept = getattr(status, 'encoded', None)
    got = None if kept is None else kept.get(offset & 3)
    if got is None:
        values, written = status.values, []
        pad = -offset & 3
        written += (_PAD[pad], _COUNT.pack(len(values)))
        _strings_into(written, offset + pad + 4, [s for kv in values.items() for s in kv])
        got = b''.join(written)
        if kept is not None:
            kept[offset & 3] = got
    parts.append(got)
    return offset + len(got)


def diagnostic_status_bytes(status) -> bytes:
    """A serialized diagnostic_msgs/DiagnosticStatus, for ``publish`` (written here: about half
    of what rclpy takes to fill and serialize a typed status of twenty values)."""
    parts = [ENCAPSULATION]
    _status_into(parts, 0, status)
    return b''.join(parts)


def diagnostic_array_bytes(sec: int, nanosec: int, statuses, frame_id: str = '') -> bytes:
    """A serialized diagnostic_msgs/DiagnosticArray of ``statuses`` (as ``diagnostic_status_bytes``)."""
    name = frame_id.encode('utf-8') + b'\0'
    head = _STAMP_LEN.pack(sec, nanosec, len(name)) + name
    offset = len(head)
    pad = -offset & 3
    parts = [ENCAPSULATION, head, _PAD[pad], _COUNT.pack(len(statuses))]
    offset += pad + 4
    for status in statuses:
        offset = _status_into(parts, offset, status)
    return b''.join(parts)
