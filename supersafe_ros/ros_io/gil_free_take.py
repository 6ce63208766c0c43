"""Take a serialized message without holding the GIL: rcl called through ctypes.

rclpy's ``take_message(msg_type, raw=True)`` copies the message out of the middleware
while it holds the GIL: about 0.2 s for a 50 MB value function on this 2-core machine
at load 6, and far longer under load, during which no other thread of the process runs
(a filter's watchdog and decisions). Here ``rcl_take_serialized_message`` is called
through ctypes, which releases the GIL for the call, and the bytes are copied into a
numpy buffer the caller owns with ``ctypes.memmove``, also without the GIL; the
middleware's buffer is freed at once.

Kept because it wins clearly over rclpy's public take (``bench/bench_take.py``,
bench/results/take.md, 2026-12-03, 2 shared cores, load 10-22, half of it beside two CPU
burners): a thread of the process sleeping 1 ms at a time stalled 5-56 ms while 50 MB were
taken here, 129-1,793 ms while rclpy took them (22 rounds each); the filter's longest
cmd_vel gap during a 50 MB value function was shorter than with rclpy's take in 24 of 26
pairs (52-103 against 115-179 ms on the quietest round). rclpy's take (``take_path:
public``) is the fallback, which the tests cover too.

This touches rcl's C API directly: ``rcutils_uint8_array_t`` and ``rcutils_allocator_t``
(their layout has not changed since ROS 2 Foxy) and a ``rmw_message_info_t`` written
into a zeroed buffer larger than it (64 bytes in Jazzy). The libraries are the ones
rclpy has loaded. ``GilFreeTaker()`` raises OSError when they or their symbols cannot
be found; ``ros_io.direct_take`` then falls back to its public path, where rclpy takes.
"""
from __future__ import annotations

import ctypes

import numpy as np

RCL_RET_OK = 0
RCL_RET_SUBSCRIPTION_TAKE_FAILED = 401
MESSAGE_INFO_BYTES = 256         # room for rmw_message_info_t (64 bytes in Jazzy)


class _Allocator(ctypes.Structure):
    _fields_ = [('allocate', ctypes.c_void_p), ('deallocate', ctypes.c_void_p),
                ('reallocate', ctypes.c_void_p), ('zero_allocate', ctypes.c_void_p),
                ('state', ctypes.c_void_p)]


class _ErrorString(ctypes.Structure):
    _fields_ = [('str', ctypes.c_char * 1024)]        # rcutils_error_string_t


class _Uint8Array(ctypes.Structure):
    _fields_ = [('buffer', ctypes.c_void_p), ('buffer_length', ctypes.c_size_t),
                ('buffer_capacity', ctypes.c_size_t), ('allocator', _Allocator)]


def _loaded_library(name: str) -> str:
    """The path of ``name`` (e.g. 'librcl.so') as this process has mapped it (rclpy loaded it)."""
    import rclpy.impl.implementation_singleton  # noqa: F401  (loads rcl and rcutils)
    with open('/proc/self/maps') as maps:
        for line in maps:
            path = line.rsplit(None, 1)[-1] if line.count('/') else ''
            if path.rsplit('/', 1)[-1] == name:
                return path
    import ctypes.util
    found = ctypes.util.find_library(name[3:].split('.', 1)[0])
    if found is None:
        raise OSError(f'{name} is not loaded and cannot be found')
    return found


class GilFreeTaker:
    """``take(subscription)``: the next serialized message of an rclpy Subscription as a numpy
    uint8 array (None when there is none), taken and copied with the GIL released."""

    def __init__(self):
        rcl = ctypes.CDLL(_loaded_library('librcl.so'))
        rcutils = ctypes.CDLL(_loaded_library('librcutils.so'))
        self._take = rcl.rcl_take_serialized_message
        self._take.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Uint8Array), ctypes.c_void_p, ctypes.c_void_p]
        self._take.restype = ctypes.c_int32
        self._error = rcutils.rcutils_get_error_string
        self._error.restype = _ErrorString
        self._reset_error = rcutils.rcutils_reset_error
        self._reset_error.restype = None
        self._default_allocator = rcutils.rcutils_get_default_allocator
        self._default_allocator.restype = _Allocator
        self._init = rcutils.rcutils_uint8_array_init
        self._init.argtypes = [ctypes.POINTER(_Uint8Array), ctypes.c_size_t, ctypes.POINTER(_Allocator)]
        self._init.restype = ctypes.c_int32
        self._fini = rcutils.rcutils_uint8_array_fini
        self._fini.argtypes = [ctypes.POINTER(_Uint8Array)]
        self._fini.restype = ctypes.c_int32

    def take(self, subscription):
        """The next message of ``subscription`` (an rclpy Subscription made with raw=True; the
        caller holds its handle), or None if none is waiting."""
        array = _Uint8Array()
        allocator = self._default_allocator()
        if self._init(ctypes.byref(array), 0, ctypes.byref(allocator)) != RCL_RET_OK:
            raise MemoryError('rcutils_uint8_array_init failed')
        info = ctypes.create_string_buffer(MESSAGE_INFO_BYTES)
        try:
            ret = self._take(subscription.handle.pointer, ctypes.byref(array), info, None)
            if ret == RCL_RET_SUBSCRIPTION_TAKE_FAILED:
                self._reset_error()
                return None
            if ret != RCL_RET_OK:
                why = self._error().str.decode(errors='replace')
                self._reset_error()
                raise RuntimeError(f'rcl_take_serialized_message failed ({ret}): {why}')
            out = np.empty(array.buffer_length, dtype=np.uint8)
            if array.buffer_length:
                ctypes.memmove(out.ctypes.data, array.buffer, array.buffer_length)
            return out
        finally:
            self._fini(ctypes.byref(array))
