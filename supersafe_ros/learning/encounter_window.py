"""The encounters an online first-passage fit uses: the newest ones that the library can explain.

An online learner evaluates each finished encounter under every library entry once, when
it arrives (``estimators.encounter_intervals``), and keeps the newest ``size`` of them.
One encounter that no admissible entry can explain (``estimators.unexplained_encounters``:
an intervention after the robot's closest approach, such as a hasty click on an obstacle
the robot has just passed) would make every log-likelihood -inf for as long as it stayed
in the window, and no fit could be made again. So:

* an encounter no admissible entry explains on its own is set aside when it arrives;
* when each remaining encounter is explained by some entry but no entry explains them
  all, the fewest that make the fit possible are set aside
  (``estimators.conflicting_encounters``).

Each is reported through ``set_aside(reason, details)`` (the caller logs and counts it);
its record stays wherever the caller stored it. ROS-free.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .encounters import EncounterRecord
from .estimators import (EncounterIntervals, concat_intervals, conflicting_encounters, encounter_intervals,
                         select_encounters, unexplained_encounters)

ALONE = 'no library entry explains its encounter'
JOINTLY = 'no library entry explains its encounter with the others'


def describe(record: EncounterRecord) -> str:
    """One line naming an encounter and why it cannot be explained."""
    x, y, theta = record.frames[-1]
    how = 'intervened' if record.intervened else 'ended'
    return (f'{record.robot} at obstacle_{record.obstacle}, {how} at t={record.t[-1]:.3f} s in state '
            f'({x:.2f}, {y:.2f}, {theta:.2f}) after {len(record.frames) - 1} frames, one of them at or '
            'below its value')


class EncounterWindow:
    """The newest ``size`` explainable encounters as intervals under every entry (module doc)."""

    def __init__(self, entries, admissible, size: int, set_aside: Callable[[str, str], None]):
        self.entries = list(entries)
        self.admissible = np.asarray(admissible, dtype=bool)
        self.size = int(size)
        self.set_aside = set_aside
        self.intervals: EncounterIntervals | None = None
        self.records: list[EncounterRecord] = []       # one per column of ``intervals``

    def add(self, records) -> None:
        """Evaluate ``records`` (finished encounters) and keep the explainable ones."""
        records = list(records)
        if not records:
            return
        iv = encounter_intervals(self.entries, [r.to_encounter() for r in records])
        alone = unexplained_encounters(iv, self.admissible)
        for k in np.flatnonzero(alone):
            self.set_aside(ALONE, describe(records[k]))
        if alone.all():
            return
        iv = select_encounters(iv, ~alone)
        kept = [r for r, a in zip(records, alone) if not a]
        iv = iv if self.intervals is None else concat_intervals([self.intervals, iv])
        self.records = (self.records + kept)[-self.size:]
        n = iv.lo.shape[1]
        self.intervals = iv if n <= self.size else select_encounters(iv, np.arange(n - self.size, n))
        jointly = conflicting_encounters(self.intervals, self.admissible)
        if jointly.any():
            for k in np.flatnonzero(jointly):
                self.set_aside(JOINTLY, describe(self.records[k]))
            self.intervals = select_encounters(self.intervals, ~jointly)
            self.records = [r for r, j in zip(self.records, jointly) if not j]
            if not self.records:
                self.intervals = None

    def __len__(self) -> int:
        return len(self.records)
