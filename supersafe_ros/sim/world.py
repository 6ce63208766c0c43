"""The team task of the paper, without ROS: obstacles, goals, trips, crashes, score.

Field: x in [-half_width, half_width], y in [-half_height, half_height] (map frame).
Robots make trips between the two sides: a trip's goal is a point on the goal line
x = +-goal_x with a random y; the trip is complete when the robot crosses that line
(a Dubins car cannot always hit a point, but it can always cross a line), and the
next goal is on the other side.

Obstacles: discs of radius ``radius`` (or, with ``radii``, obstacle i of radii[i mod len]:
several sizes in turn); ``n_obstacles`` centres are sampled uniformly between the goal
lines with at least ``2 radius + spacing`` (the largest radius) between centres. An
intervention removes one obstacle and spawns a replacement with the same spacing
rule and at least ``respawn_clearance`` from every robot (rejection sampling; if
no place qualifies after ``max_tries`` the clearance is halved, and so on, so the
world never stalls - the relaxation is reported).

Crash: a robot's centre more than ``crash_tolerance`` inside an obstacle disc. One
crash is counted per entry: the robot must leave the disc before the same obstacle
can count again. The tolerance (5 cm) is for grazes: a filter acting on the zero
level set of the standard value function skims the rim by design (V = 0 means a
closest approach of exactly the radius), and the value function's numerical error
and the discrete control steps put that skim a few millimetres either side.

Intervention classification (paper Sec. V-A): a false positive iff every robot
within ``near_distance`` of the removed obstacle had detected it (its latest
detections contain that obstacle). With no robot near, nobody needed saving:
also a false positive.

Score (paper Sec. IV-C): +trip_reward per trip, -crash_penalty per crash,
-intervention_penalty per intervention (half a crash by default).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from .dubins_sim import base_seed, keyed_rng
from .efficiency import OVERRIDE, EfficiencyMeter, team_efficiency


@dataclass(frozen=True)
class WorldConfig:
    half_width: float = 20.0
    half_height: float = 12.0
    goal_x: float = 16.0
    n_obstacles: int = 10
    radius: float = 1.8
    # obstacle id i has radius radii[i % len(radii)] (sizes in turn); () = every one of ``radius``
    # (zeros are dropped: config/world.yaml's [0.0], a parameter list cannot be empty)
    radii: tuple = ()
    crash_tolerance: float = 0.05   # a graze this close to the rim is not a crash
    spacing: float = 2.0            # extra gap between obstacle discs
    goal_margin: float = 4.0        # obstacles keep this far inside the goal lines
    respawn_clearance: float = 8.0  # new obstacles appear at least this far from robots
    near_distance: float = 6.0      # robots this close to an obstacle count for FP
    detection_tolerance: float = 0.5  # a detection within this of a centre names it
    trip_reward: float = 10.0
    crash_penalty: float = 20.0
    intervention_penalty: float = 10.0
    max_tries: int = 2000

    def __post_init__(self):
        for name in ('half_width', 'half_height', 'goal_x', 'radius', 'near_distance',
                     'detection_tolerance'):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f'{name} must be positive and finite, got {v}')
        if self.goal_x >= self.half_width:
            raise ValueError('goal_x must lie inside the field (< half_width)')
        object.__setattr__(self, 'radii', tuple(float(r) for r in self.radii if r != 0.0))
        if not all(math.isfinite(r) and r > 0 for r in self.radii):
            raise ValueError(f'radii must be positive and finite, got {self.radii}')
        if self.goal_x - self.goal_margin <= self.largest_radius:
            raise ValueError('goal_margin leaves no room for obstacles')
        if self.n_obstacles < 0:
            raise ValueError('n_obstacles must be >= 0')

    @property
    def largest_radius(self) -> float:
        return max(self.radii) if self.radii else self.radius

    def radius_of(self, ids) -> np.ndarray:
        """The radii of obstacles ``ids`` (int array)."""
        ids = np.asarray(ids, dtype=int)
        if not self.radii:
            return np.full(ids.shape, self.radius)
        return np.asarray(self.radii)[ids % len(self.radii)]


@dataclass
class Intervention:
    obstacle_id: int
    robot: str | None
    time: float
    false_positive: bool
    near_robots: tuple
    undetected_by: tuple


@dataclass
class RobotRecord:
    name: str
    position: np.ndarray | None = None
    goal: np.ndarray | None = None
    side: int = 1                      # +1: heading for x = +goal_x, -1: for -goal_x
    trips: int = 0
    crashes: int = 0
    inside: set = field(default_factory=set)      # obstacle ids the robot is inside
    detections: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    detections_time: float | None = None


class World:
    """Obstacles, goals and the team's counts; feed it poses, detections and interventions."""

    def __init__(self, config: WorldConfig, robots, seed: int | None = 0):
        self.config = config
        self.seed = base_seed(seed)
        # separate streams: obstacle placement, and each robot's goals, so the order in
        # which robots' events are processed does not change what anyone draws
        self.rng = keyed_rng(self.seed, 'obstacles')
        self.robots = {name: RobotRecord(name) for name in robots}
        self.goal_rngs = {name: keyed_rng(self.seed, 'goals', name) for name in robots}
        if not self.robots:
            raise ValueError('the world needs at least one robot')
        self.obstacles: dict[int, np.ndarray] = {}
        self._arrays = None    # cached (ids, xy); None after any change
        self.next_id = 0
        self.interventions: list[Intervention] = []
        self.relaxed_spawns = 0
        # H2 measures (sim/efficiency.py): the filter's action in force per robot
        self.meters = {name: EfficiencyMeter() for name in robots}
        self.filter_actions = {name: None for name in robots}
        for _ in range(config.n_obstacles):
            self._spawn(clearance=0.0)

    # ----- obstacles -----------------------------------------------------------------
    def obstacle_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(ids int[K], centres float[K, 2]) in id order."""
        key = tuple(self.obstacles)
        if self._arrays is None or self._arrays[0] != key:
            ids = np.array(sorted(self.obstacles), dtype=int)
            xy = np.array([self.obstacles[i] for i in ids], dtype=float).reshape(-1, 2)
            self._arrays = (key, ids, xy)
        return self._arrays[1], self._arrays[2]

    def _robot_xy(self) -> np.ndarray:
        pts = [r.position[:2] for r in self.robots.values() if r.position is not None]
        return np.array(pts, dtype=float).reshape(-1, 2)

    def _spawn(self, clearance: float) -> int:
        c = self.config
        min_gap = 2 * c.largest_radius + c.spacing
        xmax = c.goal_x - c.goal_margin
        ymax = c.half_height - c.largest_radius
        robots = self._robot_xy()
        _, others = self.obstacle_arrays()
        relax = 1.0
        while True:
            for _ in range(c.max_tries):
                p = np.array([self.rng.uniform(-xmax, xmax), self.rng.uniform(-ymax, ymax)])
                if len(others) and np.min(np.hypot(*(others - p).T)) < min_gap * relax:
                    continue
                if len(robots) and np.min(np.hypot(*(robots - p).T)) < clearance * relax:
                    continue
                oid = self.next_id
                self.next_id += 1
                self.obstacles[oid] = p
                return oid
            relax *= 0.5        # crowded field: halve the spacing rules and try again
            self.relaxed_spawns += 1

    # ----- robots ---------------------------------------------------------------------
    def new_goal(self, name: str) -> np.ndarray:
        """Draw the next goal of a robot, on its current side."""
        r = self.robots[name]
        c = self.config
        r.goal = np.array([r.side * c.goal_x,
                           self.goal_rngs[name].uniform(-(c.half_height - 2.0), c.half_height - 2.0)])
        return r.goal

    def initial_side(self, name: str, x: float) -> None:
        """Head for the far side from where the robot starts; draws its first goal."""
        r = self.robots[name]
        r.side = 1 if x <= 0 else -1
        self.new_goal(name)

    def set_filter_action(self, name: str, action: str) -> None:
        """The robot's safety filter reported ``action`` (pass / override / fail_safe)."""
        if name not in self.filter_actions:
            raise KeyError(f'unknown robot {name}')
        self.filter_actions[name] = str(action)

    def update_pose(self, name: str, state, time: float | None = None) -> dict:
        """Advance the counts for one robot pose; returns {'trip': bool, 'crashed': [ids]}.

        With ``time`` (sim seconds) the pose also feeds the robot's efficiency meter."""
        r = self.robots[name]
        s = np.asarray(state, dtype=float).reshape(3)
        if not np.all(np.isfinite(s)):
            raise ValueError(f'pose of {name} is not finite')
        if r.position is None and r.goal is None:
            self.initial_side(name, s[0])
        r.position = s
        events = {'trip': False, 'crashed': []}
        ids, xy = self.obstacle_arrays()
        radii = self.config.radius_of(ids) if self.config.radii else self.config.radius
        if time is not None:
            self.meters[name].pose(s, time, r.goal, self.filter_actions[name] == OVERRIDE, xy, radii)
        if len(ids):
            inside_now = set(ids[np.hypot(*(xy - s[:2]).T)
                                 < radii - self.config.crash_tolerance].tolist())
            for oid in sorted(inside_now - r.inside):
                r.crashes += 1
                events['crashed'].append(int(oid))
            r.inside = inside_now
        crossed = s[0] >= self.config.goal_x if r.side > 0 else s[0] <= -self.config.goal_x
        if crossed:
            self.meters[name].trip_completed()
            r.trips += 1
            r.side = -r.side
            self.new_goal(name)
            events['trip'] = True
        return events

    def update_detections(self, name: str, xy, time: float) -> None:
        pts = np.asarray(xy, dtype=float).reshape(-1, 2)
        if not np.all(np.isfinite(pts)):
            raise ValueError(f'detections of {name} are not finite')
        r = self.robots[name]
        r.detections = pts
        r.detections_time = float(time)

    def had_detected(self, name: str, obstacle_id: int) -> bool:
        r = self.robots[name]
        centre = self.obstacles[obstacle_id]
        if len(r.detections) == 0:
            return False
        return bool(np.min(np.hypot(*(r.detections - centre).T)) <= self.config.detection_tolerance)

    def robot_at(self, xy, tolerance: float = 1.0) -> str | None:
        """The robot whose last position is within ``tolerance`` of ``xy`` (closest), if any."""
        best, best_d = None, tolerance
        for name, r in self.robots.items():
            if r.position is None:
                continue
            d = float(np.hypot(*(r.position[:2] - np.asarray(xy, dtype=float))))
            if d <= best_d:
                best, best_d = name, d
        return best

    # ----- interventions ---------------------------------------------------------------
    def classify(self, obstacle_id: int) -> tuple[bool, tuple, tuple]:
        """(false_positive, near robots, near robots that had not detected it)."""
        centre = self.obstacles[obstacle_id]
        near = tuple(name for name, r in self.robots.items()
                     if r.position is not None
                     and np.hypot(*(r.position[:2] - centre)) <= self.config.near_distance)
        undetected = tuple(n for n in near if not self.had_detected(n, obstacle_id))
        return len(undetected) == 0, near, undetected

    def set_obstacles(self, centres) -> list[int]:
        """Replace every obstacle by discs at ``centres`` (K, 2), with new ids (a scene reset).

        ValueError for non-finite centres; the obstacles stay as they were then.
        """
        xy = np.asarray(centres, dtype=float).reshape(-1, 2)
        if not np.all(np.isfinite(xy)):
            raise ValueError('obstacle centres must be finite')
        self.obstacles.clear()
        for r in self.robots.values():
            r.inside.clear()
        ids = []
        for p in xy:
            self.obstacles[self.next_id] = p.copy()
            ids.append(self.next_id)
            self.next_id += 1
        return ids

    def intervene(self, obstacle_id: int, time: float, robot: str | None = None,
                  respawn: bool = True):
        """Remove an obstacle (classifying the intervention first) and, with ``respawn``,
        spawn a replacement.

        Returns (Intervention, new obstacle id or None). KeyError for an unknown obstacle.
        """
        if obstacle_id not in self.obstacles:
            raise KeyError(f'no obstacle {obstacle_id} (already removed or never existed)')
        fp, near, undetected = self.classify(obstacle_id)
        record = Intervention(int(obstacle_id), robot, float(time), fp, near, undetected)
        self.interventions.append(record)
        del self.obstacles[obstacle_id]
        for r in self.robots.values():
            r.inside.discard(obstacle_id)
        new_id = self._spawn(self.config.respawn_clearance) if respawn else None
        return record, new_id

    # ----- counts ----------------------------------------------------------------------
    def stats(self) -> dict:
        c = self.config
        trips = sum(r.trips for r in self.robots.values())
        crashes = sum(r.crashes for r in self.robots.values())
        n_int = len(self.interventions)
        fps = sum(i.false_positive for i in self.interventions)
        score = c.trip_reward * trips - c.crash_penalty * crashes - c.intervention_penalty * n_int
        return {'trips': trips, 'crashes': crashes, 'interventions': n_int,
                'false_positives': fps, 'score': score}

    def efficiency(self) -> dict:
        """The team's H2 measures so far (sim/efficiency.team_efficiency)."""
        return team_efficiency(self.meters.values(), sum(r.trips for r in self.robots.values()))
