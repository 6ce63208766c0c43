"""Encounters built online from what a team publishes: robot poses, the obstacle set, interventions.

ROS-free (the learner node feeds it messages as plain numbers). An *encounter* is one
robot approaching one obstacle, seen as states relative to the obstacle (obstacle at
the origin, axes as the map), the unit the first-passage estimator scores
(``estimators.fit_first_passage``). For each (robot, obstacle) pair:

* it **starts** at the first pose with the relative state inside the library's grid
  while the robot approaches (the distance to the centre is not growing);
* it **ends**
  - at an intervention on that obstacle (``intervention``): its frames are those
    stamped strictly before the intervention, then the intervention frame: the robot's
    first pose at or after the intervention (the pose judged unsafe), unless that pose comes
    after a jump or after the obstacle left the set (the next scene, a teleport: never the
    pose judged); then the reported state stands in, and the frames just before it at that
    same state (within ``same_pose`` metres: the pose the supervisor judged, stamped before
    the intervention that reports it) are that frame, not frames judged safe;
  - when the robot has passed the obstacle (the distance grows:
    rel . (cos theta, sin theta) > 0), the frame where that is first seen included;
  - when the pair leaves the grid;
  - when the obstacle disappears (or moves) from the obstacle set;
  - when the robot jumps (teleport, scene reset): a pose more than
    ``jump_distance + speed * dt`` from the previous one, or a stamp going back;
  - after ``max_frames`` frames (it is then a finished encounter without intervention,
    and the next frame starts a new one: bounded memory for a robot circling an obstacle).

Encounters that end without an intervention count: leaving them out is the censoring
that biases the paper's estimator.

Ordering. Poses, obstacle sets and interventions come on separate topics, so they may
arrive out of order. Every input carries its time stamp, and the builder orders by
stamps, not arrival:

* with ``reorder`` > 0, a robot's pose stamped t is judged only once that robot has a
  pose stamped t + ``reorder`` or later (or ``stale_wall`` wall seconds after it arrived,
  ``tick``), so an obstacle set or intervention that arrives up to ``reorder`` seconds of
  pose time after poses stamped later than it is still in force for them (DDS orders
  messages within a topic, not across topics; a set read after the poses it precedes
  would miss the encounter's start, and an intervention then finds no encounter);

* an obstacle set stamped T applies to a robot's poses stamped >= T (each robot keeps
  its own place in the list of obstacle-set versions); unstamped sets (T = 0) apply at
  once (the learner node stamps an unstamped set with its arrival time, as it does an
  unstamped intervention), and a set that no robot's poses reach within ``stale_wall``
  wall seconds (the clock stopped, a robot went quiet) applies then (``tick``);
* an encounter that ended without an intervention is held for ``grace`` seconds of pose
  time before it is final, so an intervention that arrives late still finds it; frames
  stamped at or after an intervention are dropped from its encounter. When the robot's
  poses stop (the end of a stream), held encounters become final ``stale_wall`` wall
  seconds after its last pose arrived (``tick``), so the end of a session is fitted
  without waiting for more data;
* an intervention names its obstacle, not its robot: it goes to the encounter of that
  obstacle (open, or ended within the grace time) whose frames pass closest to the
  intervention state, within ``match_tolerance`` metres. An intervention no encounter
  matches is reported as unmatched (the node still stores it as an intervention).

After an intervention, no new encounter with that obstacle starts until it leaves the
obstacle set (the world removes it) or ``pending_timeout`` seconds of pose time pass.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from collections import deque
import json
import math

import numpy as np

from .data import Encounter

END_REASONS = ('intervention', 'passed', 'left_grid', 'obstacle_gone', 'jump', 'max_frames', 'shutdown')

# a robot placed on the grid's edge (a scene's start at the library's lo) lands a float hair outside
# or inside depending on the arithmetic that put it there: within a micrometre counts as inside
GRID_EDGE = 1e-6


@dataclass(frozen=True)
class EncounterRecord:
    """One finished encounter: frames (T, 3) relative to the obstacle, stamps t (T,) in s."""

    robot: str
    obstacle: int
    t: tuple                    # frame stamps [s]
    frames: tuple               # ((x, y, theta), ...) relative to the obstacle
    intervened: bool
    reason: str                 # one of END_REASONS

    def __post_init__(self):
        if len(self.t) != len(self.frames) or not self.frames:
            raise ValueError(f'encounter {self.robot}/{self.obstacle}: {len(self.t)} stamps for '
                             f'{len(self.frames)} frames (need >= 1)')
        if self.reason not in END_REASONS:
            raise ValueError(f'unknown end reason {self.reason!r}')

    @property
    def key(self):
        return (self.robot, int(self.obstacle), round(float(self.t[0]), 9))

    def to_encounter(self) -> Encounter:
        """The estimator's form (``data.Encounter``)."""
        return Encounter(np.asarray(self.frames, dtype=float), self.intervened,
                         scene=f'{self.robot}/obstacle_{self.obstacle}@{self.t[0]:.3f}',
                         t=np.asarray(self.t, dtype=float))

    def to_json(self) -> str:
        return json.dumps({'robot': self.robot, 'obstacle': int(self.obstacle),
                           't': [round(float(v), 9) for v in self.t],
                           'frames': [[float(v) for v in f] for f in self.frames],
                           'intervened': bool(self.intervened), 'reason': self.reason},
                          separators=(',', ':'))

    @classmethod
    def from_json(cls, line: str) -> 'EncounterRecord':
        d = json.loads(line)
        frames = tuple(tuple(float(v) for v in f) for f in d['frames'])
        if not all(len(f) == 3 and all(math.isfinite(v) for v in f) for f in frames):
            raise ValueError('encounter frames must be finite (x, y, theta)')
        return cls(str(d['robot']), int(d['obstacle']), tuple(float(v) for v in d['t']), frames,
                   bool(d['intervened']), str(d['reason']))


