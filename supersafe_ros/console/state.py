"""What the console shows, without ROS: robots, obstacles, the world's counts and crashes.

ROS callbacks write into a ``ConsoleState`` from the executor's thread; the web
server reads ``snapshot()`` from its asyncio thread. Every access holds one lock,
and writes are O(1), so neither side waits on the other for long.

The robots' detection state is deliberately absent: as in the paper, the person
must infer from the motion whether a robot has seen an obstacle.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import json
import math
import threading

STATS = ('score', 'trips', 'crashes', 'interventions')
MAX_MESSAGE_CHARS = 4096
RECENT_EVENTS = 20       # crashes kept for the page (it draws the recent ones)


@dataclass(frozen=True)
class Field:
    """The world's geometry (world_node's half_width, half_height, goal_x)."""

    half_width: float = 20.0
    half_height: float = 12.0
    goal_x: float = 16.0

    def as_dict(self) -> dict:
        return {'half_width': self.half_width, 'half_height': self.half_height,
                'goal_x': self.goal_x}


@dataclass(frozen=True)
class InterventionRequest:
    """What to publish on /interventions: the concerned robot's state relative to the
    obstacle (obstacle at the origin, axes as map), at the stamp of that robot's pose."""

    obstacle_id: int
    robot: str | None
    rel_state: tuple
    stamp_ns: int


class ClientMessageError(ValueError):
    """A WebSocket message from a page that the console cannot act on."""


def _ref(msg: dict):
    """The message's ``ref``, echoed in the reply: absent, an integer or a string (Python's
    JSON reader takes NaN and Infinity, which no JSON reader on the page could read back)."""
    ref = msg.get('ref')
    if ref is not None and (isinstance(ref, bool) or not isinstance(ref, (int, str))):
        raise ClientMessageError('"ref" must be an integer or a string')
    return ref


def parse_client_message(text, extra_types=()) -> dict:
    """Validate one message from the page; returns {'type': ..., ...} or raises
    ClientMessageError with the reason (sent back to the page). A message whose type is
    in ``extra_types`` is returned as it came (its handler checks the rest)."""
    if not isinstance(text, str):
        raise ClientMessageError('messages must be JSON text')
    if len(text) > MAX_MESSAGE_CHARS:
        raise ClientMessageError('message too long')
    try:
        msg = json.loads(text)
    except ValueError as exc:
        raise ClientMessageError(f'not JSON: {exc}') from None
    except RecursionError:     # '[' * 4000: the decoder recurses once per level
        raise ClientMessageError('not JSON this console accepts: nested too deeply') from None
    if not isinstance(msg, dict) or not isinstance(msg.get('type'), str):
        raise ClientMessageError('a message is a JSON object with a string "type"')
    kind = msg['type']
    if kind in extra_types:
        return msg
    if kind == 'intervene':
        oid = msg.get('obstacle')
        if isinstance(oid, bool) or not isinstance(oid, int) or oid < 0:
            raise ClientMessageError('"intervene" needs "obstacle": a non-negative integer id')
        return {'type': 'intervene', 'obstacle': oid, 'ref': _ref(msg)}
    if kind == 'ping':
        return {'type': 'ping', 'ref': _ref(msg)}
    if kind == 'watch':
        return {'type': 'watch'}
    known = ', '.join(('intervene', 'ping', 'watch') + tuple(extra_types))
    raise ClientMessageError(f'unknown message type {kind!r} (known: {known})')


