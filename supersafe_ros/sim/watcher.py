"""The simulated supervisor's judgement, without ROS: the noisy idealized supervisor.

Paper Sec. III-B: the supervisor holds an internal value function V_S (its own
dynamics model, here a Dubins car with its own w_max, obstacle radius and horizon)
and a margin mu. Each time it judges an approach it draws w ~ N(0, sigma^2) and
intervenes when the robot reaches the mu + w level set:

    intervene  iff  V_S(x_rel) <= mu + w,

with x_rel the robot's state relative to the obstacle (obstacle at the origin, axes
as the map). One judgement - one draw of w - per *encounter*: an encounter of
(robot, obstacle) starts when the relative state enters V_S's grid and ends when it
leaves it again (or the obstacle disappears). Within an encounter the threshold
stays fixed, so the noise is per approach, as in the paper's Phase II data.

After an intervention the obstacle is pending removal: it is not judged again,
for any robot, until the world has removed it (or ``pending_timeout`` passes, in
which case the supervisor may intervene again).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from ..reach.value_function import ValueFunction


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
    rng: np.random.Generator = field(default_factory=np.random.default_rng)
    pending_timeout: float = 5.0
    thresholds: dict = field(default_factory=dict)   # (robot, obstacle id) -> mu + w
    pending: dict = field(default_factory=dict)      # obstacle id -> time intervened

    def __post_init__(self):
        if not (math.isfinite(self.mu) and math.isfinite(self.sigma) and self.sigma >= 0):
            raise ValueError(f'mu must be finite and sigma >= 0, got mu={self.mu}, sigma={self.sigma}')

    def obstacles_changed(self, ids) -> None:
        """Forget encounters and pending removals of obstacles that are gone."""
        alive = set(int(i) for i in np.asarray(ids).reshape(-1))
        self.pending = {o: t for o, t in self.pending.items() if o in alive}
        self.thresholds = {k: v for k, v in self.thresholds.items() if k[1] in alive}

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
        values = np.where(inside, self.vf.value(rel), np.inf)
        best = None
        for k, oid in enumerate(ids.tolist()):
            key = (robot, oid)
            if not inside[k]:
                self.thresholds.pop(key, None)       # encounter over
                continue
            if key not in self.thresholds:           # a new approach: one noisy judgement
                self.thresholds[key] = self.mu + self.sigma * float(self.rng.standard_normal())
            if oid in self.pending:
                continue
            margin = values[k] - self.thresholds[key]
            if margin <= 0 and (best is None or margin < best[0]):
                best = (margin, k, oid)
        if best is None:
            return None
        _, k, oid = best
        self.pending[oid] = float(time)
        self.thresholds.pop((robot, oid), None)
        return Decision(robot, oid, float(time), rel[k].copy(), float(values[k]),
                        float(values[k] - best[0]))
