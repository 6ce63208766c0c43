"""A differential-drive robot's world without ROS: walls, boxes and posts, an exact laser, a
unicycle, the planner that drives it along its path, and the trips of issue 36.

**Obstacles** (metres, the odom frame, which is the world's here). Each has a signed distance d
(negative inside):
  * a wall, the segment [a, b] of thickness t (a capsule: its ends are round),
        d(p) = |p - a - clip((p - a).e / |e|^2, 0, 1) e| - t/2,   e = b - a;
  * a convex polygon with vertices v_0..v_{M-1} counter-clockwise (a box turned 45 degrees),
        d(p) = -+ min_i dist(p, [v_i, v_{i+1}]),   - when cross(v_{i+1} - v_i, p - v_i) > 0 for every i;
  * a disc (c, r) (a post), d(p) = |p - c| - r.
``clearance(p) = min over obstacles d(p)``, the distance to the nearest obstacle surface (exact:
the distance to a union is the least distance to its members), over (N, 2) points at once.

**The laser.** Beam j leaves the sensor o in the direction u_j = (cos phi_j, sin phi_j),
phi_j = yaw + angle_j; its range is the least t >= 0 at which o + t u_j meets a surface, +inf
when that is beyond ``range_max`` (REP 117: no return). With cross(p, q) = p_x q_y - p_y q_x:
  * the segment a + s e, s in [0, 1]:  t = cross(a - o, e) / cross(u, e),
    s = cross(a - o, u) / cross(u, e)  (from o + t u = a + s e crossed with e and with u);
  * the disc (c, r):  t = b - sqrt(b^2 - q),  b = u.(c - o),  q = |c - o|^2 - r^2, when b^2 >= q
    (from inside, q < 0: t = b + sqrt(b^2 - q), the far side; sim/laser.py's disc math);
  * a polygon: its edges; a wall: its two sides [a +- (t/2) n, b +- (t/2) n] (n the unit normal)
    and its two round ends, the discs (a, t/2) and (b, t/2). From outside, the first piece a
    beam meets is the wall's first surface: it reaches an inner part of a piece only after
    crossing the wall's boundary. (A sensor inside an obstacle is a collision already.)
Work: beams x pieces, vectorised.

**The unicycle.** State (x, y, theta), the command (v, w) held over dt along the exact arc:
    theta' = theta + w dt,
    (x', y') = (x, y) + v dt sinc(w dt / 2) (cos(theta + w dt / 2), sin(theta + w dt / 2)),
sinc(z) = sin(z) / z (1 at 0): the integral of v (cos, sin)(theta + w s) over s in [0, dt],
with no division by a small w. The robot is a disc of ``radius``: it collides where
clearance < radius (``collides``: the entries into that set along a path of poses, and how
deep; poses 1 cm apart at 0.5 m/s and 50 Hz).

**The planner** (``PathFollower``): pure pursuit of a carrot on the polyline of waypoints
(the planner's path, length S, arc length s). Its progress s* = argmin over s >= s*_prev of
|path(s) - p| (it never goes back along its path); the carrot q = path(min(s* + L, S)) with
L = ``lookahead``; the turn w = clip(gain wrap(atan2(q - p) - theta), -w_max, w_max); the speed
    v = cruise clip(|goal - p| / slow_radius, least_fraction, 1)
(linear from ``slow_radius``, the floor so that it gets there), and v = w = 0 once the robot is
within ``goal_tolerance`` of the goal, for good (the goal reached). It knows nothing of the
obstacles: the path is its plan. ``planner_time``: the time it takes alone (no filter) to drive
its path to the goal, the reference of "the planner's own time".

**The trips** (``scenario(name)``; every scenario's geometry is in ``GEOMETRY``, below): a
frozen ``Scenario`` with its world, start, waypoints, goal and its path's least clearance
from the obstacles minus the robot's radius (sampled every 1 cm along the path: within 5 mm).

This module imports numpy and the standard library only (no module of this package), so that
bench/bench_trips.py and test/unicycle_graph_support.py can load it by its path while another
checkout's supersafe_ros is under test.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
import math

import numpy as np

CRUISE_SPEED = 0.5       # m/s: the planner's (the TwistStamped at 0.5 m/s)
W_MAX = 1.0              # rad/s: the planner's largest turn rate (config/nav2_safety_filter.yaml's omega_max)
ROBOT_RADIUS = 0.25      # m: the robot
PATH_STEP = 0.01         # m: the path's clearance is sampled this often


def _cross(ax, ay, bx, by):
    return ax * by - ay * bx


def segment_distance(points, a, b) -> np.ndarray:
    """(N, S) distances from points (N, 2) to the segments [a_k, b_k] (a, b: (S, 2))."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)[:, None, :]
    a = np.asarray(a, dtype=float).reshape(-1, 2)[None]
    e = np.asarray(b, dtype=float).reshape(-1, 2)[None] - a
    length2 = np.maximum(np.einsum('nsk,nsk->ns', e, e), 1e-300)
    s = np.clip(np.einsum('nsk,nsk->ns', p - a, e) / length2, 0.0, 1.0)
    return np.linalg.norm(p - a - s[..., None] * e, axis=-1)


