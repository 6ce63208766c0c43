"""The filter's local map of what its range sensors saw: a rolling window of cells, as a Nav2 obstacle layer.

A scan that reads NaN, or a beam that did not come back, says nothing about the wall that the
previous scan saw; so the filter keeps what its sensors saw in a map, in the pose's frame (odom),
and a cell is forgotten only when a beam is seen to pass through it.

**Cells.** Square cells of side c on a world-fixed lattice: global cell (I, J) is [I c, (I + 1) c) x
[J c, (J + 1) c); the window is n x n of them (n = ceil(size / c)) from corner cell (I0, J0), so
its cell (i, j) = global (I0 + i, J0 + j) and ``origin`` = (I0 c, J0 c); ``occupied[i, j]`` (i along
x, j along y). Each cell is occupied or not, and seen or not (marked or cleared at least once).
``follow(x, y)`` centres the window on the robot the first time, then moves it, by whole cells
(I0 = round(x / c - n / 2)), only when the robot is farther than ``recentre`` from its centre: a
move is an exact shift of the arrays; cells that leave are forgotten, cells that enter are unknown.

**One message** (``integrate_rays``: a scan's ``readings.Rays``; ``integrate_points``: a
cloud's points), seen from the sensor at (x_s, y_s, yaw) in the map frame (the robot's pose at the
stamp composed with the sensor's mount, by the caller), in this order:

1. **clear** every cell that a clearing beam's segment s + t u, 0 <= t < clear, passes through
   (u = (cos(yaw + a), sin(yaw + a))), found exactly from the segment's crossings of the cell lines
   across its major axis (a beam with |u_x| >= |u_y| crosses the lines x = k c one after another and
   lies in at most two rows of cells between two of them: the cells just before and just after each
   crossing, and its first and last cells): every cell the segment crosses over more than 1e-5 of a
   cell is cleared, and none that it does not come within 1e-7 of a cell of (rounding); a cell it
   only touches at a corner stays;
2. **mark** each return's cell, and, with ``slack`` (the returns' placement uncertainty: a pose not
   exactly at the stamp), every cell whose centre is within the slack of the return; marks win
   over the clears of the same message (so a beam's own return's cell stays occupied);
3. **depth** marks: with ``depth`` > 0 the cells that each return's beam passes through from the
   return to ``depth`` behind it (the object's far side, which the sensor cannot see), except the
   cells this message cleared (a cell seen free now is not guessed occupied). The slack does not
   widen them (it widens the return's own mark only).

A cloud has no beams: each point marks its cell, and its rays from the sensor clear. To bound the
work (100,000 points), the points are binned by bearing, in bins of 2 pi / m with m > 2 pi R / c
(R the distance from the sensor to the window's farthest corner: a bin is under a cell wide at the
window's edge), and only the ray to each bin's nearest point clears (exact for that point; the
bin's farther points clear nothing). ``depth`` and ``slack`` apply to a cloud's points as to a scan's
returns (the beam of a point: the ray from the sensor to it). Cells outside the window are ignored.

**Why clearing fewer is the safe side.** A cell wrongly left occupied is an obstacle that is not
there: the filter may slow or turn the robot for nothing. A cell wrongly cleared is an obstacle
forgotten: the robot may drive into it. So every approximation here clears fewer: a grazed cell
stays, a beam never clears its own return's cell, a reading that says nothing clears nothing, a
cloud's farther points in a bin clear nothing. **Why marks win within a message**: a clearing beam
crosses a cell along one line and a return in that cell says something is in it; both are of the
same instant, and a cell is occupied when anything is anywhere in it (Nav2 clears, then marks).

**Unknown cells** (never seen, or gone out of the window and back) are not occupied: callers read
them as free, as Nav2's obstacle layer does with ``track_unknown_space`` false (the lead decides
what a caller does with ``seen``). The cells' union is what the map holds: ``occupied_centres``
gives the occupied cells near a point, each to be taken as the disc of radius ``cell_radius`` = c
sqrt(2) / 2 about its centre (the disc that holds the whole cell).

**An occupancy grid** (``integrate_grid``: nav_msgs/OccupancyGrid, its cell (0, 0)'s corner at
origin_pose in the map frame, data row-major, row = y): each window cell whose centre lies on the
grid takes the grid cell's value: >= occupied_threshold occupied, 0 .. threshold - 1 free, -1
(unknown) leaves it as it was; values outside -1 .. 100 refuse the grid.

**Cost** (vectorised, no Python loop over beams or points; bench/bench_local_map.py prints it): a
scan is O(beams x range / c) (two cells per column crossing, in (beams x columns) blocks of beams of
similar length, so that short beams are not padded to the longest), plus a few byte-wide passes over
the part of the window the message reaches; a mark with slack s is O((s / c)^2) cells; past 2^20
marks x cells (a large cloud) the marks are merged per cell first, each cell's disc grown by its half
diagonal (a superset), in 2 s / c + 3 passes over that part of the window. A slack over the window's
side is refused (the pose is too far from the stamp to place anything). Depth adds O(returns x depth
/ c); a cloud is O(M) to bin its points and a scan of at most m rays; a grid O(the window's cells on
its footprint). ``version`` grows by one whenever a cell changes (occupied, or seen for the first
time) or the window moves, so a background solve can tell that the map it read is out of date
(``snapshot``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

MAX_CELLS_PER_SIDE = 4096
GRID_MAX_CELLS = 4096 * 4096
EPS = 1e-6            # cells: a crossing shorter than this may be missed (a graze)
DELTA = 1e-5          # cells: segments are clipped this far inside the box (never an index outside it)
BUDGET = 1 << 20      # elements of one vectorised block of marks x disc cells
TRACE_BLOCK = 1 << 16  # elements of one block of beams x columns (~0.5 MB of indices: stays in cache)
PAD_FREE = 8192       # padding elements a block may waste beyond a quarter (cheaper than another block)


@dataclass(frozen=True)
class MapSettings:
    """The local map's cell side ``cell`` (m), window side ``size`` (m), ``recentre`` (m: the window moves
    when the robot is farther than this from its centre; default size / 4) and ``depth`` (m: each return
    also marks its beam this far behind it)."""

    cell: float = 0.05
    size: float = 10.0
    recentre: float | None = None
    depth: float = 0.0

    def __post_init__(self):
        for name in ('cell', 'size'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f'MapSettings: {name} must be finite and > 0, got {v}')
        if self.size / self.cell > MAX_CELLS_PER_SIDE:
            raise ValueError(f'MapSettings: size / cell = {self.size / self.cell:g} cells a side, over '
                             f'{MAX_CELLS_PER_SIDE}')
        recentre = self.size / 4.0 if self.recentre is None else self.recentre
        if not (math.isfinite(recentre) and 0 < recentre <= self.size / 2.0):
            raise ValueError(f'MapSettings: recentre must be finite, > 0 and <= size / 2 ({self.size / 2:g}), '
                             f'got {recentre}')
        object.__setattr__(self, 'recentre', float(recentre))
        if not (math.isfinite(self.depth) and self.depth >= 0):
            raise ValueError(f'MapSettings: depth must be finite and >= 0, got {self.depth}')

    @property
    def cells(self) -> int:
        """Cells a side of the window."""
        return max(1, math.ceil(self.size / self.cell - 1e-9))


@dataclass(frozen=True, eq=False)
class MapSnapshot:
    """What a background solve reads: the window's ``origin`` (x0, y0), ``cell``, ``occupied`` (a
    read-only copy) and the map's ``version`` when it was taken."""

    origin: tuple
    cell: float
    occupied: np.ndarray
    version: int


