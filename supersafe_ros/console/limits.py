"""The console's bounds, without ROS: which clicks become interventions, and how many
unfinished HTTP requests it holds.

``InterventionLimiter``: a click flood must not flood the world.

A person clicks an obstacle once; a stuck mouse button, a script or an impatient
double click sends the same obstacle many times before the world's answer arrives, and
every copy after the first is rejected by the world with an ERROR line. The limiter
lets through

* one intervention per obstacle at a time: a click on an obstacle whose intervention is
  on its way (sent, not yet answered by the world, for at most ``confirm_timeout`` s)
  is refused, and so is a click on an obstacle the world has removed;
* at most ``per_second`` interventions in any one second (sliding window).

Refused clicks publish nothing and get their reason back. Work per click is O(1) (the
window holds at most ``per_second`` times).

``UnfinishedRequests``: a client that opens connections and sends a request's headers
slowly, or never, holds a file descriptor each (1,000 such requests were held for 150 s
each and took the process from 24 to 1,024 descriptors). The server closes a connection
whose request headers are not complete within its header timeout (``server``), and this
caps how many connections may be without a complete request at once: when one more
opens, the oldest of them is closed.
"""
from __future__ import annotations

from collections import deque
import math
import threading
import time

GONE_MEMORY = 1000      # removed obstacle ids remembered (ids grow; old ones never come back)


class InterventionLimiter:
    def __init__(self, per_second: float = 3.0, confirm_timeout: float = 3.0, clock=time.monotonic):
        if not (per_second >= 1 and math.isfinite(per_second)):
            raise ValueError('per_second must be a finite number >= 1')
        if not (confirm_timeout > 0):
            raise ValueError('confirm_timeout must be positive')
        self.per_second = int(per_second)
        self.confirm_timeout = float(confirm_timeout)
        self.clock = clock
        self._lock = threading.Lock()
        self._sent = deque()                 # times of the interventions let through, last second
        self._pending: dict[int, float] = {}  # obstacle -> time sent, until the world answers
        self._gone: dict[int, None] = {}     # obstacles the world removed (ordered: oldest first)
        self.refused = 0

    def admit(self, obstacle_id: int) -> str | None:
        """None if this click may be published (and it is counted as sent), else the reason
        it may not, in the participant's words."""
        now = self.clock()
        with self._lock:
            while self._sent and now - self._sent[0] >= 1.0:
                self._sent.popleft()
            reason = None
            if obstacle_id in self._gone:
                reason = 'That obstacle is already gone.'
            elif now - self._pending.get(obstacle_id, -math.inf) < self.confirm_timeout:
                reason = 'That obstacle is already being removed.'
            elif len(self._sent) >= self.per_second:
                reason = 'Too many clicks: wait a moment, then click again.'
            if reason is not None:
                self.refused += 1
                return reason
            self._sent.append(now)
            self._pending[obstacle_id] = now
            return None

    def removed(self, obstacle_id: int) -> None:
        """The world has removed this obstacle (its /world/intervention_log record)."""
        with self._lock:
            self._pending.pop(obstacle_id, None)
            self._gone[obstacle_id] = None
            while len(self._gone) > GONE_MEMORY:
                del self._gone[next(iter(self._gone))]

    def forget(self, obstacle_id: int) -> None:
        """No answer will come for this one (e.g. it was never published): clickable again."""
        with self._lock:
            self._pending.pop(obstacle_id, None)

    def reset(self) -> None:
        """A new world (the session's next phase): obstacle ids start again from 0."""
        with self._lock:
            self._pending.clear()
            self._gone.clear()


class UnfinishedRequests:
    """Connections that have not sent a complete request yet: at most ``cap`` at once.

    ``opened(key)`` returns the connection to close when the cap is exceeded (the oldest
    unfinished one: a client that sends its headers at once, such as a page, is never the
    oldest for long, while a slow one ages) or None; ``finished(key)`` when its request's
    headers are complete; ``closed(key)`` when it goes (counted in ``abandoned`` if it never
    finished: a timeout, an eviction or a client that gave up)."""

    def __init__(self, cap: int):
        if int(cap) < 1:
            raise ValueError('the cap on unfinished requests must be at least 1')
        self.cap = int(cap)
        self._open: dict = {}   # key -> None, oldest first
        self.evicted = 0        # closed because the cap was exceeded
        self.abandoned = 0      # closed before a complete request
        self.peak = 0

    def __len__(self) -> int:
        return len(self._open)

    def opened(self, key):
        self._open[key] = None
        self.peak = max(self.peak, len(self._open))
        if len(self._open) <= self.cap:
            return None
        oldest = next(iter(self._open))
        del self._open[oldest]
        self.evicted += 1
        self.abandoned += 1
        return oldest

    def finished(self, key) -> None:
        self._open.pop(key, None)

    def closed(self, key) -> None:
        if key in self._open:
            del self._open[key]
            self.abandoned += 1