@dataclass
class _Open:
    robot: str
    obstacle: int
    t: list = field(default_factory=list)
    frames: list = field(default_factory=list)
    centre: tuple = (0.0, 0.0)            # the obstacle's centre (map)
    ended_at: float | None = None         # pose time it ended (held for the grace time)
    reason: str = ''
    await_t: float | None = None          # intervened at this time; waiting for the next pose
    await_state: tuple | None = None      # the intervention's reported state (fallback frame)
    gone_at: float | None = None          # pose time the obstacle left the robot's set (lingering)


class EncounterBuilder:
    """Per (robot, obstacle) encounters from stamped poses, obstacle sets and interventions.

    lo, hi: the library grid's (xmin, ymin), (xmax, ymax); speed: the robots' speed [m/s]
    (for the jump test).
    """

    def __init__(self, lo, hi, speed: float, *, jump_distance: float = 1.0, grace: float = 2.0,
                 match_tolerance: float = 1.0, pending_timeout: float = 5.0, max_frames: int = 2000,
                 stale_wall: float = 2.0, max_versions: int = 1000, removal_delay: float = 1.0,
                 reorder: float = 0.0, same_pose: float = 0.05):
        self.lo = np.asarray(lo, dtype=float).reshape(2)
        self.hi = np.asarray(hi, dtype=float).reshape(2)
        if not np.all(self.hi > self.lo):
            raise ValueError(f'grid bounds must have hi > lo, got {lo}, {hi}')
        for name, v in (('speed', speed), ('jump_distance', jump_distance), ('grace', grace),
                        ('match_tolerance', match_tolerance), ('pending_timeout', pending_timeout),
                        ('stale_wall', stale_wall), ('reorder', reorder), ('same_pose', same_pose)):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f'{name} must be finite and >= 0, got {v}')
        if max_frames < 2:
            raise ValueError(f'max_frames must be >= 2, got {max_frames}')
        self.speed, self.jump_distance, self.grace = float(speed), float(jump_distance), float(grace)
        self.match_tolerance, self.pending_timeout = float(match_tolerance), float(pending_timeout)
        self.max_frames, self.stale_wall, self.max_versions = int(max_frames), float(stale_wall), max_versions
        self.removal_delay, self.reorder, self.same_pose = float(removal_delay), float(reorder), float(same_pose)
        self._last_wall: dict[str, float] = {}     # robot -> arrival (wall) of its newest pose
        self._held: dict[str, deque] = {}           # robot -> poses (t, x, y, th, wall) not judged yet
        self._lingering: dict[tuple, float] = {}    # (robot, obstacle) -> pose time it ends at
        # obstacle-set versions: [stamp, first_seen_wall, {id: (x, y)}]; robots index into it
        self._versions = [[-math.inf, -math.inf, {}]]
        self._base = 0                    # version number of self._versions[0]
        self._robot_version: dict[str, int] = {}
        self._last_pose: dict[str, tuple] = {}      # robot -> (t, x, y)
        self._open: dict[tuple, _Open] = {}         # (robot, obstacle) -> encounter in progress
        self._closing: list[_Open] = []             # ended without intervention, within grace
        self._awaiting: list[_Open] = []            # intervened, waiting for the robot's next pose
        self._pending: list[tuple] = []             # interventions ahead of some robot's poses
        self._blocked: dict[int, float] = {}        # obstacle -> intervention time
        self._finished: list[EncounterRecord] = []
        self.newest = -math.inf                     # newest pose stamp received
        self.counts = {'unmatched_interventions': 0, 'jumps': 0, 'ignored_poses': 0}
        self.counts.update({r: 0 for r in END_REASONS})

    # -- inputs ------------------------------------------------------------------------------
    def set_obstacles(self, ids, xy, stamp: float = 0.0, wall: float = 0.0) -> None:
        """The whole obstacle set (ids (N,), centres (N, 2)) as of ``stamp`` [s] (0: now)."""
        ids = [int(i) for i in np.asarray(ids).reshape(-1)]
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        if len(ids) != len(xy) or not np.all(np.isfinite(xy)):
            raise ValueError('obstacle set: ids and finite centres must match one to one')
        stamp = float(stamp)
        if not math.isfinite(stamp) or stamp < 0:
            raise ValueError(f'obstacle set stamp must be finite and >= 0, got {stamp}')
        centres = {i: (float(x), float(y)) for i, (x, y) in zip(ids, xy)}
        if stamp == 0.0:
            # unstamped: in force for every robot at once
            self._versions.append([-math.inf, wall, centres])
            newest = self._base + len(self._versions) - 1
            for r in list(self._robot_version):
                self._advance(r, newest, self._last_pose[r][0] if r in self._last_pose else self.newest)
        else:
            self._versions.append([stamp, wall, centres])
        self._prune()

    def pose(self, robot: str, stamp: float, state, wall: float = 0.0) -> None:
        """One robot pose (map frame) stamped ``stamp`` [s], arrived at ``wall`` (``tick``'s clock)."""
        x, y, th = (float(v) for v in np.asarray(state, dtype=float).reshape(3))
        stamp = float(stamp)
        if not all(math.isfinite(v) for v in (x, y, th, stamp)):
            raise ValueError(f'pose of {robot} is not finite ({x}, {y}, {th}) at {stamp}')
        self.newest = max(self.newest, stamp)
        self._last_wall[robot] = float(wall)
        if robot not in self._robot_version:
            self._robot_version[robot] = self._base     # keeps the sets its held poses may need
        if self.reorder <= 0.0:
            self._judge(robot, stamp, x, y, th)
            return
        held = self._held.setdefault(robot, deque())
        if held and stamp < held[-1][0]:
            self._release(robot, math.inf)      # the stamps went back (a reset): judge what came before
        held.append((stamp, x, y, th, float(wall)))
        self._release(robot, stamp - self.reorder)

    def _release(self, robot, until, wall=None):
        """Judge the robot's held poses stamped <= until (or arrived stale_wall before wall)."""
        held = self._held.get(robot)
        while held and (held[0][0] <= until or (wall is not None and held[0][4] + self.stale_wall <= wall)):
            t, x, y, th, _ = held.popleft()
            self._judge(robot, t, x, y, th)
        if held is not None and not held:
            del self._held[robot]

    def _judge(self, robot, stamp, x, y, th):
        """One pose, in its turn: encounters start, grow and end."""
        prev = self._last_pose.get(robot)
        jumped = False
        if prev is not None:
            dt = stamp - prev[0]
            if dt < 0 or math.hypot(x - prev[1], y - prev[2]) > self.jump_distance + self.speed * dt:
                jumped = True
                self.counts['jumps'] += 1
                self._end_robot(robot, 'jump', prev[0])
        if self._awaiting:
            self._resolve_awaiting(robot, stamp, x, y, th, jumped)
        self._last_pose[robot] = (stamp, x, y)
        self._advance_to_stamp(robot, stamp)
        obstacles = self._versions[self._robot_version[robot] - self._base][2]
        if self._lingering:
            for key, until in list(self._lingering.items()):
                if key[0] != robot:
                    continue
                enc = self._open.get(key)
                if enc is None:
                    del self._lingering[key]
                elif stamp > until or key[1] in obstacles:      # gone (or moved: a new encounter)
                    del self._lingering[key]
                    self._end(key, 'obstacle_gone', stamp)
                else:
                    obstacles = {**obstacles, key[1]: enc.centre}
        c, s = math.cos(th), math.sin(th)
        for oid, (cx, cy) in obstacles.items():
            rx, ry = x - cx, y - cy
            key = (robot, oid)
            inside = (self.lo[0] - GRID_EDGE <= rx <= self.hi[0] + GRID_EDGE
                      and self.lo[1] - GRID_EDGE <= ry <= self.hi[1] + GRID_EDGE)
            passed = rx * c + ry * s > 0.0
            enc = self._open.get(key)
            if enc is not None:
                if not inside:
                    self._end(key, 'left_grid', stamp)
                    continue
                enc.t.append(stamp)
                enc.frames.append((rx, ry, th))
                if passed:
                    self._end(key, 'passed', stamp)
                elif len(enc.frames) >= self.max_frames:
                    self._end(key, 'max_frames', stamp)
                continue
            if not inside or passed:
                continue
            blocked = self._blocked.get(oid)
            if blocked is not None:
                if stamp - blocked <= self.pending_timeout:
                    continue
                del self._blocked[oid]
            self._open[key] = _Open(robot, oid, [stamp], [(rx, ry, th)], (cx, cy))
        self._expire(stamp)
        self._match_pending()

    def intervention(self, obstacle: int, stamp: float, rel_state, wall: float = 0.0) -> None:
        """An intervention on ``obstacle`` at ``stamp`` [s], the robot's state relative to it.

        It is matched once every robot's poses have reached ``stamp`` (the poses before it
        may still be on their way), or ``stale_wall`` seconds after ``wall`` (``tick``)."""
        rel = np.asarray(rel_state, dtype=float).reshape(3)
        stamp = float(stamp)
        if not (np.all(np.isfinite(rel)) and math.isfinite(stamp)):
            raise ValueError('intervention state and stamp must be finite')
        self._pending.append((stamp, int(obstacle), tuple(float(v) for v in rel), float(wall)))
        self._match_pending()

    def _match_pending(self, wall: float | None = None):
        if not self._pending:
            return
        # the poses judged so far (a robot whose poses are all still held has reached nothing)
        reached = min((self._last_pose[r][0] if r in self._last_pose else -math.inf for r in self._robot_version),
                      default=-math.inf)
        still = []
        for stamp, obstacle, rel, arrived in sorted(self._pending):
            if stamp <= reached + 1e-9 or (wall is not None and arrived + self.stale_wall <= wall):
                self._match(obstacle, stamp, rel)
            else:
                still.append((stamp, obstacle, rel, arrived))
        self._pending = still

    def _match(self, obstacle: int, stamp: float, rel_state) -> bool:
        """Attach an intervention to its encounter.

        The encounter's intervention frame is the robot's first pose stamped at or after
        the intervention (the pose the supervisor judged unsafe; the reported state may be
        interpolated between poses, and an interval whose lower end is the threshold itself
        would bias mu upwards). If that pose has not arrived yet, the encounter waits for
        it (up to the grace time, then the reported state stands in).
        Returns False if no encounter matches (counted as unmatched)."""
        rel = np.asarray(rel_state, dtype=float).reshape(3)
        stamp = float(stamp)
        if not (np.all(np.isfinite(rel)) and math.isfinite(stamp)):
            raise ValueError('intervention state and stamp must be finite')
        obstacle = int(obstacle)
        best, best_d = None, math.inf
        for enc in list(self._open.values()) + self._closing:
            if enc.obstacle != obstacle or enc.t[0] > stamp + 1e-9 or enc.await_t is not None:
                continue
            f = np.asarray(enc.frames)
            d = float(np.min(np.hypot(f[:, 0] - rel[0], f[:, 1] - rel[1])))
            if d < best_d:
                best, best_d = enc, d
        self._blocked[obstacle] = stamp
        if best is None or best_d > self.match_tolerance:
            self.counts['unmatched_interventions'] += 1
            return False
        if best in self._closing:
            self._closing.remove(best)
        else:
            del self._open[(best.robot, best.obstacle)]
        # frames after the obstacle left the set (lingering) are never the pose judged
        after = [k for k, tk in enumerate(best.t) if tk >= stamp - 1e-9 and not self._after_removal(best, stamp, tk)]
        keep = [k for k, tk in enumerate(best.t) if tk < stamp - 1e-9]
        frame = (best.t[after[0]], best.frames[after[0]]) if after else None
        best.t = [best.t[k] for k in keep]
        best.frames = [best.frames[k] for k in keep]
        best.await_t, best.await_state = stamp, tuple(float(v) for v in rel)
        if frame is not None:
            self._intervened(best, *frame)
        elif best.ended_at is not None or self._after_removal(best, stamp, math.inf):
            self._intervened(best)       # it has ended: no later pose of it can be the one judged
        else:
            best.ended_at = stamp        # the pose judged may still be on its way
            self._awaiting.append(best)
        return True

    def _intervened(self, enc, t=None, frame=None):
        """Finish ``enc`` (its frames: those before the intervention) with the intervention
        frame: the pose judged (``t``, ``frame``), or else the reported state, which then
        stands for the frames just before it at the same state (``same_pose``)."""
        ts, frames = list(enc.t), list(enc.frames)
        if frame is None:
            t, frame = enc.await_t, enc.await_state
            while frames and math.hypot(frames[-1][0] - frame[0], frames[-1][1] - frame[1]) <= self.same_pose:
                ts.pop()
                frames.pop()
        record = EncounterRecord(enc.robot, enc.obstacle, tuple(ts + [t]), tuple(frames + [tuple(frame)]), True,
                                 'intervention')
        self.counts['intervention'] += 1
        self._finished.append(record)

    def _resolve_awaiting(self, robot, stamp, x, y, th, jumped):
        """The robot's pose after a pending intervention becomes the intervention frame,
        unless it comes after a jump or after the obstacle left the set (then the reported
        state stands in)."""
        still = []
        for enc in self._awaiting:
            if enc.robot != robot:
                still.append(enc)
            elif jumped or self._gone_by(robot, enc, stamp):
                self._intervened(enc)
            elif stamp >= enc.await_t - 1e-9:
                self._intervened(enc, stamp, (x - enc.centre[0], y - enc.centre[1], th))
            else:
                still.append(enc)
        self._awaiting = still

    def _gone_by(self, robot, enc, stamp) -> bool:
        """Whether ``enc``'s obstacle left the set (or moved) after its intervention and by
        the robot's pose stamped ``stamp`` (``_after_removal``), by the versions in force."""
        if enc.gone_at is None:
            v = self._robot_version[robot]
            last = self._base + len(self._versions) - 1
            while v < last and self._versions[v + 1 - self._base][0] <= stamp:
                v += 1
                if self._versions[v - self._base][2].get(enc.obstacle) != enc.centre:
                    enc.gone_at = self._versions[v - self._base][0]
                    break
        return self._after_removal(enc, enc.await_t, stamp)

    @staticmethod
    def _after_removal(enc, intervention: float, stamp: float) -> bool:
        """A pose stamped ``stamp`` comes after the obstacle left the set, by a removal
        stamped after the intervention (a pose stamped with the removal itself was seen
        before it: the world removes on the intervention that pose caused). A removal
        stamped at or before the intervention is the world's coarse clock lagging: the
        removal the intervention caused cannot precede it, so it says nothing about which
        pose was judged."""
        return enc.gone_at is not None and intervention + 1e-9 < enc.gone_at < stamp - 1e-9

    def tick(self, wall: float) -> None:
        """Wall-clock housekeeping: apply obstacle sets that no robot's poses have reached
        within ``stale_wall`` seconds of their arrival (``wall`` is the arrival clock), and
        judge poses held that long (a robot that stopped publishing). When a robot's poses
        stopped ``stale_wall`` seconds ago, its encounters held for the grace time become final
        and its interventions waiting for the pose judged take their reported state: no pose
        time will pass for them (the end of a stream), and the fit should not wait."""
        for r in list(self._held):
            self._release(r, -math.inf, wall)
        for k, v in enumerate(self._versions):
            if v[0] > -math.inf and v[1] + self.stale_wall <= wall:
                v[0] = -math.inf       # in force now
        # an intervention about to be matched by wall time needs its poses judged first: read
        # before them (topics cross), it would otherwise find its encounter not begun
        due = [p[0] for p in self._pending if p[3] + self.stale_wall <= wall]
        if due:
            for r in list(self._held):
                self._release(r, max(due))
        for r in list(self._robot_version):
            if r in self._last_pose:           # (a robot whose poses are all held stays put)
                self._advance_to_stamp(r, self._last_pose[r][0])
        self._prune()
        self._match_pending(wall)
        quiet = {r for r, w in self._last_wall.items() if w + self.stale_wall <= wall and r not in self._held}
        if quiet:
            for enc in [e for e in self._closing if e.robot in quiet]:
                self._closing.remove(enc)
                self._emit(enc)
            for enc in [e for e in self._awaiting if e.robot in quiet]:
                self._awaiting.remove(enc)
                self._intervened(enc)

    def finish_all(self) -> None:
        """Shutdown: pending interventions are matched, encounters held for the grace time
        are final; open ones are dropped (they had not ended)."""
        for r in list(self._held):
            self._release(r, math.inf)
        self._match_pending(math.inf)
        for enc in self._closing:
            self._emit(enc)
        self._closing = []
        for enc in self._awaiting:
            self._intervened(enc)
        self._awaiting = []

    def pop_finished(self) -> list[EncounterRecord]:
        """Encounters finished since the last call (in the order they became final)."""
        out, self._finished = self._finished, []
        return out

    @property
    def open_count(self) -> int:
        return len(self._open) + len(self._closing) + len(self._awaiting) + len(self._pending)

    # -- internals --------------------------------------------------------------------------
    def _advance_to_stamp(self, robot, stamp):
        v = self._robot_version[robot]
        last = self._base + len(self._versions) - 1
        target = v
        while target < last and self._versions[target + 1 - self._base][0] <= stamp:
            target += 1
        if target != v:
            self._advance(robot, target, stamp)

    def _advance(self, robot, version, stamp):
        """Move ``robot`` to obstacle-set ``version``: end its encounters with obstacles
        that are gone or moved there."""
        first = self._robot_version[robot]
        old = self._versions[first - self._base][2]
        new = self._versions[version - self._base][2]
        self._robot_version[robot] = version
        for oid in list(old):
            if new.get(oid) != old[oid] and (robot, oid) in self._open:
                t_change = self._left_at(first, version, oid, old[oid])
                # a set's stamp may lag the true time (a node on a coarse clock): the
                # encounter goes on for removal_delay, so no frame before the removal is cut
                # (frames after an intervention are dropped anyway, and a jump still ends it)
                start = stamp if t_change == -math.inf else t_change
                self._lingering[(robot, oid)] = start + self.removal_delay
                self._open[(robot, oid)].gone_at = start
        for enc in self._awaiting:
            if enc.robot == robot and enc.gone_at is None and new.get(enc.obstacle) != enc.centre:
                t_change = self._left_at(first, version, enc.obstacle, enc.centre)
                enc.gone_at = stamp if t_change == -math.inf else t_change
        for oid in list(self._blocked):
            if oid not in new and all(oid not in self._versions[self._robot_version[r] - self._base][2]
                                      for r in self._robot_version):
                del self._blocked[oid]

    def _left_at(self, first, version, oid, centre) -> float:
        """Stamp of the first version after ``first`` (up to ``version``) without obstacle
        ``oid`` at ``centre``: when it left (a later set may already stamp the next scene)."""
        return next(self._versions[v - self._base][0] for v in range(first + 1, version + 1)
                    if self._versions[v - self._base][2].get(oid) != centre)

    def _end_robot(self, robot, reason, stamp):
        for key in [k for k in self._open if k[0] == robot]:
            self._end(key, reason, stamp)

    def _end(self, key, reason, stamp):
        enc = self._open.pop(key)
        enc.ended_at, enc.reason = stamp, reason
        if reason == 'max_frames':
            self._emit(enc)          # no intervention can belong to it: it is over by our choice
        else:
            self._closing.append(enc)

    def _expire(self, now):
        keep = []
        for enc in self._closing:
            # the grace runs on the encounter's own robot's poses (robots may lag each other)
            if self._last_pose[enc.robot][0] - enc.ended_at > self.grace:
                self._emit(enc)
            else:
                keep.append(enc)
        self._closing = keep
        still = []
        for enc in self._awaiting:        # no pose after the intervention: its own state stands in
            if self._last_pose[enc.robot][0] - enc.await_t > self.grace:
                self._intervened(enc)
            else:
                still.append(enc)
        self._awaiting = still
        for oid, t in list(self._blocked.items()):
            if now - t > self.pending_timeout:
                del self._blocked[oid]

    def _emit(self, enc):
        self.counts[enc.reason] += 1
        self._finished.append(EncounterRecord(enc.robot, enc.obstacle, tuple(enc.t), tuple(enc.frames),
                                              False, enc.reason))

    def _prune(self):
        """Drop obstacle-set versions every robot has moved past (bounded memory)."""
        # before any pose every set is kept (up to max_versions): the first poses may be older
        lowest = min(self._robot_version.values(), default=self._base)
        drop = max(lowest - self._base, len(self._versions) - self.max_versions, 0)
        drop = min(drop, len(self._versions) - 1)
        if drop > 0:
            self._versions = self._versions[drop:]
            self._base += drop
            for r, v in self._robot_version.items():
                if v < self._base:
                    self._robot_version[r] = self._base
