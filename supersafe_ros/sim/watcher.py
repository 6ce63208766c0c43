"""The simulated supervisor's judgement, without ROS: the noisy idealized supervisor.

Paper Sec. III-B: the supervisor holds an internal value function V_S (its own
dynamics model, here a Dubins car with its own w_max, obstacle radius and horizon)
and a margin mu. Each time it judges an approach it draws w ~ N(0, sigma^2) and
intervenes when the robot reaches the mu + w level set:

    intervene  iff  V_S(x_rel) <= mu + w,

with x_rel the robot's state relative to the obstacle (obstacle at the origin, axes
as the map). One judgement - one draw of w, keyed by (seed, robot, obstacle,
approach number) so it does not depend on message order - per *encounter*: an encounter of
(robot, obstacle) starts when the relative state enters V_S's grid and ends when it
leaves it again (or the obstacle disappears). Within an encounter the threshold
stays fixed, so the noise is per approach, as in the paper's Phase II data.

After an intervention the obstacle is pending removal: it is not judged again,
for any robot, until the world has removed it (or ``pending_timeout`` passes, in
which case the supervisor may intervene again).

The idealized supervisor watches continuous motion; the simulation shows it poses
every step (0.15 m apart at 3 m/s and 0.05 s). So that this sampling does not bias
what is learned (V at the reported state would be up to |dV/ds| x 0.15 below the
level), the reported state and time are those of the level crossing, interpolated
linearly in V between the last pose above the level and the first at or below it:

    f = (V_prev - level) / (V_prev - V),   x* = x_prev + f (x - x_prev),   t* likewise.

When an encounter starts below its level there is nothing to interpolate from and
the pose itself is reported.

``model`` chooses how an alarm (V_S <= mu + w) becomes an intervention
(``sim.supervisor_models``): ``memoryless``, the paper's, at once; ``attentive``, only
while the supervisor is not convinced, from the robot's turns in this approach, that the
robot has seen the obstacle.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from ..reach.grid import wrap_angle
from ..reach.value_function import ValueFunction
from .dubins_sim import base_seed, keyed_rng
from .supervisor_models import AttentiveParams, DetectionBelief, check_model


@dataclass
class Decision:
    robot: str
    obstacle_id: int
    time: float
    rel_state: np.ndarray       # (x, y, theta) relative to the obstacle
    value: float                # V_S(rel_state)
    threshold: float            # mu + w of this encounter


@dataclass
class Watcher:
    """Per (robot, obstacle) encounter tracking and the intervention rule."""

    vf: ValueFunction
    mu: float = 0.0
    sigma: float = 0.0
    seed: int | None = None
    pending_timeout: float = 5.0
    thresholds: dict = field(default_factory=dict)   # (robot, obstacle id) -> mu + w
    pending: dict = field(default_factory=dict)      # obstacle id -> time intervened
    previous: dict = field(default_factory=dict)     # (robot, obstacle id) -> (rel state, V, t)
    encounters: dict = field(default_factory=dict)   # (robot, obstacle id) -> approaches so far
    model: str = 'memoryless'
    attentive: AttentiveParams = field(default_factory=AttentiveParams)
    beliefs: dict = field(default_factory=dict)      # (robot, obstacle id) -> DetectionBelief
    withheld: int = 0                                # alarms not acted on (attentive: convinced)

    def __post_init__(self):
        if not (math.isfinite(self.mu) and math.isfinite(self.sigma) and self.sigma >= 0):
            raise ValueError(f'mu must be finite and sigma >= 0, got mu={self.mu}, sigma={self.sigma}')
        check_model(self.model)
        self.seed = base_seed(self.seed)

    def obstacles_changed(self, ids) -> None:
        """Forget encounters and pending removals of obstacles that are gone."""
        alive = set(int(i) for i in np.asarray(ids).reshape(-1))
        self.pending = {o: t for o, t in self.pending.items() if o in alive}
        self.thresholds = {k: v for k, v in self.thresholds.items() if k[1] in alive}
        self.previous = {k: v for k, v in self.previous.items() if k[1] in alive}
        self.beliefs = {k: v for k, v in self.beliefs.items() if k[1] in alive}

    def judge(self, robot: str, state, time: float, obstacle_ids, obstacle_xy) -> Decision | None:
        """Judge one robot state against every obstacle; returns an intervention or None.

        At most one intervention per call: the obstacle with the smallest V_S - (mu + w).
        """
        s = np.asarray(state, dtype=float).reshape(3)
        if not np.all(np.isfinite(s)):
            raise ValueError(f'state of {robot} is not finite')
        ids = np.asarray(obstacle_ids, dtype=int).reshape(-1)
        xy = np.asarray(obstacle_xy, dtype=float).reshape(-1, 2)
        if len(ids) == 0:
            return None
        for oid, t in list(self.pending.items()):
            if time - t > self.pending_timeout:
                del self.pending[oid]      # the world never removed it: judge it afresh
        rel = np.column_stack([s[0] - xy[:, 0], s[1] - xy[:, 1], np.full(len(ids), s[2])])
        inside = self.vf.grid.contains(rel)
        values = np.full(len(ids), np.inf)
        if inside.any():                 # only the obstacles near enough to judge are evaluated
            values[inside] = self.vf.value(rel[inside])
        best = None
        urgent = int(np.argmin(values)) if inside.any() else -1
        for k, oid in enumerate(ids.tolist()):
            key = (robot, oid)
            if not inside[k]:
                self.thresholds.pop(key, None)       # encounter over
                self.previous.pop(key, None)
                self.beliefs.pop(key, None)
                continue
            if key not in self.thresholds:           # a new approach: one noisy judgement
                n = self.encounters.get(key, 0)
                self.encounters[key] = n + 1
                w = float(keyed_rng(self.seed, robot, oid, n).standard_normal())
                self.thresholds[key] = self.mu + self.sigma * w
                self.beliefs.pop(key, None)
            prev = self.previous.get(key)
            self.previous[key] = (rel[k].copy(), float(values[k]), float(time))
            convinced = self.model == 'attentive' and self._convinced(key, prev, rel[k], time, k == urgent)
            if oid in self.pending:
                continue
            margin = values[k] - self.thresholds[key]
            if margin <= 0 and convinced:
                self.withheld += 1
                continue
            if margin <= 0 and (best is None or margin < best[0]):
                best = (margin, k, oid, prev)
        if best is None:
            return None
        _, k, oid, prev = best
        level = self.thresholds.pop((robot, oid))
        self.previous.pop((robot, oid), None)
        self.beliefs.pop((robot, oid), None)
        self.pending[oid] = float(time)
        x, v, t = rel[k].copy(), float(values[k]), float(time)
        if prev is not None and prev[1] > level and prev[2] < t:
            f = (prev[1] - level) / (prev[1] - v)
            dth = float(wrap_angle(x[2] - prev[0][2]))
            x = np.array([prev[0][0] + f * (x[0] - prev[0][0]), prev[0][1] + f * (x[1] - prev[0][1]),
                          float(wrap_angle(prev[0][2] + f * dth))])
            t = prev[2] + f * (t - prev[2])
            v = float(self.vf.value(x[None])[0])
        return Decision(robot, oid, t, x, v, level)

    def _convinced(self, key, prev, rel, time: float, urgent: bool) -> bool:
        """The attentive supervisor's belief after this frame (``supervisor_models``): the
        turn from the previous frame of this approach counts for this obstacle if it is the
        robot's most urgent (lowest V_S) and the robot was heading toward it."""
        belief = self.beliefs.get(key)
        if belief is None:
            belief = self.beliefs[key] = DetectionBelief(self.attentive)
        if prev is None or not prev[2] < time:
            return belief.convinced
        return belief.update(prev[0], rel, time, urgent)
