"""Inputs a node turns away, told in the log without flooding it (ROS-free bookkeeping).

Per reason (a short fixed phrase such as ``duplicate`` or ``invalid stamp``):

* the first one is logged at once, with its details;
* the others within ``period`` seconds are counted, and when the period ends one line
  says how many there were, with the latest as an example (the caller's timer calls
  ``flush``, so the summary comes on time, not with the next burst); a reason that keeps
  coming is thus logged at most once a period;
* ``close`` tells what is still pending and the totals per reason (at shutdown).

    log = RejectionLog('intervention', 'rejected', node.get_logger().warn)
    log.add('invalid stamp', 'stamp (-1 s, 0 ns) is not a valid time', time.monotonic())
    log.flush(time.monotonic())          # on a timer
    log.close(time.monotonic())          # at shutdown
"""
from __future__ import annotations

from collections.abc import Callable


class RejectionLog:
    """Rejections per reason, each reason logged at most once per ``period`` (see the module doc)."""

    def __init__(self, noun: str, verb: str, log: Callable[[str], None], period: float = 1.0):
        self.noun, self.verb, self.log, self.period = noun, verb, log, float(period)
        self.totals: dict[str, int] = {}
        self.latest = ''                         # 'reason: details' of the newest
        self._windows: dict[str, list] = {}      # reason -> [end, counted since the line, example]

    @property
    def total(self) -> int:
        return sum(self.totals.values())

    def add(self, reason: str, details: str, now: float) -> None:
        """One rejection for ``reason`` at ``now`` (a steady clock, seconds)."""
        self.totals[reason] = self.totals.get(reason, 0) + 1
        self.latest = f'{reason}: {details}'
        window = self._windows.get(reason)
        if window is None:
            self.log(f'{self.noun} {self.verb} ({reason}): {details}')
            self._windows[reason] = [now + self.period, 0, '']
        else:
            window[1] += 1
            window[2] = details

    def flush(self, now: float, force: bool = False) -> int:
        """Log the summary of every reason whose period has ended (all with ``force``);
        returns the number of lines logged."""
        lines = 0
        for reason, (end, count, example) in list(self._windows.items()):
            if now < end and not force:
                continue
            if count:
                self.log(f'{count} more {self.noun}{"s" if count > 1 else ""} {self.verb} ({reason}) in the last '
                         f'{self.period:g} s; latest: {example}')
                lines += 1
            if count and not force:
                self._windows[reason] = [now + self.period, 0, '']   # still coming: the next line in a period
            else:
                del self._windows[reason]
        return lines

    def summary(self) -> str:
        """'N (reason a 3, reason b 1)', or '0'."""
        if not self.totals:
            return '0'
        return f'{self.total} (' + ', '.join(f'{r} {n}' for r, n in sorted(self.totals.items())) + ')'

    def close(self, now: float) -> None:
        """Shutdown: the pending counts, then the totals (when there were any)."""
        self.flush(now, force=True)
        if self.totals:
            self.log(f'{self.noun}s {self.verb} this run: {self.summary()}')