@dataclass(frozen=True)
class ViewSummary:
    """What the last message did: its ``kind`` ('scan', 'cloud', 'grid'), the cells it ``marked`` and
    ``cleared`` (cleared and not marked), its readings' ``counts`` and ``problem`` ('' when fine)."""

    kind: str
    marked: int
    cleared: int
    counts: dict = field(default_factory=dict)
    problem: str = ''

    def as_dict(self) -> dict:
        """The summary as plain values (the filter's state)."""
        return {'kind': self.kind, 'marked': self.marked, 'cleared': self.cleared, **self.counts,
                'problem': self.problem}


def _finite_pose(pose, what: str):
    x, y, yaw = (float(v) for v in pose)
    if not all(math.isfinite(v) for v in (x, y, yaw)):
        raise ValueError(f'{what} must be finite, got ({x}, {y}, {yaw})')
    return x, y, yaw


def _per_item(value, count: int, what: str) -> np.ndarray:
    """A scalar or one value per item, finite and >= 0, as (count,)."""
    v = np.asarray(value, dtype=np.float64)
    if v.ndim == 0:
        v = np.full(count, float(v))
    elif v.shape != (count,):
        raise ValueError(f'{what} must be a number or one per item ({count}), got shape {v.shape}')
    if count and not (np.all(np.isfinite(v)) and v.min() >= 0.0):
        raise ValueError(f'{what} must be finite and >= 0')
    return v


