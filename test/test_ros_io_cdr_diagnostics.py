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


def test_the_strings_kept_stay_bounded_and_every_status_reads_back():
    """Values that never recur (a number per robot per tick) fill the kept strings up to their bound
    at most; a status is the same bytes whether its strings were kept or not."""
    from supersafe_ros.ros_io import cdr
    status = statuses()[0]
    first = diagnostic_status_bytes(status)
    assert diagnostic_status_bytes(status) == first          # its strings kept now
    for i in range(cdr._ENCODED_KEPT + 10):
        made = Status(0, 'r', 'm', 'h', {'x': f'{i * 0.001:.6f}'})
        diagnostic_status_bytes(made)
        assert len(cdr._ENCODED) <= cdr._ENCODED_KEPT
    same(deserialize_message(diagnostic_status_bytes(made), DiagnosticStatus), made)
    assert diagnostic_status_bytes(status) == first


def test_a_states_values_written_once_read_back_under_every_name_and_place():
    """A state's values are serialized once per alignment and kept: copies of it under other names
    (the /diagnostics status of a robot, longer or shorter than its state's) and at other places of an
    array are the bytes of statuses made anew, and read back as made."""
    from supersafe_ros.nodes.filter_diagnostics import status_copy
    state = statuses()[3]
    first = diagnostic_status_bytes(state)
    assert state.encoded, 'its values kept'
    copies = [status_copy(state, 'n' * k, 'h' * (k % 3), 'm' * (2 * k)) for k in range(8)]
    assert all(c.values is state.values and c.encoded is state.encoded for c in copies)
    for made in ([state] + copies, copies[::-1], statuses() + copies):
        kept = diagnostic_array_bytes(3, 4, made)
        assert kept == diagnostic_array_bytes(3, 4, [Status(s.level, s.name, s.message, s.hardware_id,
                                                            dict(s.values)) for s in made])
        msg = deserialize_message(kept, DiagnosticArray)
        for got, status in zip(msg.status, made):
            same(got, status)
    assert len(state.encoded) >= 3, 'several alignments met'
    assert diagnostic_status_bytes(state) == first
