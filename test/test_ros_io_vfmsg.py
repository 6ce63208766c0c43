"""Value function <-> std_msgs/Float32MultiArray (supersafe_ros.ros_io.vfmsg): exact and validated."""
import array
import json

import numpy as np
import pytest

from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.value_function import ValueFunction
from supersafe_ros.ros_io.vfmsg import (ValueFunctionMessageError, msg_metadata, msg_to_value_function,
                                        value_function_to_msg)


def make_vf(shape=(9, 7, 6)):
    rng = np.random.default_rng(1)
    # awkward float32 values (denormals, huge, tiny): any quantisation would show
    values = rng.standard_normal(shape).astype(np.float32) * np.float32(1e3)
    values.flat[0] = np.float32(1e-42)
    values.flat[1] = np.float32(3.4e38)
    return ValueFunction(Grid((-8.0, -7.5), (8.25, 7.0), shape), values,
                         {'speed': 3.0, 'omega_max': 0.375, 'radius': 1.8, 'horizon': 3.0})


def test_round_trip_is_exact_and_self_describing():
    vf = make_vf()
    msg = value_function_to_msg(vf, source='learned', mu=0.25, sigma=0.5, alpha=0.25, estimator='paper',
                                interventions=12)
    assert [d.label for d in msg.layout.dim[:3]] == ['x', 'y', 'theta']
    assert [d.size for d in msg.layout.dim[:3]] == [9, 7, 6]
    assert [d.stride for d in msg.layout.dim[:3]] == [9 * 7 * 6, 7 * 6, 6]
    back = msg_to_value_function(msg)
    assert back.grid == vf.grid
    assert back.values.dtype == np.float32
    assert np.array_equal(back.values.view(np.uint32), vf.values.view(np.uint32))   # bit for bit
    assert back.meta['omega_max'] == 0.375 and back.meta['mu'] == 0.25 and back.meta['source'] == 'learned'
    meta = msg_metadata(msg)
    assert meta['grid'] == {'lo': [-8.0, -7.5], 'hi': [8.25, 7.0], 'shape': [9, 7, 6]}


def test_round_trip_through_serialisation():
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Float32MultiArray
    vf = make_vf()
    raw = serialize_message(value_function_to_msg(vf, source='standard'))
    back = msg_to_value_function(deserialize_message(raw, Float32MultiArray))
    assert np.array_equal(back.values, vf.values)


def _broken(mutate):
    msg = value_function_to_msg(make_vf(), source='learned')
    mutate(msg)
    return msg


def _set_meta(msg, **kw):
    meta = json.loads(msg.layout.dim[3].label)
    meta.update(kw)
    msg.layout.dim[3].label = json.dumps(meta)


@pytest.mark.parametrize('what,mutate', [
    ('nan value', lambda m: m.data.__setitem__(5, float('nan'))),
    ('inf value', lambda m: m.data.__setitem__(0, float('inf'))),
    ('too few values', lambda m: setattr(m, 'data', m.data[:-1])),
    ('empty', lambda m: setattr(m, 'data', array.array('f'))),
    ('3 dims', lambda m: setattr(m.layout, 'dim', m.layout.dim[:3])),
    ('label', lambda m: setattr(m.layout.dim[0], 'label', 'y')),
    ('stride', lambda m: setattr(m.layout.dim[1], 'stride', 1)),
    ('size', lambda m: setattr(m.layout.dim[2], 'size', 5)),
    ('zero size', lambda m: setattr(m.layout.dim[2], 'size', 0)),
    ('offset', lambda m: setattr(m.layout, 'data_offset', 3)),
    ('not json', lambda m: setattr(m.layout.dim[3], 'label', '{oops')),
    ('format', lambda m: _set_meta(m, format='other')),
    ('grid hi<lo', lambda m: _set_meta(m, grid={'lo': [8, 8], 'hi': [-8, -8], 'shape': [9, 7, 6]})),
    ('grid nan', lambda m: _set_meta(m, grid={'lo': [float('nan'), 0], 'hi': [8, 8], 'shape': [9, 7, 6]})),
    ('grid shape', lambda m: _set_meta(m, grid={'lo': [-8, -8], 'hi': [8, 8], 'shape': [9, 7, 7]})),
    ('grid missing', lambda m: _set_meta(m, grid=None)),
    ('omega nan', lambda m: _set_meta(m, omega_max=float('nan'))),
    ('alpha string', lambda m: _set_meta(m, alpha='high')),
])
def test_malformed_messages_are_rejected_with_a_reason(what, mutate):
    with pytest.raises(ValueFunctionMessageError) as exc:
        msg_to_value_function(_broken(mutate))
    assert str(exc.value)