def _shifted(a: np.ndarray, di: int, dj: int) -> np.ndarray:
    """``a`` moved so that out[i, j] = a[i + di, j + dj] (False where that is outside ``a``)."""
    n_i, n_j = a.shape
    out = np.zeros_like(a)
    if abs(di) < n_i and abs(dj) < n_j:
        out[max(0, -di):min(n_i, n_i - di), max(0, -dj):min(n_j, n_j - dj)] = \
            a[max(0, di):min(n_i, n_i + di), max(0, dj):min(n_j, n_j + dj)]
    return out


def _clip(start, direction, length, shape):
    """(t0, t1): the part of each segment start + t direction, 0 <= t < length, inside the box
    [DELTA, n - DELTA] of each axis (Liang-Barsky); t1 <= t0 when none is."""
    t0 = np.zeros(len(direction))
    t1 = np.asarray(length, dtype=np.float64).copy()
    for axis, n in enumerate(shape):
        p, d = start[:, axis], direction[:, axis]
        lo, hi = DELTA, n - DELTA
        with np.errstate(divide='ignore', invalid='ignore'):
            a, b = (lo - p) / d, (hi - p) / d
        inside = (p >= lo) & (p <= hi)
        still = d == 0
        t0 = np.maximum(t0, np.where(still, np.where(inside, -np.inf, np.inf), np.minimum(a, b)))
        t1 = np.minimum(t1, np.where(still, np.where(inside, np.inf, -np.inf), np.maximum(a, b)))
    return t0, t1


def _along_major(mask, p0, q0, dp, dq, length, n_minor: int) -> None:
    """Set in ``mask`` (flat, major x n_minor + minor) the cells that segments (p0, q0) + t (dp, dq),
    EPS <= t <= length - EPS, pass through, their major axis the one with |dp| >= |dq|, all in the box.

    Column k (k = 0 the start's) is entered across the cell line b_k = c0 + s k + [s < 0] at t_k =
    (b_k - p0) / dp, where the minor coordinate is G_k = A + k D (D = dq / |dp|, |D| <= 1): the
    segment is in the start cell, in the end cell, and on either side of each crossing k = 1..N, in
    (c0 + s (k - 1), floor(G_k - EPS D)) and (c0 + s k, floor(G_k + EPS D)) (the nudge picks the cell
    the segment is in just before and after the line, not one it only touches at a corner). A cell's
    flat index (c0 + s k) n_minor + floor(G) is one truncation of k (s n_minor + D) + c0 n_minor + A.
    """
    if len(p0) == 0:
        return
    s = np.sign(dp)
    c0 = np.floor(p0 + EPS * dp)
    last = np.floor(p0 + (length - EPS) * dp)
    mask[(c0 * n_minor + np.floor(q0 + EPS * dq)).astype(np.intp)] = True
    mask[(last * n_minor + np.floor(q0 + (length - EPS) * dq)).astype(np.intp)] = True
    crossings = s * (last - c0)
    order = np.argsort(crossings, kind='stable')
    order = order[crossings[order] >= 1]
    sorted_n = crossings[order]
    at = 0
    while at < len(order):
        # a block: the next beams (by crossings) while padding them all to the most wastes at most a
        # quarter (+ PAD_FREE elements), at most TRACE_BLOCK elements: columns 1..least for all, the rest
        # clamped to each beam's own
        rest = sorted_n[at:]
        padded = np.arange(1.0, len(rest) + 1.0) * rest
        fits = (padded <= 1.25 * np.cumsum(rest) + PAD_FREE) & (padded <= TRACE_BLOCK)
        end = at + (max(1, int(np.argmin(fits))) if not fits.all() else len(rest))
        b, least, most = order[at:end], int(sorted_n[at]), int(sorted_n[end - 1])
        at = end
        sb, cb = s[b], c0[b]
        slope = dq[b] / np.abs(dp[b])
        a = q0[b] + (cb + (sb < 0) - p0[b]) * dq[b] / dp[b]
        w = sb * n_minor + slope
        right = (cb * n_minor + a + EPS * slope)[:, None]
        left = ((cb - sb) * n_minor + a - EPS * slope)[:, None]
        _scatter(mask, np.multiply.outer(w, np.arange(1.0, least + 1.0)), right, left)
        if most > least:
            tail = np.minimum(np.arange(least + 1.0, most + 1.0)[None, :], crossings[b][:, None])
            tail *= w[:, None]
            _scatter(mask, tail, right, left)