def ray_segment(origin, directions, a, b) -> np.ndarray:
    """(B, S) ranges t >= 0 at which the rays origin + t u_j meet the segments [a_k, b_k]; +inf if not."""
    o = np.asarray(origin, dtype=float).reshape(2)
    u = np.asarray(directions, dtype=float).reshape(-1, 2)[:, None, :]
    a = np.asarray(a, dtype=float).reshape(-1, 2)[None]
    e = np.asarray(b, dtype=float).reshape(-1, 2)[None] - a
    ao = a - o
    denom = _cross(u[..., 0], u[..., 1], e[..., 0], e[..., 1])
    ok = np.abs(denom) > 1e-12            # parallel beams meet a segment's ends through its neighbours
    safe = np.where(ok, denom, 1.0)
    t = _cross(ao[..., 0], ao[..., 1], e[..., 0], e[..., 1]) / safe
    s = _cross(ao[..., 0], ao[..., 1], u[..., 0], u[..., 1]) / safe
    hit = ok & (t >= 0.0) & (s >= 0.0) & (s <= 1.0)
    return np.where(hit, t, np.inf)


def ray_disc(origin, directions, centres, radii) -> np.ndarray:
    """(B, K) ranges at which the rays meet the discs (the far side from inside); +inf if not."""
    o = np.asarray(origin, dtype=float).reshape(2)
    u = np.asarray(directions, dtype=float).reshape(-1, 2)
    rel = np.asarray(centres, dtype=float).reshape(-1, 2) - o
    r = np.asarray(radii, dtype=float).reshape(-1)
    b = u @ rel.T                                            # (B, K)
    q = np.einsum('ij,ij->i', rel, rel) - r * r              # (K,)
    disc = b * b - q
    root = np.sqrt(np.maximum(disc, 0.0))
    t = np.where(q > 0, b - root, b + root)
    return np.where((disc >= 0) & (t >= 0), t, np.inf)


def box(cx: float, cy: float, width: float, height: float, yaw: float = 0.0) -> tuple:
    """The corners (counter-clockwise) of a width x height rectangle centred on (cx, cy), turned by yaw."""
    c, s = math.cos(yaw), math.sin(yaw)
    half = ((-width / 2, -height / 2), (width / 2, -height / 2), (width / 2, height / 2), (-width / 2, height / 2))
    return tuple((cx + c * x - s * y, cy + s * x + c * y) for x, y in half)


def _counter_clockwise(vertices) -> np.ndarray:
    v = np.asarray(vertices, dtype=float).reshape(-1, 2)
    area2 = np.sum(_cross(v[:, 0], v[:, 1], np.roll(v, -1, 0)[:, 0], np.roll(v, -1, 0)[:, 1]))
    return v if area2 > 0 else v[::-1]


