"""What a filter node tells: its robots' state messages, and complaints without floods.

* ``StateReporter.state_message(name, out)``: a robot's state, a ``Status`` (the fields of a
  diagnostic_msgs/DiagnosticStatus as plain data, published serialized by
  ``ros_io.cdr.diagnostic_status_bytes``: a fleet sends hundreds a tick, and a typed status of
  twenty KeyValues costs about twice as much to fill and serialize): OK pass / WARN override /
  ERROR fail_safe, the decision's record plus the set update (``set_update``,
  ``set_update_reason``, counts), the time base and the cluster solves that failed (each one
  logged once), those shared by every robot of a tick read once (``shared_values``);
* ``StateThrottle`` / ``FleetThrottle``: when a robot's state is due (every change of
  action or set update, else at ``state_rate`` on a fixed phase);
* ``Complaints.complain(kind, text)``: the same kind of complaint logged at most every
  ``LOG_THROTTLE_S``;
* ``HoldSummary``: lockstep answers held for a cluster solve, one INFO line every
  ``HOLD_SUMMARY_S`` (each hold is a DEBUG line: a 3.5 min team run logged 377 of them).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from operator import ne
import time

import numpy as np

from ..filter import default_cluster_store

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
    ``values`` a dict of strings."""

    level: int
    name: str
    message: str = ''
    hardware_id: str = ''
    values: dict = field(default_factory=dict)


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
        update, reason = s.set_update
        return {'set_update': update, 'set_update_reason': reason,
                'sets_accepted': str(s.set_updates['accepted']), 'sets_rejected': str(s.set_updates['rejected']),
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
    """When to publish a robot's state: on every change of action or set update, and every
    ``period`` on a fixed phase (``phase`` in [0, 1) of a period), so that a fleet's periodic
    states are spread over the period instead of all falling on one tick."""

    __slots__ = ('t', 'action', 'update')

    def __init__(self, phase=0.0, now=None, period=1.0):
        self.t = -math.inf if now is None else now - period * (1.0 - phase)
        self.action, self.update = None, None

    def due(self, now, action, update, period) -> bool:
        changed = action != self.action or update is not self.update
        self.action, self.update = action, update
        if now - self.t >= period:
            # keep the phase; restart it after a long pause (or at start)
            self.t = self.t + period if now - self.t < 2.0 * period else now
            return True
        return changed


class FleetThrottle:
    """``StateThrottle`` for a fleet's n robots at once (robot i on phase i / n), as arrays: the
    same rule and the same arithmetic, without a call per robot each tick."""

    def __init__(self, n, now, period):
        self.t = now - period * (1.0 - np.arange(n) / n)
        self.action, self.update = [None] * n, None

    def due(self, now, actions, update, period) -> list:
        """The robots (indices) whose state is due, given every robot's action now."""
        n = len(self.t)
        changed = np.fromiter(map(ne, actions, self.action), dtype=bool, count=n)
        if update is not self.update:
            changed[:] = True
        self.action, self.update = list(actions), update
        late = now - self.t >= period
        if late.any():
            t = self.t[late]
            # keep the phase; restart it after a long pause (or at start)
            self.t[late] = np.where(now - t < 2.0 * period, t + period, now)
        return np.flatnonzero(late | changed).tolist()
