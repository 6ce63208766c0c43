"""Collision trials: filtered robots in closed loop with detected discs, ROS-free.

A trial is one robot's encounter with a layout of discs: from its start, across the
layout, to its goal line. The collision tests and ``bench/bench_collisions.py``
count, with this loop, collisions with *detected* obstacles (every obstacle of a
robot's layout is detected, from the start). Each robot has its own layout, start
and goal and does not meet the others, so many trials run side by side through one
vectorised filter call per tick.

One tick of ``step`` seconds, as in the lockstep team graph:

1. the robot is at x_k (time t_k = k step) and publishes its pose stamped t_k;
2. the planner steers for the goal from x_k (``goal_seeking_turn_rate``), at its speed
   (``speeds``: the robot's largest ``speed`` throughout, or a profile that slows, stops,
   waits and speeds up, ``speed_profiles``);
3. the filter decides at t_k; with probability ``stale_probability`` its pose
   callback has not run yet and it holds the pose of step k-1 (stamped t_{k-1}),
   the race measured in the team graph (7.3 % of decisions near obstacles);
4. the robot moves along the exact arc of the filter's command (turn clipped to
   +-w_max; the linear.x it was sent, clipped to [0, speed], or for a constant-speed
   robot, ``FilterConfig.constant_speed``, its speed) to x_{k+1}; the distance to every
   disc is checked at ``substeps`` points along the arc.

A collision is an entry deeper than ``depth`` into a disc (counted once per
entry). A trial ends when the robot crosses its goal line; one that has not
crossed it after ``time_limit`` seconds was trapped.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..filter.decide import step_many
from ..filter.inputs import RobotFilter
from ..filter.propagation import arc_flow
from ..filter.types import FilterConfig
from ..reach.grid import wrap_angle
from .laser import beam_angles, ray_cast


@dataclass(frozen=True)
class CollisionTrial:
    """One approach: discs (K, 2) centres of ``run_trials``' radius or (K, 3) [x, y, r] of
    their own radius, a start state, a goal point and the goal line's normal.

    The trial is done when (p - goal) . direction >= 0.
    """

    discs: np.ndarray
    start: tuple
    goal: tuple
    direction: tuple = (1.0, 0.0)


@dataclass
class TrialResult:
    """Counts over trials run together (``run_trials``), added up with ``add``."""

    trials: int = 0
    collisions: int = 0            # entries deeper than ``depth``
    deep_collisions: int = 0       # entries deeper than ``deep``
    max_depth: float = 0.0
    trapped: int = 0               # not across the goal line within the time limit
    decisions: int = 0
    stale_decisions: int = 0
    overrides: int = 0
    sim_time: float = 0.0          # robot-seconds simulated
    max_speed_excess: float = 0.0  # the most a robot was sent beyond its planner's speed [m/s]
    depths: list = field(default_factory=list)

    def add(self, other: 'TrialResult') -> None:
        for name in ('trials', 'collisions', 'deep_collisions', 'trapped', 'decisions',
                     'stale_decisions', 'overrides', 'sim_time'):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.max_depth = max(self.max_depth, other.max_depth)
        self.max_speed_excess = max(self.max_speed_excess, other.max_speed_excess)
        self.depths.extend(other.depths)

    def summary(self) -> str:
        return (f'{self.trials} encounters, {self.collisions} collisions > 1 cm '
                f'({self.deep_collisions} > 5 cm, deepest {100 * self.max_depth:.1f} cm), '
                f'{self.trapped} trapped, {self.overrides / max(self.decisions, 1):.1%} overrides, '
                f'{self.stale_decisions / max(self.decisions, 1):.1%} decisions on the previous pose')


@dataclass(frozen=True)
class ScanSensor:
    """A robot that sees its layout only through a planar laser, as ``supersafe team --sensors scan``
    does: ``beams`` beams round the full circle ray-cast from the robot's centre against the discs
    whose centre is within ``range_max`` (the simulated robot's sensor, ``sim.laser``; +inf where
    nothing is within range), its scans kept in a local map and judged by the map's one avoid value,
    as the filter node does with ``detections_type`` laser_scan (``filter_inputs.SensorMap``): each
    scan's REP 117 readings (``readings.scan_rays``, a +inf clearing to range_max with
    ``inf_is_valid``) put into a ``local_map.LocalMap`` (``cell``, ``size``, ``depth``) at the
    scan's own pose (gap 0), and the map's value (``map_value``: ``value_cell``,
    ``value_headings``, ``value_horizon``, ``value_reach``, the robot's clearance ``robot_radius``)
    solved every ``value_every`` steps and in force one step after it was asked for (a background
    solve's latency: the value is that of the map at its solve time). ``stale_probability``: the
    filter decides on the previous scan's map. ``markers``: the filter is given the seen discs
    themselves (a MarkerArray of the exact obstacles within range), the reference that tells what
    the map and its value do from what the law does with exact discs."""

    beams: int = 360
    range_max: float = 10.0
    robot_radius: float = 0.1
    depth: float = 5.2
    cell: float = 0.2
    size: float = 30.0
    inf_is_valid: bool = True
    value_cell: float = 0.25
    value_headings: int = 38
    value_horizon: float = 1.5
    value_reach: float = 3.0
    value_every: int = 2
    stale_probability: float = 0.0
    markers: bool = False

    def discs(self, state, layout, radii) -> np.ndarray:
        """``markers``: the (K, 3) discs within range of ``state``, what a MarkerArray detector gives."""
        near = np.hypot(layout[:, 0] - state[0], layout[:, 1] - state[1]) <= self.range_max
        return np.column_stack([layout[near], radii[near]])

    def robot(self, config) -> '_MapRobot':
        """One robot's map, its value (solved inline, in force a step later) and its view."""
        return _MapRobot(self, config)


class _MapRobot:
    """A ``ScanSensor`` robot's local map and values (``view``: what its filter judges by)."""

    def __init__(self, sensor: ScanSensor, config):
        from ..filter.sensing.local_map import LocalMap, MapSettings
        from ..filter.constraints.map_rows import MapView
        from ..filter.sensing.map_value import MapValueSettings, MapValueWorker
        self.sensor = sensor
        self.map = LocalMap(MapSettings(cell=sensor.cell, size=sensor.size, depth=sensor.depth))
        settings = MapValueSettings(cell=sensor.value_cell, headings=sensor.value_headings,
                                    horizon=sensor.value_horizon, reach=sensor.value_reach,
                                    recentre=min(0.5, sensor.value_reach))
        self.worker = MapValueWorker(config.speed, config.omega_max, sensor.robot_radius, settings, inline=True)
        self.in_force = None          # the value solved at the last request, in force from the next step
        self.view = MapView(self.map, sensor.robot_radius, self, 'scan')
        self.steps = 0

    def latest(self):
        return self.in_force

    def scan(self, state, layout, radii) -> None:
        """A scan of ``layout`` taken at ``state``, put into the map."""
        from ..filter.sensing.readings import scan_rays
        s = self.sensor
        a = beam_angles(s.beams)
        near = np.hypot(layout[:, 0] - state[0], layout[:, 1] - state[1]) <= s.range_max + radii
        ranges = ray_cast(state, a, layout[near], radii[near], s.range_max)
        rays = scan_rays(ranges, float(a[0]), float(a[-1]), float(a[1] - a[0]), 0.05, s.range_max,
                         inf_is_valid=s.inf_is_valid)
        self.map.follow(float(state[0]), float(state[1]))
        self.map.integrate_rays((float(state[0]), float(state[1]), float(state[2])), rays)

    def step(self, state) -> None:
        """One step: the value asked for a step ago comes into force; every ``value_every`` steps the
        map's value is asked for around ``state``."""
        self.in_force = self.worker.latest()
        if self.steps % self.sensor.value_every == 0:
            self.worker.submit(self.map.snapshot(), (float(state[0]), float(state[1])), stamp=self.steps)
        self.steps += 1


def single_disc_trials(n, rng, distance=9.0, offset=3.0, heading_noise=0.3) -> list:
    """Approaches to one disc at the origin: start at x = -distance with a lateral offset,
    goal on the far side with another offset, heading roughly at the goal."""
    out = []
    for _ in range(n):
        y0, y1 = rng.uniform(-offset, offset, 2)
        heading = np.arctan2(y1 - y0, 2 * distance) + rng.uniform(-heading_noise, heading_noise)
        out.append(CollisionTrial(np.zeros((1, 2)), (-distance, y0, heading), (distance, y1)))
    return out


def row_layout(spacing=4.5, count=3) -> np.ndarray:
    """Discs in a row along x, centres ``spacing`` apart, centred on the origin."""
    return np.stack([(np.arange(count) - (count - 1) / 2) * spacing, np.zeros(count)], axis=1)


def cup_layout(rng, gaps=(3.0, 3.6), radius=1.8) -> np.ndarray:
    """Three discs in a cup opening toward -x: a bottom disc and two wings, every gap
    (rim to rim) drawn from ``gaps``."""
    g_wings, g_side = rng.uniform(*gaps, 2)
    dy = (g_wings + 2 * radius) / 2
    dx = np.sqrt((g_side + 2 * radius) ** 2 - dy ** 2)
    return np.array([[dx / 2, 0.0], [-dx / 2, dy], [-dx / 2, -dy]])


def random_layout(rng, count, half=7.0, min_gap=0.5, radius=1.8, tries=2000) -> np.ndarray:
    """``count`` discs uniform in a square of half-width ``half``, rims at least ``min_gap`` apart."""
    out = []
    for _ in range(tries):
        p = rng.uniform(-half, half, 2)
        if all(np.hypot(*(p - q)) >= 2 * radius + min_gap for q in out):
            out.append(p)
            if len(out) == count:
                break
    return np.array(out)


def field_trials(n, rng, radii=(0.8, 1.8, 2.6), count=10, half_x=9.0, half_y=12.0, gap=2.0,
                 goal_x=16.0) -> list:
    """Crossings of a team world (``sim.world``): ``count`` discs of ``radii`` in turn, centres
    uniform in [-half_x, half_x] x [-half_y, half_y] and at least 2 max(radii) + ``gap`` apart;
    a robot starts on one goal line x = -+goal_x (sides in turn) heading for a random point of
    the other. ``half_x`` <= goal_x - max(radii) - 4 keeps every start 4 m or more from a rim
    (above the level whatever its heading)."""
    out = []
    big = max(radii)
    for i in range(n):
        lay = []
        for _ in range(20000):
            p = rng.uniform((-half_x, -half_y), (half_x, half_y))
            if all(np.hypot(p[0] - q[0], p[1] - q[1]) >= 2 * big + gap for q in lay):
                lay.append((p[0], p[1], radii[len(lay) % len(radii)]))
                if len(lay) == count:
                    break
        side = 1.0 if i % 2 else -1.0
        y0, y1 = rng.uniform(-half_y + 1.0, half_y - 1.0, 2)
        start = (-goal_x * side, y0, float(np.arctan2(y1 - y0, 2 * goal_x * side)))
        out.append(CollisionTrial(np.array(lay), start, (goal_x * side, y1), (side, 0.0)))
    return out


def layout_trials(layouts, rng, margin=10.0, offset=None) -> list:
    """One approach per layout from a random direction, across it to the far side.

    The start is ``margin`` beyond the layout's farthest disc, with a lateral offset
    within the layout's extent (default), so most straight paths meet a disc.
    """
    out = []
    for discs in layouts:
        discs = np.asarray(discs, dtype=float)
        discs = discs.reshape(-1, discs.shape[-1] if discs.ndim == 2 else 2)
        rim = discs[:, 2] if discs.shape[1] == 3 else 1.8
        extent = float(np.max(np.hypot(discs[:, 0], discs[:, 1]) + rim))
        phi = rng.uniform(-np.pi, np.pi)
        d, nrm = np.array([np.cos(phi), np.sin(phi)]), np.array([-np.sin(phi), np.cos(phi)])
        spread = extent if offset is None else offset
        b0, b1 = rng.uniform(-spread, spread, 2)
        start = -(extent + margin) * d + b0 * nrm
        goal = (extent + margin) * d + b1 * nrm
        heading = np.arctan2(*(goal - start)[::-1]) + rng.uniform(-0.2, 0.2)
        out.append(CollisionTrial(discs, (start[0], start[1], heading), tuple(goal), tuple(d)))
    return out


def speed_profiles(rng, n, speed=3.0, kinds=('slow', 'stop_and_go', 'ramp', 'random')):
    """A planner's speed per trial that is not the robot's largest: ``speeds(t, idx)`` -> the
    linear.x of trials ``idx`` at time t, each trial one of ``kinds`` (drawn in turn) with its
    own phase: 'slow' a constant fraction of ``speed`` (0.1 to 0.9), 'stop_and_go' waits
    stopped and drives at full speed in turns (0.3 to 2 s each: a planner that stops at a
    door and goes on), 'ramp' accelerates from 0 to full speed and brakes to a crawl over a
    few seconds, 'random' a new speed in [0, speed] every 0.2 to 1 s (0 one time in four)."""
    kind = np.array([kinds[i % len(kinds)] for i in range(n)])
    fraction = rng.uniform(0.1, 0.9, n)
    on, off, phase = rng.uniform(0.3, 2.0, n), rng.uniform(0.3, 2.0, n), rng.uniform(0.0, 4.0, n)
    period = rng.uniform(2.0, 6.0, n)
    hold = rng.uniform(0.2, 1.0, n)
    table = rng.uniform(0.0, speed, (n, 256))
    table[rng.random((n, 256)) < 0.25] = 0.0

    def speeds(t, idx):
        k = kind[idx]
        cycle = np.mod(t + phase[idx], on[idx] + off[idx])
        wave = 0.5 - 0.5 * np.cos(2.0 * np.pi * (t + phase[idx]) / period[idx])
        slot = np.minimum((t / hold[idx]).astype(int), table.shape[1] - 1)
        return np.select([k == 'slow', k == 'stop_and_go', k == 'ramp'],
                         [fraction[idx] * speed, np.where(cycle < off[idx], 0.0, speed), speed * wave],
                         table[idx, slot])
    return speeds


def run_trials(trials, guard, step=0.05, stale_probability=0.0, late_probability=0.0,
               config=None, rng=None,
               radius=1.8, depth=0.01, deep=0.05, time_limit=30.0, substeps=4,
               omega_max=1.0, speed=3.0, gain=2.0, speeds=None, sensor=None, safe_set=None,
               trace=None) -> TrialResult:
    """Run every trial to its goal line (or the time limit) under ``guard``.

    ``late_probability``: the filter's reply misses its step (the lockstep moved on
    on an earlier reply), so the robot holds its previous command one step longer.
    ``speeds``: the planner's linear.x, ``speeds(t, idx)`` for the trials ``idx`` still
    running (``speed_profiles``); None: ``speed`` throughout. The robot drives at the
    linear.x it was sent (clipped to [0, speed]), a constant-speed robot at ``speed``.

    ``sensor``: a ``ScanSensor``: the filter sees the layout through a laser, its scans kept in a
    local map judged by the map's value (as the node does), or with ``markers`` the discs within
    range (``safe_set`` tells it which discs its value function's grid can reach); collisions are
    still counted against the layout. ``trace``: a list to which each decision's (trial, t, state,
    action, discs given) is appended (to look at a crash).

    ``guard(filters, t)`` returns one FilterOutput per filter: e.g.
    ``lambda fs, t: step_many(fs, safe_set, t)``.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    config = config or FilterConfig(speed=speed, omega_max=omega_max)
    n = len(trials)
    state = np.array([e.start for e in trials], dtype=float).reshape(n, 3)
    goal = np.array([e.goal for e in trials], dtype=float).reshape(n, 2)
    direction = np.array([e.direction for e in trials], dtype=float).reshape(n, 2)
    filters = [RobotFilter(config, f'robot_{i}') for i in range(n)]
    previous = state.copy()
    applied = np.zeros(n)                           # the command the robot holds
    applied_speed = np.zeros(n)
    width = max(len(e.discs) for e in trials)
    discs = np.full((n, width, 2), 1e9)             # padded: far-away fillers never collide
    radii = np.full((n, width), float(radius))
    for i, e in enumerate(trials):
        d = np.asarray(e.discs, dtype=float)
        discs[i, :len(d)] = d[:, :2]
        if d.shape[1] == 3:
            radii[i, :len(d)] = d[:, 2]
    inside = np.zeros((n, width), dtype=bool)
    scans = [None] * n                              # with a sensor: the scan's discs each filter holds
    mapped = sensor is not None and not sensor.markers
    robots = [sensor.robot(config) for _ in range(n)] if mapped else None
    deepest = np.zeros((n, width))
    active = np.ones(n, dtype=bool)
    res = TrialResult(trials=n)

    def close(mask):
        d = deepest[mask]
        res.depths.extend(d.tolist())
        res.deep_collisions += int(np.sum(d > deep))
        res.max_depth = max(res.max_depth, float(d.max(initial=0.0)))
        deepest[mask] = 0.0

    ticks = int(np.ceil(time_limit / step))
    for k in range(ticks):
        t = k * step
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        stale = rng.random(len(idx)) < stale_probability if k > 0 else np.zeros(len(idx), bool)
        error = wrap_angle(np.arctan2(goal[idx, 1] - state[idx, 1], goal[idx, 0] - state[idx, 0])
                           - state[idx, 2])
        planned = np.clip(gain * error, -omega_max, omega_max)
        linear = np.full(len(idx), float(speed)) if speeds is None else np.asarray(speeds(t, idx), dtype=float)
        for j, i in enumerate(idx):
            f = filters[i]
            if stale[j]:
                f.update_pose(previous[i], t, stamp=t - step)
            else:
                f.update_pose(state[i], t, stamp=t)
            if sensor is None:
                f.update_detections(trials[i].discs, t)
            elif mapped:
                robot = robots[i]
                robot.step(state[i])
                if k == 0 or rng.random() >= sensor.stale_probability:
                    robot.scan(state[i], discs[i], radii[i])
                f.update_view(robot.view, t)
            else:
                if k == 0 or rng.random() >= sensor.stale_probability:
                    scans[i] = sensor.discs(state[i], discs[i], radii[i])
                f.update_detections(scans[i], t, safe_set)
            f.update_command(float(planned[j]), t, None if speeds is None else float(linear[j]))
        outs = guard([filters[i] for i in idx], t)
        decided = np.clip(np.array([o.omega for o in outs]), -omega_max, omega_max)
        driven = np.full(len(idx), float(speed)) if config.constant_speed else \
            np.clip(np.array([o.linear for o in outs]), 0.0, speed)
        late = rng.random(len(idx)) < late_probability if k > 0 else np.zeros(len(idx), bool)
        omega = np.where(late, applied[idx], decided)
        v = np.where(late, applied_speed[idx], driven)
        applied[idx], applied_speed[idx] = decided, driven
        res.max_speed_excess = max(res.max_speed_excess, float(np.max(driven - linear, initial=0.0)))
        res.decisions += len(idx)
        res.stale_decisions += int(stale.sum())
        res.overrides += sum(o.action != 'pass' for o in outs)
        if trace is not None:
            trace.extend((int(i), t, state[i].copy(), o.action, None if scans[i] is None else scans[i])
                         for i, o in zip(idx.tolist(), outs))
        previous[idx] = state[idx]
        for s in range(1, substeps + 1):
            pts = arc_flow(state[idx], v, omega, np.full(len(idx), step * s / substeps))
            d = radii[idx] - np.linalg.norm(pts[:, None, :2] - discs[idx], axis=2)   # depth into each disc
            entered = (d > depth) & ~inside[idx]
            res.collisions += int(entered.sum())
            inside[idx] |= d > depth
            deepest[idx] = np.maximum(deepest[idx], d)
            left = np.zeros_like(inside)
            left[idx] = inside[idx] & (d < 0.0)      # an entry ends when the robot is out again
            if left.any():
                close(left)
                inside[left] = False
        state[idx] = arc_flow(state[idx], v, omega, np.full(len(idx), step))
        res.sim_time += step * len(idx)
        across = np.einsum('ij,ij->i', state[idx, :2] - goal[idx], direction[idx]) >= 0.0
        active[idx[across]] = False
    if inside.any():
        close(inside)
    res.trapped = int(active.sum())
    return res


def standard_guard(safe_set):
    """The per-obstacle filter of ``core`` as a guard."""
    return lambda filters, t: step_many(filters, safe_set, t)