@dataclass(frozen=True)
class World:
    """Obstacles in the plane: ``walls`` ((x0, y0, x1, y1, thickness), ...), convex ``polygons``
    (((x, y), ...), ...) and ``discs`` ((x, y, radius), ...); see the module for the math."""

    walls: tuple = ()
    polygons: tuple = ()
    discs: tuple = ()

    @cached_property
    def _walls(self) -> np.ndarray:
        return np.asarray(self.walls, dtype=float).reshape(-1, 5)

    @cached_property
    def _discs(self) -> np.ndarray:
        return np.asarray(self.discs, dtype=float).reshape(-1, 3)

    @cached_property
    def _edges(self) -> tuple:
        """(starts (E, 2), ends (E, 2), the first edge of each polygon (P,)) of every polygon's edges."""
        starts, ends, first = [], [], []
        for vertices in self.polygons:
            v = _counter_clockwise(vertices)
            first.append(sum(len(s) for s in starts))
            starts.append(v)
            ends.append(np.roll(v, -1, axis=0))
        if not starts:
            return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, dtype=int)
        return np.concatenate(starts), np.concatenate(ends), np.asarray(first, dtype=int)

    @cached_property
    def _wall_pieces(self) -> tuple:
        """(side starts, side ends) (2W, 2) and the round ends (centres (2W, 2), radii (2W,))."""
        w = self._walls
        a, b, half = w[:, 0:2], w[:, 2:4], w[:, 4] / 2.0
        e = b - a
        n = np.column_stack([-e[:, 1], e[:, 0]]) / np.maximum(np.linalg.norm(e, axis=1), 1e-300)[:, None]
        off = n * half[:, None]
        return (np.concatenate([a + off, a - off]), np.concatenate([b + off, b - off]),
                np.concatenate([a, b]), np.concatenate([half, half]))

    def clearance(self, points) -> np.ndarray:
        """(N,) signed distance from each point (N, 2) to the nearest obstacle surface (negative
        inside; +inf in an empty world)."""
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        out = np.full(len(p), np.inf)
        if len(self._walls):
            w = self._walls
            out = np.minimum(out, (segment_distance(p, w[:, 0:2], w[:, 2:4]) - w[:, 4] / 2.0).min(axis=1))
        if len(self._discs):
            d = self._discs
            out = np.minimum(out, (np.linalg.norm(p[:, None, :] - d[None, :, :2], axis=-1) - d[:, 2]).min(axis=1))
        starts, ends, first = self._edges
        if len(starts):
            dist = segment_distance(p, starts, ends)                        # (N, E)
            e = ends - starts
            rel = p[:, None, :] - starts[None]
            left = _cross(e[None, :, 0], e[None, :, 1], rel[..., 0], rel[..., 1]) > 0.0
            nearest = np.minimum.reduceat(dist, first, axis=1)               # (N, P)
            inside = np.logical_and.reduceat(left, first, axis=1)
            out = np.minimum(out, np.where(inside, -nearest, nearest).min(axis=1))
        return out

    def ray_cast(self, pose_of_sensor, angles, range_max: float) -> np.ndarray:
        """float32 ranges of beams at ``angles`` (the sensor's frame) from ``pose_of_sensor``
        (x, y, yaw): the nearest surface along each, +inf where none is within ``range_max``."""
        x, y, yaw = (float(v) for v in pose_of_sensor)
        a = yaw + np.asarray(angles, dtype=float).reshape(-1)
        u = np.column_stack([np.cos(a), np.sin(a)])
        o = (x, y)
        best = np.full(len(a), np.inf)
        starts, ends, _ = self._edges
        side_a, side_b, end_c, end_r = self._wall_pieces
        for hits in (ray_segment(o, u, np.concatenate([starts, side_a]), np.concatenate([ends, side_b])),
                     ray_disc(o, u, np.concatenate([self._discs[:, :2], end_c]),
                              np.concatenate([self._discs[:, 2], end_r]))):
            if hits.shape[1]:
                best = np.minimum(best, hits.min(axis=1))
        best[best > range_max] = np.inf
        return best.astype(np.float32)


