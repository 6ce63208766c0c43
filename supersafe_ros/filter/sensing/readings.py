"""What one range-sensor message says, checked: a scan's beams as REP 117 readings, a cloud's points, the pose.

These are pure functions over a message's fields (plain Python and numpy values, no rclpy); the
filter's local map (``filter.sensing.local_map``) takes what they return.

**A laser scan** (``scan_rays``). Beam i points at a_i = angle_min + i angle_increment in the
sensor's frame and reads r_i. REP 117 says what a reading means, and so what it tells the map:

    finite r in [range_min, range_max]   a return: free space on [0, r), an object at r
    -inf                                 an object closer than range_min: free on [0, range_min),
                                         an object taken at range_min
    +inf                                 no return within range: free on [0, range_max) when the
                                         driver says so (``inf_is_valid``, as Nav2's), else nothing
    NaN                                  an erroneous measurement: nothing
    finite r < range_min (or negative)   nothing (the sensor's own blind zone, or junk)
    finite r > range_max                 a beam that did not come back: nothing

So each beam has a clear length (0: clears nothing) and maybe a mark at ``mark_range``; a beam
that says nothing never clears what an earlier scan saw (a scan of NaNs is not "nothing there").
Counts of each kind come with the beams, and ``Rays.problem()`` says in words when a scan looks
wrong (more than a quarter of its beams NaN or below range_min, or not one usable reading).

A scan whose geometry is not a scan is refused (ValueError naming the fault and its values):
more beams than ``max_beams`` (checked before the ranges are read), angles or range limits not
finite, angle_increment 0, range_min < 0 or > range_max, a beam count that disagrees with the
angles (|(angle_max - angle_min) / angle_increment + 1 - len(ranges)| > 1.5), or angles that span
more than 2 pi + one increment. A clockwise scan is accepted: angle_increment < 0 iff angle_max <
angle_min (a positive increment needs angle_max >= angle_min); its beams are at angle_min + i
angle_increment like any scan's, so their angles descend, and nothing else changes.

**A point cloud** (``cloud_xy``): the finite x, y of a PointCloud2's points in its frame (z
ignored). Its layout must be exactly what it declares: x and y FLOAT32 (7) or FLOAT64 (8), every
field inside a point (0 <= offset, offset + size x count <= point_step), x and y apart,
point_step > 0, row_step = point_step x width and len(data) = row_step x height. The last two
catch a sender whose point_step (say 12) is not the stride it wrote (16): with row_step 12 n and
16 n bytes the length is wrong, with row_step 16 n the rows are. Either byte order. A point whose
x or y is not finite is dropped and counted (``CloudPoints.dropped``).

**The pose at a message's stamp** (``interpolated_pose``). Between the two received poses that
bracket the stamp t (t0 <= t <= t1), when both are within ``max_gap`` of it, the pose is the
linear interpolation with w = (t - t0) / (t1 - t0):

    x = x0 + w (x1 - x0),  y = y0 + w (y1 - y0),  theta = theta0 + w wrap(theta1 - theta0)

and its gap is 0 (trusted as exact, as tf trusts its interpolation). Its error on a path of
acceleration at most a and heading rate change at most b between the stamps is at most
a (t1 - t0)^2 / 8 in position and b (t1 - t0)^2 / 8 in heading (linear interpolation's bound); a
Dubins car at speed v turning at omega has a = v omega and b = 0: on a 3 m/s, 1 rad/s arc with
poses 0.1 s apart, 3.75 mm and no heading error. Otherwise the pose is the nearest received one
and the gap |its stamp - t| (the caller inflates by the motion possible in that time); (None, inf)
with no pose.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import NamedTuple

import numpy as np

MAX_BEAMS_DEFAULT = 1_000_000
MAX_POINTS_DEFAULT = 1_000_000
POINT_FIELD_SIZES = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 8: 8}    # PointField INT8 .. FLOAT64
FLOAT_FIELDS = {7: 'f4', 8: 'f8'}                                         # FLOAT32, FLOAT64


@dataclass(frozen=True, eq=False)
class Rays:
    """One scan's beams as REP 117 readings (``scan_rays``): per beam its angle in the sensor's frame,
    the length it clears (0: none), whether it marks and where (``mark_range``, 0 where it does not),
    and the counts of each kind of reading."""

    angles: np.ndarray
    clear: np.ndarray
    mark: np.ndarray
    mark_range: np.ndarray
    returns: int
    near_objects: int
    no_return: int
    erroneous: int
    below_min: int
    beyond_max: int
    beams: int
    inf_is_valid: bool = False
    range_min: float = 0.0
    range_max: float = math.inf

    def counts(self) -> dict:
        """The counts by kind, for a view summary."""
        kinds = ('beams', 'returns', 'near_objects', 'no_return', 'erroneous', 'below_min', 'beyond_max')
        return {k: getattr(self, k) for k in kinds}

    @property
    def usable(self) -> int:
        """Beams that put something into the map: returns, objects closer than range_min, and with
        ``inf_is_valid`` the beams that saw nothing within range_max."""
        return self.returns + self.near_objects + (self.no_return if self.inf_is_valid else 0)

    @property
    def faulty(self) -> bool:
        """No beam, or every beam an erroneous measurement (NaN) or below range_min (negative ones too):
        the sensor did not look. (A scan of beams that did not come back, +inf or beyond range_max,
        looked and saw nothing within its range: it is not faulty, though it clears nothing unless the
        driver says +inf is valid.)"""
        return self.beams == 0 or self.erroneous + self.below_min == self.beams

    def problem(self) -> str:
        """A plain-words note when the scan looks wrong ('' when it is fine): more than a quarter of
        its beams NaN or below range_min, or beams but not one usable reading, or no beams at all."""
        n = self.beams
        if n == 0:
            return 'the scan has no beams: it says nothing'
        bad = []
        if self.erroneous:
            bad.append(f'{self.erroneous} of {n} beams NaN (erroneous measurements, REP 117)')
        if self.below_min:
            bad.append(f'{self.below_min} of {n} beams below range_min {self.range_min:g}')
        if 4 * (self.erroneous + self.below_min) > n:
            return ' and '.join(bad) + ': they clear nothing'
        if 4 * self.near_objects > n:
            return (f'{self.near_objects} of {n} beams -inf (objects closer than range_min {self.range_min:g}, '
                    'REP 117): marked there')
        if self.usable > 0:
            return ''
        kinds = []
        if self.no_return:
            kinds.append(f'{self.no_return} +inf (no return within range_max; inf_is_valid is false)')
        if self.beyond_max:
            kinds.append(f'{self.beyond_max} beyond range_max {self.range_max:g} (did not come back)')
        kinds += bad
        return f'not one usable reading in {n} beams: ' + ', '.join(kinds) + '; they clear nothing'


def _read_only(*arrays):
    for a in arrays:
        a.setflags(write=False)
    return arrays


def scan_rays(ranges, angle_min: float, angle_max: float, angle_increment: float, range_min: float,
              range_max: float, inf_is_valid: bool = False, max_beams: int = MAX_BEAMS_DEFAULT) -> Rays:
    """A LaserScan's beams as REP 117 readings (see the module); ValueError naming the fault and its
    values for a scan whose geometry is invalid (its length is checked before its ranges are read)."""
    n = len(ranges)
    if n > max_beams:
        raise ValueError(f'scan refused: {n} beams exceed max_beams={max_beams}')
    for name, v in (('angle_min', angle_min), ('angle_max', angle_max), ('angle_increment', angle_increment),
                    ('range_min', range_min), ('range_max', range_max)):
        if not math.isfinite(v):
            raise ValueError(f'scan refused: {name} is {v} (must be finite)')
    a0, a1, inc, rmin, rmax = (float(v) for v in (angle_min, angle_max, angle_increment, range_min, range_max))
    if inc == 0.0:
        raise ValueError('scan refused: angle_increment is 0 (must be finite and > 0, or < 0 for a clockwise '
                         'scan with angle_max < angle_min)')
    if inc < 0.0 and not a1 < a0:
        raise ValueError(f'scan refused: angle_increment is {inc:g} < 0 but angle_max {a1:g} >= angle_min '
                         f'{a0:g} (a clockwise scan runs from angle_min down to angle_max)')
    if inc > 0.0 and a1 < a0:
        raise ValueError(f'scan refused: angle_increment is {inc:g} > 0 but angle_max {a1:g} < angle_min {a0:g} '
                         '(a clockwise scan has a negative increment)')
    if rmin < 0.0:
        raise ValueError(f'scan refused: range_min is {rmin:g} (must be >= 0)')
    if rmin > rmax:
        raise ValueError(f'scan refused: range_min {rmin:g} > range_max {rmax:g}')
    expected = (a1 - a0) / inc + 1.0
    if abs(expected - n) > 1.5:
        raise ValueError(f'scan refused: {n} ranges but its angles give {expected:.1f} beams '
                         f'((angle_max - angle_min) / angle_increment + 1 with {a0:g}, {a1:g}, {inc:g})')
    if abs(a1 - a0) > 2.0 * math.pi + abs(inc):
        raise ValueError(f'scan refused: its angles span {abs(a1 - a0):g} rad, over 2 pi + one increment '
                         f'({2.0 * math.pi + abs(inc):g})')
    r = np.asarray(ranges, dtype=np.float64).reshape(-1)
    finite = np.isfinite(r)
    nan = np.isnan(r)
    near = r == -np.inf
    far = r == np.inf
    with np.errstate(invalid='ignore'):
        returned = finite & (r >= rmin) & (r <= rmax)
        below = finite & (r < rmin)
    beyond = finite & (r > rmax)
    clear = np.where(returned, r, 0.0)
    clear[near] = rmin
    if inf_is_valid:
        clear[far] = rmax
    mark = returned | near
    mark_range = np.where(returned, r, 0.0)
    mark_range[near] = rmin
    angles = a0 + inc * np.arange(n, dtype=np.float64)
    _read_only(angles, clear, mark, mark_range)
    return Rays(angles, clear, mark, mark_range, returns=int(returned.sum()), near_objects=int(near.sum()),
                no_return=int(far.sum()), erroneous=int(nan.sum()), below_min=int(below.sum()),
                beyond_max=int(beyond.sum()), beams=n, inf_is_valid=bool(inf_is_valid), range_min=rmin,
                range_max=rmax)


class CloudPoints(NamedTuple):
    """A cloud's finite points: ``xy`` (M, 2) in its frame, and how many points were dropped as not finite."""

    xy: np.ndarray
    dropped: int


