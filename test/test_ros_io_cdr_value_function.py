"""Value functions decoded from serialized bytes agree with rclpy's decoding, bit for bit."""
import numpy as np
import pytest
from rclpy.serialization import serialize_message

from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.value_function import ValueFunction
from supersafe_ros.ros_io.cdr import serialized_to_value_function
from supersafe_ros.ros_io.vfmsg import ValueFunctionMessageError, msg_to_value_function, value_function_to_msg


def message(shape=(9, 7, 6), seed=0, **extra):
    grid = Grid((-3.0, -2.0), (3.0, 2.5), shape)
    values = np.random.default_rng(seed).normal(size=shape).astype(np.float32)
    return value_function_to_msg(ValueFunction(grid, values, {'omega_max': 0.75, 'speed': 3.0}), **extra)


@pytest.mark.parametrize('shape', [(9, 7, 6), (2, 2, 3), (5, 5, 5)])
def test_serialized_decoding_matches_rclpy(shape):
    msg = message(shape, source='learned', mu=0.3, sigma=0.1, label='ünïcode')
    got = serialized_to_value_function(serialize_message(msg))
    ref = msg_to_value_function(msg)
    assert got.grid == ref.grid and got.meta == ref.meta
    assert np.array_equal(got.values.view(np.uint32), ref.values.view(np.uint32))


def test_bad_serialized_messages_are_refused_with_a_reason():
    msg = message(source='learned')
    data = serialize_message(msg)
    with pytest.raises(ValueFunctionMessageError, match='truncated'):
        serialized_to_value_function(data[:len(data) // 2])
    msg.data[3] = float('nan')
    with pytest.raises(ValueFunctionMessageError, match='NaN'):
        serialized_to_value_function(serialize_message(msg))
    with pytest.raises(ValueFunctionMessageError):
        serialized_to_value_function(b'\x00\x01\x00\x00')
