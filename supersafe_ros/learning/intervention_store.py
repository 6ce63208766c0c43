"""Append-only, durable stores of accepted records (JSON lines): interventions and encounters.

One line per intervention::

    {"stamp_ns": 1700000000123456789, "frame": "obstacle_7", "x": -2.1, "y": 0.4,
     "theta": 0.05, "received": 1700000000.2}

``append`` writes one whole line and, by default, fsyncs before returning, so a
record that was acknowledged survives a crash or power cut. ``append(..., sync=False)``
only hands the line to the kernel (it survives a crash of the process, not a power
cut) and ``sync()`` fsyncs every such line at once: the learner's group commit, which
takes a burst of interventions without one fsync each. On open the file is read
back; a torn last line (the process died mid-write: no newline, or not JSON) is
cut off so the next append starts on a clean line — only that never-acknowledged
record is lost. A damaged line elsewhere is skipped and counted, never silently
rewritten. An exclusive lock (flock) keeps two learners from writing one file.
``archive`` renames the file aside (nothing is deleted) and starts an empty one:
the reset for a new subject.
"""
from __future__ import annotations

from dataclasses import dataclass
import fcntl
import json
import math
import os
import re
import time

import numpy as np


_TRAILING_DIGITS = re.compile(r'[0-9]+$')


@dataclass(frozen=True)
class Intervention:
    """One accepted intervention: the robot's state in the obstacle's frame."""

    stamp_ns: int       # time of the intervention (header.stamp), nanoseconds
    frame: str          # the obstacle's frame, e.g. 'obstacle_7'
    x: float
    y: float
    theta: float
    received: float = 0.0   # wall time it was stored (seconds since the epoch)

    def __post_init__(self):
        if not all(math.isfinite(v) for v in (self.x, self.y, self.theta)):
            raise ValueError(f'intervention state is not finite ({self.x}, {self.y}, {self.theta})')
        if not self.frame:
            raise ValueError('intervention frame is empty')

    @property
    def obstacle(self):
        """The obstacle's number: the frame's trailing digits as an integer, so that
        ``obstacle_7``, ``obstacle_07`` and ``obstacle_007`` name one obstacle (the frame
        text itself for a frame without digits)."""
        digits = _TRAILING_DIGITS.search(self.frame)
        return int(digits.group()) if digits else self.frame

    @property
    def key(self):
        """Identity for duplicate detection: the same event republished, whatever the spelling
        of its frame. The message names no robot: one obstacle's intervention at one stamp
        concerns one robot (the nearest, or the one the supervisor judged)."""
        return (self.obstacle, int(self.stamp_ns))

    @property
    def state(self):
        return (self.x, self.y, self.theta)

    def to_json(self) -> str:
        return json.dumps({'stamp_ns': int(self.stamp_ns), 'frame': self.frame, 'x': float(self.x),
                           'y': float(self.y), 'theta': float(self.theta),
                           'received': float(self.received)}, sort_keys=True)

    @classmethod
    def from_json(cls, line: str) -> 'Intervention':
        d = json.loads(line)
        return cls(int(d['stamp_ns']), str(d['frame']), float(d['x']), float(d['y']),
                   float(d['theta']), float(d.get('received', 0.0)))


class StoreLockedError(RuntimeError):
    """Another process holds the store."""


