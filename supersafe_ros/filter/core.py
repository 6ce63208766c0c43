"""The safety filter of one robot (or many), as a ROS-free state machine.

Inputs (each with the time it arrived, seconds on the caller's clock):

* the robot's pose (x, y, theta) in ``map``;
* the detected obstacles: centres (N, 2) in ``map`` (N may be 0);
* the planner's turn-rate command;
* the safe set in force: a value function V with its level alpha (``SafeSet``).

Output per step (``FilterOutput``): the turn rate to send and a record of what was
decided and why. The law (``supersafe_ros.filter.law``) is applied to the robot's
state relative to every detected obstacle; the smallest V governs:

    pass      V_min > alpha                 forward the planner's command
    override  V_min <= alpha                u* = w_max sign(dV/dtheta) of that obstacle
    fail_safe pose or detections stale/invalid (see below)

Delay compensation (every decision on the pose it is for). A pose describes the
robot at its stamp, not at the decision: in a lockstep graph the filter may decide
at step k on the pose of step k-1, and a real robot's pose is some milliseconds
old. The filter knows what the robot did since: it sent the commands. So it first
propagates the pose over its age (decision time - stamp) along exact Dubins arcs
under the commands it sent in that interval (``propagate_pose``), and judges the
robot's state *now*.

Lookahead (the hold time). The command sent now holds until the robot applies the
next one, one control period later, so V sampled once per period can jump from
just above alpha to below it (by up to speed x period): the filter also overrides
when the planner's command, held for the lookahead from the state now, would end
at V <= alpha. The lookahead is max(``lookahead``, control period), the period
being ``control_period`` or, if 0, measured (median interval between pose stamps
and between planner commands, the larger). V at the end of the hold is enough:
by the dynamic programming principle a state the arc passes with V < 0 forces
V < 0 at its end as well.

Hysteresis ("until the robot is clear"): once overriding, the filter keeps
overriding until V_min > alpha + clear_margin. Without it the robot would leave
the override the instant V crosses alpha, turn back toward the obstacle under the
planner and re-enter at once, chattering along the level set. The margin is in
the units of V (metres of clearance for the signed-distance keep-out).

Fail safe. The planner's command is never forwarded when the filter cannot judge
it: no pose yet, the newest pose was invalid (NaN/inf, wrong frame) or older than
``pose_timeout``, or the same for detections (``detections_timeout``). Then:

* if the last valid pose and detections are younger than ``hold_timeout``: the
  avoid control u* for that last valid state against the most constraining
  obstacle (the best the filter knows to do);
* otherwise, or if no obstacle is near: the stop-turn policy — linear.x = 0 (a
  robot that can stop, stops) and a full-rate left turn, angular.z = +w_max. A
  Dubins robot that cannot stop then circles on radius speed / w_max (3 m by
  default) around where its state was lost, instead of driving on blindly.

``step_many`` evaluates many robots with one vectorised call of the law (one
value-function interpolation over every robot-obstacle pair); ``RobotFilter.step``
is the one-robot case of it.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
import math

import numpy as np

from .law import evaluate_pairs, tie_tolerance  # noqa: F401  (the law's rule; re-exported)
from ..reach.grid import wrap_angle
from ..reach.value_function import ValueFunction

PERIOD_SAMPLES = 16    # intervals in the median that measures the control period

PASS = 'pass'
OVERRIDE = 'override'
FAIL_SAFE = 'fail_safe'

# diagnostic_msgs/DiagnosticStatus levels, by action
LEVEL_OK, LEVEL_WARN, LEVEL_ERROR = 0, 1, 2
LEVEL_OF_ACTION = {PASS: LEVEL_OK, OVERRIDE: LEVEL_WARN, FAIL_SAFE: LEVEL_ERROR}


@dataclass(frozen=True)
class FilterConfig:
    """Parameters of the filter (times in seconds, rates in rad/s)."""

    speed: float = 3.0               # robot speed (informative in the Twist)
    omega_max: float = 1.0           # the robot's turn-rate bound: |u*| = omega_max
    pose_timeout: float = 0.5        # a pose older than this is stale
    detections_timeout: float = 1.0  # detections older than this are stale
    hold_timeout: float = 1.0        # last valid state still usable for fail-safe avoidance
    cmd_timeout: float = 0.5         # planner silent longer than this: zero twist
    clear_margin: float = 0.2        # hysteresis: release override when V > alpha + margin
    lookahead: float = 0.1           # override if the planner's command would reach alpha this soon
    control_period: float = 0.0      # the robot's command hold time; 0 = measure it from arrivals
    # propagate each pose over its age under the commands sent, and keep the lookahead >= the
    # control period (False: judge the pose as if current and use ``lookahead`` as given, the
    # behaviour before issue 9; for ablation benchmarks only)
    compensate_delay: bool = True
    # obstacles closer than cluster_link (0 = 2 radius + a turning diameter) are judged by
    # their union's value (filter.cluster), at level cluster_alpha, with the true dynamics
    clusters: bool = True
    radius: float = 1.8              # obstacle radius (cluster values)
    cluster_link: float = 0.0
    cluster_alpha: float = 0.0       # the union's level (the standard set's alpha)

    def __post_init__(self):
        for name in ('speed', 'omega_max', 'pose_timeout', 'detections_timeout', 'hold_timeout',
                     'cmd_timeout', 'clear_margin', 'lookahead', 'control_period', 'radius',
                     'cluster_link'):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {v}')
        if not math.isfinite(self.cluster_alpha):
            raise ValueError(f'cluster_alpha must be finite, got {self.cluster_alpha}')


@dataclass(frozen=True)
class SafeSet:
    """A value function and the level alpha below which the filter overrides.

    ``source`` is 'standard' (true dynamics, computed locally) or 'learned'
    (received from the learner).
    """

    vf: ValueFunction
    alpha: float
    source: str = 'standard'

    def __post_init__(self):
        if not math.isfinite(self.alpha):
            raise ValueError(f'alpha must be finite, got {self.alpha}')

    @property
    def omega_max(self):
        return self.vf.meta.get('omega_max')


@dataclass
class FilterOutput:
    """What one step decided."""

    omega: float                 # turn rate to command (angular.z)
    linear: float                # linear.x to command (speed, or 0 for stop-turn)
    action: str                  # pass | override | fail_safe
    reason: str
    obstacle_index: int = -1     # index in the last detections, -1 if none
    obstacle_xy: tuple = (math.nan, math.nan)
    value: float = math.inf      # smallest V over the detections (+inf: none near)
    alpha: float = math.nan
    source: str = ''
    omega_max_set: float = math.nan  # omega_max of the safe set's model
    pose_age: float = 0.0        # seconds the pose was propagated over before judging
    lookahead: float = 0.0       # hold time the planner's command was judged over [s]
    clusters_solving: int = 0    # clusters near the robot whose union value is still being solved

    @property
    def level(self) -> int:
        return LEVEL_OF_ACTION[self.action]

    def record(self) -> dict:
        """Flat key/value record (for the diagnostic state message)."""
        return {
            'action': self.action,
            'reason': self.reason,
            'cmd_angular_z': f'{self.omega:.6g}',
            'cmd_linear_x': f'{self.linear:.6g}',
            'obstacle_index': str(self.obstacle_index),
            'obstacle_x': f'{self.obstacle_xy[0]:.6g}',
            'obstacle_y': f'{self.obstacle_xy[1]:.6g}',
            'value': f'{self.value:.6g}',
            'alpha': f'{self.alpha:.6g}',
            'omega_max': f'{self.omega_max_set:.6g}',
            'source': self.source,
            'pose_age': f'{self.pose_age:.6g}',
            'lookahead': f'{self.lookahead:.6g}',
            'clusters_solving': str(self.clusters_solving),
        }


@dataclass
class _Input:
    """The newest valid sample of one input, and whether a newer one was rejected."""

    value: object = None
    t: float = -math.inf          # arrival time of the newest valid sample
    stamp: float = -math.inf      # the time it describes (its header stamp; arrival if unstamped)
    rejected: str = ''            # reason the newest sample was rejected ('' if it was valid)
    rejected_t: float = -math.inf

    def accept(self, value, t, stamp=None):
        self.value, self.t, self.rejected = value, float(t), ''
        self.stamp = float(t) if stamp is None else float(stamp)

    def age(self, t) -> float:
        """Age at ``t``: since its stamp, or since arrival if that is earlier (a stamp ahead
        of the receiver's clock is not believed)."""
        return t - min(self.t, self.stamp)

    def reject(self, reason, t):
        self.rejected, self.rejected_t = str(reason), float(t)


@dataclass
class RobotFilter:
    """Filter state of one robot: the last inputs and whether it is overriding."""

    config: FilterConfig = field(default_factory=FilterConfig)
    name: str = ''

    def __post_init__(self):
        self.pose = _Input()
        self.detections = _Input()
        self.command = _Input()
        self.overriding = False
        self.sent = deque()    # (decision time, turn rate) of the commands sent, oldest first
        self._pose_intervals = deque(maxlen=PERIOD_SAMPLES)
        self._command_intervals = deque(maxlen=PERIOD_SAMPLES)

    # -- inputs ------------------------------------------------------------------------
    def update_pose(self, state, t, stamp=None) -> None:
        """A pose (x, y, theta) in map, arrived at ``t``; raises ValueError (and records it)
        if not finite.

        ``stamp``: the time the pose describes (its header stamp) on the same clock as
        ``t``, or None to take the arrival time. The filter propagates the pose from its
        stamp to the decision time under the commands it sent.
        """
        s = np.asarray(state, dtype=float).reshape(-1)
        if s.shape != (3,) or not np.all(np.isfinite(s)):
            reason = f'pose is not a finite (x, y, theta): {s.tolist()}'
            self.pose.reject(reason, t)
            raise ValueError(reason)
        if stamp is not None and not math.isfinite(float(stamp)):
            reason = f'pose stamp is not finite ({stamp})'
            self.pose.reject(reason, t)
            raise ValueError(reason)
        previous = self.pose.stamp if self.pose.value is not None else None
        self.pose.accept(s, t, stamp)
        if previous is not None and self.pose.stamp > previous:
            self._pose_intervals.append(self.pose.stamp - previous)

    def reject_pose(self, reason, t) -> None:
        """Record a pose message the caller could not convert (wrong frame, bad quaternion)."""
        self.pose.reject(reason, t)

    def update_detections(self, centres, t) -> None:
        """Obstacle centres (N, 2) in map, N >= 0; raises ValueError if malformed."""
        c = np.asarray(centres, dtype=float)
        if c.size == 0:
            c = np.zeros((0, 2))
        if c.ndim != 2 or c.shape[1] != 2 or not np.all(np.isfinite(c)):
            reason = f'detections must be finite (N, 2) centres, got shape {c.shape}'
            self.detections.reject(reason, t)
            raise ValueError(reason)
        self.detections.accept(c, t)

    def reject_detections(self, reason, t) -> None:
        self.detections.reject(reason, t)

    def update_command(self, omega, t) -> None:
        """The planner's turn rate; a non-finite one is rejected and the previous kept."""
        w = float(omega)
        if not math.isfinite(w):
            reason = f'planner command is not finite ({w})'
            self.command.reject(reason, t)
            raise ValueError(reason)
        previous = self.command.t if self.command.value is not None else None
        self.command.accept(w, t)
        if previous is not None and t > previous:
            self._command_intervals.append(t - previous)

    def control_period(self) -> float:
        """The hold time of a command: configured, else measured (0 until measurable).

        Measured as the larger of the median intervals between pose stamps (the
        robot's step) and between planner commands (when new commands come).
        """
        if self.config.control_period > 0.0:
            return self.config.control_period
        medians = [float(np.median(d)) for d in (self._pose_intervals, self._command_intervals) if d]
        return max(medians) if medians else 0.0

    def lookahead(self) -> float:
        cfg = self.config
        return max(cfg.lookahead, self.control_period()) if cfg.compensate_delay else cfg.lookahead

    # -- decision ------------------------------------------------------------------------
    def problem(self, t) -> str:
        """Why the filter cannot judge the planner's command now ('' if it can)."""
        cfg = self.config
        for label, inp, timeout in (('pose', self.pose, cfg.pose_timeout),
                                    ('detections', self.detections, cfg.detections_timeout)):
            if inp.rejected:
                return f'{label} rejected: {inp.rejected}'
            if inp.value is None:
                return f'no {label} received yet'
            age = t - inp.t     # since arrival: a pose that keeps coming is not lost
            if age > timeout:
                return f'{label} stale ({age:.3g} s old > {timeout:g} s)'
        return ''

    def step(self, safe_set: SafeSet, t, clusters=None) -> FilterOutput:
        return step_many([self], safe_set, t, clusters)[0]

    # -- what the robot did since its pose ---------------------------------------------
    def record_sent(self, omega, t) -> None:
        """Remember a command sent at ``t`` (step_many does this for every decision)."""
        self.sent.append((float(t), float(omega)))
        keep = max(self.config.hold_timeout, self.config.pose_timeout) + 1.0
        while len(self.sent) > 1 and self.sent[1][0] <= t - keep:
            self.sent.popleft()

    def segments_since(self, t0, t1):
        """[(turn rate, duration)] the robot held from ``t0`` to ``t1``, by the commands sent.

        A command counts from the time it was sent until the next one. Before the
        first command remembered: the planner's current command (clipped), else 0.
        """
        if t1 <= t0:
            return []
        w = self.config.omega_max
        before = _clip(self.command.value, w) if self.command.value is not None else 0.0
        inside = []      # commands sent in (t0, t1), newest first
        current = before
        for ts, omega in reversed(self.sent):
            if ts >= t1:
                continue
            if ts <= t0:
                current = omega
                break
            inside.append((ts, omega))
        segments, start = [], t0
        for ts, omega in reversed(inside):
            segments.append((current, ts - start))
            start, current = ts, omega
        segments.append((current, t1 - start))
        return segments


def arc_flow(states, speed, omega, dt) -> np.ndarray:
    """Exact Dubins arcs for arrays of states (N, 3), speeds, turn rates and durations (N,)."""
    s = np.asarray(states, dtype=float)
    x, y, th = s[:, 0], s[:, 1], s[:, 2]
    th1 = th + omega * dt
    turning = np.abs(omega * dt) > 1e-9
    safe = np.where(turning, omega, 1.0)
    ax = np.where(turning, (np.sin(th1) - np.sin(th)) / safe, np.cos(th) * dt)
    ay = np.where(turning, (np.cos(th) - np.cos(th1)) / safe, np.sin(th) * dt)
    return np.stack([x + speed * ax, y + speed * ay, wrap_angle(th1)], axis=1)


def propagate_poses(filters, use, t):
    """Each robot's state at ``t`` (rows in the order of ``use``) and the pose ages.

    The pose is moved from its stamp to ``t`` along the arcs of the commands sent
    (at most ``hold_timeout`` of them: older poses only feed the stop-turn).
    """
    states = np.array([filters[i].pose.value for i in use], dtype=float).reshape(-1, 3)
    ages = np.zeros(len(use))
    plans = []
    for row, i in enumerate(use):
        f = filters[i]
        if not f.config.compensate_delay:
            plans.append([])
            continue
        t0 = min(f.pose.t, f.pose.stamp)
        ages[row] = max(0.0, min(t - t0, f.config.hold_timeout))
        plans.append(f.segments_since(t - ages[row], t))
    depth = max((len(p) for p in plans), default=0)
    if depth == 0:
        return states, ages
    speed = np.array([filters[i].config.speed for i in use])
    for k in range(depth):
        omega = np.array([p[k][0] if k < len(p) else 0.0 for p in plans])
        dt = np.array([p[k][1] if k < len(p) else 0.0 for p in plans])
        states = arc_flow(states, speed, omega, dt)
    return states, ages


def _pairs(filters, use, states):
    """Relative states of every (robot, obstacle) pair for the robots in ``use``."""
    rel, robot, obstacle = [], [], []
    for row, i in enumerate(use):
        f = filters[i]
        x = states[row]
        c = f.detections.value
        if len(c) == 0:
            continue
        r = np.empty((len(c), 3))
        r[:, 0] = x[0] - c[:, 0]
        r[:, 1] = x[1] - c[:, 1]
        r[:, 2] = x[2]
        rel.append(r)
        robot.append(np.full(len(c), i))
        obstacle.append(np.arange(len(c)))
    if not rel:
        return np.zeros((0, 3)), np.zeros(0, int), np.zeros(0, int)
    return np.concatenate(rel), np.concatenate(robot), np.concatenate(obstacle)


def _planned_turn(f, t) -> float:
    """The command the filter would forward (a silent planner counts as 0), clipped."""
    cfg = f.config
    fresh = f.command.value is not None and t - f.command.t <= cfg.cmd_timeout
    return _clip(f.command.value, cfg.omega_max) if fresh else 0.0


def _clip(value, bound) -> float:
    """value clipped to +-bound (scalars; np.clip costs ~10 us a call)."""
    return max(-bound, min(bound, float(value)))


def step_many(filters, safe_set: SafeSet, t, clusters=None) -> list:
    """One decision per robot filter, with one vectorised evaluation of the law.

    Robots that can be judged use their current pose and detections; robots that
    fail safe use their last valid pose and detections if younger than
    ``hold_timeout``, else the stop-turn policy. ``clusters``: the ClusterStore
    for obstacles judged together (None: the process's shared store for the
    robots' configuration; see ``filter.cluster``).
    """
    n = len(filters)
    problems = [f.problem(t) for f in filters]
    usable = []   # robots whose (last valid) state enters the law
    for i, f in enumerate(filters):
        if not problems[i]:
            usable.append(i)
        elif (f.pose.value is not None and f.detections.value is not None
              and t - f.pose.t <= f.config.hold_timeout and t - f.detections.t <= f.config.hold_timeout):
            usable.append(i)
    states, ages = propagate_poses(filters, usable, t)
    state_of = {i: states[row] for row, i in enumerate(usable)}
    age_of = dict(zip(usable, ages))
    rel, robot, obstacle = _pairs(filters, usable, states)
    value, turn = evaluate_pairs(safe_set.vf, rel)
    horizons = {i: filters[i].lookahead() for i in usable}
    turn, value_next = _sampled_control(filters, safe_set.vf, rel, robot, t, horizons, turn)
    # pairs are grouped by robot, in order: robot i's pairs are [first[i], last[i])
    first = {int(i): int(k) for i, k in zip(*np.unique(robot, return_index=True))} if len(robot) else {}

    alpha = float(safe_set.alpha)
    set_omega = safe_set.omega_max
    set_omega = float(set_omega) if set_omega is not None else math.nan
    out = []
    for i, f in enumerate(filters):
        cfg = f.config
        c = _Constraints.of_pairs(f, i, first, value, turn, value_next, obstacle, alpha, safe_set.source)
        if i in state_of and cfg.clusters and len(f.detections.value) > 1:
            _add_cluster_constraints(c, f, state_of[i], horizons[i], t, clusters)
        common = dict(alpha=alpha, source=safe_set.source, omega_max_set=set_omega,
                      pose_age=float(age_of.get(i, 0.0)), lookahead=float(horizons.get(i, 0.0)),
                      clusters_solving=c.solving)
        if problems[i]:
            f.overriding = False   # re-enter by the law once inputs are back
            k = c.smallest()
            common.update(c.describe(k, f))
            if k >= 0:
                out.append(FilterOutput(cfg.omega_max * c.turn[k], cfg.speed, FAIL_SAFE,
                                        f'{problems[i]}; avoiding {c.label(k)} from the last '
                                        f'valid state (V={c.value[k]:.3g})', **common))
            else:
                why = 'no recent valid state' if i not in usable else 'no obstacle near the last valid state'
                out.append(FilterOutput(cfg.omega_max, 0.0, FAIL_SAFE,
                                        f'{problems[i]}; {why}: stop-turn', **common))
            continue
        k, kind = c.governing(f.overriding, cfg.clear_margin)
        common.update(c.describe(k, f))
        if kind:
            f.overriding = True
            lv = c.level[k]
            if kind == 'enter':
                why = f'V={c.value[k]:.3g} <= alpha={lv:.3g} at {c.label(k)}'
            elif kind == 'ahead':
                why = (f'the planner\'s command would reach V={c.value_next[k]:.3g} <= alpha={lv:.3g} '
                       f'within {horizons[i]:.3g} s ({c.label(k)})')
            else:
                why = f'V={c.value[k]:.3g} <= alpha+margin={lv + cfg.clear_margin:.3g}: not clear yet'
            out.append(FilterOutput(cfg.omega_max * c.turn[k], cfg.speed, OVERRIDE, why, **common))
            continue
        f.overriding = False
        if f.command.value is None or t - f.command.t > cfg.cmd_timeout:
            # Nav2 style: no input, zero twist (a Dubins robot drives straight on;
            # the filter still guards it against every detected obstacle)
            out.append(FilterOutput(0.0, 0.0, PASS, 'clear; planner silent: zero command', **common))
        else:
            why = ('clear: no obstacle near' if k < 0 else
                   f'clear: V={c.value[k]:.3g} > alpha={c.level[k]:.3g}')
            # the robot's bound, whatever the planner asked (angular.z = 1e30 goes out as w_max)
            omega = _clip(f.command.value, cfg.omega_max)
            out.append(FilterOutput(omega, cfg.speed, PASS, why, **common))
    for f, o in zip(filters, out):
        f.record_sent(o.omega, t)
    return out


class _Constraints:
    """What one robot must respect: per obstacle (the safe set in force) and per cluster.

    Each constraint has a value V, its level, the unit avoid turn, V after the
    planner's command is held for the lookahead, the obstacle it names and whether
    it is *sound for its layout* (a cluster's union value or the loiter fallback;
    these govern first whenever they act, see ``governing``).
    """

    def __init__(self):
        self.value, self.level, self.turn, self.value_next = [], [], [], []
        self.obstacle, self.sound, self.source, self.members, self.group = [], [], [], [], []
        self.solving = 0     # clusters of this robot whose union value is being solved

    @classmethod
    def of_pairs(cls, f, i, first, value, turn, value_next, obstacle, alpha, source):
        c = cls()
        if i in first:
            a = first[i]
            b = a + len(f.detections.value)
            c.value = value[a:b].tolist()
            c.turn = turn[a:b].tolist()
            c.value_next = value_next[a:b].tolist()
            c.obstacle = obstacle[a:b].tolist()
            m = b - a
            c.level, c.sound, c.source, c.members = [alpha] * m, [False] * m, [source] * m, [1] * m
            c.group = list(range(m))    # each obstacle its own group until clustered
        return c

    def add(self, value, level, turn, value_next, obstacle, source, members, group):
        self.value.append(float(value))
        self.level.append(float(level))
        self.turn.append(float(turn))
        self.value_next.append(float(value_next))
        self.obstacle.append(int(obstacle))
        self.sound.append(True)
        self.source.append(source)
        self.members.append(int(members))
        self.group.append(group)

    def margins(self, idx):
        return [self.value[k] - self.level[k] for k in idx]

    def smallest(self, idx=None) -> int:
        """The constraint with the smallest V - level (-1 if none is finite)."""
        idx = list(range(len(self.value))) if idx is None else idx
        finite = [k for k in idx if math.isfinite(self.value[k])]
        if not finite:
            return -1
        return min(finite, key=lambda k: self.value[k] - self.level[k])

    def governing(self, overriding, clear_margin):
        """(constraint, why) that makes the filter override, or (smallest, '') to pass.

        Within a cluster its sound constraint (union value or fallback) comes first: if
        it enters, looks ahead to its level or holds its hysteresis, the cluster's
        members' own constraints are set aside, so the union's avoid turn is never
        traded for a single member's. Between clusters and lone obstacles (farther
        apart than the link distance) the smallest value governs, as per obstacle.
        """
        n = len(self.value)
        enter = [self.value[k] <= self.level[k] for k in range(n)]
        ahead = [self.value_next[k] <= self.level[k] for k in range(n)]
        stay = [overriding and self.value[k] <= self.level[k] + clear_margin for k in range(n)]
        acts = [enter[k] or ahead[k] or stay[k] for k in range(n)]
        governed = {self.group[k] for k in range(n) if self.sound[k] and acts[k]}
        use = [k for k in range(n) if self.sound[k] or self.group[k] not in governed]
        for flags, why, score in ((enter, 'enter', self.value), (ahead, 'ahead', self.value_next),
                                  (stay, 'stay', self.value)):
            hit = [k for k in use if flags[k]]
            if hit:
                return min(hit, key=lambda q: score[q] - self.level[q]), why
        return self.smallest(), ''

    def label(self, k) -> str:
        if self.members[k] > 1:
            return f'a cluster of {self.members[k]} obstacles ({self.source[k]}, nearest {self.obstacle[k]})'
        return f'obstacle {self.obstacle[k]}'

    def describe(self, k, f) -> dict:
        if k < 0:
            return dict(obstacle_index=-1, obstacle_xy=(math.nan, math.nan), value=math.inf)
        j = self.obstacle[k]
        d = dict(obstacle_index=j, obstacle_xy=tuple(float(v) for v in f.detections.value[j]),
                 value=self.value[k], alpha=self.level[k])
        if self.sound[k]:
            d['source'] = self.source[k]
        return d


def _add_cluster_constraints(c: _Constraints, f, state, horizon, t, store) -> None:
    """Cluster constraints of robot ``f`` at its (propagated) ``state``."""
    from . import cluster as cl
    cfg = f.config
    store = store if store is not None else default_cluster_store(cfg)
    st = store.settings
    key_det = f.detections.value
    cache = f.__dict__.get('_cluster_cache')
    if cache is None or cache[0] is not key_det:
        groups = [g for g in cl.components(key_det, st.link_distance) if len(g) > 1]
        frames = [cl.canonical(key_det[g], st.key_resolution) for g in groups]
        cache = (key_det, groups, frames)
        f._cluster_cache = cache
    _, groups, frames = cache
    if not groups:
        return
    # sampled control: each command holds for ``horizon``. The union's turn is the bang
    # (+-w_max) with the larger V at the end of its hold, and the planner's command is
    # judged by what the filter can still do after it: the better bang held for one more
    # period (a pass never leaves the robot where no held turn keeps V above the level)
    u = _planned_turn(f, t)
    w = cfg.omega_max
    speed = np.full(3, cfg.speed)
    hold = np.full(3, horizon)
    ahead = arc_flow(state[None], speed[:1], np.array([u]), hold[:1])[0]
    points = arc_flow(np.stack([state, state, ahead, ahead]), np.full(4, cfg.speed),
                      np.array([w, -w, w, -w]), np.full(4, horizon))
    for gi, (g, (key, origin, angle, centres)) in enumerate(zip(groups, frames)):
        group = ('cluster', gi)
        for j in g:                 # the members' own constraints belong to the cluster
            if j < len(c.group):
                c.group[j] = group
        nearest = int(g[np.argmin(np.hypot(*(key_det[g] - state[:2]).T))])
        solved = store.get(key)
        if solved is None:
            store.request(key, centres)
            if store.solving(key):
                c.solving += 1
        if solved is not None:
            v, _ = solved.evaluate(cl.to_frame(np.vstack([state[None], points, ahead[None]]), origin, angle))
            turn = 1.0 if v[1] >= v[2] - solved.tie else -1.0
            c.add(v[0], cfg.cluster_alpha, turn, min(v[5], max(v[3], v[4])), nearest, 'cluster', len(g),
                  group)
        else:
            # the loiter-circle fallback keeps its invariant only from a state with a clear
            # circle; from any other state the per-obstacle rule (always in the list) is the
            # best known until the union's value is in force
            v, turn = cl.orbit_value(np.stack([state, ahead]), key_det[g], st.radius + st.margin,
                                     st.turning_radius)
            if v[0] > 0.0:
                c.add(v[0], 0.0, turn[0], v[1], nearest, 'cluster-fallback', len(g), group)


_STORES = {}


def default_cluster_store(cfg: FilterConfig):
    """The process's shared ClusterStore for a robot configuration (background solves)."""
    from .cluster import ClusterSettings, ClusterStore
    settings = ClusterSettings(radius=cfg.radius, speed=cfg.speed, omega_max=cfg.omega_max,
                               link=cfg.cluster_link)
    store = _STORES.get(settings)
    if store is None:
        store = _STORES[settings] = ClusterStore(settings)
    return store


def _sampled_control(filters, vf: ValueFunction, rel, robot, t, horizons, turn):
    """The avoid turn and the lookahead value of every pair, for commands held over H.

    H is the robot's lookahead (>= its control period). A command holds for H, so:

    * the avoid turn is the bang (+-w_max) whose hold ends at the larger V (ties
      left, within the law's tie tolerance); as H -> 0 this is sign(dV/dtheta), the
      continuous law, which it keeps where both ends are off the grid;
    * the planner's command is judged by what the filter can still do after it:
      V where the command's hold ends, and after the better bang held for one more
      period from there (the smaller of the two). A pass therefore never leaves the
      robot below the level, nor where no held turn keeps V above it (the filter
      acts one hold early rather than one hold late).

    A silent planner counts as a zero command (what the filter would forward).
    Translation invariance: the relative state moves like the robot itself.
    Returns (unit turn, V after the planner's hold and the best bang's).
    """
    if len(rel) == 0:
        return turn, np.zeros(0)
    # per-robot values, repeated over each robot's pairs (pairs are grouped by robot)
    robots, counts = np.unique(robot, return_counts=True)
    per = np.array([(_planned_turn(filters[i], t), horizons[i], filters[i].config.speed,
                     filters[i].config.omega_max) for i in robots], dtype=float).reshape(-1, 4)
    omega, horizon, speed, bang = (np.repeat(per[:, c], counts) for c in range(4))
    if not np.any(horizon > 0):
        return turn, np.full(len(rel), np.inf)
    ahead = arc_flow(rel, speed, omega, horizon)
    starts = np.concatenate([rel, rel, ahead, ahead])
    ends = arc_flow(starts, np.tile(speed, 4), np.concatenate([bang, -bang, bang, -bang]),
                    np.tile(horizon, 4))
    v = vf.value(np.concatenate([ends, ahead]), outside=np.inf).reshape(5, len(rel))
    left, right = v[0], v[1]
    held = np.where(left >= right - tie_tolerance(vf), 1.0, -1.0)
    use = (horizon > 0) & (np.isfinite(left) | np.isfinite(right))
    value_next = np.where(horizon > 0, np.minimum(v[4], np.maximum(v[2], v[3])), np.inf)
    return np.where(use, held, turn), value_next
