"""What a filter knows of its robot: the newest pose, detections (discs of the configured
radius or their own, ``filter.constraints.discs``) and planner command (turn rate and linear.x; each
with when it arrived and whether a newer one was rejected); beside them, written by the
decision alone (``filter.sent.record``), whether it is overriding and the commands it sent
with the speed the robot drives under each (to propagate an old pose to now,
``filter.propagation``).

``RobotFilter`` is one robot's input state; ``update_poses``, ``update_commands`` and
``update_detections_all`` feed many robots at once (the fleet node's batched topics: one
validation for all rows). ``RobotFilter.step`` decides (``filter.decide.step_many``).

The control period (how long a command holds) is measured, when not configured, as the
larger of the median intervals between pose stamps and between planner commands over the
last PERIOD_SAMPLES (``_Intervals``: immutable windows, shared by robots fed by one message).
"""
from __future__ import annotations

from bisect import bisect_left, insort
from collections import deque
from dataclasses import dataclass, field
from itertools import repeat
import math
from operator import attrgetter, is_

import numpy as np

from .decide import step_many
from .constraints.discs import checked_discs
from .commands import SPEED_TOLERANCE, command_excess
from .constraints.nearby import drop_note, message_reach, within_limit
from .types import FilterConfig, FilterOutput, SafeSet

PERIOD_SAMPLES = 16    # intervals in the median that measures the control period
NO_DISCS = np.zeros((0, 2))
NO_DISCS.flags.writeable = False
_COMMAND, _LINEAR, _CONFIG = attrgetter('command'), attrgetter('linear'), attrgetter('config')