def _bytes_of(data) -> np.ndarray:
    """The message's data as a flat uint8 array (bytes, bytearray, array.array, memoryview, numpy, a list)."""
    if isinstance(data, np.ndarray):
        return np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    try:
        return np.frombuffer(memoryview(data).cast('B'), dtype=np.uint8)
    except TypeError:
        return np.asarray(data, dtype=np.uint8).reshape(-1)


def cloud_xy(data, fields: dict, point_step: int, row_step: int, width: int, height: int, is_bigendian: bool,
             max_points: int = MAX_POINTS_DEFAULT) -> CloudPoints:
    """The finite x, y of a PointCloud2's points in its frame and the count dropped (see the module).

    ``fields``: name -> (offset, datatype, count) of the message's PointFields. ValueError naming the
    fault and its numbers when the layout is not exactly what the message declares; the sizes are
    checked before any point is read.
    """
    width, height, point_step, row_step = int(width), int(height), int(point_step), int(row_step)
    if width < 0 or height < 0:
        raise ValueError(f'cloud refused: width {width} and height {height} must be >= 0')
    n = width * height
    if n > max_points:
        raise ValueError(f'cloud refused: {width} x {height} = {n} points exceed max_points={max_points}')
    for name in ('x', 'y'):
        if name not in fields:
            raise ValueError(f'cloud refused: no field {name!r} (fields: {sorted(fields)})')
        if int(fields[name][1]) not in FLOAT_FIELDS:
            raise ValueError(f'cloud refused: field {name!r} has datatype {fields[name][1]} (FLOAT32 (7) or '
                             'FLOAT64 (8) expected)')
    if point_step <= 0:
        raise ValueError(f'cloud refused: point_step is {point_step} (must be > 0)')
    spans = {}
    for name, (offset, datatype, count) in fields.items():
        offset, datatype, count = int(offset), int(datatype), int(count)
        if datatype not in POINT_FIELD_SIZES:
            raise ValueError(f'cloud refused: field {name!r} has datatype {datatype} (not a PointField type 1..8)')
        if count < 0:
            raise ValueError(f'cloud refused: field {name!r} has count {count}')
        size = POINT_FIELD_SIZES[datatype] * max(count, 1)     # x and y are read even with count 0
        if offset < 0 or offset + size > point_step:
            raise ValueError(f'cloud refused: field {name!r} at offset {offset} with {size} bytes does not fit '
                             f'point_step {point_step}')
        spans[name] = (offset, offset + size)
    (x0, x1), (y0, y1) = spans['x'], spans['y']
    if x0 < y1 and y0 < x1:
        raise ValueError(f'cloud refused: fields x (bytes {x0}..{x1}) and y (bytes {y0}..{y1}) overlap')
    if row_step != point_step * width:
        stride = f': its rows\' stride is {row_step / width:g} bytes a point' if width else ''
        raise ValueError(f'cloud refused: row_step {row_step} != point_step {point_step} x width {width} '
                         f'({point_step * width}){stride}, point_step says {point_step}')
    raw = _bytes_of(data)
    if len(raw) != row_step * height:
        stride = f': its real stride is {len(raw) / n:g} bytes a point, point_step says {point_step}' if n else ''
        raise ValueError(f'cloud refused: data is {len(raw)} bytes, not row_step {row_step} x height {height} '
                         f'({row_step * height}){stride}')
    if n == 0:
        return CloudPoints(np.zeros((0, 2)), 0)
    order = '>' if is_bigendian else '<'
    xy = np.empty((n, 2))
    for k, name in enumerate(('x', 'y')):
        offset, datatype, _ = fields[name]
        xy[:, k] = np.ndarray((n,), dtype=np.dtype(order + FLOAT_FIELDS[int(datatype)]), buffer=raw,
                              offset=int(offset), strides=(point_step,))
    ok = np.isfinite(xy[:, 0]) & np.isfinite(xy[:, 1])
    dropped = n - int(ok.sum())
    return CloudPoints(xy[ok] if dropped else xy, dropped)


