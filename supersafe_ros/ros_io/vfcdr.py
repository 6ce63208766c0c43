"""A value-function message decoded straight from its serialized (CDR) bytes.

rclpy's ``deserialize_message`` copies a 50 MB Float32MultiArray into a Python
array in one C call that holds the GIL for 0.3 s or more, stalling every other
thread of the process (the filter's control path). The layout of a
std_msgs/Float32MultiArray in little-endian CDR is simple, so the header is read
here in Python and the data is a zero-copy numpy view of the bytes; the checks are
``vfmsg.msg_to_value_function``'s own. Big-endian CDR (never produced on this
machine's architectures) falls back to rclpy.
"""
from __future__ import annotations

import struct
from types import SimpleNamespace

import numpy as np

from .vfmsg import ValueFunctionMessageError, msg_to_value_function

_CDR_LE = b'\x00\x01'


class _Reader:
    def __init__(self, data):
        self.buf = memoryview(data)
        self.pos = 4          # after the encapsulation header; alignment counts from here

    def align(self, n):
        rel = self.pos - 4
        self.pos += (-rel) % n

    def u32(self):
        self.align(4)
        if self.pos + 4 > len(self.buf):
            raise ValueFunctionMessageError('serialized value function is truncated')
        (v,) = struct.unpack_from('<I', self.buf, self.pos)
        self.pos += 4
        return v

    def string(self):
        n = self.u32()
        if n == 0 or self.pos + n > len(self.buf):
            raise ValueFunctionMessageError('serialized value function has a bad string')
        s = bytes(self.buf[self.pos:self.pos + n - 1]).decode('utf-8', errors='replace')
        self.pos += n
        return s


def serialized_to_value_function(data):
    """ValueFunction from the serialized bytes of a /safe_set/value_function message (bytes, or
    a numpy uint8 array as ``ros_io.gil_free_take`` gives; the values are a view of it)."""
    if len(data) < 8:
        raise ValueFunctionMessageError(f'serialized value function of {len(data)} bytes is too short')
    if bytes(data[:2]) != _CDR_LE:
        from rclpy.serialization import deserialize_message
        from std_msgs.msg import Float32MultiArray
        return msg_to_value_function(deserialize_message(bytes(data), Float32MultiArray))
    r = _Reader(data)
    n_dims = r.u32()
    if n_dims > 16:
        raise ValueFunctionMessageError(f'{n_dims} layout dimensions')
    dims = []
    for _ in range(n_dims):
        label = r.string()
        dims.append(SimpleNamespace(label=label, size=r.u32(), stride=r.u32()))
    data_offset = r.u32()
    count = r.u32()
    if r.pos + 4 * count > len(r.buf):
        raise ValueFunctionMessageError(f'serialized value function is truncated: {count} values announced')
    values = np.frombuffer(r.buf, dtype='<f4', count=count, offset=r.pos)
    msg = SimpleNamespace(layout=SimpleNamespace(dim=dims, data_offset=data_offset), data=values)
    return msg_to_value_function(msg)
