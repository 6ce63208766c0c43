"""The fleet node reads batched poses straight from the CDR buffer; it must read exactly what
rclpy's deserialization and ``posearray_to_states`` read (states bit for bit, the same bad
rows and reasons, the same stamp, the same rejections)."""
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from diagnostic_msgs.msg import DiagnosticStatus

from supersafe_ros.ros_io import fleetmsg, rosmsg
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


def test_refilled_state_status_equals_a_new_one():
    """A robot's state status is refilled in place (the fleet node's periodic states): it must
    read back (serialized) exactly as a new one, whether the keys stay or change."""
    rng = np.random.default_rng(3)
    keys = [f'k{i}' for i in range(19)]
    status = rosmsg.make_diagnostic('r0', {k: 'x' for k in keys}, 'start', 0)
    for trial in range(30):
        ks = keys if trial % 3 else keys[:int(rng.integers(1, 19))] + ['extra']
        values = {k: rng.choice(['pass', 1.5, -3, float('nan'), '']) for k in ks}
        level, message = int(rng.integers(0, 3)), f'm{trial}'
        status = rosmsg.refill_diagnostic(status, f'r{trial}', values, message, level)
        fresh = rosmsg.make_diagnostic(f'r{trial}', values, message, level)
        a, b = (deserialize_message(serialize_message(m), DiagnosticStatus) for m in (status, fresh))
        assert (a.level, a.name, a.message, a.hardware_id) == (b.level, b.name, b.message, b.hardware_id)
        assert [(kv.key, kv.value) for kv in a.values] == [(kv.key, kv.value) for kv in b.values]
