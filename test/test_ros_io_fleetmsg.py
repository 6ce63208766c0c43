"""The fleet node reads batched poses straight from the CDR buffer; it must read exactly what
rclpy's deserialization and ``posearray_to_states`` read (states bit for bit, the same bad
rows and reasons, the same stamp, the same rejections)."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from diagnostic_msgs.msg import DiagnosticStatus

from supersafe_ros.nodes.filter_state import Status
from supersafe_ros.ros_io import cdr, fleetmsg, rosmsg
from supersafe_ros.ros_io.rosmsg import MessageError


def message(rng, n, frame):
    msg = rosmsg.xy_to_posearray(rng.uniform(-50, 50, (n, 2)))
    msg.header.frame_id = frame
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(rng.integers(0, 2**31)), int(rng.integers(0, 10**9))
    for p in msg.poses:
        q = rng.normal(size=4) * rng.choice([1.0, 1e-3, 1e3])
        p.position.z = float(rng.normal())
        p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = (float(v) for v in q)
        r = rng.random()
        if r < 0.05:
            p.position.x = float('nan')
        elif r < 0.1:
            p.orientation.w = float('inf')
        elif r < 0.15:
            p.orientation.x = p.orientation.y = p.orientation.z = p.orientation.w = 0.0
    return msg


@pytest.mark.parametrize('frame', ['map', '', 'm', 'mapp', 'a_longer_frame_name', 'map7chr'])
def test_cdr_poses_read_as_rclpy_reads_them(frame):
    rng = np.random.default_rng(len(frame))
    for n in (0, 1, 3, 50):
        msg = message(rng, n, frame)
        data = serialize_message(msg)
        for expect_frame in ('map', None):
            try:
                want = fleetmsg.posearray_to_states(msg, n, expect_frame)
            except MessageError as exc:
                with pytest.raises(MessageError, match=str(exc).replace('(', r'\(').replace(')', r'\)')):
                    fleetmsg.posearray_cdr_to_states(data, n, expect_frame)
                continue
            states, bad, stamp = fleetmsg.posearray_cdr_to_states(data, n, expect_frame)
            assert states.tobytes() == want[0].tobytes() and bad == want[1]
            assert (stamp.sec, stamp.nanosec) == (msg.header.stamp.sec, msg.header.stamp.nanosec)
        with pytest.raises(MessageError, match='for'):
            fleetmsg.posearray_cdr_to_states(data, n + 1, None)


def test_truncated_or_foreign_buffers():
    msg = message(np.random.default_rng(0), 5, 'map')
    data = serialize_message(msg)
    with pytest.raises(MessageError, match='not a serialized PoseArray'):
        fleetmsg.posearray_cdr_to_states(data[:-8], 5)


def test_a_serialized_state_reads_back_as_a_typed_one():
    """A robot's state is written as CDR bytes (ros_io.cdr, the fleet node's hundreds a tick): it
    must read back exactly as the typed status of the same fields, whatever its keys and values."""
    rng = np.random.default_rng(3)
    keys = [f'k{i}' for i in range(19)]
    for trial in range(30):
        ks = keys if trial % 3 else keys[:int(rng.integers(1, 19))] + ['extra']
        values = {k: str(rng.choice(['pass', 1.5, -3, float('nan'), '', 'ünï'])) for k in ks}
        level, message = int(rng.integers(0, 3)), f'm{trial}' * int(rng.integers(0, 4))
        status = Status(level, f'r{trial}', message, f'/r{trial}'[:int(rng.integers(0, 4))], values)
        typed = rosmsg.make_diagnostic(status.name, values, message, level)
        typed.hardware_id = status.hardware_id
        a = deserialize_message(cdr.diagnostic_status_bytes(status), DiagnosticStatus)
        b = deserialize_message(serialize_message(typed), DiagnosticStatus)
        assert (a.level, a.name, a.message, a.hardware_id) == (b.level, b.name, b.message, b.hardware_id)
        assert [(kv.key, kv.value) for kv in a.values] == [(kv.key, kv.value) for kv in b.values]


# -- the per-robot topics, taken serialized (ros_io.cdr) ------------------------------------------
FRAMES = ['map', '', 'm', 'mapp', 'map7chr', 'a_longer_frame_name', 'kart\u00e9']


def _same_outcome(read, msg, view):
    """``read`` gives the same value (bit for bit) or the same MessageError for the message and
    for the view of its serialized bytes."""
    try:
        want = read(msg)
    except MessageError as exc:
        with pytest.raises(MessageError) as got:
            read(view)
        assert str(got.value) == str(exc)
        return 'rejected'
    have = read(view)
    assert np.asarray(have, dtype=float).tobytes() == np.asarray(want, dtype=float).tobytes()
    return 'read'


def _odd_floats(rng, k):
    """k floats, some NaN, inf, zero or huge."""
    v = rng.normal(size=k) * rng.choice([1.0, 1e-3, 1e3, 1e300])
    for i in range(k):
        r = rng.random()
        v[i] = float('nan') if r < 0.05 else float('-inf') if r < 0.1 else 0.0 if r < 0.2 else v[i]
    return [float(x) for x in v]


def test_pose_stamped_view_reads_as_the_message():
    from geometry_msgs.msg import PoseStamped
    from supersafe_ros.ros_io import cdr
    rng = np.random.default_rng(11)
    outcomes = set()
    for trial in range(400):
        msg = PoseStamped()
        msg.header.frame_id = FRAMES[trial % len(FRAMES)]
        msg.header.stamp.sec, msg.header.stamp.nanosec = int(rng.integers(-2**31, 2**31)), int(rng.integers(0, 10**9))
        p, q = msg.pose.position, msg.pose.orientation
        p.x, p.y, p.z, q.x, q.y, q.z, q.w = _odd_floats(rng, 7)
        if trial % 4 == 0:
            q.x = q.y = q.z = q.w = 0.0
        view = cdr.pose_stamped(serialize_message(msg))
        frame_id, stamp, v = view
        assert (stamp.sec, stamp.nanosec) == (msg.header.stamp.sec, msg.header.stamp.nanosec)
        assert v == (p.x, p.y, p.z, q.x, q.y, q.z, q.w) or np.isnan(v).any()
        for frame in ('map', None):
            outcomes.add(_same_outcome(lambda m: rosmsg.pose_to_state(m, frame) if m is msg else rosmsg.planar_state(
                m[0], m[2][0], m[2][1], m[2][3], m[2][4], m[2][5], m[2][6], frame), msg, view))
    assert outcomes == {'read', 'rejected'}


def test_pose_array_and_twist_views_read_as_the_messages():
    from geometry_msgs.msg import Twist
    from supersafe_ros.ros_io import cdr
    rng = np.random.default_rng(12)
    outcomes = set()
    for trial in range(200):
        n = int(rng.integers(0, 6))
        msg = rosmsg.xy_to_posearray(rng.uniform(-50, 50, (n, 2)))
        msg.header.frame_id = FRAMES[trial % len(FRAMES)]
        for pose in msg.poses:
            pose.position.x, pose.position.y, pose.position.z = _odd_floats(rng, 3)
        view = cdr.pose_array(serialize_message(msg))
        assert len(view.poses) == n
        for frame in ('map', None):
            outcomes.add(_same_outcome(lambda m: rosmsg.posearray_to_xy(m, frame), msg, view))
        cmd = Twist()
        cmd.linear.x, cmd.linear.y, cmd.linear.z, cmd.angular.x, cmd.angular.y, cmd.angular.z = _odd_floats(rng, 6)
        outcomes.add(_same_outcome(rosmsg.twist_turn_rate, cmd, cdr.twist(serialize_message(cmd))))
    assert outcomes == {'read', 'rejected'}


def test_twist_bytes_deserialize_to_the_twist():
    from geometry_msgs.msg import Twist
    from supersafe_ros.ros_io import cdr
    for lin, ang in ((3.0, -1.0), (0.0, 0.0), (-0.0, 1e-300), (2.5, float('inf'))):
        data = cdr.twist_bytes(lin, ang)
        msg = deserialize_message(data, Twist)
        assert (msg.linear.x, msg.angular.z) == (lin, ang)
        assert (msg.linear.y, msg.linear.z, msg.angular.x, msg.angular.y) == (0.0,) * 4
        ref = Twist()
        ref.linear.x, ref.angular.z = lin, ang
        assert data == serialize_message(ref)


def test_views_reject_truncated_bytes_and_read_other_encodings():
    import struct
    from supersafe_ros.ros_io import cdr
    msg = rosmsg.state_to_pose((1.0, 2.0, 0.5))
    data = serialize_message(msg)
    for cut in (8, 20, len(data) - 8):
        with pytest.raises(MessageError, match='not a serialized'):
            cdr.pose_stamped(data[:cut])
    arr = serialize_message(rosmsg.xy_to_posearray([(1.0, 2.0), (3.0, 4.0)]))
    with pytest.raises(MessageError, match='not a serialized'):
        cdr.pose_array(arr[:-8])
    with pytest.raises(MessageError, match='not a serialized'):
        cdr.twist(cdr.twist_bytes(1.0, 2.0)[:-1])
    # big-endian CDR (encapsulation 00 00): handed to rclpy
    big = b'\x00\x00\x00\x00' + struct.pack('>6d', 3.0, 0.0, 0.0, 0.0, 0.0, -0.5)
    assert rosmsg.twist_turn_rate(cdr.twist(big)) == -0.5
    frame_id, stamp, values = cdr.pose_stamped(data)
    assert (frame_id, values[:2]) == ('map', (1.0, 2.0))


def test_pose_array_positions_read_as_one_array_and_written_back():
    """``cdr.pose_array_xy`` reads a PoseArray's positions as rclpy does (truncated bytes are
    refused, other encodings handed to rclpy); ``cdr.pose_array_bytes`` writes one that rclpy
    reads back (100,000 poses: no object per pose either way)."""
    from geometry_msgs.msg import PoseArray
    from supersafe_ros.ros_io import cdr
    rng = np.random.default_rng(13)
    for n in (0, 1, 2, 7, 2000, 100_000):
        for frame in (FRAMES if n < 100_000 else FRAMES[:1]):
            xy = rng.uniform(-1e4, 1e4, (n, 2))
            msg = rosmsg.xy_to_posearray(xy[:50], frame=frame) if n <= 50 else None
            data = cdr.pose_array_bytes(xy, frame, 12, 345)
            if n == 100_000:        # (rclpy takes seconds to build 100,000 poses: read back by ours only)
                assert np.array_equal(cdr.pose_array_xy(data)[1], xy)
                continue
            back = deserialize_message(data, PoseArray)
            assert (back.header.frame_id, back.header.stamp.sec, back.header.stamp.nanosec) == (frame, 12, 345)
            assert len(back.poses) == n
            if n:
                i = int(rng.integers(n))
                p = back.poses[i]
                assert (p.position.x, p.position.y, p.position.z, p.orientation.w) == (*xy[i], 0.0, 1.0)
            header, got = cdr.pose_array_xy(data)
            assert header.frame_id == frame and np.array_equal(got, xy) and got.flags.writeable
            if msg is not None:
                header, got = cdr.pose_array_xy(serialize_message(msg))
                assert np.array_equal(got, rosmsg.posearray_to_xy(msg, None))
    with pytest.raises(MessageError, match='detections is not a serialized PoseArray'):
        cdr.pose_array_xy(cdr.pose_array_bytes(np.ones((3, 2)))[:-8], 'detections')
    import struct
    big_endian = b'\x00\x00\x00\x00' + struct.pack('>iII', 0, 0, 4) + b'map\x00' + struct.pack('>I', 0)
    assert cdr.pose_array_xy(big_endian)[1].shape == (0, 2)
