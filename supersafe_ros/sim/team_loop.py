"""The team's lockstep closed loop in one Python process, without ROS.

Why: in the node graph every lockstep step costs ~30 ms of CPU spread over eight rclpy
processes (messages, executors, DDS), so a study of hundreds of games cannot run fast
on two cores. The decisions themselves (Dubins flow, sensor, world counts, supervisor,
planner, filter law) are the package's ROS-free core modules; this loop calls the same
modules in the order the lockstep graph runs them, so a game here is the graph's
experiment without the transport.

One step at sim time t (``sim_clock_node`` lockstep; the nodes named in brackets):

1. every robot integrates from t - dt to t under the command in force
   (``RobotSim.advance``, at most one step: [dubins_robot]) and senses the obstacles it
   knows (``LossySensor``, miss draws keyed by (seed, trip, obstacle));
2. the world counts each pose (trips, crashes, H2 meters with the filter action that was
   in force over the segment) and takes its detections [world];
3. the supervisor judges every pose against the obstacles it knows (``Watcher``); each
   intervention goes to the world, which classifies it (FP or not), removes the obstacle
   and spawns a replacement [supervisor -> world];
4. a new goal (the first pose, a trip) starts a new sensor trip [world -> robot goal];
5. the planner answers the pose with the goal it knew before this step's world update
   [planner], and each filter decides on this step's pose and detections with that
   command [safety_filter]. Clusters of detected obstacles are solved before the decision,
   as the graph's filter holds its answer until the union value is in force
   (``cluster_hold_timeout``);
6. the robot takes the decision as its command at t, the world the decision's action
   (H2 meters of the next segment);
7. an online learner, if any, reads the step and may put a refitted set in force for the
   next step's decisions (the study's ``learned_online``).

Which planner command a lockstepped filter judges is a race in the graph: it answers a
pose on arrival, and the planner's answer to the same pose may come before or after
(safety_filter_node, ``lockstep``). ``planner_lag`` True judges the previous pose's
command instead. Measured against the graph (bench/bench_study.py --compare, 2 subjects,
8 games): the graph completed 11-16 trips per game, as this loop does without the lag
(16); with the lag the goal-seeking planner, saturated when the new goal is behind the
robot, chatters between +-w_max one step out of phase and some robots drive off the
field (4-6 trips in some games). So the default is no lag.

Differences from the graph, on purpose: no message is lost or reordered (the graph's
supervisor and world may lag the robots by up to two steps, ``observer_lag``); each
game starts from fresh robots and filters (the study's kept-alive graph carries the
last game's command over for its first step); cluster values are solved inline.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import functools
import math

import numpy as np

from ..filter.clusters.geometry import ClusterSettings, canonical, components
from ..filter.clusters.store import ClusterStore, settings_of
from ..filter import FilterConfig, RobotFilter, SafeSet, step_many
from .dubins_sim import LossySensor, RobotSim
from .planner import goal_seeking_turn_rate
from .watcher import Watcher
from .world import World, WorldConfig


@dataclass(frozen=True)
class RobotParams:
    """A robot, its sensor and its planner (config/robot.yaml, config/planner.yaml)."""

    speed: float = 3.0
    w_max: float = 1.0
    sensor_range: float = 10.0
    miss_probability: float = 0.2
    command_timeout: float = 0.5
    timeout_behavior: str = 'loiter'
    planner_gain: float = 2.0
    planner_w_max: float = 1.0


@dataclass
class _Robot:
    name: str
    sim: RobotSim
    sensor: LossySensor
    filter: RobotFilter
    goal: np.ndarray | None = None       # the goal the planner knows
    seen_xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    seen_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))


class TeamLoop:
    """World, N x (robot, planner, safety filter), supervisor: ``run(seconds)`` steps them.

    ``safe_set``: the set in force in every filter. ``watcher``: the supervisor's rule
    (None: no supervisor). ``robot_seeds``: each robot's sensor seed. ``filtered`` False
    forwards the planner's command unfiltered (an ablation: what the filter prevents).
    ``observer``: told of every robot's decision (``step(loop, t, name, state, seen_ids,
    seen_xy, action)``) and intervention (``intervention(loop, decision, record)``), e.g.
    ``study.game_trace.GameTrace``; it only reads. ``learner``: told of each step's end
    (``step(loop, t, states)``: the poses, ``loop.interventions``, the world's obstacles);
    a SafeSet it returns is in force in every filter from the next step (the study's
    ``learned_online``: ``study.online.OnlineLearner``).
    """

    def __init__(self, world_config: WorldConfig, world_seed: int, starts: dict, robot_seeds: dict,
                 robot: RobotParams, filter_config: FilterConfig, safe_set: SafeSet,
                 watcher: Watcher | None, step: float, respawn: bool = True, filtered: bool = True,
                 clusters: ClusterStore | None = None, planner_lag: bool = False, observer=None,
                 learner=None):
        if not (math.isfinite(step) and step > 0):
            raise ValueError(f'step must be positive, got {step}')
        self.step_s = float(step)
        self.world = World(world_config, list(starts), seed=world_seed)
        self.watcher = watcher
        self.safe_set = safe_set
        self.respawn = respawn
        self.planner_lag = planner_lag
        self.observer = observer
        self.learner = learner
        self.filtered = filtered
        self.params = robot
        self.clusters = clusters if clusters is not None else inline_cluster_store(filter_config)
        self.robots = [
            _Robot(name,
                   RobotSim(pose, speed=robot.speed, omega_max=robot.w_max,
                            command_timeout=robot.command_timeout,
                            timeout_behavior=robot.timeout_behavior, max_step=self.step_s),
                   LossySensor(robot.sensor_range, robot.miss_probability, seed=robot_seeds[name]),
                   RobotFilter(filter_config, name))
            for name, pose in starts.items()]
        self.time = 0.0
        self.steps = 0
        self.decisions = {'pass': 0, 'override': 0, 'fail_safe': 0}
        self.interventions = []          # (Decision, world Intervention record)
        self.trace = []                  # per step (t, states (N, 3)) when ``record`` is set
        self.record = False

    # -- one step ---------------------------------------------------------------------------
    def step(self) -> None:
        t = self.time + self.step_s if self.steps else self.time
        self.steps += 1
        self.time = t
        ids, xy = self.world.obstacle_arrays()
        states = {}
        for r in self.robots:                                    # 1. integrate and sense
            states[r.name] = r.sim.advance(t).copy()
            r.seen_ids, r.seen_xy = r.sensor.sense(states[r.name][:2], ids, xy)
        goals_before = {r.name: r.goal for r in self.robots}
        for r in self.robots:                                    # 2. the world counts
            self.world.update_detections(r.name, r.seen_xy, t)
            self.world.update_pose(r.name, states[r.name], t)
        if self.watcher is not None:                             # 3. the supervisor judges
            decisions = [d for d in (self.watcher.judge(r.name, states[r.name], t, ids, xy)
                                     for r in self.robots) if d is not None]
            for d in decisions:
                self._intervene(d)
        for r in self.robots:                                    # 4. a new goal: a new trip
            goal = self.world.robots[r.name].goal
            if r.goal is None or goal is not r.goal and not np.array_equal(goal, r.goal):
                r.sensor.new_trip()
                r.goal = goal
        if not self.planner_lag:
            self._plan(states, goals_before, t)
        for r in self.robots:                                    # 5. the filters decide
            r.filter.update_pose(states[r.name], t, stamp=t)
            r.filter.update_detections(r.seen_xy, t)
        if self.filtered:
            self._solve_clusters()
            outs = step_many([r.filter for r in self.robots], self.safe_set, t, self.clusters)
            commands = zip(outs.omega, outs.action)
        else:
            commands = (((r.filter.command.value or 0.0), 'pass') for r in self.robots)
        for r, (omega, action) in zip(self.robots, commands):   # 6. commands and actions
            r.sim.command(omega, t)
            self.world.set_filter_action(r.name, action)
            self.decisions[action] = self.decisions.get(action, 0) + 1
            if self.observer is not None:
                self.observer.step(self, t, r.name, states[r.name], r.seen_ids, r.seen_xy, action)
        if self.planner_lag:
            self._plan(states, goals_before, t)
        if self.record:
            self.trace.append((t, np.array([states[r.name] for r in self.robots])))
        if self.learner is not None:                             # 7. a learner may refit
            new = self.learner.step(self, t, states)
            if new is not None:
                self.safe_set = new

    def _plan(self, states, goals, t) -> None:
        """The planners answer this step's poses with the goals they knew before it."""
        for r in self.robots:
            goal = goals[r.name]
            if goal is not None:
                r.filter.update_command(goal_seeking_turn_rate(
                    states[r.name], goal, self.params.planner_gain, self.params.planner_w_max), t)

    def _intervene(self, d) -> None:
        """The world removes the obstacle the supervisor named (world_node.on_intervention)."""
        if d.obstacle_id not in self.world.obstacles:
            return                               # already removed: the world rejects it
        centre = self.world.obstacles[d.obstacle_id]
        robot = self.world.robot_at(centre + d.rel_state[:2], 1.0)
        record, _ = self.world.intervene(d.obstacle_id, d.time, robot, respawn=self.respawn)
        self.interventions.append((d, record))
        if self.observer is not None:
            self.observer.intervention(self, d, record)
        self.watcher.obstacles_changed(self.world.obstacle_arrays()[0])

    def _solve_clusters(self) -> None:
        """Every cluster a filter will judge this step has its union value in force (the
        graph's filter holds its answer for the solve; here the solve runs inline)."""
        settings = self.clusters.settings
        for r in self.robots:
            det = r.filter.detections.value
            if not r.filter.config.clusters or det is None or len(det) < 2:
                continue
            for g in components(det, settings.link_distance):
                if len(g) > 1:
                    key, _, _, centres = canonical(det[g], settings.key_resolution)
                    if self.clusters.get(key) is None:
                        self.clusters.request(key, centres)

    def run(self, seconds: float) -> None:
        """Step until ``seconds`` of sim time have passed since the first pose."""
        n = int(round(float(seconds) / self.step_s))
        if not self.steps:
            self.step()                          # the first pose (the robots are parked)
        for _ in range(n):
            self.step()

    # -- results ----------------------------------------------------------------------------
    def stats(self) -> dict:
        """The world's counts and H2 measures (as /world/stats carries them)."""
        out = dict(self.world.stats())
        out.update(self.world.efficiency())
        out['relaxed_spawns'] = self.world.relaxed_spawns
        return out


def inline_cluster_store(cfg: FilterConfig) -> ClusterStore:
    """A cluster store for the filter's configuration that solves in the caller's thread
    (values on disk are shared with the graph's filters: ``disk_cache``)."""
    return ClusterStore(settings_of(cfg), background=False)


@functools.lru_cache(maxsize=2)
def process_cluster_store(settings: ClusterSettings) -> ClusterStore:
    """One inline store per process and settings, kept across games: a value once loaded
    (disk cache) or solved is not read and differentiated again in the next game (the
    values are the same either way; LRU-bounded)."""
    return ClusterStore(settings, background=False, capacity=192)
