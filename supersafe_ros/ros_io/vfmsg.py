"""Value function <-> std_msgs/Float32MultiArray, exact and self-describing.

Message layout (topic ``/safe_set/value_function``):

* ``data``: the float32 values, C order (x slowest, theta fastest), exactly the
  array of the ValueFunction (it is float32 already, so nothing is rounded).
* ``layout.data_offset``: 0.
* ``layout.dim[0..2]``: labels ``x``, ``y``, ``theta``; sizes nx, ny, nth; strides as
  the MultiArrayLayout convention (dim[i].stride = product of sizes i..end), so any
  generic consumer can index the array.
* ``layout.dim[3]``: a singleton axis (size 1, stride 1) whose *label* carries the
  metadata as JSON — Float32MultiArray has no string field, and a second topic
  would need pairing and could be seen half-updated. The JSON holds at least::

      {"format": "supersafe_ros/value_function/1",
       "grid": {"lo": [xmin, ymin], "hi": [xmax, ymax], "shape": [nx, ny, nth]},
       "theta_nodes": "-pi + k 2pi/nth",
       ... the value function's meta (speed, omega_max, radius, horizon, ...)
       ... and the publisher's extras (source, mu, sigma, alpha, estimator, ...)}

The grid is self-described by lo/hi/shape (x and y nodes include both ends,
theta periodic), so a subscriber needs no shared configuration.
"""
from __future__ import annotations

import array
import json
import math

import numpy as np
from std_msgs.msg import Float32MultiArray, MultiArrayDimension

from ..reach.grid import Grid
from ..reach.value_function import ValueFunction

FORMAT = 'supersafe_ros/value_function/1'
AXES = ('x', 'y', 'theta')
META_AXIS = 3
MAX_VALUES = 64 * 1024 * 1024   # refuse absurd sizes before allocating (256 MB of float32)


class ValueFunctionMessageError(ValueError):
    """A value-function message that cannot be used, with the reason."""


def _jsonable(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, float) and not math.isfinite(v):
        return None   # JSON has no NaN; absent values become null
    return v


def value_function_to_msg(vf: ValueFunction, **extra) -> Float32MultiArray:
    """Message carrying ``vf`` exactly, with its grid, meta and ``extra`` as JSON."""
    values = np.ascontiguousarray(vf.values, dtype=np.float32)
    nx, ny, nth = values.shape
    meta = {k: _jsonable(v) for k, v in vf.meta.items()}
    meta.update({k: _jsonable(v) for k, v in extra.items()})
    meta['format'] = FORMAT
    meta['grid'] = vf.grid.to_dict()
    meta['theta_nodes'] = '-pi + k 2pi/nth'
    msg = Float32MultiArray()
    msg.layout.data_offset = 0
    msg.layout.dim = [
        MultiArrayDimension(label='x', size=nx, stride=nx * ny * nth),
        MultiArrayDimension(label='y', size=ny, stride=ny * nth),
        MultiArrayDimension(label='theta', size=nth, stride=nth),
        MultiArrayDimension(label=json.dumps(meta, sort_keys=True, default=str), size=1, stride=1),
    ]
    # array('f') from the raw bytes: rclpy accepts it without a per-element check
    msg.data = array.array('f', values.tobytes())
    return msg


def msg_metadata(msg: Float32MultiArray) -> dict:
    """The JSON metadata of a value-function message (validated layout, not the data)."""
    dims = list(msg.layout.dim)
    if len(dims) != 4:
        raise ValueFunctionMessageError(f'expected 4 layout dimensions (x, y, theta, meta), got {len(dims)}')
    labels = tuple(d.label for d in dims[:3])
    if labels != AXES:
        raise ValueFunctionMessageError(f'layout labels are {labels}, expected {AXES}')
    try:
        meta = json.loads(dims[META_AXIS].label)
    except ValueError as exc:
        raise ValueFunctionMessageError(f'metadata label is not JSON: {exc}') from None
    if not isinstance(meta, dict) or meta.get('format') != FORMAT:
        raise ValueFunctionMessageError(f"metadata has no format '{FORMAT}'")
    return meta


def msg_to_value_function(msg: Float32MultiArray) -> ValueFunction:
    """ValueFunction from a message; raises ValueFunctionMessageError with the reason.

    Checks: layout (4 dims, labels, strides, offset 0), the grid in the metadata
    (finite, hi > lo, shape matching the layout sizes), the number of values, and
    that every value is finite.
    """
    meta = msg_metadata(msg)
    dims = list(msg.layout.dim)
    sizes = [int(d.size) for d in dims[:3]]
    if min(sizes) < 1 or math.prod(sizes) > MAX_VALUES:
        raise ValueFunctionMessageError(f'layout sizes {sizes} are empty or too large')
    expected_strides = [sizes[0] * sizes[1] * sizes[2], sizes[1] * sizes[2], sizes[2]]
    strides = [int(d.stride) for d in dims[:3]]
    if strides != expected_strides or int(dims[META_AXIS].size) != 1:
        raise ValueFunctionMessageError(f'layout strides {strides} are not C order {expected_strides}')
    if int(msg.layout.data_offset) != 0:
        raise ValueFunctionMessageError(f'data_offset must be 0, got {msg.layout.data_offset}')
    try:
        grid = Grid.from_dict(meta['grid'])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueFunctionMessageError(f'metadata grid is invalid: {exc}') from None
    if list(grid.shape) != sizes:
        raise ValueFunctionMessageError(f'metadata grid shape {list(grid.shape)} != layout sizes {sizes}')
    values = np.frombuffer(msg.data, dtype=np.float32) if isinstance(msg.data, array.array) \
        else np.asarray(msg.data, dtype=np.float32)
    if values.size != math.prod(sizes):
        raise ValueFunctionMessageError(f'{values.size} values for a grid of {sizes} '
                                        f'({math.prod(sizes)} expected)')
    if not np.all(np.isfinite(values)):
        raise ValueFunctionMessageError(f'{int(np.sum(~np.isfinite(values)))} values are NaN or infinite')
    for key in ('omega_max', 'speed', 'radius', 'alpha', 'mu', 'sigma'):
        v = meta.get(key)
        if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)):
            raise ValueFunctionMessageError(f'metadata {key}={v!r} is not a finite number')
    vf_meta = {k: v for k, v in meta.items() if k not in ('format', 'grid', 'theta_nodes')}
    return ValueFunction(grid, values.reshape(sizes).copy(), vf_meta)
