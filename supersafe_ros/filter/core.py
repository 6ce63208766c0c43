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
value-function interpolation over every robot-obstacle pair); every robot's
constraints (per obstacle and per cluster) are rows of one table, and the rule that
picks the governing one is applied with array reductions over it. The robots' inputs are
read into columns once (``_gather``: their age, plans, lookahead and planner's command as
arrays), so the Python left per robot is a few attribute reads and recording its command. The result (``Decisions``)
holds the commands as lists and builds each robot's ``FilterOutput``, with its reason,
only when it is read. It decides exactly
as the robot-by-robot implementation it replaced (test_filter_vectorised.py keeps that
one as the reference). ``RobotFilter.step`` is the one-robot case of it: a robot's own
filter node decides on the path from pose to cmd_vel, where numpy's cost per call (about
1 us warm, several times that in a process woken by a pose) would be most of the time,
so one robot is decided with Python scalars (``_decide_one``: the same operations and
ties, the same decisions bit for bit, tested against the fleet path).
"""
from __future__ import annotations

from bisect import bisect_left, insort
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
import itertools
import math
from operator import attrgetter, is_, is_not

import numpy as np

from .law import avoid_turn, avoid_turn_at, evaluate_pairs, tie_tolerance  # noqa: F401  (the law's rule; re-exported)
from ..reach.grid import TWO_PI, wrap_angle
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
            object.__setattr__(self, name, float(v))   # floats in every command (speed=3 goes out as 3.0)
        if not math.isfinite(self.cluster_alpha):
            raise ValueError(f'cluster_alpha must be finite, got {self.cluster_alpha}')
        object.__setattr__(self, 'cluster_alpha', float(self.cluster_alpha))

    @property
    def sent_kept(self) -> float:
        """How long the commands sent are remembered: a pose is propagated over at most
        hold_timeout and judged stale after pose_timeout, plus a second."""
        return max(self.hold_timeout, self.pose_timeout) + 1.0


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
        self._pose_intervals = _NO_INTERVALS      # windows of the last intervals (immutable: robots
        self._command_intervals = _NO_INTERVALS   # fed by one message share them)

    # -- inputs ------------------------------------------------------------------------
    def update_pose(self, state, t, stamp=None) -> None:
        """A pose (x, y, theta) in map, arrived at ``t``; raises ValueError (and records it)
        if not finite.

        ``stamp``: the time the pose describes (its header stamp) on the same clock as
        ``t``, or None to take the arrival time. The filter propagates the pose from its
        stamp to the decision time under the commands it sent.
        """
        s = np.asarray(state, dtype=float).reshape(-1)
        if s.shape != (3,) or not all(map(math.isfinite, s.tolist())):    # (np.isfinite: ~10x the cost)
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
            self._pose_intervals = self._pose_intervals.then(self.pose.stamp - previous)

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
            self._command_intervals = self._command_intervals.then(t - previous)

    def control_period(self) -> float:
        """The hold time of a command: configured, else measured (0 until measurable).

        Measured as the larger of the median intervals between pose stamps (the
        robot's step) and between planner commands (when new commands come).
        """
        if self.config.control_period > 0.0:
            return self.config.control_period
        poses, commands = self._pose_intervals.middle, self._command_intervals.middle   # None: empty
        if poses is None:
            return 0.0 if commands is None else commands
        return poses if commands is None else max(poses, commands)

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
        keep = self.config.sent_kept
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


def update_poses(filters, states, t, stamp=None, skip=None) -> None:
    """``filters[i].update_pose(states[i], t, stamp)`` for every robot whose ``skip[i]`` is
    falsy (the fleet node's batched poses: one validation for all rows, then a few
    assignments per robot instead of a call that re-validates one row). Raises ValueError
    before updating anyone if a row to take is not finite or the stamp is not."""
    s = np.asarray(states, dtype=float).reshape(len(filters), 3)
    take = _taken(filters, skip)
    if not np.all(np.isfinite(s[take])):
        raise ValueError('poses are not finite (x, y, theta)')
    t = float(t)
    stamp = t if stamp is None else float(stamp)
    if not math.isfinite(stamp):
        raise ValueError(f'pose stamp is not finite ({stamp})')
    _accept_rows(filters, 'pose', s, take, t, stamp)


def update_commands(filters, omegas, t, skip=None) -> None:
    """``filters[i].update_command(omegas[i], t)`` for every robot whose ``skip[i]`` is falsy
    (the fleet node's batched commands). Raises ValueError before updating anyone if a turn
    rate to take is not finite."""
    w = np.asarray(omegas, dtype=float).reshape(len(filters))
    take = _taken(filters, skip)
    if not np.all(np.isfinite(w[take])):
        raise ValueError('planner commands are not finite')
    t = float(t)
    _accept_rows(filters, 'command', w.tolist(), take, t, t)


def _taken(filters, skip) -> np.ndarray:
    return np.ones(len(filters), bool) if skip is None else ~np.array([bool(b) for b in skip], dtype=bool)


def _accept_rows(filters, name, rows, take, t, stamp) -> None:
    """Each taken row becomes its filter's newest ``name`` input (pose or command), arrived at
    ``t`` and describing ``stamp``; the interval since the previous stamp feeds the measured
    control period (as ``update_pose`` / ``update_command`` do). Robots with the same window
    and the same previous stamp get the same next window, made once."""
    windows = '_pose_intervals' if name == 'pose' else '_command_intervals'
    made = {}      # (window before, previous stamp) -> window after (kept alive here: ids stay unique)
    for f, row, ok in zip(filters, rows, take.tolist()):
        if not ok:
            continue
        inp = f.pose if name == 'pose' else f.command
        previous = inp.stamp if inp.value is not None else None
        inp.value, inp.t, inp.rejected, inp.stamp = row, t, '', stamp
        if previous is not None and stamp > previous:
            before = getattr(f, windows)
            after = made.get((before, previous))
            if after is None:
                after = made[(before, previous)] = before.then(stamp - previous)
            setattr(f, windows, after)


def update_detections_all(filters, centres, t) -> None:
    """``update_detections(centres, t)`` for every robot, with one array shared by all (the
    fleet node's batched detections; robots that share it share its cluster frames)."""
    c = np.asarray(centres, dtype=float)
    if c.size == 0:
        c = np.zeros((0, 2))
    if c.ndim != 2 or c.shape[1] != 2 or not np.all(np.isfinite(c)):
        raise ValueError(f'detections must be finite (N, 2) centres, got shape {c.shape}')
    t = float(t)
    for f in filters:
        f.detections.accept(c, t)


class _Intervals:
    """The last PERIOD_SAMPLES intervals in arrival order (``recent``), the same sorted
    (``ordered``) and their median (``middle``, None if empty), made once: a window is never
    changed, ``then`` makes the next one, so robots fed by one message share their windows and
    a fleet's tick makes one window instead of one per robot."""

    __slots__ = ('recent', 'ordered', 'middle')

    def __init__(self, recent=(), ordered=()):
        self.recent, self.ordered = tuple(recent), tuple(ordered)
        self.middle = _median_of_sorted(self.ordered) if self.ordered else None

    def then(self, interval) -> '_Intervals':
        """The window after one more interval (the oldest leaves when it is full)."""
        ordered = list(self.ordered)
        recent = self.recent
        if len(recent) == PERIOD_SAMPLES:
            del ordered[bisect_left(ordered, recent[0])]
            recent = recent[1:]
        insort(ordered, interval)
        return _Intervals(recent + (interval,), ordered)

    def __len__(self):
        return len(self.recent)

    def __iter__(self):
        return iter(self.recent)

    def __getitem__(self, i):
        return self.recent[i]


_NO_INTERVALS = _Intervals()


def _median_of_sorted(s) -> float:
    """np.median of a few sorted finite floats, bit for bit (the mean of the two middle ones for
    an even count, (a + b) / 2 as numpy computes it), without numpy's cost (~10 us a call)."""
    k = len(s) // 2
    return float(s[k]) if len(s) % 2 else float((s[k - 1] + s[k]) / 2.0)


def arc_flow(states, speed, omega, dt) -> np.ndarray:
    """Exact Dubins arcs for arrays of states (N, 3), speeds, turn rates and durations (N,)."""
    s = np.asarray(states, dtype=float)
    x, y, th = s[:, 0], s[:, 1], s[:, 2]
    th1 = th + omega * dt
    turning = np.abs(omega * dt) > 1e-9
    safe = np.where(turning, omega, 1.0)
    c0, s0 = np.cos(th), np.sin(th)      # both branches use them: computed once
    ax = np.where(turning, (np.sin(th1) - s0) / safe, c0 * dt)
    ay = np.where(turning, (c0 - np.cos(th1)) / safe, s0 * dt)
    return np.stack([x + speed * ax, y + speed * ay, wrap_angle(th1)], axis=1)


def _bang_ends(states, speed, bang, hold) -> np.ndarray:
    """Where holding +bang, then -bang, for ``hold`` from ``states`` (k, 3) ends: (2k, 3), the
    left turns' ends first."""
    return arc_flow(np.concatenate([states, states]), np.tile(speed, 2), np.concatenate([bang, -bang]),
                    np.tile(hold, 2))


def _better_bang(left, right, tie) -> np.ndarray:
    """The unit turn whose hold ends at the larger V: left (+1) unless V after the right turn
    is larger by more than ``tie`` (the value's tie tolerance: ties turn left)."""
    return np.where(left >= right - tie, 1.0, -1.0)


def _follow(states, omegas, dts, speed) -> np.ndarray:
    """``states`` (N, 3) moved along their robots' plans at ``speed`` (N,): arc k of robot i
    holds ``omegas[k, i]`` for ``dts[k, i]`` (``_gather``'s arcs; shorter plans padded with
    zero-length arcs, which only wrap theta); with no arcs at all, theta wrapped all the same
    (a robot's state does not depend on the other robots' plans)."""
    if len(omegas) == 0:
        states[:, 2] = wrap_angle(states[:, 2])
        return states
    for omega, dt in zip(omegas, dts):
        states = arc_flow(states, speed, omega, dt)
    return states


class _Robots:
    """The inputs of a fleet's robots as columns (``_gather``): for all N robots, their
    configurations, problems ('' if judged), turn bound and history kept; for the M robots
    whose (last valid) state enters the law (``use``, their rows), everything the law needs."""

    __slots__ = ('filters', 'use', 'problems', 'all_configs', 'all_bang', 'all_keep', 'configs', 'failing',
                 'poses', 'omega_arcs', 'dt_arcs', 'age', 'dets', 'horizon', 'planned', 'speed', 'bang',
                 'overriding', 'margin', 'fresh', 'cluster_alpha')


_NEVER = (math.inf, 0.0)      # the (time, turn) a robot with no such command sent shows: no arc starts then
_VALUE, _T, _STAMP, _REJECTED = (attrgetter(a) for a in ('value', 't', 'stamp', 'rejected'))


def _judged(f, t):
    """(why ``f`` cannot be judged now, '' if it can; whether its (last valid) state enters
    the law: judged, or failing safe with a pose and detections younger than hold_timeout)."""
    cfg, pose, det = f.config, f.pose, f.detections
    if (pose.rejected or det.rejected or pose.value is None or det.value is None
            or t - pose.t > cfg.pose_timeout or t - det.t > cfg.detections_timeout):
        return f.problem(t), (pose.value is not None and det.value is not None
                              and t - pose.t <= cfg.hold_timeout and t - det.t <= cfg.hold_timeout)
    return '', True


def _config_columns(configs, names):
    """Per robot, the configuration fields ``names`` as float columns (robots share a few
    configurations: each field is read once per distinct one)."""
    c = configs[0] if configs else None
    if c is not None and all(map(is_, configs, itertools.repeat(c))):   # one configuration (not just equal ones:
        # 0.0 == -0.0, and a zero's sign shows in the commands)
        return [np.full(len(configs), float(getattr(c, a))) for a in names]
    distinct = {id(c): c for c in configs}
    index = {k: i for i, k in enumerate(distinct)}
    row = np.fromiter((index[id(c)] for c in configs), dtype=np.intp, count=len(configs))
    return [np.array([float(getattr(c, a)) for c in distinct.values()])[row] for a in names]


def _gather(filters, t) -> _Robots:
    """The fleet's inputs as columns, with ``_judged``, ``_plan``, ``_command_fresh``,
    ``RobotFilter.lookahead`` and ``_planned_turn`` evaluated over them: the same comparisons
    and the same arithmetic (Python's min and max as ``_py_min``/``_py_max``), so the same
    values bit for bit; a robot whose plan is neither of ``_plan``'s two common cases gets
    ``segments_since`` (a pose older than two commands sent)."""
    rb = _Robots()
    n = len(filters)
    configs = [f.config for f in filters]
    (pose_timeout, det_timeout, hold, bang_all, compensate, cmd_timeout, look, period, speed, margin,
     cluster_alpha, rb.all_keep) = _config_columns(configs, (
        'pose_timeout', 'detections_timeout', 'hold_timeout', 'omega_max', 'compensate_delay', 'cmd_timeout',
        'lookahead', 'control_period', 'speed', 'clear_margin', 'cluster_alpha', 'sent_kept'))
    rb.all_configs, rb.all_bang = configs, bang_all
    poses, dets = [f.pose for f in filters], [f.detections for f in filters]
    pose_t = np.fromiter(map(_T, poses), dtype=float, count=n)
    det_t = np.fromiter(map(_T, dets), dtype=float, count=n)
    pose_values, det_values = list(map(_VALUE, poses)), list(map(_VALUE, dets))
    has = (np.fromiter(map(is_not, pose_values, itertools.repeat(None)), dtype=bool, count=n)
           & np.fromiter(map(is_not, det_values, itertools.repeat(None)), dtype=bool, count=n))
    clean = np.ones(n, bool)
    for inputs in (poses, dets):
        if any(map(_REJECTED, inputs)):
            clean &= ~np.fromiter(map(bool, map(_REJECTED, inputs)), dtype=bool, count=n)
    judged = has & clean & ~(t - pose_t > pose_timeout) & ~(t - det_t > det_timeout)
    rb.problems = [''] * n
    for i in np.flatnonzero(~judged).tolist():
        rb.problems[i] = filters[i].problem(t)
    use = np.flatnonzero(judged | (has & (t - pose_t <= hold) & (t - det_t <= hold)))
    rb.use, m = use, len(use)
    if m < n:
        filters, configs, poses, pose_values, det_values = (
            [x[i] for i in use.tolist()] for x in (filters, configs, poses, pose_values, det_values))
        pose_t = pose_t[use]
        (hold, compensate, cmd_timeout, look, period, speed, bang, margin, cluster_alpha) = (
            c[use] for c in (hold, compensate, cmd_timeout, look, period, speed, bang_all, margin, cluster_alpha))
    else:
        bang = bang_all
    rb.filters, rb.configs, rb.failing = filters, configs, ~judged[use]
    rb.speed, rb.bang, rb.margin, rb.cluster_alpha = speed, bang, margin, cluster_alpha
    rb.dets = det_values
    rb.poses = np.array(pose_values, dtype=float).reshape(m, 3)
    rb.overriding = np.fromiter((f.overriding for f in filters), dtype=bool, count=m)
    compensate = compensate != 0.0

    # _plan: the pose's age, and the arcs held since its stamp
    stamp = np.fromiter(map(_STAMP, poses), dtype=float, count=m)
    age = t - np.where(stamp < pose_t, stamp, pose_t)
    age = np.where(compensate, _py_max(0.0, _py_min(age, hold)), 0.0)
    rb.age = age
    t0 = t - age
    sents = [f.sent for f in filters]
    last = np.fromiter(itertools.chain.from_iterable(s[-1] if s else _NEVER for s in sents), dtype=float,
                       count=2 * m).reshape(m, 2)
    prev = np.fromiter(itertools.chain.from_iterable(s[-2] if len(s) > 1 else _NEVER for s in sents),
                       dtype=float, count=2 * m).reshape(m, 2)
    moving = compensate & (t > t0)
    one = moving & (last[:, 0] <= t0)                        # nothing sent since the pose: one arc
    two = moving & ~one & (prev[:, 0] <= t0) & (t0 < last[:, 0]) & (last[:, 0] < t)   # one command since
    rest = np.flatnonzero(moving & ~one & ~two).tolist()
    plans = [filters[i].segments_since(float(t0[i]), t) for i in rest]
    depth = max([len(p) for p in plans] + [2 if two.any() else 1 if one.any() else 0])
    omegas, dts = np.zeros((depth, m)), np.zeros((depth, m))
    if depth:
        omegas[0, one], dts[0, one] = last[one, 1], t - t0[one]
        omegas[0, two], dts[0, two] = prev[two, 1], last[two, 0] - t0[two]
    if depth > 1:
        omegas[1, two], dts[1, two] = last[two, 1], t - last[two, 0]
    for i, plan in zip(rest, plans):
        for k, (w, d) in enumerate(plan):
            omegas[k, i], dts[k, i] = w, d
    rb.omega_arcs, rb.dt_arcs = omegas, dts

    # _command_fresh, _planned_turn (clipped as _clip) and the lookahead
    commands = [f.command for f in filters]
    value = list(map(_VALUE, commands))
    rb.fresh = fresh = (np.fromiter(map(is_not, value, itertools.repeat(None)), dtype=bool, count=m)
                        & (t - np.fromiter(map(_T, commands), dtype=float, count=m) <= cmd_timeout))
    value = np.array([0.0 if v is None else v for v in value] if None in value else value, dtype=float)
    clipped = np.where(value < bang, value, bang)
    clipped = np.where(clipped > -bang, clipped, -bang)
    rb.planned = np.where(fresh, clipped, 0.0)
    # measured period: the larger median of the pose and command intervals (each > 0; none: 0)
    measured = _py_max(*(np.array([0.0 if w.middle is None else w.middle for w in windows], dtype=float)
                         for windows in ([f._pose_intervals for f in filters], [f._command_intervals for f in filters])))
    period = np.where(period > 0.0, period, measured)
    rb.horizon = np.where(compensate, _py_max(look, period), look)
    return rb


def _plan(f, t):
    """(pose age, [(turn rate, duration)] held from the pose's stamp to ``t``) of one robot;
    (0, ()) without delay compensation."""
    if not f.config.compensate_delay:
        return 0.0, ()
    pose = f.pose
    age = max(0.0, min(t - min(pose.t, pose.stamp), f.config.hold_timeout))
    t0 = t - age
    sent = f.sent
    # segments_since's answer in the two common cases: nothing sent since the pose (one arc),
    # or one command sent since (a robot deciding on a pose older than its last decision)
    if sent and sent[-1][0] <= t0 and t > t0:
        return age, ((sent[-1][1], t - t0),)
    if len(sent) > 1 and sent[-2][0] <= t0 < sent[-1][0] < t:
        ts = sent[-1][0]
        return age, ((sent[-2][1], ts - t0), (sent[-1][1], t - ts))
    return age, f.segments_since(t0, t)


def _command_fresh(f, t) -> bool:
    """Whether the planner's command is recent enough to forward."""
    return f.command.value is not None and t - f.command.t <= f.config.cmd_timeout


def _planned_turn(f, t, fresh=None) -> float:
    """The command the filter would forward (a silent planner counts as 0), clipped;
    ``fresh``: ``_command_fresh(f, t)`` if the caller has it."""
    if fresh is None:
        fresh = _command_fresh(f, t)
    return _clip(f.command.value, f.config.omega_max) if fresh else 0.0


def _clip(value, bound) -> float:
    """value clipped to +-bound (scalars; np.clip costs ~10 us a call)."""
    return max(-bound, min(bound, float(value)))


def _first_min(segment, position, score, mask, n) -> np.ndarray:
    """Per segment 0..n-1: the row with the smallest ``score`` among ``mask``, the first
    by ``position`` on ties (Python's ``min`` over a list in that order); -1 if none."""
    out = np.full(n, -1, dtype=np.intp)
    idx = np.flatnonzero(mask)
    if len(idx):
        order = idx[np.lexsort((position[idx], score[idx], segment[idx]))]
        seg = segment[order]
        first = np.flatnonzero(np.concatenate(([True], seg[1:] != seg[:-1])))
        out[seg[first]] = order[first]
    return out


def _first_min_of_runs(score, run, starts) -> np.ndarray:
    """Per run of equal ``run`` labels 0..k-1 (consecutive, each non-empty, beginning at
    ``starts``): the index of its smallest ``score``, the first on ties (``_first_min`` over
    rows in run order, without its sort); ``score`` has no NaN."""
    if len(starts) == 0:
        return np.zeros(0, dtype=np.intp)
    at = np.flatnonzero(score == np.minimum.reduceat(score, starts)[run])
    return at[np.concatenate(([True], run[at[1:]] != run[at[:-1]]))]


def _py_max(a, b):
    """Python's max(a, b) elementwise (a on ties: -0.0 and 0.0 come out as Python's would)."""
    return np.where(b > a, b, a)


def _py_min(a, b):
    return np.where(b < a, b, a)


class _Table:
    """Every constraint of every robot, one row each (pairs first, then clusters).

    Columns: the robot (row in ``use``), its position in the robot's list (ties go to
    the first), V, level, the unit avoid turns (``turns_of(rows)``: read only for the rows
    robots avoid by), V after the planner's hold, the obstacle
    it names (index in the robot's detections) and its centre, whether it is sound for
    its layout (a cluster's union value or the loiter fallback), its group (a lone
    obstacle, or the cluster its members belong to), members, and for a cluster row whether it
    is the loiter fallback (its source 'cluster-fallback', else 'cluster').
    """

    __slots__ = ('robot', 'position', 'value', 'level', 'turns_of', 'value_next', 'obstacle', 'xy',
                 'sound', 'group', 'members', 'fallback')


def step_many(filters, safe_set: SafeSet, t, clusters=None) -> list:
    """One decision per robot filter, with one vectorised evaluation of the law.

    Robots that can be judged use their current pose and detections; robots that
    fail safe use their last valid pose and detections if younger than
    ``hold_timeout``, else the stop-turn policy. ``clusters``: the ClusterStore
    for obstacles judged together (None: the process's shared store for the
    robots' configuration; see ``filter.cluster``).

    The robots' inputs are gathered into columns once (``_gather``), and every
    robot's constraints (one per detected obstacle, one per cluster) are rows of
    one table; the rule that picks the governing one (``_govern``) is evaluated
    over the table with array operations. Returns ``Decisions``: the commands as
    lists, each robot's ``FilterOutput`` built when read.
    """
    if len(filters) == 1:
        f = filters[0]
        problem, usable = _judged(f, t)
        if usable:
            return _decide_one(f, problem, safe_set, t, clusters)
    rb = _gather(filters, t)
    m = len(rb.use)
    states = _follow(rb.poses, rb.omega_arcs, rb.dt_arcs, rb.speed)
    horizon, planned, speed, bang, dets = rb.horizon, rb.planned, rb.speed, rb.bang, rb.dets
    counts = np.fromiter(map(len, dets), dtype=np.intp, count=m)

    # -- one row per (robot, detected obstacle): the safe set in force -------------------------
    n_pairs = int(counts.sum())
    start = np.concatenate(([0], np.cumsum(counts)[:-1])).astype(np.intp) if m else np.zeros(0, np.intp)
    pair_robot = np.repeat(np.arange(m), counts)
    if n_pairs:
        centres = np.concatenate([d for d in dets if len(d)])
        rel = np.empty((n_pairs, 3))
        rel[:, 0] = states[pair_robot, 0] - centres[:, 0]
        rel[:, 1] = states[pair_robot, 1] - centres[:, 1]
        rel[:, 2] = states[pair_robot, 2]
    else:
        centres, rel = np.zeros((0, 2)), np.zeros((0, 3))
    value, value_next = _pair_reads(safe_set.vf, rel, planned[pair_robot], horizon[pair_robot], speed[pair_robot],
                                    bang[pair_robot], float(safe_set.alpha))
    position = np.arange(n_pairs) - start[pair_robot]
    group = np.arange(n_pairs)          # each obstacle its own group until clustered
    cl = _cluster_rows(rb.filters, rb.configs, states, planned, horizon, speed, bang, rb.cluster_alpha, dets, start,
                       clusters)
    group[cl['member_pairs']] = n_pairs + cl['member_groups']
    tab = _Table()
    k = len(cl['robot'])
    cat = (lambda a, b: np.concatenate([a, b])) if k else (lambda a, b: a)   # noqa: E731
    tab.robot = cat(pair_robot, cl['robot'])
    tab.position = cat(position, counts[cl['robot']] + cl['index'])
    tab.value = cat(value, cl['value'])
    tab.level = cat(np.full(n_pairs, float(safe_set.alpha)), cl['level'])
    tab.value_next = cat(value_next, cl['value_next'])
    tab.obstacle = cat(position, cl['obstacle'])
    tab.xy = cat(centres, cl['xy'])
    tab.sound = cat(np.zeros(n_pairs, bool), np.ones(k, bool))
    tab.group = cat(group, n_pairs + cl['group'])
    tab.members = cat(np.ones(n_pairs, np.intp), cl['members'])
    tab.fallback = cat(np.zeros(n_pairs, bool), cl['fallback'])

    k_gov, kind = _govern(tab, rb.overriding, rb.margin, n_pairs + cl['n_groups'], m)
    k_small = _first_min(tab.robot, tab.position, tab.value - tab.level, np.isfinite(tab.value), m)

    def turns_of(rows) -> np.ndarray:
        """The unit avoid turns of table ``rows`` (read only for the rows robots avoid by)."""
        out = np.zeros(len(rows))
        pair = rows < n_pairs
        p = rows[pair]
        r = pair_robot[p]
        out[pair] = _pair_turns(safe_set.vf, rel[p], value[p], horizon[r], speed[r], bang[r])
        out[~pair] = cl['turns_of'](rows[~pair] - n_pairs)
        return out

    tab.turns_of = turns_of
    return _outputs(filters, rb, safe_set, t, tab, k_gov, kind, k_small, cl['solving'])


def _decide_one(f, problem, safe_set, t, clusters) -> Decisions:
    """``step_many`` for one robot with a state to judge (a robot's own filter node).

    The same values (``_pair_values``, ``_cluster_rows``) and the same rules, with the
    table's few rows in Python lists instead of arrays: numpy's cost per call is most of
    one robot's decision, and on the path from pose to cmd_vel every microsecond shows.
    Same arithmetic, same ties (smallest score, then the first in the robot's list), so
    the same decisions bit for bit (test_filter_vectorised: each robot decided alone
    decides as in a fleet).
    """
    cfg = f.config
    age, plan = _plan(f, t)
    x, y, th = f.pose.value.tolist()      # _follow's arcs, in Python floats
    for omega, dt in plan:
        x, y, th = _arc(x, y, th, cfg.speed, omega, dt)
    if not plan:
        th = _wrap(th)
    states = np.array([[x, y, th]])
    fresh = _command_fresh(f, t)
    horizon, planned = float(f.lookahead()), _planned_turn(f, t, fresh)
    speed, bang = float(cfg.speed), float(cfg.omega_max)
    det = f.detections.value
    n_pairs = len(det)
    pairs = _robot_pair_values(safe_set.vf, x, y, th, det.tolist(), planned, horizon, speed, bang, FEW_PAIRS)
    if pairs is None:
        rel = np.empty((n_pairs, 3))
        rel[:, 0] = x - det[:, 0]
        rel[:, 1] = y - det[:, 1]
        rel[:, 2] = th
        pairs = [a.tolist() for a in _pair_values(safe_set.vf, rel, np.full(n_pairs, planned),
                                                  np.full(n_pairs, horizon), np.full(n_pairs, speed),
                                                  np.full(n_pairs, bang))]
    value, turn, value_next = pairs
    one = lambda v: np.array([v], dtype=float)      # noqa: E731  (a robot's column)
    cl = _cluster_rows([f], [cfg], states, one(planned), one(horizon), one(speed), one(bang), one(cfg.cluster_alpha),
                       [det], np.zeros(1, np.intp), clusters)
    alpha = float(safe_set.alpha)
    group = list(range(n_pairs))
    for p, g in zip(cl['member_pairs'].tolist(), cl['member_groups'].tolist()):
        group[p] = n_pairs + g
    tab = _Table()
    tab.position = list(range(n_pairs)) + [n_pairs + i for i in cl['index'].tolist()]
    tab.value = value + cl['value'].tolist()
    tab.level = [alpha] * n_pairs + cl['level'].tolist()
    tab.value_next = value_next + cl['value_next'].tolist()
    tab.obstacle = list(range(n_pairs)) + cl['obstacle'].tolist()
    tab.xy = np.concatenate([det, cl['xy']]) if len(cl['xy']) else det
    tab.sound = [False] * n_pairs + [True] * len(cl['robot'])
    tab.group = group + [n_pairs + g for g in cl['group'].tolist()]
    tab.members = [1] * n_pairs + cl['members'].tolist()
    tab.fallback = [False] * n_pairs + cl['fallback'].tolist()

    k_gov, kind, k_small = _govern_one(tab, f.overriding, float(cfg.clear_margin))

    # _outputs for one robot
    failing = bool(problem)
    overrides = not failing and kind > 0
    named = k_gov if overrides else k_small
    avoid = named >= 0
    if overrides or (failing and avoid):      # the pairs' turns are read; a cluster row's on demand
        w = bang * (turn[named] if named < n_pairs else float(cl['turns_of']([named - n_pairs])[0]))
    else:
        w = bang if failing else planned
    stopped = (failing and not avoid) or (not failing and not overrides and not fresh)
    v = 0.0 if stopped else speed
    a = FAIL_SAFE if failing else OVERRIDE if overrides else PASS
    f.overriding = overrides
    f.record_sent(w, t)
    common, solving = _set_fields(safe_set), int(cl['solving'][0])
    return Decisions([w], [v], [a], lambda i: _explain(problem, cfg, w, v, a, common, tab, named, kind, fresh,
                                                       horizon, age, solving, False))


def _govern_one(tab, overriding, margin):
    """``_govern`` and ``_first_min`` for one robot whose table columns are lists: (the row
    that makes it override and why, or -1 and 0 to pass; the row with the smallest finite
    V - level, or -1). The same rule: within a cluster its sound row first, then enter,
    ahead, stay, each by the smallest score and the first in the robot's list on ties."""
    rows = range(len(tab.value))
    enter = [tab.value[r] <= tab.level[r] for r in rows]
    ahead = [tab.value_next[r] <= tab.level[r] for r in rows]
    stay = [overriding and tab.value[r] <= tab.level[r] + margin for r in rows]
    governed = {tab.group[r] for r in rows if tab.sound[r] and (enter[r] or ahead[r] or stay[r])}
    usable = [tab.sound[r] or tab.group[r] not in governed for r in rows]
    k_gov, kind = -1, 0
    for code, flags, values in ((1, enter, tab.value), (2, ahead, tab.value_next), (3, stay, tab.value)):
        hits = [(values[r] - tab.level[r], tab.position[r], r) for r in rows if usable[r] and flags[r]]
        if hits:
            k_gov, kind = min(hits)[2], code
            break
    finite = [(tab.value[r] - tab.level[r], tab.position[r], r) for r in rows if math.isfinite(tab.value[r])]
    return k_gov, kind, min(finite)[2] if finite else -1


def _govern(tab, overriding, margin, n_groups, m):
    """(constraint, why) per robot row that makes the filter override, or (smallest, '') to pass.

    Within a cluster its sound constraint (union value or fallback) comes first: if
    it enters, looks ahead to its level or holds its hysteresis, the cluster's
    members' own constraints are set aside, so the union's avoid turn is never
    traded for a single member's. Between clusters and lone obstacles (farther
    apart than the link distance) the smallest value governs, as per obstacle.
    Checked in order: enter (V <= level), ahead (V after the planner's hold <=
    level), stay (overriding and V <= level + clear margin); within each, the
    smallest V - level (resp. V_next - level), first in the robot's list on ties.
    """
    r = tab.robot
    enter = tab.value <= tab.level
    ahead = tab.value_next <= tab.level
    stay = overriding[r] & (tab.value <= tab.level + margin[r])
    acts = enter | ahead | stay
    governed = np.zeros(n_groups, bool)
    governed[tab.group[tab.sound & acts]] = True
    use = tab.sound | ~governed[tab.group]
    k = np.full(m, -1, dtype=np.intp)
    kind = np.zeros(m, dtype=np.int8)      # 0 pass, 1 enter, 2 ahead, 3 stay
    open_ = np.ones(m, bool)
    for code, flags, score in ((1, enter, tab.value - tab.level), (2, ahead, tab.value_next - tab.level),
                               (3, stay, tab.value - tab.level)):
        hit = _first_min(r, tab.position, score, use & flags & open_[r], m)
        got = hit >= 0
        k[got], kind[got] = hit[got], code
        open_ &= ~got
    return k, kind


_KINDS = ('', 'enter', 'ahead', 'stay')
_ACTIONS = np.array([PASS, OVERRIDE, FAIL_SAFE], dtype=object)     # by code: 0 pass, 1 override, 2 fail safe


class Decisions(Sequence):
    """What ``step_many`` decided, one entry per robot filter, in order.

    ``omega``, ``linear`` and ``action`` are lists: the commands to send, all a batched caller
    needs every tick. ``decisions[i]`` is robot i's ``FilterOutput`` with its reason, built on
    first access from values fixed at the decision (formatting a thousand reasons costs more
    than deciding them, and most are never read).
    """

    __slots__ = ('omega', 'linear', 'action', '_describe', '_built')

    def __init__(self, omega, linear, action, describe):
        self.omega, self.linear, self.action, self._describe = omega, linear, action, describe
        self._built = [None] * len(action)

    def __len__(self):
        return len(self._built)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        got = self._built[i]
        if got is None:
            got = self._built[i] = self._describe(range(len(self))[i])
        return got

    def __repr__(self):
        return f'Decisions({list(self)!r})'


def _outputs(filters, rb, safe_set, t, tab, k_gov, kind, k_small, solving) -> Decisions:
    """Every robot's command (as lists), its filter's state (overriding, the command
    remembered as sent), and a builder of its FilterOutput."""
    n, use = len(filters), rb.use
    m = len(use)
    row_of = np.full(n, -1, dtype=np.intp)
    row_of[use] = np.arange(m)
    horizon, planned, speed, bang, fresh = rb.horizon, rb.planned, rb.speed, rb.bang, rb.fresh
    failing = rb.failing
    overrides = ~failing & (kind > 0)
    named = np.where(overrides, k_gov, k_small)      # the constraint each robot's output names
    avoid = named >= 0
    # fail safe: avoid from the last valid state, or stop-turn; override: the avoid turn; pass: the
    # planner's command clipped to the robot's bound (0 if silent). Turns are read for the robots
    # that avoid, only.
    avoiding = overrides | (failing & avoid)
    turn = np.zeros(m)
    turn[avoiding] = tab.turns_of(named[avoiding])
    omega_row = np.where(avoiding, bang * turn, np.where(failing, bang, planned))
    stopped = (failing & ~avoid) | (~failing & ~overrides & ~fresh)
    linear_row = np.where(stopped, 0.0, speed)
    code_row = np.where(failing, 2, np.where(overrides, 1, 0))
    # per robot (rows of ``use`` in place; a robot with no recent valid state: stop-turn)
    omega, linear, code, over = rb.all_bang.copy(), np.zeros(n), np.full(n, 2), np.zeros(n, bool)
    omega[use], linear[use], code[use], over[use] = omega_row, linear_row, code_row, overrides
    omega, linear, over = omega.tolist(), linear.tolist(), over.tolist()
    action = _ACTIONS[code].tolist()
    _record_all(filters, omega, over, t, rb.all_keep)
    rows = row_of.tolist()
    problems, configs = rb.problems, rb.all_configs      # configs as at the decision (a parameter change
    common = _set_fields(safe_set)                       # replaces a robot's)
    fresh, kind, named, ages = fresh.tolist(), kind.tolist(), named.tolist(), rb.age

    def describe(i) -> FilterOutput:
        row = rows[i]
        if row < 0:
            return _explain(problems[i], configs[i], omega[i], linear[i], action[i], common, None, -1, 0, False,
                            0.0, 0.0, 0, True)
        return _explain(problems[i], configs[i], omega[i], linear[i], action[i], common, tab, named[row], kind[row],
                        fresh[row], float(horizon[row]), float(ages[row]), int(solving[row]), False)

    return Decisions(omega, linear, action, describe)


def _record_all(filters, omega, over, t, keep) -> None:
    """Each robot's ``overriding = over[i]`` and ``record_sent(omega[i], t)``, in one loop (a
    fleet's tick: the method's call and its configuration lookups cost more than its work);
    ``keep``: each robot's ``config.sent_kept``."""
    ts = float(t)
    for f, w, o, cut in zip(filters, omega, over, (t - keep).tolist()):
        f.overriding = o  # failing safe clears it: re-enter by the law once inputs are back
        sent = f.sent
        sent.append((ts, w))
        while len(sent) > 1 and sent[1][0] <= cut:
            sent.popleft()


def _set_fields(safe_set) -> dict:
    """The FilterOutput fields every robot's decision takes from the safe set in force."""
    set_omega = safe_set.omega_max
    return dict(alpha=float(safe_set.alpha), source=safe_set.source,
                omega_max_set=float(set_omega) if set_omega is not None else math.nan)


def _explain(problem, cfg, w, v, a, set_fields, tab, k, kind, fresh, horizon, age, solving, lost) -> FilterOutput:
    """One robot's FilterOutput: its command (w, v, a) and why, from the table row ``k`` that it
    names (-1: none) and how it acted on it (``kind``, see ``_govern``); ``lost``: no recent
    valid state (stop-turn)."""
    common = dict(set_fields, pose_age=age, lookahead=horizon, clusters_solving=solving)
    if k < 0:
        common.update(obstacle_index=-1, obstacle_xy=(math.nan, math.nan), value=math.inf)
        value = level = math.nan
    else:
        value, level = float(tab.value[k]), float(tab.level[k])
        members, obstacle = int(tab.members[k]), int(tab.obstacle[k])
        common.update(obstacle_index=obstacle, obstacle_xy=tuple(float(c) for c in tab.xy[k]), value=value,
                      alpha=level)
        source = 'cluster-fallback' if tab.fallback[k] else 'cluster'     # a cluster row's
        if tab.sound[k]:
            common['source'] = source
        label = (f'a cluster of {members} obstacles ({source}, nearest {obstacle})' if members > 1
                 else f'obstacle {obstacle}')
    if problem:
        if k >= 0:
            why = f'{problem}; avoiding {label} from the last valid state (V={value:.3g})'
        else:
            why = f'{problem}; {"no recent valid state" if lost else "no obstacle near the last valid state"}' \
                  ': stop-turn'
    elif a == OVERRIDE:
        how = _KINDS[kind]
        if how == 'enter':
            why = f'V={value:.3g} <= alpha={level:.3g} at {label}'
        elif how == 'ahead':
            why = (f'the planner\'s command would reach V={float(tab.value_next[k]):.3g} <= alpha={level:.3g} '
                   f'within {horizon:.3g} s ({label})')
        else:
            why = f'V={value:.3g} <= alpha+margin={level + cfg.clear_margin:.3g}: not clear yet'
    elif not fresh:
        # Nav2 style: no input, zero twist (a Dubins robot drives straight on; the filter still
        # guards it against every detected obstacle)
        why = 'clear; planner silent: zero command'
    else:
        # the robot's bound, whatever the planner asked (angular.z = 1e30 goes out as w_max)
        why = 'clear: no obstacle near' if k < 0 else f'clear: V={value:.3g} > alpha={level:.3g}'
    return FilterOutput(w, v, a, why, **common)


class _ClusterFrames:
    """The clusters (>1 member) of one detections array and their canonical frames, as arrays
    (computed once per detections array and store settings; robots given the same array, as
    the fleet node's batched detections, share them)."""

    def __init__(self, det, store):
        from . import cluster as cl
        st = store.settings
        groups = [g for g in cl.components(det, st.link_distance) if len(g) > 1]
        self.n = len(groups)
        self.keys, self.centres = [], []
        origin, angle, cs, sn = [], [], [], []
        for g in groups:
            key, o, a, c = cl.canonical(det[g], st.key_resolution)
            self.keys.append(key)
            self.centres.append(c)
            origin.append(o)
            angle.append(a)
            cs.append(math.cos(a))      # as cluster.to_frame computes them
            sn.append(math.sin(a))
        size = [len(g) for g in groups]
        # per cluster: origin x, y, angle, cos, sin, members; per member (in its cluster's order): index, x, y
        self.frames = np.column_stack([np.array(origin, dtype=float).reshape(-1, 2), angle, cs, sn, size])
        member = np.concatenate(groups) if groups else np.zeros(0, np.intp)
        self.members = np.column_stack([member, det[member]])


_FRAMES_BY_CONTENT: dict = {}      # (link, resolution, shape, bytes) -> _ClusterFrames
_FRAMES_KEPT = 4096


def _cluster_frames(det, store) -> _ClusterFrames:
    """The cluster frames of a detections array, shared by content: robots sent equal
    detections in separate messages (per-robot topics) compute them once. Bounded: the
    oldest entries go first."""
    st = store.settings
    key = (st.link_distance, st.key_resolution, det.shape, det.tobytes())
    got = _FRAMES_BY_CONTENT.get(key)
    if got is None:
        if len(_FRAMES_BY_CONTENT) >= _FRAMES_KEPT:
            for old in list(_FRAMES_BY_CONTENT)[:_FRAMES_KEPT // 4]:
                del _FRAMES_BY_CONTENT[old]
        got = _FRAMES_BY_CONTENT[key] = _ClusterFrames(det, store)
        got.frames.flags.writeable = got.members.flags.writeable = False
    return got


_NONE_I, _NONE_F, _NONE_B = np.zeros(0, np.intp), np.zeros(0), np.zeros(0, bool)
_NONE_I.flags.writeable = _NONE_F.flags.writeable = _NONE_B.flags.writeable = False
_NO_CLUSTERS = dict(robot=_NONE_I, index=_NONE_I, value=_NONE_F, level=_NONE_F,
                    turns_of=lambda r: np.zeros(len(r)), value_next=_NONE_F,
                    obstacle=_NONE_I, xy=_NONE_F.reshape(0, 2), group=_NONE_I, members=_NONE_I, fallback=_NONE_B,
                    member_pairs=_NONE_I, member_groups=_NONE_I, n_groups=0)


def _cluster_rows(filters, configs, states, planned, horizon, speed, bang, cluster_alpha, dets, start,
                  store_arg) -> dict:
    """The cluster constraints of every robot, as table columns (see ``_Table``).

    A robot with clusters enabled and more than one detection gets, per cluster of its
    detections (obstacles within the link distance, see ``filter.cluster``), one row:

    * the union's value if solved, read at its state now; its turn is the bang
      (+-w_max) with the larger V at the end of its hold (ties left), and the planner's
      command is judged by V where its hold ends and after the better bang held one
      more period from there (the smaller): a pass never leaves the robot where no
      held turn keeps V above the level;
    * else the loiter-circle fallback (``cluster.orbit_value``) if the robot's state now
      has a clear circle (its invariant holds only from such a state; from any other,
      the per-obstacle rows, always in the table, are the best known until the
      union's value is in force).

    Either way the cluster's members' own rows join the cluster's group. All (robot,
    cluster) instances are evaluated together: one arc_flow for the holds, one value
    read per distinct cluster value, one fallback evaluation per store. The rows' turns
    are read on demand (``turns_of``, for the rows robots avoid by).
    """
    m = len(filters)
    solving = np.zeros(m, dtype=np.intp)
    entries = {}      # (frames, store) -> rows of the robots that use them, in order
    shared = {}
    stores = {}       # id(config) -> its default store (robots of a fleet share one config)
    joins = {}        # (id(detections), id(config)) -> the entry its robots join (None: no clusters)
    # runs of robots with the same detections array and configuration (a batched fleet: one run)
    # join their entry at once (found in C: no numpy on a lone robot's path)
    end = 0
    for _, run in itertools.groupby(zip(map(id, dets), map(id, configs))):
        row, end = end, end + len(list(run))
        f, det, cfg = filters[row], dets[row], configs[row]
        key = (id(det), id(cfg))
        if key in joins:            # robots given one detections array (the batched fleet)
            entry = joins[key]
            if entry is not None:
                entry[2].extend(range(row, end))
            continue
        joins[key] = None
        if not cfg.clusters or len(det) <= 1:
            continue
        store = store_arg
        if store is None:
            store = stores.get(id(cfg))
            if store is None:
                store = stores[id(cfg)] = default_cluster_store(cfg)
        cache = f.__dict__.get('_cluster_cache')
        if cache is None or cache[0] is not det:
            got = shared.get((id(det), id(store)))
            if got is None:
                got = shared[(id(det), id(store))] = _cluster_frames(det, store)
            cache = f._cluster_cache = (det, got)
        fr = cache[1]
        if fr.n:
            entry = entries.get((id(fr), id(store)))
            if entry is None:
                entry = entries[(id(fr), id(store))] = (fr, store, [])
            entry[2].extend(range(row, end))
            joins[key] = entry
    if not entries:
        return dict(_NO_CLUSTERS, solving=solving)
    entries = list(entries.values())

    # the union's value of each cluster geometry, looked up (and requested) in the order the
    # robots meet them: the first (robot, cluster) of a geometry sees the store before its
    # request, every later one after it (as robot-by-robot lookups would: an inline store
    # solves at the request)
    firsts = sorted((rows[0], gi, e) for e, (fr, _, rows) in enumerate(entries) for gi in range(fr.n))
    known = {}        # (store, key) -> [value before, busy before, value after, busy after, (e, gi) first]
    for _, gi, e in firsts:
        fr, store, _ = entries[e]
        sk = (id(store), fr.keys[gi])
        if sk in known:
            continue
        before = store.get(fr.keys[gi])
        if before is None:
            store.request(fr.keys[gi], fr.centres[gi])
            busy = store.solving(fr.keys[gi])
            after = store.get(fr.keys[gi])
            known[sk] = [before, busy, after, store.solving(fr.keys[gi]) if after is None else False, (e, gi)]
        else:
            known[sk] = [before, False, before, False, (e, gi)]
    values = []       # distinct union values in force; instances refer to them by index
    index_of = {}

    def value_index(v):
        if v is None:
            return -1
        j = index_of.get(id(v))
        if j is None:
            j = index_of[id(v)] = len(values)
            values.append(v)
        return j

    # the frames of every entry in one table (frame f: an entry's cluster), and per frame the
    # union value in force (index into ``values``, -1: none) before and after its request
    n_frames = np.array([fr.n for fr, _, _ in entries], dtype=np.intp)
    n_rows = np.array([len(rows) for _, _, rows in entries], dtype=np.intp)
    frame0 = np.cumsum(n_frames) - n_frames
    f_val, f_busy, first_inst = [], [], []
    inst0 = np.cumsum(n_rows * n_frames) - n_rows * n_frames
    for e, (fr, store, _) in enumerate(entries):
        for gi, key in enumerate(fr.keys):
            b, bb, a, ab, first = known[(id(store), key)]
            f_val.append(value_index(a))
            f_busy.append(ab)
            if first == (e, gi):      # the first robot of this entry is the first to meet the key
                first_inst.append((int(inst0[e]) + gi, value_index(b), bb))
    f_val = np.array(f_val, dtype=np.intp)
    f_busy = np.array(f_busy, dtype=bool)
    frames = np.concatenate([fr.frames for fr, _, _ in entries])
    f_origin, f_angle, f_cos, f_sin = frames[:, 0:2], frames[:, 2], frames[:, 3], frames[:, 4]
    f_size = frames[:, 5].astype(np.intp)
    stores, store_index = [], {}
    for _, store, _ in entries:
        if id(store) not in store_index:
            store_index[id(store)] = len(stores)
            stores.append(store)
    f_store = np.repeat(np.array([store_index[id(st)] for _, st, _ in entries], dtype=np.intp), n_frames)
    member_table = np.concatenate([fr.members for fr, _, _ in entries])
    m_member, m_xy = member_table[:, 0].astype(np.intp), member_table[:, 1:3]
    f_mstart = np.cumsum(f_size) - f_size

    # one instance per (robot, cluster): entry by entry, robot-major within an entry
    n_inst = int(np.sum(n_rows * n_frames))
    inst_entry = np.repeat(np.arange(len(entries)), n_rows * n_frames)
    q = np.arange(n_inst) - inst0[inst_entry]
    g_e = n_frames[inst_entry]
    all_rows = np.fromiter(itertools.chain.from_iterable(rows for _, _, rows in entries), dtype=np.intp,
                           count=int(n_rows.sum()))
    inst_row = all_rows[(np.cumsum(n_rows) - n_rows)[inst_entry] + q // g_e]
    inst_gi = q % g_e
    frame = frame0[inst_entry] + inst_gi
    val, busy = f_val[frame], f_busy[frame]
    for k, b, bb in first_inst:
        val[k], busy[k] = b, bb
    # an instance whose union value is in force but whose grid no hold can reach reads V = +inf at
    # all six states below: its row never acts nor names the smallest V, so it is left out (most of
    # a wide fleet's instances; requests and solving counts come from the instances not in force)
    far = _beyond_grid(values, val, states[inst_row, :2] - f_origin[frame],
                       2.0 * speed[inst_row] * horizon[inst_row] + 1.0)
    if far.any():
        near = ~far
        inst_row, inst_gi, frame, val, busy = inst_row[near], inst_gi[near], frame[near], val[near], busy[near]
        n_inst = len(inst_row)
    size = f_size[frame]
    member_inst = np.repeat(np.arange(n_inst), size)
    mg = f_mstart[frame][member_inst] + (np.arange(int(size.sum())) - np.repeat(np.cumsum(size) - size, size))
    members = m_member[mg]
    c = {'gi': inst_gi, 'origin': f_origin[frame], 'angle': f_angle[frame], 'cos': f_cos[frame],
         'sin': f_sin[frame], 'store': f_store[frame], 'busy': busy, 'val': val}
    m_ = {'xy': m_xy[mg]}
    np.add.at(solving, inst_row, c['busy'].astype(np.intp))
    member_pairs = start[inst_row][member_inst] + members     # the members' own rows join the cluster

    # holds from the state now: the planner's command, then both bangs from its end (the bangs
    # from the state now give the avoid turn, read only for the rows a robot names: turns_of)
    rows = np.flatnonzero(np.bincount(inst_row, minlength=m))     # np.unique's, without a sort
    s0 = states[rows]
    ahead_r = arc_flow(s0, speed[rows], planned[rows], horizon[rows])
    w = bang[rows]
    pts = _bang_ends(ahead_r, speed[rows], w, horizon[rows])
    where = np.searchsorted(rows, inst_row)
    nr = len(rows)
    state, ahead = s0[where], ahead_r[where]

    # the member nearest to the robot (the first on ties) names the cluster: an instance's members
    # are one run of member_inst, in their cluster's order (distances are finite: states are)
    d = np.hypot(*(m_['xy'] - states[inst_row[member_inst], :2]).T)
    nearest_m = _first_min_of_runs(d, member_inst, np.cumsum(size) - size)
    nearest, nearest_xy = members[nearest_m], m_['xy'][nearest_m]

    val = c['val']
    ok = val >= 0

    def union_values(idx, s):
        """V of the union values in force at instances ``idx``, at their states ``s`` (k, len(idx),
        3) in the map frame (+inf off the grid), and each instance's tie tolerance."""
        v = np.full(s.shape[:2], np.inf)
        tie = np.zeros(len(idx))
        origin, angle, cs, sn = c['origin'][idx], c['angle'][idx], c['cos'][idx], c['sin'][idx]
        dx, dy = s[..., 0] - origin[:, 0], s[..., 1] - origin[:, 1]      # cluster.to_frame
        in_frame = np.stack([cs * dx + sn * dy, -sn * dx + cs * dy, s[..., 2] - angle], axis=-1)
        for j, cv in enumerate(values):
            sel = np.flatnonzero(val[idx] == j)
            if len(sel):
                v[:, sel] = cv.value(in_frame[:, sel].reshape(-1, 3)).reshape(len(s), len(sel))
                tie[sel] = cv.tie
        return v, tie

    v4 = np.full((4, n_inst), np.inf)
    if np.any(ok):
        idx = np.flatnonzero(ok)
        w_ = where[idx]
        v4[:, idx] = union_values(idx, np.stack([state[idx], pts[w_], pts[nr + w_], ahead[idx]]))[0]
    u_next = _py_min(v4[3], _py_max(v4[1], v4[2]))

    # the loiter fallback where no union value is in force
    f_value = np.full((2, n_inst), -np.inf)
    f_turn = np.zeros(n_inst)
    for k, store in enumerate(stores):
        sel = ~ok & (c['store'] == k)
        if np.any(sel):
            st = store.settings
            v, u = _orbit_values(np.stack([state[sel], ahead[sel]]), m_['xy'], member_inst, sel,
                                 st.radius + st.margin, st.turning_radius)
            f_value[:, sel] = v
            f_turn[sel] = u[0]
    keep = ok | (f_value[0] > 0.0)
    kept = np.flatnonzero(keep)

    def turns_of(r) -> np.ndarray:
        """The unit avoid turn of the returned rows ``r``: with a union value in force, the bang
        (+-w_max) whose hold from the state now ends at the larger V (ties left, within the
        value's tie tolerance); with the fallback, its loiter circle's turn."""
        i = kept[np.asarray(r, dtype=np.intp)]
        out = f_turn[i]
        u = i[ok[i]]
        if len(u):
            robot = inst_row[u]
            ends = _bang_ends(state[u], speed[robot], bang[robot], horizon[robot]).reshape(2, len(u), 3)
            (left, right), tie = union_values(u, ends)
            out[ok[i]] = _better_bang(left, right, tie)
        return out

    level = cluster_alpha[inst_row]
    return dict(robot=inst_row[keep], index=c['gi'][keep], value=np.where(ok, v4[0], f_value[0])[keep],
                level=np.where(ok, level, 0.0)[keep], turns_of=turns_of,
                value_next=np.where(ok, u_next, f_value[1])[keep], obstacle=nearest[keep],
                xy=nearest_xy[keep], group=np.arange(n_inst)[keep], members=size[keep], fallback=~ok[keep],
                member_pairs=member_pairs, member_groups=member_inst, n_groups=n_inst, solving=solving)


def _beyond_grid(values, val, offset, reach) -> np.ndarray:
    """Per instance: its union value is in force (``val`` indexes ``values``) and its robot,
    ``offset`` (k, 2) from the cluster frame's origin, is farther than ``reach`` beyond every
    corner of that value's grid (frames only rotate about the origin, so a distance bound needs
    no rotation): every state within ``reach`` of the robot is off the grid."""
    if not values:
        return np.zeros(len(val), bool)
    corner = np.array([max(math.hypot(x, y) for x in (g.lo[0], g.hi[0]) for y in (g.lo[1], g.hi[1]))
                       for g in (cv.vf.grid for cv in values)] + [math.inf])
    return np.hypot(offset[:, 0], offset[:, 1]) > corner[val] + reach    # val -1 -> inf: never far


def _orbit_values(states, member_xy, member_inst, sel, radius, turning_radius):
    """``cluster.orbit_value`` for many (state, cluster) pairs at once.

    ``states`` (2, k, 3): the state now and after the planner's hold of each selected
    cluster instance; its discs are the rows of ``member_xy`` whose ``member_inst`` is
    selected by ``sel``. Returns (clearance (2, k), turn (2, k)).
    """
    inst = np.flatnonzero(sel)
    col = np.full(len(sel), -1, np.intp)
    col[inst] = np.arange(len(inst))
    take = sel[member_inst]
    c = member_xy[take]
    seg = col[member_inst[take]]                     # members are grouped by instance, in order
    starts = np.flatnonzero(np.concatenate(([True], seg[1:] != seg[:-1])))
    out = []
    for side in (1.0, -1.0):
        mx = states[..., 0] - side * turning_radius * np.sin(states[..., 2])
        my = states[..., 1] + side * turning_radius * np.cos(states[..., 2])
        dist = np.hypot(mx[:, seg] - c[:, 0], my[:, seg] - c[:, 1])
        out.append(np.minimum.reduceat(np.abs(dist - turning_radius) - radius, starts, axis=1))
    left, right = out
    return np.maximum(left, right), np.where(left >= right, 1.0, -1.0)


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


def _pair_values(vf: ValueFunction, rel, omega, horizon, speed, bang):
    """V, the avoid turn and the lookahead value of every pair, for commands held over H.

    First the law at the pair's relative state (``law.evaluate_pairs``): V (+inf off the
    grid) and the unit turn sign(dV/dtheta) (ties left; 0 off the grid).

    Per pair: the planner's (clipped) command ``omega``, the hold H (``horizon``, the
    robot's lookahead, >= its control period), the robot's speed and turn bound
    ``bang``. A command holds for H, so:

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
    ``_pair_reads`` reads V and V next of every pair in one call, ``_pair_turns`` the turns
    (the fleet path reads turns only for the rows its robots name).
    Returns (V, unit turn, V after the planner's hold and the best bang's).
    """
    value, value_next = _pair_reads(vf, rel, omega, horizon, speed, bang)
    return value, _pair_turns(vf, rel, value, horizon, speed, bang), value_next


def _pair_reads(vf: ValueFunction, rel, omega, horizon, speed, bang, level=math.inf):
    """(V, V next) of ``_pair_values``: V at the pair's state and where the planner's hold and
    both bangs after it end, in one read; V next only where it can be at or below ``level``
    (the pairs' alpha; +inf: everywhere), else a lower bound above it (so the row never looks
    ahead: the same decisions).

    The holds end within 2 speed H of the pair's state, so no read there can be below
    ``vf.radial_minimum`` over that band of radii: a pair whose bound is above the level
    needs no hold read (most pairs on the grid, away from their obstacle)."""
    n = len(rel)
    value, value_next = np.full(n, np.inf), np.full(n, np.inf)
    if n == 0:
        return value, value_next
    holds = bool(np.any(horizon > 0))
    # pairs too far from the grid for any hold to reach it: every V below is +inf, so V and V_next
    # stay +inf (two holds move the robot at most 2 speed H; +1 m for round-off); without holds,
    # the pairs on the grid
    g = vf.grid
    reach = 2.0 * speed * horizon + 1.0 if holds else 0.0
    near = np.flatnonzero((rel[:, 0] >= g.lo[0] - reach) & (rel[:, 0] <= g.hi[0] + reach)
                          & (rel[:, 1] >= g.lo[1] - reach) & (rel[:, 1] <= g.hi[1] + reach))
    if len(near) == 0:
        return value, value_next
    rel = rel[near]
    k = len(rel)
    if not holds:
        value[near] = vf.value(rel, outside=np.inf)
        return value, value_next
    horizon, speed = horizon[near], speed[near]
    if level < math.inf:
        radius, travel = np.hypot(rel[:, 0], rel[:, 1]), 2.0 * speed * horizon
        bound = vf.radial_minimum(radius - travel, radius + travel)
        held = np.flatnonzero((horizon > 0) & ~(bound > level + 1e-6))     # read unless above the level
    else:           # every hold read (a lone robot's many pairs: no bound to compute)
        bound = np.full(k, np.inf)
        held = np.flatnonzero(horizon > 0)
    h = len(held)
    ahead = arc_flow(rel[held], speed[held], omega[near][held], horizon[held])
    v = vf.value(np.concatenate([rel, _bang_ends(ahead, speed[held], bang[near][held], horizon[held]), ahead]),
                 outside=np.inf)
    value[near] = v[:k]
    later = np.where(horizon > 0, bound, np.inf)
    later[held] = np.minimum(v[k + 2 * h:], np.maximum(v[k:k + h], v[k + h:k + 2 * h]))
    value_next[near] = later
    return value, value_next


def _pair_turns(vf: ValueFunction, rel, value, horizon, speed, bang):
    """The unit avoid turns of ``_pair_values`` for pairs at ``rel`` with V ``value``: the
    law's sign(dV/dtheta) where V is finite (on the grid), else 0; with a hold, the bang whose
    hold ends at the larger V (ties left) wherever either end is on the grid. (A pair
    ``_pair_reads`` left out as beyond any hold's reach has both ends off the grid: 0.)"""
    turn = np.zeros(len(rel))
    inside = np.isfinite(value)
    if np.any(inside):
        turn[inside] = avoid_turn(vf, rel[inside])
    held = np.flatnonzero(horizon > 0)
    if len(held):
        ends = _bang_ends(rel[held], speed[held], bang[held], horizon[held])
        left, right = vf.value(ends, outside=np.inf).reshape(2, len(held))
        use = np.isfinite(left) | np.isfinite(right)
        turn[held] = np.where(use, _better_bang(left, right, tie_tolerance(vf)), turn[held])
    return turn


FEW_PAIRS = 3     # a robot decided alone reads V in Python floats up to this many pairs near the grid


def _arc(x, y, th, speed, omega, dt):
    """``arc_flow`` of one state, in Python floats (the same operations, the same bits)."""
    th1 = th + omega * dt
    if abs(omega * dt) > 1e-9:
        ax = (math.sin(th1) - math.sin(th)) / omega
        ay = (math.cos(th) - math.cos(th1)) / omega
    else:
        ax, ay = math.cos(th) * dt, math.sin(th) * dt
    return x + speed * ax, y + speed * ay, _wrap(th1)


def _wrap(theta):
    """``wrap_angle`` of one angle, in Python floats (the same operations, the same bits)."""
    return (theta + math.pi) % TWO_PI - math.pi


def _robot_pair_values(vf: ValueFunction, x, y, th, centres, planned, horizon, speed, bang, few):
    """``_pair_values`` for one robot's pairs (its state x, y, th; ``centres`` a list of
    (cx, cy); its command, hold, speed and bound), as lists; None if more than ``few``
    pairs are near the grid (then numpy's evaluation is the cheaper).

    V is read state by state in Python floats (``ValueFunction.value_at``): a robot's own
    filter has one or two obstacles near, and numpy's cost per call (some 150 calls) is
    most of its decision. The same operations in the same order, so the same values bit
    for bit (test_filter_vectorised: each robot decided alone decides as in a fleet).
    """
    g = vf.grid
    inf = math.inf
    reach = 2.0 * speed * horizon + 1.0 if horizon > 0 else 0.0
    rel = [(x - cx, y - cy) for cx, cy in centres]
    near = [j for j, (rx, ry) in enumerate(rel) if g.lo[0] - reach <= rx <= g.hi[0] + reach
            and g.lo[1] - reach <= ry <= g.hi[1] + reach]
    if len(near) > few:
        return None
    n = len(rel)
    value, turn, value_next = [inf] * n, [0.0] * n, [inf] * n
    if not near:
        return value, turn, value_next
    tol = tie_tolerance(vf)
    for j in near:
        rx, ry = rel[j]
        v0 = value[j] = vf.value_at(rx, ry, th, outside=inf)
        if v0 != inf:       # on the grid: the law's turn
            turn[j] = avoid_turn_at(vf, rx, ry, th)
        if horizon > 0:     # (without a hold: V_next = +inf and the law's turn)
            left = vf.value_at(*_arc(rx, ry, th, speed, bang, horizon), outside=inf)
            right = vf.value_at(*_arc(rx, ry, th, speed, -bang, horizon), outside=inf)
            ax, ay, ath = _arc(rx, ry, th, speed, planned, horizon)
            end_left = vf.value_at(*_arc(ax, ay, ath, speed, bang, horizon), outside=inf)
            end_right = vf.value_at(*_arc(ax, ay, ath, speed, -bang, horizon), outside=inf)
            v_ahead = vf.value_at(ax, ay, ath, outside=inf)
            better = end_left if end_left > end_right else end_right       # np.maximum
            value_next[j] = v_ahead if v_ahead < better else better          # np.minimum
            if left != inf or right != inf:
                turn[j] = 1.0 if left >= right - tol else -1.0
    return value, turn, value_next