def _scatter(mask, kw, right, left) -> None:
    """Set the cells kw + right and kw + left (their flat indices, truncated) in ``mask``."""
    cells = np.empty(kw.shape, dtype=np.intp)
    np.add(kw, right, out=cells, casting='unsafe')
    mask[cells] = True
    np.add(kw, left, out=cells, casting='unsafe')
    mask[cells] = True


def _trace(start, direction, length, shape) -> np.ndarray:
    """(shape) bool: the cells that the segments start + t direction, 0 <= t < length (box cell units,
    ``direction`` unit rows), pass through within the box; the beams along x index the box, those along y
    its transpose (each its own major axis)."""
    along_x = np.zeros(shape[0] * shape[1], dtype=bool)
    along_y = np.zeros(shape[1] * shape[0], dtype=bool)
    if len(direction):
        start = np.broadcast_to(np.asarray(start, dtype=np.float64), direction.shape)
        t0, t1 = _clip(start, direction, length, shape)
        keep = (t1 - t0 > 2.0 * EPS) & ((direction[:, 0] != 0.0) | (direction[:, 1] != 0.0))
        p = start[keep] + t0[keep, None] * direction[keep]
        d, span = direction[keep], (t1 - t0)[keep]
        ax = np.abs(d[:, 0]) >= np.abs(d[:, 1])
        ay = ~ax
        _along_major(along_x, p[ax, 0], p[ax, 1], d[ax, 0], d[ax, 1], span[ax], shape[1])
        _along_major(along_y, p[ay, 1], p[ay, 0], d[ay, 1], d[ay, 0], span[ay], shape[0])
    out = along_x.reshape(shape)
    out |= along_y.reshape(shape[::-1]).T
    return out


def _disc_cells(points, radius, shape) -> np.ndarray:
    """(shape) bool: the cells whose centres lie within ``radius`` (per point) of the ``points`` (box cell
    units), point by point in blocks of BUDGET elements; past BUDGET in all, the points are merged per cell
    first (a superset): each cell with points holds the largest of their radii + sqrt(2) / 2 about its
    centre: one pass over the box per offset of the disc, or for a wide disc per row offset (2 r + 1)."""
    # a centre within r of a point of cell (a, b) is that of a cell (a + di, b + dj) with |(di, dj)| <= r + sqrt(1/2)
    largest = float(radius.max()) + math.sqrt(0.5)
    reach = math.ceil(largest)
    di, dj = np.meshgrid(np.arange(-reach, reach + 1), np.arange(-reach, reach + 1), indexing='ij')
    keep = np.hypot(di, dj) <= largest
    di, dj = di[keep], dj[keep]
    cell = np.floor(points)
    near = (cell[:, 0] >= -reach) & (cell[:, 0] < shape[0] + reach) & (cell[:, 1] >= -reach) & \
        (cell[:, 1] < shape[1] + reach)                         # the others reach no cell of the box
    points, radius, cell = points[near], radius[near], cell[near]
    border = 2 * reach
    ext = (shape[0] + 2 * border, shape[1] + 2 * border)
    out = np.zeros(ext, dtype=bool)
    if len(points) * len(di) <= BUDGET:
        offset = (di * ext[1] + dj)[None, :]
        base = ((cell[:, 0] + border) * ext[1] + cell[:, 1] + border).astype(np.intp)[:, None]
        dx = (cell[:, 0] + 0.5 - points[:, 0])[:, None] + di
        dy = (cell[:, 1] + 0.5 - points[:, 1])[:, None] + dj
        dx *= dx
        dy *= dy
        dx += dy
        out.reshape(-1)[(base + offset)[dx <= (radius * radius)[:, None]]] = True
    else:
        holds = np.full(ext, -1.0, dtype=np.float32)
        np.maximum.at(holds.reshape(-1), ((cell[:, 0] + border) * ext[1] + cell[:, 1] + border).astype(np.intp),
                      ((radius + math.sqrt(0.5)) * (1.0 + 1e-6)).astype(np.float32))   # rounded up: a superset
        box = (slice(border, border + shape[0]), slice(border, border + shape[1]))
        if len(di) <= 9 * (2 * reach + 1):
            for a, b in zip(di.tolist(), dj.tolist()):
                # cell (i, j) is within the disc of the cell (i - a, j - b) when that one's holds |(a, b)|
                out[box] |= holds[border - a:border - a + shape[0], border - b:border - b + shape[1]] >= \
                    np.float32(math.hypot(a, b))
        else:
            # a wide disc, row offset by row offset a: a source (i - a, s) of radius r covers (i, x) when
            # |x - s| <= w = floor(sqrt(r^2 - a^2)) (w = -1: none): some source left of x reaches it (a
            # running max of s + w) or one right of it (a running min of s - w)
            squared = holds * holds
            squared[holds < 0.0] = -1.0
            column = np.arange(ext[1], dtype=np.float32)
            for a in range(-reach, reach + 1):
                left = squared[border - a:border - a + shape[0]] - np.float32(a * a)
                width = np.floor(np.sqrt(np.maximum(left, 0.0)))
                width -= left < 0.0
                right = np.maximum.accumulate(column + width, axis=1)
                left = np.minimum.accumulate((column - width)[:, ::-1], axis=1)[:, ::-1]
                out[box[0]] |= (right >= column) | (left <= column)
    return out[border:border + shape[0], border:border + shape[1]]