def interpolated_pose(stamps, states, stamp: float, max_gap: float):
    """(pose (3,) x, y, theta, gap) of the robot at ``stamp`` from the poses received (``stamps``
    ascending, ``states`` rows (x, y, theta)): interpolated with gap 0 between the two that bracket it
    when both are within ``max_gap`` of it, else the nearest pose and |its stamp - stamp|; (None, inf)
    with no pose (see the module)."""
    s = np.asarray(stamps, dtype=np.float64).reshape(-1)
    if len(s) == 0:
        return None, math.inf
    if not (math.isfinite(stamp) and max_gap >= 0.0):
        raise ValueError(f'interpolated_pose: stamp {stamp} must be finite and max_gap {max_gap} >= 0')
    x = np.asarray(states, dtype=np.float64).reshape(len(s), 3)
    hi = int(np.searchsorted(s, stamp, side='left'))          # s[hi - 1] < stamp <= s[hi]
    if 0 < hi < len(s) and s[hi] - stamp <= max_gap and stamp - s[hi - 1] <= max_gap and s[hi] > s[hi - 1]:
        w = (stamp - s[hi - 1]) / (s[hi] - s[hi - 1])
        a, b = x[hi - 1], x[hi]
        turn = math.remainder(b[2] - a[2], 2.0 * math.pi)
        heading = math.remainder(a[2] + w * turn, 2.0 * math.pi)
        return np.array([a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]), heading]), 0.0
    near = [i for i in (hi - 1, hi) if 0 <= i < len(s)]
    i = min(near, key=lambda j: abs(s[j] - stamp))
    return x[i].copy(), abs(float(s[i]) - float(stamp))