class ConsoleState:
    """Latest poses, obstacles and stats; a version number per part so the server sends
    only what changed."""

    def __init__(self, robots, field: Field = Field()):
        self.field = field
        self.robots = [r.strip('/') for r in robots]
        self._lock = threading.Lock()
        self._poses: dict[str, tuple] = {}        # robot -> (x, y, theta, stamp_ns)
        self._obstacles: dict[int, tuple] = {}    # id -> (x, y, radius)
        self._stats: dict[str, float] = {s: 0 for s in STATS}
        self._events = deque(maxlen=RECENT_EVENTS)   # crashes, newest last
        self._event_count = 0
        self._sim_time = 0.0
        self.pose_version = 0
        self.obstacle_version = 0
        self.stats_version = 0
        self.event_version = 0
        self.changed = None          # callable(kind) run after each change (outside the lock)

    def _notify(self, kind):
        if self.changed is not None:
            self.changed(kind)

    # ----- writers (ROS thread) -------------------------------------------------------
    def reset(self, robots) -> None:
        """A new graph (the participant session's phases): these robots, and no poses,
        obstacles or counts until the new graph sends them."""
        with self._lock:
            self.robots = [r.strip('/') for r in robots]
            self._poses = {}
            self._obstacles = {}
            self._stats = {s: 0 for s in STATS}
            self._events.clear()
            self._sim_time = 0.0
            self.pose_version += 1
            self.obstacle_version += 1
            self.stats_version += 1
            self.event_version += 1
        self._notify('obstacles')

    def set_pose(self, robot: str, x: float, y: float, theta: float, stamp_ns: int) -> None:
        if robot not in self.robots:
            raise ValueError(f'unknown robot {robot!r}')
        if not all(math.isfinite(v) for v in (x, y, theta)):
            raise ValueError(f'pose of {robot} is not finite')
        with self._lock:
            self._poses[robot] = (float(x), float(y), float(theta), int(stamp_ns))
            # the newest pose's time: the page's countdown follows sim time
            self._sim_time = max(self._sim_time, stamp_ns * 1e-9)
            self.pose_version += 1
        self._notify('pose')

    def set_obstacles(self, obstacles: dict) -> None:
        """{id: (x, y, radius)}: the whole current set (as /obstacle_markers carries it)."""
        new = {int(k): tuple(float(v) for v in xyr) for k, xyr in obstacles.items()}
        with self._lock:
            if new == self._obstacles:
                return
            self._obstacles = new
            self.obstacle_version += 1
        self._notify('obstacles')

    def set_stats(self, values: dict) -> None:
        """The world's /world/stats values (strings); keeps the counts the page shows."""
        stats = {}
        for k in STATS:
            try:
                v = float(values[k])
            except (KeyError, TypeError, ValueError):
                continue
            stats[k] = int(v) if v.is_integer() else v
        with self._lock:
            if 'sim_time' in values:
                try:
                    t = float(values['sim_time'])
                    if math.isfinite(t):
                        self._sim_time = max(self._sim_time, t)
                except ValueError:
                    pass
            if all(self._stats.get(k) == v for k, v in stats.items()):
                return
            self._stats.update(stats)
            self.stats_version += 1
        self._notify('stats')

    def add_crash(self, values: dict) -> None:
        """A /world/events 'crash' (robot, obstacle, time, x, y as strings): the page marks it.
        Raises ValueError for a record without a finite position."""
        x, y, t = (float(values.get(k, 'nan')) for k in ('x', 'y', 'time'))
        if not all(math.isfinite(v) for v in (x, y, t)):
            raise ValueError(f'crash event without a finite x, y, time: {values}')
        with self._lock:
            self._event_count += 1
            self._events.append({'id': self._event_count, 'kind': 'crash',
                                 'robot': str(values.get('robot', '')), 'obstacle': str(values.get('obstacle', '')),
                                 'x': round(x, 2), 'y': round(y, 2), 'time': round(t, 3)})
            self.event_version += 1
        self._notify('obstacles')     # at once, like a removal

    # ----- readers ----------------------------------------------------------------------
    def versions(self) -> tuple:
        with self._lock:
            return self.pose_version, self.obstacle_version, self.stats_version, self.event_version

    def snapshot(self, with_obstacles: bool = True, with_stats: bool = True,
                 with_events: bool = True) -> dict:
        """A JSON-ready view: robots [x, y, theta] rounded to cm / mrad; ``events``: the
        recent crashes ({id, kind, robot, obstacle, x, y, time})."""
        with self._lock:
            out = {'type': 'state', 'sim_time': round(self._sim_time, 3),
                   'robots': {r: [round(p[0], 2), round(p[1], 2), round(p[2], 3)]
                              for r, p in self._poses.items()},
                   'versions': [self.pose_version, self.obstacle_version, self.stats_version,
                                self.event_version]}
            if with_obstacles:
                out['obstacles'] = [[i, round(o[0], 3), round(o[1], 3), round(o[2], 3)]
                                    for i, o in sorted(self._obstacles.items())]
            if with_stats:
                out['stats'] = dict(self._stats)
            if with_events:
                out['events'] = list(self._events)
        return out

    def has_obstacle(self, obstacle_id: int) -> bool:
        with self._lock:
            return obstacle_id in self._obstacles

    def intervention(self, obstacle_id: int) -> InterventionRequest:
        """The intervention a click on ``obstacle_id`` stands for: the robot it concerns is
        the nearest robot (the one whose approach the person is reacting to), its state
        relative to the obstacle as supervisor_node publishes it. Raises KeyError if the
        obstacle is gone, LookupError if no robot has reported a pose yet."""
        with self._lock:
            if obstacle_id not in self._obstacles:
                raise KeyError(obstacle_id)
            ox, oy, _ = self._obstacles[obstacle_id]
            if not self._poses:
                raise LookupError('no robot pose yet')
            robot, (x, y, th, stamp) = min(
                self._poses.items(), key=lambda kv: math.hypot(kv[1][0] - ox, kv[1][1] - oy))
        return InterventionRequest(obstacle_id, robot, (x - ox, y - oy, th), stamp)
