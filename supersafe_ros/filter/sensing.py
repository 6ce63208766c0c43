"""Obstacles from a range sensor: laser returns and cloud points as covering discs in map.

A laser scan or a point cloud shows an object as many returns that move from message to
message. The filter judges discs (x, y, r) by ``V_r = V_R + R - r``, one row each; here a
message's returns become a few such discs, in bounded work, without a new value function:

1. **Returns** (``scan_points``, ``cloud_xy``): beam i of a scan is the point
   ``rho_i (cos a_i, sin a_i)`` with ``a_i = angle_min + i angle_increment``, in the sensor's
   frame; a range that is not finite, below ``range_min`` or above ``range_max`` is no
   return (a driver's "nothing seen" or a bad reading: no obstacle). A cloud's points are its
   x, y fields (z ignored), in the sensor's frame; a point that is not finite is none.
2. **Into map** (``to_map``): p_map = T_robot(t_s) T_mount p, with the robot's pose at the
   message's stamp t_s and the sensor's static mount (x_m, y_m, yaw_m) in the robot's frame.
   The pose at t_s is the received pose whose stamp is nearest (``nearest_pose``), held
   dt = |t_s - t_pose| apart. With |linear| <= v and |turn rate| <= w_max, the robot moved
   at most v dt and turned at most w_max dt in that time, so a return at distance rho from the
   robot's centre lies within ``v dt + rho w_max dt`` of where it is placed
   (``stamp_slack``): every return is inflated by that slack as well, and placing it with the
   nearest pose is sound (conservative) whatever the robot did between the stamps.
3. **Inflated returns and what lies behind them**: a return is a point of an object's
   surface; the robot (a disc of ``robot_radius`` about its centre) touches it iff its centre
   is within ``robot_radius`` of the point, so each return is the disc (p, robot_radius +
   slack). The sensor does not see the object's far side, and an object's part that the
   robot cannot see now may be what it meets next (a robot turning round a large obstacle
   sees its flank only once beside it). Every point of a convex object lies on a beam behind
   the first surface that beam meets, at most the object's depth (its diameter) behind it.
   So each return stands for the segment from p to p + ``obstacle_depth`` u (u the beam's
   direction), sampled every h <= 2 x its inflation (``shadows``): every point of the
   segment is within h/2 of a sample, so the inflated samples hold the whole segment, and
   the discs below hold the samples. With ``obstacle_depth`` at least the diameter of the
   objects about, the discs hold every point of each object the sensor has seen a part of
   (up to the beams' angular gaps at its limbs: a few mm were seen outside), except a part
   both hidden behind another object and beyond ``range_max`` (a partial view; checked in
   closed loop by test/test_filter_scan_collisions.py). Holding what was seen is not
   avoiding it: docs/filter_node.md says what the filter guarantees with these discs. The samples
   stay in a budget (50,000): beyond it the returns are first merged per cell, each cell's
   by its centre inflated by the cell's half diagonal delta, and by 2 delta depth / rho for
   the spread of their beams over the depth (rho: the centre's range), and sampled from there.
   ``obstacle_depth`` 0 judges the surface alone.
4. **Groups and covering discs** (``covering_discs``): the returns are binned into square
   cells of side ``cell``; occupied cells that touch (the 8 neighbours) form a group (the
   connected components of the occupied cells: close returns, whatever their order). A
   group's disc has its centre c at the middle of its returns' bounding box and the radius
   ``max_i |p_i - c| + inflation``: it contains every inflated return of its group, and,
   being convex, every segment between two of them (the surface a sensor saw between
   neighbouring beams). A group whose disc would be wider than ``max_radius`` (a wall, a
   large object with its beams) is covered in pieces instead: its returns binned into
   squares of side ``max_radius`` sqrt 2, each square's by one disc (the same rule: radius at
   most ``max_radius`` + inflation), so a long wall does not become one disc over the robot,
   nor a swarm of small discs each easy to avoid alone (with ``max_radius`` <= ``cell`` /
   sqrt 2, cell by cell). Every disc contains
   its inflated returns: the union of the discs contains every inflated return, so a robot
   kept out of every disc touches no return (the filter's guarantee for discs carries over
   to what the sensor saw).

Bounded work: O(M log M) for M returns (one sort for the cells, one connected-components
pass over at most 4 M neighbour pairs), no loop over returns in Python; the discs number at
most the occupied cells. A message of more than ``MAX_POINTS_DEFAULT`` (the node's
``max_sensor_points``) points is refused before anything is read from it.

A message with no return in range means "looked, nothing seen": zero discs, fresh.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

MAX_POINTS_DEFAULT = 1_000_000
_CLOUD_TYPES = {7: 'f4', 8: 'f8'}     # PointField.FLOAT32, FLOAT64
NO_DISCS = np.zeros((0, 3))


def scan_points(ranges, angle_min: float, angle_increment: float, range_min: float,
                range_max: float) -> np.ndarray:
    """(M, 2) returns of a laser scan in the sensor's frame (see the module, 1); ValueError if
    the scan's geometry is not finite."""
    for name, v in (('angle_min', angle_min), ('angle_increment', angle_increment),
                    ('range_min', range_min), ('range_max', range_max)):
        if not math.isfinite(v):
            raise ValueError(f'scan {name} is not finite ({v})')
    r = np.asarray(ranges, dtype=float).reshape(-1)
    with np.errstate(invalid='ignore'):
        ok = np.isfinite(r) & (r >= range_min) & (r <= range_max)
    idx = np.flatnonzero(ok)
    a = angle_min + angle_increment * idx
    rho = r[idx]
    return np.column_stack([rho * np.cos(a), rho * np.sin(a)])


