"""State messages written as CDR bytes read back by rclpy as the statuses they were made from."""
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.serialization import deserialize_message

from supersafe_ros.nodes.filter_state import Status
from supersafe_ros.ros_io.cdr import diagnostic_array_bytes, diagnostic_status_bytes


def statuses():
    # string lengths of every residue mod 4 (each next string's alignment differs), empty and
    # non-ASCII strings, no values at all
    return [Status(0, 'robot_0', 'pass: clear', '/robot_0', {'action': 'pass', 'value': '1.5', 'x': ''}),
            Status(1, 'r1', 'override: wall 0.8 m ahead ≤ α', '', {'reason': 'wall ≤ 0.8 m', 'ab': 'abc'}),
            Status(2, '', '', 'hw', {}),
            Status(1, 'a' * 7, 'b' * 6, 'c' * 5, {'k' * n: 'v' * (n + 1) for n in range(1, 9)})]


def same(msg, status):
    assert msg.level == bytes([status.level])
    assert (msg.name, msg.message, msg.hardware_id) == (status.name, status.message, status.hardware_id)
    assert [(kv.key, kv.value) for kv in msg.values] == list(status.values.items())


@pytest.mark.parametrize('k', range(4))
def test_a_status_reads_back_as_made(k):
    status = statuses()[k]
    same(deserialize_message(diagnostic_status_bytes(status), DiagnosticStatus), status)


@pytest.mark.parametrize('frame', ['', 'map', 'odom_x'])
def test_an_array_reads_back_with_its_stamp_and_every_status(frame):
    made = statuses()
    msg = deserialize_message(diagnostic_array_bytes(12, 345, made, frame), DiagnosticArray)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (12, 345, frame)
    assert len(msg.status) == len(made)
    for got, status in zip(msg.status, made):
        same(got, status)
    empty = deserialize_message(diagnostic_array_bytes(1, 2, [], frame), DiagnosticArray)
    assert list(empty.status) == []