# -- the unicycle ----------------------------------------------------------------------------
def unicycle_step(state, v, w, dt):
    """The state(s) (..., 3) after the command (v, w) held for dt along the exact arc (the module)."""
    s = np.asarray(state, dtype=float)
    half = 0.5 * np.asarray(w, dtype=float) * dt
    chord = np.asarray(v, dtype=float) * dt * np.sinc(half / np.pi)        # np.sinc(z) = sin(pi z) / (pi z)
    heading = s[..., 2] + half
    return np.stack([s[..., 0] + chord * np.cos(heading), s[..., 1] + chord * np.sin(heading),
                     s[..., 2] + 2.0 * half], axis=-1)


@dataclass(frozen=True)
class Contact:
    """A path's contact with the obstacles: ``entries`` of the robot's disc into any obstacle,
    ``poses_inside`` (how many poses overlap one) and ``depth``, the deepest overlap (m, 0 if none)."""

    entries: int
    poses_inside: int
    depth: float


def collides(world: World, points, radius: float = ROBOT_RADIUS) -> Contact:
    """Where the robot's disc of ``radius`` at the path's points (N, 2) overlaps an obstacle
    (clearance < radius): entries (outside -> inside, the first point counting if inside), poses, depth."""
    inside_by = radius - world.clearance(points)
    inside = inside_by > 0.0
    entries = int(np.count_nonzero(inside[1:] & ~inside[:-1])) + int(inside[:1].sum())
    return Contact(entries, int(inside.sum()), float(inside_by[inside].max()) if inside.any() else 0.0)