def cloud_xy(data, fields: dict, point_step: int, row_step: int, width: int, height: int,
             is_bigendian: bool, max_points: int = MAX_POINTS_DEFAULT) -> np.ndarray:
    """(M, 2) finite x, y of a PointCloud2's points in the sensor's frame (z ignored).

    ``fields``: name -> (offset, datatype, count) of the message's PointFields; x and y must
    be FLOAT32 or FLOAT64. ValueError (with the reason) when the layout does not fit the data
    (sizes, offsets, a missing field) or the cloud has more than ``max_points`` points; the
    check is made on the sizes before any point is read.
    """
    n = int(width) * int(height)
    if n > max_points:
        raise ValueError(f'cloud of {n} points exceeds max_sensor_points={max_points}')
    for name in ('x', 'y'):
        if name not in fields:
            raise ValueError(f'cloud has no field {name!r} (fields: {sorted(fields)})')
        if fields[name][1] not in _CLOUD_TYPES:
            raise ValueError(f'cloud field {name!r} has datatype {fields[name][1]}: FLOAT32 (7) or FLOAT64 (8) '
                             'expected')
    point_step, row_step = int(point_step), int(row_step)
    if n == 0:
        return np.zeros((0, 2))
    if point_step <= 0 or row_step < point_step * int(width):
        raise ValueError(f'cloud point_step {point_step} / row_step {row_step} do not fit width {width}')
    buf = memoryview(data).cast('B') if not isinstance(data, np.ndarray) else data.reshape(-1).view(np.uint8)
    if len(buf) < row_step * (int(height) - 1) + point_step * int(width):
        raise ValueError(f'cloud data of {len(buf)} bytes is shorter than its {height} x {width} points')
    out = np.empty((n, 2))
    order = '>' if is_bigendian else '<'
    raw = np.frombuffer(buf, dtype=np.uint8)
    for k, name in enumerate(('x', 'y')):
        offset, datatype, _ = fields[name]
        size = 4 if datatype == 7 else 8
        if offset < 0 or offset + size > point_step:
            raise ValueError(f'cloud field {name!r} at offset {offset} does not fit point_step {point_step}')
        dtype = np.dtype(order + _CLOUD_TYPES[datatype])
        rows = [np.ndarray((int(width),), dtype=dtype, buffer=raw, offset=row * row_step + offset,
                           strides=(point_step,)) for row in range(int(height))] if height > 1 else [
            np.ndarray((int(width),), dtype=dtype, buffer=raw, offset=offset, strides=(point_step,))]
        out[:, k] = np.concatenate(rows) if len(rows) > 1 else rows[0]
    return out[np.isfinite(out).all(axis=1)]