@dataclass
class _Input:
    """The newest valid sample of one input, and whether a newer one was rejected."""

    value: object = None
    t: float = -math.inf          # arrival time of the newest valid sample
    stamp: float = -math.inf      # the time it describes (its header stamp; arrival if unstamped)
    rejected: str = ''            # reason the newest sample was rejected ('' if it was valid)
    rejected_t: float = -math.inf
    note: str = ''                # what was made of the newest sample (a command clipped, detections dropped)
    kept: object = None           # detections: the message's indices of those kept (None: all)
    dropped: int = 0              # detections: how many of the message were dropped
    dropped_safely: bool = True   # detections: all of them beyond any robot's reach (nearby.drop_note)
    radii: object = None          # detections: each one's radius (M,), None: all the configured radius
    linear: object = None         # command: the planner's linear.x (None: not given, taken as the speed)
    solve_clusters: bool = True   # detections: their clusters' union values may be solved (cluster_rows)
    refused: str = ''             # a map view: why the newest messages were refused (they leave the view
    refusals: int = 0             # as it was, to go stale) and how many since the last valid one
    # detections: what decisions derived from this array and keep for the next while it is the same
    # (never an input; filter.derived: written by the recorder; ``RobotFilter.derived``)
    derived: dict = field(default_factory=dict)

    def accept(self, value, t, stamp=None):
        self.value, self.t, self.rejected, self.note = value, float(t), '', ''
        self.refused, self.refusals = '', 0
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
        self.sent = deque()    # (decision time, turn rate, speed driven) of the commands sent, oldest first
        self.pose_intervals = _NO_INTERVALS      # windows of the last intervals (immutable: robots
        self.command_intervals = _NO_INTERVALS   # fed by one message share them)
        self.view = None       # a robot judged by its local map: its MapView (filter.constraints.map_rows), else None

    @property
    def derived(self) -> dict:
        """What decisions derived from this robot's detections array and keep for the next while that
        array is the same (never an input; ``filter.derived``: written by the recorder), kept with
        the detections (``detections.derived``: a decision reads it from their record)."""
        return self.detections.derived

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
            self.pose_intervals = self.pose_intervals.then(self.pose.stamp - previous)

    def reject_pose(self, reason, t) -> None:
        """Record a pose message the caller could not convert (wrong frame, bad quaternion)."""
        self.pose.reject(reason, t)

    def update_detections(self, rows, t, safe_set=None, solve_clusters=True) -> None:
        """Obstacles in map, N >= 0: (N, 2) centres, each of the configured ``radius``, or
        (N, 3) rows [x, y, r] of their own radius r (finite, > 0; ``filter.constraints.discs``: a disc
        larger than ``radius`` is judged as a ring of discs of that radius); raises ValueError
        (and records it) if malformed.

        More than ``max_detections``: the nearest to the robot's pose are kept, the rest
        dropped, and ``detections.note`` says whether that is safe (they are farther than
        any can constrain the robot while judged, by ``safe_set``'s grid; unknown without).

        ``solve_clusters``: False for detections that change every message (discs made from
        a laser scan or a point cloud): their clusters are judged by the loiter fallback and
        the per-disc rows, never by a union value solved in the background (a new geometry per
        message would queue a solve per message and none would be in force in time).
        """
        try:
            c, radii, origin = checked_discs(rows, self.config.radius)
        except ValueError as exc:
            self.detections.reject(str(exc), t)
            raise
        _store_detections([self], c, radii, origin, t, safe_set, self.config, solve_clusters)

    def reject_detections(self, reason, t) -> None:
        self.detections.reject(reason, t)

    def update_view(self, view, t) -> None:
        """A valid view of the robot's local map at ``t`` (``filter.constraints.map_rows.MapView``: the map a
        sensor message has just updated, the robot's clearance and the map's values): the robot
        is judged by the map's value (one row for all it holds) and its speed cut on the map's
        occupied cells, not by detected discs; the view is fresh until ``detections_timeout``."""
        self.view = view
        inp = self.detections
        inp.accept(NO_DISCS, t)
        inp.kept, inp.dropped, inp.dropped_safely, inp.radii, inp.solve_clusters = None, 0, True, None, False

    def refuse_view(self, reason, t) -> None:
        """A sensor message refused (its geometry invalid, ...): the view stays as it was and goes
        stale at ``detections_timeout`` (the reason then names this cause)."""
        inp = self.detections
        inp.refused, inp.refusals, inp.rejected_t = str(reason), inp.refusals + 1, float(t)

    def update_command(self, omega, t, linear=None) -> None:
        """The planner's turn rate and ``linear.x`` (None: not given, taken as ``speed``); a
        command not finite is rejected (ValueError): a robot that can stop then fails safe (a zero
        twist) until a valid command comes, a constant-speed robot keeps the previous one (its
        ``cmd_timeout`` still applies). ``command.note`` says what was
        beyond the robot's limits (``commands.command_excess``): the decision clips the turn rate to
        +-omega_max and the speed to [0, speed] (``commands.planned_speed``)."""
        w = float(omega)
        v = None if linear is None else float(linear)
        if not math.isfinite(w) or (v is not None and not math.isfinite(v)):
            reason = f'not finite (angular.z={w:g}, linear.x={"not given" if v is None else format(v, "g")})'
            self.refuse_command(reason, t)
            raise ValueError(f'planner command {reason}')
        previous = self.command.t if self.command.value is not None else None
        self.command.accept(w, t)
        self.command.linear = v
        excess = command_excess(w, linear, self.config)
        if excess:
            self.command.note = excess
        if previous is not None and t > previous:
            self.command_intervals = self.command_intervals.then(t - previous)

    def refuse_command(self, reason, t) -> None:
        """A planner command refused (``reason``): a robot that can stop stops on it until a valid
        command comes (``gather.problem``); a constant-speed robot keeps the previous command until it
        is cmd_timeout old. ``command.note`` says which."""
        self.command.reject(reason, t)
        self.command.note = (f'{reason}: rejected, the previous command kept until it is cmd_timeout '
                             f'({self.config.cmd_timeout:g} s) old' if self.config.constant_speed
                             else f'{reason}: rejected, the robot stops until a valid command comes')

    def control_period(self) -> float:
        """The hold time of a command: configured, else measured (0 until measurable).

        Measured as the larger of the median intervals between pose stamps (the
        robot's step) and between planner commands (when new commands come).
        """
        if self.config.control_period > 0.0:
            return self.config.control_period
        poses, commands = self.pose_intervals.middle, self.command_intervals.middle   # None: empty
        if poses is None:
            return 0.0 if commands is None else commands
        return poses if commands is None else max(poses, commands)

    def lookahead(self) -> float:
        cfg = self.config
        return max(cfg.lookahead, self.control_period()) if cfg.compensate_delay else cfg.lookahead

    # -- decision ------------------------------------------------------------------------
    def step(self, safe_set: SafeSet, t, clusters=None) -> FilterOutput:
        """``decide.step_many`` of this one robot: its decision at ``t``."""
        return step_many([self], safe_set, t, clusters)[0]


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


def update_commands(filters, omegas, t, skip=None, linears=None) -> list:
    """``filters[i].update_command(omegas[i], t, linears[i])`` for every robot whose ``skip[i]``
    is falsy (the fleet node's batched commands; ``linears``: their linear.x, None: not
    given, taken as the speed); the rows beyond their robot's limits (``command.note`` says
    how). Raises ValueError before updating anyone if a command to take is not finite."""
    n = len(filters)
    w = np.asarray(omegas, dtype=float).reshape(n)
    take = _taken(filters, skip)
    lin = None if linears is None else np.asarray(linears, dtype=float).reshape(n)
    if not np.all(np.isfinite(w[take])) or (lin is not None and not np.all(np.isfinite(lin[take]))):
        raise ValueError('planner commands are not finite')
    t = float(t)
    _accept_rows(filters, 'command', w.tolist(), take, t, t, None if lin is None else lin.tolist())
    # the rows beyond their robot's limits get a note (the few: the rest were cleared above)
    configs = list(map(_CONFIG, filters))
    if n and all(map(is_, configs, repeat(configs[0]))):     # a fleet of one configuration: its limits
        bound, speed, constant = configs[0].omega_max, configs[0].speed, configs[0].constant_speed
    else:
        bound = np.fromiter((c.omega_max for c in configs), dtype=float, count=n)
        speed = np.fromiter((c.speed for c in configs), dtype=float, count=n)
        constant = np.fromiter((c.constant_speed for c in configs), dtype=bool, count=n)
    off = (w > bound) | (w < -bound)
    if lin is not None:
        off |= np.where(constant, ~(np.abs(lin - speed) <= SPEED_TOLERANCE * np.maximum(1.0, speed)),
                        (lin > speed) | (lin < 0.0))
    beyond = np.flatnonzero(off & take).tolist()
    for i in beyond:
        f = filters[i]
        f.command.note = command_excess(w[i], None if linears is None else float(linears[i]), f.config)
    return beyond


