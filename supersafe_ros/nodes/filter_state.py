"""What a filter node tells: its robots' state messages, and complaints without floods.

* ``StateReporter.state_message(name, out)``: a robot's state, a ``Status`` (the fields of a
  diagnostic_msgs/DiagnosticStatus as plain data, published serialized by
  ``ros_io.cdr.diagnostic_status_bytes``: a fleet sends hundreds a tick, and a typed status of
  twenty KeyValues costs about twice as much to fill and serialize): OK pass / WARN override /
  ERROR fail_safe, the decision's record plus the set update (``set_update``,
  ``set_update_reason``, counts), the time base and the cluster solves that failed (each one
  logged once), those shared by every robot of a tick read once (``shared_values``);
* ``StateThrottle``: when each robot's state is due (every change of action or set update,
  else at ``state_rate`` on a fixed phase);
* ``Story``: the robots' fail-safe states and planners' silences in the log, a line per kind of
  change;
* ``Complaints.complain(kind, text)``: the same kind of complaint logged at most every
  ``LOG_THROTTLE_S``;
* ``HoldSummary``: lockstep answers held for a cluster solve, one INFO line every
  ``HOLD_SUMMARY_S`` (each hold is a DEBUG line: a 3.5 min team run logged 377 of them).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
import time

from ..filter import FAIL_SAFE, default_cluster_store
from ..filter.commands import command_fresh

LOG_THROTTLE_S = 2.0   # the same kind of complaint at most this often
HOLD_SUMMARY_S = 30.0  # steady seconds between summaries of held steps


class Complaints:
    """Throttled log lines, per kind."""

    def __init__(self, log):
        self.log = log
        self._last = {}

    def complain(self, kind: str, text: str, level='warn'):
        """Log ``text`` at most every LOG_THROTTLE_S per ``kind``."""
        now = time.monotonic()
        if now - self._last.get(kind, -math.inf) >= LOG_THROTTLE_S:
            self._last[kind] = now
            # rclpy ties a severity to each call site: one call per level
            if level == 'error':
                self.log.error(text)
            elif level == 'info':
                self.log.info(text)
            else:
                self.log.warn(text)


class HoldSummary:
    """Held lockstep answers: each one at DEBUG, and a summary at INFO at most every
    ``period`` steady seconds (when there were any), and what is left at ``flush``."""

    def __init__(self, log, period=HOLD_SUMMARY_S, now=None):
        self.log, self.period = log, float(period)
        self._since = time.monotonic() if now is None else now
        self.count, self.total, self.longest = 0, 0.0, 0.0

    def held(self, seconds: float, now=None) -> None:
        now = time.monotonic() if now is None else now
        self.log.debug(f'step held {seconds:.3g} s until the cluster value was in force')
        self.count += 1
        self.total += seconds
        self.longest = max(self.longest, seconds)
        if now - self._since >= self.period:
            self.flush(now)

    def flush(self, now=None) -> None:
        now = time.monotonic() if now is None else now
        if self.count:
            steps = f'{self.count} step{"s" if self.count != 1 else ""}'
            self.log.info(f'{steps} held in the last {now - self._since:.0f} s until a cluster value was in '
                          f'force ({self.total:.3g} s in all, longest {self.longest:.3g} s)')
        self._since, self.count, self.total, self.longest = now, 0, 0.0, 0.0


@dataclass(slots=True)
class Status:
    """A diagnostic_msgs/DiagnosticStatus as plain data: ``level`` an int (0 OK, 1 WARN, 2 ERROR),
    ``values`` a dict of strings, never changed once made; ``encoded`` their serialized bytes
    (``ros_io.cdr``), kept for every status that shares them."""

    level: int
    name: str
    message: str = ''
    hardware_id: str = ''
    values: dict = field(default_factory=dict)
    encoded: dict = field(default_factory=dict)


class StateReporter:
    """The state messages of a filter node's robots.

    ``selector``: the set in force and its updates (``runtime.set_selector``); ``time``:
    the time base (``runtime.timebase.FilterTime``); ``config()``: the filter config in
    force (its cluster store holds the failed solves)."""

    def __init__(self, log, selector, time_base, config):
        self.log = log
        self._selector, self._time, self._config = selector, time_base, config
        self._errors_told = {}             # id(store) -> failed solves already logged
        self._store, self._store_config = None, None

    def shared_values(self) -> dict:
        """The values every robot's state carries alike at a time: the set update, the time base,
        the cluster solves that failed."""
        s = self._selector
        # the counts before the verdict (the selector's worker writes the verdict first)
        accepted, rejected = s.set_updates['accepted'], s.set_updates['rejected']
        update, reason = s.set_update
        return {'set_update': update, 'set_update_reason': reason,
                'sets_accepted': str(accepted), 'sets_rejected': str(rejected),
                'time_base': ('wall (steady)' if not self._time.sim else
                              'wall (sim time stands still)' if self._time.stalled else 'sim'),
                'cluster_solves_failed': str(self.report_cluster_errors())}

    def report_cluster_errors(self) -> int:
        """Log each cluster solve that failed (its cluster stays on the fallback); the count."""
        # called for every state message (1,000 robots in a fleet tick): the store is looked up
        # only when the config changed (cluster_link is live), the errors listed only when new
        config = self._config()
        if self._store_config is not config:
            self._store, self._store_config = default_cluster_store(config), config
        store = self._store
        told, failed = self._errors_told.get(id(store), 0), len(store.errors)
        if failed > told:
            new = store.errors_after(told)
            for key, why in new:
                self.log.error(f'cluster value {key} could not be solved ({why}): that '
                               'cluster stays on the fallback rule')
            self._errors_told[id(store)] = told + len(new)
        return failed

    def state_message(self, name: str, out, extra=None, shared=None) -> Status:
        """The state of robot ``name`` after decision ``out``; ``extra``: more values (a robot judged
        by its local map: the map's and its value's); ``shared``: ``shared_values()`` if the caller
        read them for a whole tick."""
        values = out.record()
        values.update(self.shared_values() if shared is None else shared)
        if extra:
            values.update(extra)
        return Status(out.level, name, f'{out.action}: {out.reason}', '', values)


class StateThrottle:
    """When each of a node's n robots' state is due: on every change of its action or of the set
    update, and every ``period`` on a fixed phase (robot i on phase i / n, so that a fleet's periodic
    states are spread over the period instead of all falling on one tick). Plain lists and one loop
    over the robots decided (a numpy pass costs a lone robot more than its whole check)."""

    __slots__ = ('t', 'action', 'update')

    def __init__(self, n, now, period):
        self.t = [now - period * (1.0 - i / n) for i in range(n)]
        self.action, self.update = [None] * n, [None] * n

    def due(self, now, rows, actions, update, period) -> list:
        """Which of the robots ``rows`` (indices, ``actions`` theirs in order) have their state due at
        ``now``: their positions in ``rows``."""
        out = []
        t, last, updates = self.t, self.action, self.update
        for k, (i, action) in enumerate(zip(rows, actions)):
            changed = action != last[i] or update is not updates[i]
            last[i], updates[i] = action, update
            since = now - t[i]
            if since >= period:
                # keep the phase; restart it after a long pause (or at start)
                t[i] = t[i] + period if since < 2.0 * period else now
                out.append(k)
            elif changed:
                out.append(k)
        return out


class Story:
    """What a node says of its robots' fail-safe states and planners in its log: one line per kind
    of change per decision, not one per decision (``tell``): quiet while starting (the node said
    once that it waits), INFO once a robot's inputs are valid, ERROR when they are lost, INFO when
    back; a planner gone silent (a robot that can stop is sent zero twists) and speaking again, once
    per silence. A node of one robot says that robot's reason; of a fleet, how many robots and which
    (the first five), with the first one's reason."""

    def __init__(self, log, names):
        self.log, self.names = log, list(names)
        n = len(self.names)
        self.failing = [None] * n          # None: starting; True: failing safe; False: filtering
        self.waiting_told = [False] * n    # starting: why it fails safe, said once
        self.silent = [False] * n          # the planner's silence said

    def who(self, rows) -> str:
        """'' for a node of one robot; ' for K robot(s) (names)' for a fleet's."""
        if len(self.names) == 1:
            return ''
        shown = ', '.join(self.names[i] for i in rows[:5])
        return f' for {len(rows)} robot(s) ({shown}{", ..." if len(rows) > 5 else ""})'

    def tell(self, rows, decisions, filters, t) -> None:
        """After ``decisions`` of the robots ``rows`` (their ``filters``, in order) at filter time ``t``."""
        started, waiting, lost, back, silent, speaking = [], [], [], [], [], []
        failing_before, told, said_silent = self.failing, self.waiting_told, self.silent
        for k, (i, action) in enumerate(zip(rows, decisions.action)):
            failing = action == FAIL_SAFE
            before = failing_before[i]
            if before is None:
                if not failing:
                    failing_before[i] = False
                    started.append(k)
                elif not told[i] and filters[k].pose.value is not None:
                    told[i] = True        # a pose to answer, but not yet what it takes: why, once
                    waiting.append(k)
            elif failing != before:
                failing_before[i] = failing
                (lost if failing else back).append(k)
            f = filters[k]
            command = f.command
            if command.value is not None and not f.config.constant_speed:
                fresh = command_fresh(f, t)
                if not fresh and not command.rejected and not said_silent[i]:
                    said_silent[i] = True
                    silent.append(k)
                elif fresh and said_silent[i]:
                    said_silent[i] = False
                    speaking.append(k)
        rows = list(rows)
        if started:
            self._say('info', 'inputs valid', started, rows, decisions, 'filtering ({})')
        if waiting:
            self._say('info', 'failing safe until the inputs are valid', waiting, rows, decisions, '{}', reason=True)
        if lost:
            self._say('error', 'failing safe', lost, rows, decisions, '{}', reason=True)
        if back:
            self._say('info', 'inputs valid again', back, rows, decisions, 'filtering ({})')
        if silent:
            timeout = filters[silent[0]].config.cmd_timeout
            self._say('info', f'planner silent for more than cmd_timeout ({timeout:g} s)', silent, rows, None,
                      'sending zero twists until it speaks')
        if speaking:
            self._say('info', 'planner speaking again', speaking, rows, None, '')

    def _say(self, level, what, ks, rows, decisions, detail, reason=False):
        first = decisions[ks[0]] if decisions is not None else None
        if first is not None:
            detail = detail.format(first.reason if reason else f'{first.action}: {first.reason}')
            if len(self.names) > 1:
                detail = f'the first: {detail}'
        text = f'{what}{self.who([rows[k] for k in ks])}' + (f': {detail}' if detail else '')
        # rclpy ties a severity to each call site: one call per level
        if level == 'error':
            self.log.error(text)
        else:
            self.log.info(text)
