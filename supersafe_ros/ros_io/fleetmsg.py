"""The batched fleet interface's messages <-> numpy (standard message types only).

Robot order: the ``robots`` parameter of fleet_safety_filter_node; row i is robot i.

* poses in, ``fleet/poses``: geometry_msgs/PoseArray, header.frame_id ``map``,
  header.stamp = the time the poses describe; ``poses[i]`` = robot i (planar: x, y and
  the yaw of the orientation). Exactly N poses.
* commands, ``fleet/cmd_vel_nav`` in and ``fleet/cmd_vel`` out:
  std_msgs/Float64MultiArray of N x 2 rows [linear.x, angular.z] (C order, data length
  2N), layout dim[0] = ('robot', N, 2N), dim[1] = ('linear_x,angular_z', 2, 2). On
  input the layout may be left empty; if given it must say N x 2.

Bad input raises ``MessageError`` for the whole message (wrong frame or size) or is
reported per row (``bad``: a reason per robot, '' if the row is usable).
"""
from __future__ import annotations

import array

import numpy as np

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseArray
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from . import cdr
from .rosmsg import MAP_FRAME, MessageError

COMMAND_COLUMNS = 'linear_x,angular_z'


def posearray_to_states(msg: PoseArray, n: int, frame: str | None = MAP_FRAME):
    """(states (N, 3), bad [N] reasons) of a fleet pose message with exactly ``n`` poses."""
    if frame is not None and msg.header.frame_id != frame:
        raise MessageError(f"fleet poses frame is '{msg.header.frame_id}', expected '{frame}'")
    if len(msg.poses) != n:
        raise MessageError(f'fleet poses has {len(msg.poses)} poses for {n} robots (order: the robots '
                           f'parameter)')
    a = np.array([(p.position.x, p.position.y, p.orientation.x, p.orientation.y, p.orientation.z,
                   p.orientation.w) for p in msg.poses], dtype=float).reshape(n, 6)
    return _planar_states(a, n)


def posearray_cdr_to_states(data: bytes, n: int, frame: str | None = MAP_FRAME):
    """(states (N, 3), bad [N] reasons, header stamp) of a *serialized* fleet pose message
    (a raw subscription's bytes), as ``posearray_to_states`` gives for the message.

    rclpy spends ~10 us per pose building Pose objects (10 ms for 1,000 robots, half a
    50 Hz tick); the poses are read here straight from the CDR buffer instead, as one
    (N, 7) array (layout: ``ros_io.cdr``). Any other encapsulation is deserialized by rclpy.
    """
    body = cdr.body(data)
    if body is not None:
        header, count, off = cdr.pose_array_layout(body, 'fleet poses')
        if frame is not None and header.frame_id != frame:
            raise MessageError(f"fleet poses frame is '{header.frame_id}', expected '{frame}'")
        if count != n:
            raise MessageError(f'fleet poses has {count} poses for {n} robots (order: the robots '
                               f'parameter)')
        poses = (np.frombuffer(body, dtype='<f8', count=7 * count, offset=off).reshape(count, 7) if count
                 else np.zeros((0, 7)))
        states, bad = _planar_states(poses[:, [0, 1, 3, 4, 5, 6]].astype(float), n)
        return states, bad, Time(sec=header.stamp.sec, nanosec=header.stamp.nanosec)
    from rclpy.serialization import deserialize_message
    msg = deserialize_message(bytes(data), PoseArray)
    states, bad = posearray_to_states(msg, n, frame)
    return states, bad, msg.header.stamp


def _planar_states(a, n):
    """(states (N, 3), bad reasons) of rows [x, y, qx, qy, qz, qw]."""
    x, y, qx, qy, qz, qw = a.T
    norm = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    with np.errstate(invalid='ignore', divide='ignore'):
        qx, qy, qz, qw = qx / norm, qy / norm, qz / norm, qw / norm
        yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    states = np.stack([x, y, yaw], axis=1)
    finite = np.all(np.isfinite(a), axis=1)
    bad = [''] * n
    for i in np.flatnonzero(~finite | (norm < 1e-9)):
        bad[int(i)] = (f'pose {int(i)} is not finite {a[i].tolist()}' if not finite[i]
                       else f'pose {int(i)} has a zero quaternion')
    return states, bad


def commands_to_msg(commands) -> Float64MultiArray:
    """Float64MultiArray for an (N, 2) array of [linear.x, angular.z]."""
    c = np.ascontiguousarray(commands, dtype=np.float64).reshape(-1, 2)
    n = len(c)
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label='robot', size=n, stride=2 * n),
                      MultiArrayDimension(label=COMMAND_COLUMNS, size=2, stride=2)]
    msg.data = array.array('d', c.tobytes())   # no per-element conversion in rclpy
    return msg


def msg_to_commands(msg: Float64MultiArray, n: int):
    """(commands (N, 2), bad [N] reasons) of a fleet command message for ``n`` robots."""
    dims = [(d.size, d.stride) for d in msg.layout.dim]
    if dims and dims != [(n, 2 * n), (2, 2)]:
        raise MessageError(f'fleet commands layout {dims} is not {n} robots x 2 '
                           f'({COMMAND_COLUMNS})')
    data = np.asarray(msg.data, dtype=float)
    if data.size != 2 * n:
        raise MessageError(f'fleet commands has {data.size} values for {n} robots x 2 ({COMMAND_COLUMNS})')
    c = data.reshape(n, 2)
    bad = [''] * n
    for i in np.flatnonzero(~np.isfinite(c[:, 1])):
        bad[int(i)] = f'command {int(i)} angular.z is not finite ({c[i, 1]})'
    return c, bad