def _taken(filters, skip) -> np.ndarray:
    return np.ones(len(filters), bool) if skip is None else ~np.array([bool(b) for b in skip], dtype=bool)


def _accept_rows(filters, name, rows, take, t, stamp, linears=None) -> None:
    """Each taken row becomes its filter's newest ``name`` input (pose or command, with its
    linear.x ``linears[i]`` if given), arrived at ``t`` and describing ``stamp``; the interval
    since the previous stamp feeds the measured control period (as ``update_pose`` /
    ``update_command`` do). Robots with the same window and the same previous stamp get the
    same next window, made once."""
    windows = 'pose_intervals' if name == 'pose' else 'command_intervals'
    made = {}      # (window before, previous stamp) -> window after (kept alive here: ids stay unique)
    pose = name == 'pose'
    # each command's linear.x (None: not given; left alone where it is None already)
    set_linear = not pose and (linears is not None
                               or not all(map(is_, map(_LINEAR, map(_COMMAND, filters)), repeat(None))))
    for f, row, ok, v in zip(filters, rows, take.tolist(), repeat(None) if linears is None else linears):
        if not ok:
            continue
        inp = f.pose if pose else f.command
        if set_linear:
            inp.linear = v
        previous = inp.stamp if inp.value is not None else None
        inp.value, inp.t, inp.rejected, inp.stamp, inp.note = row, t, '', stamp, ''
        if previous is not None and stamp > previous:
            before = getattr(f, windows)
            after = made.get((before, previous))
            if after is None:
                after = made[(before, previous)] = before.then(stamp - previous)
            setattr(f, windows, after)


def update_detections_all(filters, rows, t, safe_set=None, solve_clusters=True) -> None:
    """``update_detections(rows, t, safe_set, solve_clusters)`` for every robot, with one array
    shared by all (the fleet node's batched detections; robots that share it share its cluster
    frames and spatial index; radii against the first robot's ``radius``). Beyond
    ``max_detections`` (the first robot's) the nearest to any robot's pose are kept."""
    cfg = filters[0].config if filters else None
    c, radii, origin = checked_discs(rows, cfg.radius if cfg is not None else math.inf)    # (no robot: checked only)
    _store_detections(filters, c, radii, origin, float(t), safe_set, cfg, solve_clusters)


def _store_detections(filters, c, radii, origin, t, safe_set, cfg, solve_clusters) -> None:
    """The checked discs (``discs.checked_discs``) become every filter's detections, at most
    ``max_detections`` of them (``_limited``); ``kept``: the message's rows of those kept
    (None: row i is row i)."""
    c, kept, dropped, (note, safe) = _limited(c, filters, t, safe_set, cfg)
    if kept is not None and radii is not None:
        radii = radii[kept]
    if origin is not None:
        kept = origin if kept is None else origin[kept]
    solve, t = bool(solve_clusters), float(t)
    for f in filters:       # _Input.accept, and what was made of the message
        inp = f.detections
        (inp.value, inp.t, inp.stamp, inp.rejected, inp.note, inp.kept, inp.dropped, inp.dropped_safely, inp.radii,
         inp.solve_clusters) = c, t, t, '', note, kept, dropped, safe, radii, solve


def _limited(c, robots, t, safe_set, cfg):
    """(the centres kept, their indices in the message or None if all, how many were dropped,
    why: ``nearby.drop_note``): at most ``cfg.max_detections``, the nearest to the poses of
    the ``robots`` (none with a pose: the first)."""
    limit = cfg.max_detections if cfg is not None else len(c)
    if len(c) <= limit:
        return c, None, 0, ('', True)
    posed = [f for f in robots if f.pose.value is not None]
    kept, dropped_from = within_limit(c, [f.pose.value[:2] for f in posed], limit)
    reach = None
    if safe_set is not None and posed:
        # how far the robots' poses may be from where a detection can still constrain them
        reach = message_reach(cfg, safe_set.vf.grid, max(f.lookahead() for f in posed),
                              max(f.pose.age(t) for f in posed))
    return c[kept], kept, len(c) - limit, drop_note(len(c), limit, dropped_from, reach, len(posed))


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