class RecordStore:
    """Records of one subject persisted to ``path`` (JSON lines), duplicates (same
    ``key``) refused. ``record_type`` has ``key``, ``to_json()`` and ``from_json(line)``."""

    record_type = None

    def __init__(self, path, record_type=None, keep: int | None = None):
        """keep: hold only the newest ``keep`` records in ``entries`` (memory stays bounded
        over hours; the file keeps all of them and ``len()`` counts all)."""
        if record_type is not None:
            self.record_type = record_type
        self.keep = keep
        self.count = 0
        self.path = os.path.abspath(os.path.expanduser(os.fspath(path)))
        os.makedirs(os.path.dirname(self.path), exist_ok=True)
        self.entries: list = []
        self.unsynced = 0           # lines appended with sync=False since the last fsync
        self.skipped_lines = 0      # damaged lines found on load (kept in the file)
        self.torn_bytes = 0         # bytes of a torn last line cut off on load
        self._keys = set()
        self._file = None
        self._open()

    # -- file handling ------------------------------------------------------------------
    def _open(self):
        created = not os.path.exists(self.path)
        f = open(self.path, 'a+b')
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            raise StoreLockedError(f'{self.path} is in use by another process') from None
        self._file = f
        if created:
            self._fsync_dir()
        self._load()

    def _fsync_dir(self):
        fd = os.open(os.path.dirname(self.path), os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    def _load(self):
        f = self._file
        f.seek(0)
        data = f.read()
        self.entries, self._keys = [], set()
        self.skipped_lines = self.torn_bytes = 0
        good_end = 0
        pos = 0
        while pos < len(data):
            nl = data.find(b'\n', pos)
            last = nl < 0
            end = len(data) if last else nl + 1
            line = data[pos:end]
            try:
                entry = self.record_type.from_json(line.decode('utf-8'))
            except (ValueError, KeyError, TypeError, UnicodeDecodeError):
                entry = None
            if last:
                # no newline: the write was cut short, even if the bytes happen to parse
                self.torn_bytes = len(line)
                break
            if entry is None:
                if line.strip():
                    self.skipped_lines += 1
            elif entry.key not in self._keys:
                self.entries.append(entry)
                self._keys.add(entry.key)
                if self.keep is not None and len(self.entries) > 2 * self.keep:
                    del self.entries[:-self.keep]
            good_end = end
            pos = end
        self.count = len(self._keys)
        if self.keep is not None:
            del self.entries[:-self.keep]
        if self.torn_bytes:
            f.truncate(good_end)
            f.flush()
            os.fsync(f.fileno())

    def close(self):
        if self._file is not None:
            self.sync()
            try:
                fcntl.flock(self._file.fileno(), fcntl.LOCK_UN)
            finally:
                self._file.close()
                self._file = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- data -------------------------------------------------------------------------------
    def __len__(self):
        return self.count

    def __contains__(self, entry):
        return entry.key in self._keys

    def _stamped(self, entry):
        """The entry as stored (subclasses add the receipt time)."""
        return entry

    def append(self, entry, sync: bool = True) -> bool:
        """Persist ``entry`` and keep it; False if it is a duplicate.

        sync=True: write + fsync before returning. sync=False: write to the kernel only
        (safe from a process crash); ``sync()`` makes it durable."""
        if self._file is None:
            raise RuntimeError('store is closed')
        if entry.key in self._keys:
            return False
        entry = self._stamped(entry)
        self._file.write((entry.to_json() + '\n').encode('utf-8'))
        self._file.flush()
        self.unsynced += 1
        if sync:
            self.sync()
        self.entries.append(entry)
        self._keys.add(entry.key)
        self.count += 1
        if self.keep is not None and len(self.entries) > 2 * self.keep:   # amortised trim
            del self.entries[:-self.keep]
        return True

    def sync(self) -> int:
        """fsync every line appended since the last sync; returns how many."""
        n = self.unsynced
        if n and self._file is not None:
            os.fsync(self._file.fileno())
            self.unsynced = 0
        return n

    def archive(self) -> str:
        """Move the current file aside (``<path>.<UTC time>.jsonl``) and start empty.

        Returns the archive path ('' if there was nothing to archive).
        """
        archived = ''
        self.close()
        self.unsynced = 0
        if os.path.exists(self.path) and os.path.getsize(self.path) > 0:
            stem = self.path[:-6] if self.path.endswith('.jsonl') else self.path
            archived = f"{stem}.{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}.jsonl"
            n = 1
            while os.path.exists(archived):
                archived = f"{stem}.{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}.{n}.jsonl"
                n += 1
            os.replace(self.path, archived)
            self._fsync_dir()
        self._open()
        return archived


class InterventionStore(RecordStore):
    """The interventions of one subject, persisted to ``path`` (JSON lines)."""

    record_type = Intervention

    def _stamped(self, entry):
        if entry.received:
            return entry
        return Intervention(entry.stamp_ns, entry.frame, entry.x, entry.y, entry.theta, time.time())

    def states(self) -> np.ndarray:
        """(N, 3) intervention states (x, y, theta) in their obstacles' frames."""
        return np.asarray([e.state for e in self.entries], dtype=float).reshape(-1, 3)