def to_map(points, pose, mount=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(M, 2) sensor-frame points in map: the robot at ``pose`` (x, y, theta) carrying the
    sensor at ``mount`` (x_m, y_m, yaw_m) in its own frame."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    x, y, th = (float(v) for v in pose)
    mx, my, myaw = (float(v) for v in mount)
    a = th + myaw
    ca, sa = math.cos(a), math.sin(a)
    ct, st = math.cos(th), math.sin(th)
    ox, oy = x + ct * mx - st * my, y + st * mx + ct * my     # the sensor's origin in map
    return np.column_stack([ox + ca * p[:, 0] - sa * p[:, 1], oy + sa * p[:, 0] + ca * p[:, 1]])


def nearest_pose(stamps, states, stamp: float):
    """(the state whose stamp is nearest ``stamp``, |its stamp - stamp|), or (None, inf) with
    no state."""
    if len(stamps) == 0:
        return None, math.inf
    s = np.asarray(stamps, dtype=float)
    i = int(np.argmin(np.abs(s - stamp)))
    return np.asarray(states[i], dtype=float), abs(float(s[i]) - float(stamp))


def stamp_slack(points_map, pose, dt: float, speed: float, omega_max: float) -> np.ndarray:
    """Per point, how far it may be from where it was placed when the pose used is ``dt`` from
    the message's stamp: ``speed dt + rho omega_max dt``, rho its distance from the robot's
    centre (see the module, 2)."""
    p = np.asarray(points_map, dtype=float).reshape(-1, 2)
    if dt <= 0.0:
        return np.zeros(len(p))
    rho = np.hypot(p[:, 0] - pose[0], p[:, 1] - pose[1])
    return speed * dt + rho * omega_max * dt


def shadows(points_map, inflation, origin, depth: float, cell: float, budget: int = 50_000):
    """(points, inflation) standing for each return and its beam ``depth`` behind it, seen from
    the sensor at ``origin`` (see the module, 3): the segment [p, p + depth u] is sampled every
    h <= 2 inflation (and <= ``cell``), so the inflated samples hold the whole segment. Past
    ``budget`` samples the returns are first merged per cell of side ``cell`` (each cell's
    returns by the cell's centre, inflated by the cell's half diagonal delta more, and by
    2 delta depth / rho more for the beams' spread over the depth, rho the centre's range),
    and if the samples are then still further apart than 2 inflation, each sample's inflation
    grows to half their spacing."""
    p = np.asarray(points_map, dtype=float).reshape(-1, 2)
    infl = np.broadcast_to(np.asarray(inflation, dtype=float), (len(p),)).copy()
    if len(p) == 0 or depth <= 0.0:
        return p, infl
    least = float(infl.min())
    h = min(cell, 2.0 * least) if least > 0 else cell / 4.0
    n = int(math.ceil(depth / h))
    if len(p) * (n + 1) > budget:
        keys, inverse = _occupied(p, cell)
        merged = np.zeros(len(keys))
        np.maximum.at(merged, inverse, infl)
        # a return p within delta of its cell's centre c: its beam's point t behind it is within
        # delta + t |u_p - u_c| <= delta (1 + 2 t / |c - origin|) of the centre's (|u_p - u_c| <= 2 delta / rho_c)
        p, delta = (keys + 0.5) * cell, cell * math.sqrt(0.5)
        rho = np.hypot(*(p - np.asarray(origin, dtype=float).reshape(1, 2)).T)
        infl = merged + np.where(rho > 2.0 * delta, delta * (1.0 + 2.0 * depth / np.maximum(rho, 1e-12)),
                                 delta + depth)
        h = min(cell, 2.0 * float(infl.min()))
        n = min(int(math.ceil(depth / h)), max(1, budget // max(1, len(p)) - 1))
        infl = np.maximum(infl, depth / n / 2.0)    # fewer samples than 2 inflation apart: each holds more
    u = p - np.asarray(origin, dtype=float).reshape(1, 2)
    norm = np.hypot(u[:, 0], u[:, 1])
    norm[norm == 0.0] = 1.0
    u /= norm[:, None]
    steps = np.arange(n + 1) * (depth / n)                     # 0 (the return) .. depth
    samples = p[:, None, :] + steps[None, :, None] * u[:, None, :]
    return samples.reshape(-1, 2), np.repeat(infl, n + 1)


def range_discs(points, pose, gap: float, mount, robot_radius: float, depth: float, cell: float,
                max_radius: float, speed: float, omega_max: float) -> np.ndarray:
    """(K, 3) discs [x, y, r] in map of one message's returns ``points`` (M, 2, the sensor's
    frame): placed with ``pose``, ``gap`` seconds from the message's stamp (``to_map``,
    ``stamp_slack`` taken at each beam's far end, which is the farther from the robot), inflated
    by ``robot_radius`` and the slack, each beam ``depth`` behind its return (``shadows``), and
    covered by discs (``covering_discs``): the module's steps 2 to 4."""
    in_map = to_map(points, pose, mount)
    origin = to_map([(0.0, 0.0)], pose, mount)[0]
    if depth > 0 and len(in_map):
        u = in_map - origin
        n = np.hypot(u[:, 0], u[:, 1])
        n[n == 0.0] = 1.0
        far = in_map + depth * u / n[:, None]
    else:
        far = in_map
    slack = stamp_slack(far, pose, gap, speed, omega_max)
    samples, inflation = shadows(in_map, robot_radius + slack, origin, depth, cell)
    return covering_discs(samples, inflation, cell, max_radius)


def _occupied(points, cell: float):
    """(the occupied cells' (i, j), each point's row in them) of ``points`` binned into cells of
    side ``cell`` (np.unique over rows, by one 16-bit radix sort where the keys fit: O(M))."""
    ij = np.floor(points / cell).astype(np.int64)
    lo = ij.min(axis=0)
    span = int(ij[:, 1].max() - lo[1]) + 1
    key = (ij[:, 0] - lo[0]) * span + (ij[:, 1] - lo[1])
    order = np.argsort(key.astype(np.uint16) if key.max() < 2 ** 16 else key, kind='stable')
    ks = key[order]
    first = np.r_[True, ks[1:] != ks[:-1]]
    inverse = np.empty(len(key), dtype=np.int64)
    inverse[order] = np.cumsum(first) - 1
    return ij[order[first]], inverse


def covering_discs(points, inflation, cell: float, max_radius: float) -> np.ndarray:
    """(K, 3) discs [x, y, r] covering the returns ``points`` (M, 2), each inflated by
    ``inflation`` (a number or one per point): see the module, 4. ``cell`` > 0 is the
    grouping distance; a group wider than ``max_radius`` is covered in pieces of at most that
    radius (plus inflation)."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(p) == 0:
        return NO_DISCS.copy()
    if not (cell > 0 and math.isfinite(cell)):
        raise ValueError(f'cell must be finite and > 0, got {cell}')
    infl = np.asarray(inflation, dtype=float)
    infl = np.full(len(p), float(infl)) if infl.ndim == 0 else infl.reshape(len(p))
    ij = np.floor(p / cell).astype(np.int64)
    lo = ij.min(axis=0) - 1
    span = int(ij[:, 1].max() - lo[1]) + 2          # a column of empty cells on either side
    key = (ij[:, 0] - lo[0]) * span + (ij[:, 1] - lo[1])
    # the one sort: points by cell (keys of a sensor's reach fit 16 bits: numpy sorts those by radix, O(M))
    order = np.argsort(key.astype(np.uint16) if key.max() < 2 ** 16 else key, kind='stable')
    ks, ps, fs = key[order], p[order], infl[order]
    first = np.r_[True, ks[1:] != ks[:-1]]
    start = np.flatnonzero(first)                   # each cell's first point
    cell_of = np.cumsum(first) - 1                  # each (sorted) point's cell
    cell_lo = np.minimum.reduceat(ps, start, axis=0)
    cell_hi = np.maximum.reduceat(ps, start, axis=0)
    comp = _touching(ks[start], span)               # each cell's group
    k = int(comp.max()) + 1
    group_lo = np.full((k, 2), np.inf)
    group_hi = np.full((k, 2), -np.inf)
    np.minimum.at(group_lo, comp, cell_lo)
    np.maximum.at(group_hi, comp, cell_hi)
    centre = (group_lo + group_hi) / 2.0
    cell_r = _farthest(ps, fs, centre[comp][cell_of], start)
    radius = np.zeros(k)
    np.maximum.at(radius, comp, cell_r)
    wide = radius > max_radius
    if not wide.any():
        return np.column_stack([centre, radius])
    # the wide groups (walls, a large object with its beams): in pieces of at most max_radius
    # (squares of side max_radius sqrt 2, their half diagonal), not cell by cell: each piece
    # is an obstacle of about the library's size, not a swarm of small discs each easy alone
    in_wide = wide[comp][cell_of]
    coarse = max_radius * math.sqrt(2.0)
    if coarse <= cell:
        cell_centre = (cell_lo + cell_hi) / 2.0
        own_r = _farthest(ps, fs, cell_centre[cell_of], start)
        split = wide[comp]
        return np.vstack([np.column_stack([centre[~wide], radius[~wide]]),
                          np.column_stack([cell_centre[split], own_r[split]])])
    pieces = covering_discs(ps[in_wide], fs[in_wide], coarse, 0.0)     # (0: every piece its own disc)
    return np.vstack([np.column_stack([centre[~wide], radius[~wide]]), pieces])


def _farthest(points, inflation, centres, start) -> np.ndarray:
    """Per run of ``points`` (runs begin at ``start``): the largest distance from a point to its
    row of ``centres`` plus that point's inflation."""
    d = points - centres
    return np.maximum.reduceat(np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + inflation, start)


def _touching(keys, span: int) -> np.ndarray:
    """Group id of each occupied cell (its ``keys`` = i span + j, sorted, unique, with an empty
    row and column of cells around them all): the connected components of the cells that share
    a side or a corner."""
    n = len(keys)
    if n == 1:
        return np.zeros(1, dtype=np.int64)
    rows, cols = [], []
    for step in (span - 1, span, span + 1, 1):       # each touching pair once
        neighbour = keys + step
        at = np.minimum(np.searchsorted(keys, neighbour), n - 1)
        hit = keys[at] == neighbour
        rows.append(np.flatnonzero(hit))
        cols.append(at[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), dtype=np.int8), (r, c)), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)