# -- the planner -----------------------------------------------------------------------------
def wrap(angle):
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(angle, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi


def path_arc_lengths(waypoints) -> np.ndarray:
    """The arc length at each waypoint of the polyline (M,), from 0 at the first."""
    p = np.asarray(waypoints, dtype=float).reshape(-1, 2)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def point_at(waypoints, s: float) -> np.ndarray:
    """The polyline's point at arc length s (clipped to [0, S])."""
    p = np.asarray(waypoints, dtype=float).reshape(-1, 2)
    arc = path_arc_lengths(p)
    s = float(np.clip(s, 0.0, arc[-1]))
    k = int(np.clip(np.searchsorted(arc, s, side='right') - 1, 0, len(p) - 2)) if len(p) > 1 else 0
    if len(p) == 1 or arc[k + 1] <= arc[k]:
        return p[min(k, len(p) - 1)].copy()
    return p[k] + (s - arc[k]) / (arc[k + 1] - arc[k]) * (p[k + 1] - p[k])


def progress_on_path(waypoints, point, least: float = 0.0) -> float:
    """The arc length s >= ``least`` of the polyline's point nearest ``point``."""
    p = np.asarray(waypoints, dtype=float).reshape(-1, 2)
    arc = path_arc_lengths(p)
    least = float(np.clip(least, 0.0, arc[-1]))
    if len(p) < 2:
        return least
    a, e, length = p[:-1], np.diff(p, axis=0), np.diff(arc)
    unit = e / np.maximum(length, 1e-300)[:, None]
    lo = np.clip(least - arc[:-1], 0.0, length)                 # the part of each segment at s >= least
    along = np.clip(((np.asarray(point, dtype=float)[:2] - a) * unit).sum(axis=1), lo, length)
    dist = np.linalg.norm(a + along[:, None] * unit - np.asarray(point, dtype=float)[:2], axis=1)
    dist[arc[1:] < least] = np.inf
    k = int(np.argmin(dist))
    return float(max(least, arc[k] + along[k]))


def approach_speed(distance: float, cruise: float, slow_radius: float, least_fraction: float) -> float:
    """v = cruise clip(distance / slow_radius, least_fraction, 1) (cruise if slow_radius is 0)."""
    if slow_radius <= 0.0:
        return float(cruise)
    return float(cruise * min(1.0, max(least_fraction, distance / slow_radius)))


@dataclass(frozen=True)
class PlannerConfig:
    """The planner's settings (see the module): speeds in m/s and rad/s, lengths in m."""

    cruise: float = CRUISE_SPEED
    w_max: float = W_MAX
    gain: float = 2.0                # rad/s per rad of heading error to the carrot
    lookahead: float = 0.5
    slow_radius: float = 0.5
    least_fraction: float = 0.2
    goal_tolerance: float = 0.1


@dataclass
class PathFollower:
    """The planner of one trip (pure pursuit of its path; the module): ``command(state) -> (v, w)``."""

    waypoints: tuple
    config: PlannerConfig = PlannerConfig()
    progress: float = 0.0
    arrived: bool = False
    _length: float = field(default=0.0, init=False, repr=False)

    def __post_init__(self):
        self._length = float(path_arc_lengths(self.waypoints)[-1])

    @property
    def goal(self) -> np.ndarray:
        return np.asarray(self.waypoints[-1], dtype=float)

    def command(self, state) -> tuple:
        """(v, w) at ``state`` (x, y, theta); (0, 0) from the first time within the goal's tolerance on."""
        c = self.config
        x, y, theta = (float(v) for v in np.asarray(state, dtype=float)[:3])
        d_goal = math.hypot(self.goal[0] - x, self.goal[1] - y)
        if self.arrived or d_goal <= c.goal_tolerance:
            self.arrived = True
            return 0.0, 0.0
        self.progress = progress_on_path(self.waypoints, (x, y), self.progress)
        carrot = point_at(self.waypoints, min(self.progress + c.lookahead, self._length))
        error = float(wrap(math.atan2(carrot[1] - y, carrot[0] - x) - theta))
        w = float(np.clip(c.gain * error, -c.w_max, c.w_max))
        return approach_speed(d_goal, c.cruise, c.slow_radius, c.least_fraction), w


# -- the trips ---------------------------------------------------------------------------------
# Every scenario's geometry, in metres (start: x, y, heading). A door is the gap between two
# walls' round ends: wall pieces end 0.6 m + half their thickness from the door's centre line, so
# the door is 1.2 m clear. Boxes: (cx, cy, width, height, yaw); yaw pi/4 turns a corner toward a
# robot that comes along +x. Posts: (x, y, radius).
GEOMETRY = {
    'door': dict(
        about='a wall across the path at x = 4 with a 1.2 m door on the path; the robot 4 m before it, '
              'heading straight at the door, its goal 3 m behind it',
        start=(0.0, 0.0, 0.0), waypoints=((0.0, 0.0), (7.0, 0.0)),
        walls=((4.0, -6.0, 4.0, -0.65, 0.1), (4.0, 0.65, 4.0, 6.0, 0.1))),
    'open_field': dict(
        about='a 9 m trip along y = 0 past a box turned 45 degrees, a wall piece and posts of three sizes '
              '(0.1, 0.25, 0.5 m), the path at least radius + 0.35 m from each',
        start=(0.0, 0.0, 0.0), waypoints=((0.0, 0.0), (9.0, 0.0)),
        walls=((5.0, -1.0, 7.0, -1.0, 0.2),),
        boxes=((3.0, 1.25, 0.8, 0.8, math.pi / 4),),
        posts=((1.5, -0.7, 0.1), (4.5, 1.0, 0.25), (7.5, 1.4, 0.5))),
    'lane': dict(
        about='the issue\'s lane, 3.1 m wide: a wall 2.2 m to the left of a straight 12 m path, a post '
              '(radius 0.1) 0.9 m clear of it on the right, half way',
        start=(0.0, 0.0, 0.0), waypoints=((0.0, 0.0), (12.0, 0.0)),
        walls=((-2.0, 2.25, 14.0, 2.25, 0.1),),
        posts=((6.0, -1.0, 0.1),)),
    'facing_wall': dict(
        about='the robot 1.5 m from a wall (its centre to the surface), heading at it; the planner drives '
              'straight at it (its goal 3.5 m behind the wall)',
        start=(0.0, 0.0, 0.0), waypoints=((0.0, 0.0), (5.0, 0.0)),
        walls=((1.55, -4.0, 1.55, 4.0, 0.1),)),
    'combined': dict(
        about='one 11 m trip: a box turned 45 degrees (corner toward the robot), posts of three sizes '
              '(0.1, 0.25, 0.5 m), and a wall at x = 6 with a 1.2 m door on the path',
        start=(0.0, 0.0, 0.0), waypoints=((0.0, 0.0), (11.0, 0.0)),
        walls=((6.0, -6.0, 6.0, -0.65, 0.1), (6.0, 0.65, 6.0, 6.0, 0.1)),
        boxes=((2.5, 1.2, 0.8, 0.8, math.pi / 4),),
        posts=((1.2, -0.75, 0.1), (3.8, -1.1, 0.25), (9.0, 1.1, 0.5))),
}
SCENARIOS = tuple(GEOMETRY)


@dataclass(frozen=True)
class Scenario:
    """One trip: its ``world``, the robot's ``start`` (x, y, theta), the planner's ``waypoints``
    (its path, ending at ``goal``), and ``path_clearance``, the path's least clearance from the
    obstacles minus ``robot_radius`` (negative: the path itself runs into an obstacle)."""

    name: str
    world: World
    start: tuple
    waypoints: tuple
    goal: tuple
    path_clearance: float
    robot_radius: float = ROBOT_RADIUS
    about: str = ''


def path_points(waypoints, step: float = PATH_STEP) -> np.ndarray:
    """Points along the polyline at most ``step`` apart, its vertices included."""
    p = np.asarray(waypoints, dtype=float).reshape(-1, 2)
    out = [p[:1]]
    for a, b in zip(p[:-1], p[1:]):
        n = max(1, int(math.ceil(np.linalg.norm(b - a) / step)))
        out.append(a + np.linspace(0.0, 1.0, n + 1)[1:, None] * (b - a))
    return np.concatenate(out)


def scenario(name: str, robot_radius: float = ROBOT_RADIUS) -> Scenario:
    """The scenario ``name`` (one of SCENARIOS) built from GEOMETRY."""
    g = GEOMETRY[name]
    world = World(walls=tuple(g.get('walls', ())), polygons=tuple(box(*b) for b in g.get('boxes', ())),
                  discs=tuple(g.get('posts', ())))
    waypoints = tuple(tuple(map(float, w)) for w in g['waypoints'])
    clearance = float(world.clearance(path_points(waypoints)).min()) - robot_radius
    return Scenario(name, world, tuple(map(float, g['start'])), waypoints, waypoints[-1], clearance,
                    robot_radius, g['about'])


def door() -> Scenario:
    """A wall with a 1.2 m door, the path through its centre, straight at it for 4 m before."""
    return scenario('door')


def open_field() -> Scenario:
    """A 9 m trip past a box turned 45 degrees, a wall piece and posts of three sizes."""
    return scenario('open_field')


def lane() -> Scenario:
    """The issue's 3.1 m lane: a wall 2.2 m to one side of a straight 12 m path, a post 0.9 m on the other."""
    return scenario('lane')


def facing_wall() -> Scenario:
    """The robot 1.5 m from a wall, heading at it, its planner driving straight at it."""
    return scenario('facing_wall')


def combined() -> Scenario:
    """A door, a box corner toward the robot and posts of three sizes in one trip (the issue's done-when)."""
    return scenario('combined')


def drive(scenario: Scenario, commands, dt: float, max_time: float):
    """Poses (K, 3) of the robot from the scenario's start under ``commands(state) -> (v, w)`` held
    dt each, until the command is (0, 0) after a start or ``max_time``; and the time it stopped
    (None if it never did)."""
    state = np.asarray(scenario.start, dtype=float)
    poses = [state]
    for k in range(int(round(max_time / dt))):
        v, w = commands(state)
        if v == 0.0 and w == 0.0:
            return np.asarray(poses), k * dt
        state = unicycle_step(state, v, w, dt)
        poses.append(state)
    return np.asarray(poses), None


def planner_time(scenario: Scenario, dt: float = 0.02, config: PlannerConfig = PlannerConfig(),
                 max_time: float = 600.0) -> float:
    """The time (s) the planner alone takes to drive its path to the goal (no filter; it drives
    through obstacles on its path as if they were not there); inf if not within ``max_time``."""
    _, stopped = drive(scenario, PathFollower(scenario.waypoints, config).command, dt, max_time)
    return math.inf if stopped is None else float(stopped)