class LocalMap:
    """A rolling window of cells holding what the range sensors saw (see the module)."""

    def __init__(self, settings: MapSettings | None = None):
        self.settings = MapSettings() if settings is None else settings
        self.cell = float(self.settings.cell)
        n = self.settings.cells
        self.shape = (n, n)
        self._occupied = np.zeros(self.shape, dtype=bool)
        self._seen = np.zeros(self.shape, dtype=bool)
        self._corner = (-(n // 2), -(n // 2))     # global index of cell (0, 0)
        self.placed = False
        self.version = 0
        self._any, self._any_version = False, 0      # holds_any, as of a version
        self.last_view: ViewSummary | None = None

    # -- the window ----------------------------------------------------------------------------
    @property
    def origin(self) -> tuple:
        """(x0, y0): the corner of cell (0, 0), multiples of the cell."""
        return (self._corner[0] * self.cell, self._corner[1] * self.cell)

    @property
    def centre(self) -> tuple:
        """The window's centre."""
        half = self.shape[0] * self.cell / 2.0
        return (self.origin[0] + half, self.origin[1] + half)

    @property
    def occupied(self) -> np.ndarray:
        """(n, n) bool, read-only view: cell (i, j) occupied (i along x, j along y)."""
        view = self._occupied.view()
        view.flags.writeable = False
        return view

    @property
    def seen(self) -> np.ndarray:
        """(n, n) bool, read-only view: cell (i, j) marked or cleared at least once since it entered."""
        view = self._seen.view()
        view.flags.writeable = False
        return view

    @property
    def cell_radius(self) -> float:
        """cell sqrt(2) / 2: the radius of the disc about a cell's centre that holds the whole cell."""
        return self.cell * math.sqrt(2.0) / 2.0

    def follow(self, x: float, y: float) -> bool:
        """Centre the window on (x, y) the first time; later move it, by whole cells, to centre it on
        (x, y) when (x, y) is farther than ``recentre`` from its centre. True when it was placed or moved."""
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f'follow: position must be finite, got ({x}, {y})')
        if self.placed and math.hypot(x - self.centre[0], y - self.centre[1]) <= self.settings.recentre:
            return False
        n = self.shape[0]
        corner = (int(round(x / self.cell - n / 2.0)), int(round(y / self.cell - n / 2.0)))
        di, dj = corner[0] - self._corner[0], corner[1] - self._corner[1]
        if di or dj:
            self._occupied = _shifted(self._occupied, di, dj)
            self._seen = _shifted(self._seen, di, dj)
            self._corner = corner
        self.placed = True
        self.version += 1
        return True

    # -- messages --------------------------------------------------------------------------------
    def integrate_rays(self, sensor_pose, rays, slack=0.0) -> ViewSummary:
        """One scan (``readings.Rays``) seen from ``sensor_pose`` (x, y, yaw) in the map frame; ``slack``
        (m, a number or one per beam) marks every cell whose centre is within it of a return (see the
        module: clear, then mark, then depth)."""
        sx, sy, yaw = _finite_pose(sensor_pose, 'sensor_pose')
        slack = self._slack(slack, rays.beams)
        direction = np.column_stack([np.cos(rays.angles + yaw), np.sin(rays.angles + yaw)])
        clearing = rays.clear > 0.0
        marks = np.asarray(rays.mark, dtype=bool)
        hits = np.array([sx, sy]) + direction[marks] * rays.mark_range[marks][:, None]
        return self._integrate('scan', (sx, sy), direction[clearing], rays.clear[clearing], hits, slack[marks],
                               direction[marks], rays.counts(), rays.problem())

    def integrate_points(self, sensor_pose, points_xy, slack=0.0) -> ViewSummary:
        """A cloud's (M, 2) points in the sensor's frame seen from ``sensor_pose`` (x, y, yaw) in the map
        frame: each marks its cell (and, with ``slack``, the cells whose centres are within it); the ray to
        the nearest point of each bearing bin clears (see the module). Points not finite say nothing."""
        sx, sy, yaw = _finite_pose(sensor_pose, 'sensor_pose')
        p = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
        slack = self._slack(slack, len(p))
        total = len(p)
        if not np.isfinite(p).all():
            finite = np.isfinite(p[:, 0]) & np.isfinite(p[:, 1])
            p, slack = p[finite], slack[finite]
        cy, sn = math.cos(yaw), math.sin(yaw)
        offset = p @ np.array([[cy, sn], [-sn, cy]])                  # the sensor's frame turned into the map's
        hits = offset + (sx, sy)
        dist = np.sqrt(np.einsum('ij,ij->i', offset, offset))
        if not self.placed:
            self.follow(sx, sy)
        corners = np.array([[0, 0], [1, 0], [0, 1], [1, 1]]) * self.shape[0] * self.cell + self.origin
        bins = int(2.0 * math.pi * float(np.hypot(*(corners - (sx, sy)).T).max()) / self.cell) + 1
        which = ((np.arctan2(offset[:, 1], offset[:, 0]) + math.pi) * (bins / (2.0 * math.pi))).astype(np.intp)
        np.minimum(which, bins - 1, out=which)
        away = np.where(dist > 0.0, dist, np.inf)                     # a point at the sensor clears nothing
        best = np.full(bins, np.inf)
        np.minimum.at(best, which, away)
        win = np.flatnonzero(away == best[which])
        win = win[dist[win] > 0.0]
        owner = np.full(bins, -1, dtype=np.intp)
        owner[which[win]] = win                                        # ties: any one of them is the nearest
        nearest = owner[owner >= 0]
        dropped = total - len(p)
        counts = {'points': total, 'dropped': dropped, 'clearing_rays': len(nearest)}
        problem = f'{dropped} of {total} points not finite: they say nothing' if 4 * dropped > total else ''
        hit_dir = offset / np.where(dist > 0.0, dist, 1.0)[:, None] if self.settings.depth > 0 else None
        return self._integrate('cloud', (sx, sy), offset[nearest] / dist[nearest, None], dist[nearest], hits,
                               slack, hit_dir, counts, problem)

    def _slack(self, slack, count: int) -> np.ndarray:
        """The slack per return, checked: finite, >= 0 and at most the window's side (a return placed that
        loosely is not placed: the caller's pose is too far from the stamp)."""
        slack = _per_item(slack, count, 'slack')
        if count and slack.max() > self.settings.size:
            raise ValueError(f'slack {slack.max():g} m is over the window\'s side ({self.settings.size:g} m)')
        return slack

    def _integrate(self, kind, sensor, clear_dir, clear_len, hits, slack, hit_dir, counts, problem) -> ViewSummary:
        """Clear, mark, depth (the module's steps) for one message, within the box of the window it reaches."""
        if not self.placed:
            self.follow(*sensor)
        c, n, depth = self.cell, self.shape[0], self.settings.depth
        ends = np.concatenate([np.reshape(sensor, (1, 2)), np.reshape(sensor, (1, 2)) + clear_dir * clear_len[:, None]])
        lo, hi = [ends[:, 0].min(), ends[:, 1].min()], [ends[:, 0].max(), ends[:, 1].max()]
        if len(hits):
            grow = float(slack.max()) + depth                       # marks reach this far from their returns
            lo = np.minimum(lo, [hits[:, 0].min() - grow, hits[:, 1].min() - grow])
            hi = np.maximum(hi, [hits[:, 0].max() + grow, hits[:, 1].max() + grow])
        # in floats, clipped to the window before the cast (a beam may be 1e30 m long)
        lo = np.clip(np.floor(np.asarray(lo) / c) - self._corner - 1, 0, n).astype(np.int64)
        hi = np.clip(np.floor(np.asarray(hi) / c) - self._corner + 2, 0, n).astype(np.int64)
        (bi0, bj0), (bi1, bj1) = lo, hi
        if bi0 >= bi1 or bj0 >= bj1:                              # the message reaches no cell of the window
            self.last_view = ViewSummary(kind, 0, 0, counts, problem)
            return self.last_view
        shape = (int(bi1 - bi0), int(bj1 - bj0))
        base = np.array([self._corner[0] + bi0, self._corner[1] + bj0], dtype=np.float64)
        cleared = _trace(np.reshape(sensor, (1, 2)) / c - base, clear_dir, clear_len / c, shape)
        # marks in the box with a border of one cell all round, where every mark outside the box lands
        border = np.zeros((shape[0] + 2, shape[1] + 2), dtype=bool)
        at = hits / c - base
        ij = np.floor(at)
        np.clip(ij, -1.0, np.array(shape, dtype=np.float64) - 0.0, out=ij)
        border.reshape(-1)[((ij[:, 0] + 1.0) * (shape[1] + 2) + (ij[:, 1] + 1.0)).astype(np.intp)] = True
        marked = border[1:-1, 1:-1]
        if len(at) and slack.max() > 0.0:
            marked = marked | _disc_cells(at, slack / c, shape)
        if depth > 0.0 and len(at):
            marked = marked | (_trace(at, hit_dir, np.full(len(at), depth / c), shape) & ~cleared)
        return self._apply(kind, (slice(bi0, bi1), slice(bj0, bj1)), cleared, marked, counts, problem)

    def _apply(self, kind, box, cleared, marked, counts, problem) -> ViewSummary:
        """Write one message's clears and marks (marks win) into the window's ``box``."""
        occupied, seen = self._occupied[box], self._seen[box]
        freed = np.greater(cleared, marked)                 # cleared & ~marked
        seen_before = np.count_nonzero(seen)
        changed = np.count_nonzero(occupied & freed) or np.count_nonzero(np.greater(marked, occupied))
        np.greater(occupied, freed, out=occupied)           # occupied & ~freed
        occupied |= marked
        seen |= freed
        seen |= marked
        if changed or np.count_nonzero(seen) != seen_before:
            self.version += 1
        self.last_view = ViewSummary(kind, int(np.count_nonzero(marked)), int(np.count_nonzero(freed)), counts,
                                     problem)
        return self.last_view

    def integrate_grid(self, origin_pose, resolution: float, width: int, height: int, data,
                       occupied_threshold: int, max_cells: int = GRID_MAX_CELLS) -> ViewSummary:
        """A nav_msgs/OccupancyGrid's content (see the module): every window cell whose centre lies on the grid
        takes its value (>= occupied_threshold occupied, 0 .. threshold - 1 free, -1 unchanged). ValueError
        naming the fault for a malformed grid."""
        ox, oy, oyaw = _finite_pose(origin_pose, 'grid origin')
        if not (math.isfinite(resolution) and resolution > 0):
            raise ValueError(f'grid refused: resolution is {resolution} (must be finite and > 0)')
        width, height = int(width), int(height)
        if width < 0 or height < 0 or width * height > max_cells:
            raise ValueError(f'grid refused: {width} x {height} cells (each >= 0, at most {max_cells} in all)')
        if len(data) != width * height:
            raise ValueError(f'grid refused: {len(data)} values for {width} x {height} = {width * height} cells')
        if not 1 <= int(occupied_threshold) <= 100:
            raise ValueError(f'grid refused: occupied_threshold is {occupied_threshold} (must be in 1..100)')
        raw = np.frombuffer(data, dtype=np.int8) if isinstance(data, (bytes, bytearray, memoryview)) else data
        values = np.asarray(raw).astype(np.int16).reshape(-1)
        if len(values) and (values.min() < -1 or values.max() > 100):
            bad = int(np.flatnonzero((values < -1) | (values > 100))[0])
            raise ValueError(f'grid refused: value {values[bad]} at cell ({bad % width}, {bad // width}) is '
                             'outside -1..100')
        cy, sn = math.cos(oyaw), math.sin(oyaw)
        if not self.placed:
            w, h = width * resolution / 2.0, height * resolution / 2.0
            self.follow(ox + cy * w - sn * h, oy + sn * w + cy * h)
        if width * height == 0:
            self.last_view = ViewSummary('grid', 0, 0, {'cells': 0}, '')
            return self.last_view
        foot = np.array([[0, 0], [width, 0], [0, height], [width, height]], dtype=np.float64) * resolution
        foot = foot @ np.array([[cy, sn], [-sn, cy]]) + (ox, oy)
        n = self.shape[0]
        lo = np.clip(np.floor(foot.min(axis=0) / self.cell) - self._corner - 1, 0, n).astype(np.int64)
        hi = np.clip(np.floor(foot.max(axis=0) / self.cell) - self._corner + 2, 0, n).astype(np.int64)
        (bi0, bj0), (bi1, bj1) = lo, hi
        if bi0 >= bi1 or bj0 >= bj1:
            self.last_view = ViewSummary('grid', 0, 0, {'cells': width * height}, '')
            return self.last_view
        xs = (self._corner[0] + np.arange(bi0, bi1) + 0.5) * self.cell - ox
        ys = (self._corner[1] + np.arange(bj0, bj1) + 0.5) * self.cell - oy
        u = np.floor((cy * xs[:, None] + sn * ys[None, :]) / resolution).astype(np.int64)
        v = np.floor((-sn * xs[:, None] + cy * ys[None, :]) / resolution).astype(np.int64)
        on = (u >= 0) & (u < width) & (v >= 0) & (v < height)
        value = np.full(on.shape, -1, dtype=np.int16)
        value[on] = values[v[on] * width + u[on]]
        marked = value >= int(occupied_threshold)
        cleared = (value >= 0) & ~marked
        return self._apply('grid', (slice(bi0, bi1), slice(bj0, bj1)), cleared, marked,
                           {'cells': width * height}, '')

    def holds_any(self) -> bool:
        """Whether any cell is occupied (a map of free and unknown cells needs no value to be judged)."""
        if self._any_version != self.version:
            self._any, self._any_version = bool(self._occupied.any()), self.version
        return self._any

    def clear_footprint(self, x: float, y: float, radius: float) -> int:
        """Clear the cells that lie wholly within ``radius`` of (x, y) (the robot's own disc: nothing else
        can be there, so a return there is the robot itself or an artefact, as Nav2's footprint clearing);
        how many were occupied."""
        r = radius - self.cell_radius          # a cell whose centre is this close lies wholly inside
        if not (r > 0 and math.isfinite(x) and math.isfinite(y)):
            return 0
        n, c = self.shape[0], self.cell
        ci, cj = self._corner
        i0, i1 = max(0, math.floor((x - r) / c) - ci), min(n, math.floor((x + r) / c) - ci + 1)
        j0, j1 = max(0, math.floor((y - r) / c) - cj), min(n, math.floor((y + r) / c) - cj + 1)
        if i0 >= i1 or j0 >= j1:
            return 0
        cx = (self._corner[0] + np.arange(i0, i1) + 0.5) * c - x
        cy = (self._corner[1] + np.arange(j0, j1) + 0.5) * c - y
        inside = np.hypot(cx[:, None], cy[None, :]) <= r
        box = self._occupied[i0:i1, j0:j1]
        freed = int(np.count_nonzero(box & inside))
        if freed:
            box[inside] = False
            self.version += 1
        return freed

    # -- reading it --------------------------------------------------------------------------------
    def occupied_centres(self, x: float, y: float, radius: float) -> np.ndarray:
        """(K, 2) centres of the occupied cells whose centres are within ``radius`` of (x, y) (read from the
        sub-window that holds that disc)."""
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(radius) and radius >= 0):
            raise ValueError(f'occupied_centres: ({x}, {y}) and radius {radius} must be finite, radius >= 0')
        n, c = self.shape[0], self.cell
        i0 = max(0, math.floor((x - radius) / c) - self._corner[0])
        i1 = min(n, math.floor((x + radius) / c) - self._corner[0] + 1)
        j0 = max(0, math.floor((y - radius) / c) - self._corner[1])
        j1 = min(n, math.floor((y + radius) / c) - self._corner[1] + 1)
        if i0 >= i1 or j0 >= j1:
            return np.zeros((0, 2))
        i, j = np.nonzero(self._occupied[i0:i1, j0:j1])
        centres = np.column_stack([(self._corner[0] + i0 + i + 0.5) * c, (self._corner[1] + j0 + j + 0.5) * c])
        return centres[np.hypot(centres[:, 0] - x, centres[:, 1] - y) <= radius]

    def snapshot(self) -> MapSnapshot:
        """The map as a background solve reads it: origin, cell, a read-only copy of ``occupied``, version."""
        occupied = self._occupied.copy()
        occupied.flags.writeable = False
        return MapSnapshot(self.origin, self.cell, occupied, self.version)
