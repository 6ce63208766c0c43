"""What happened in a game where the prediction is made: override onsets and interventions.

The paper's prediction (Table 1) assumes the robots act exactly at their set's level and
that the supervisor's Phase III interventions are distributed as in Phase II (head-on
approaches). ``GameTrace`` watches a core-engine game (``sim.team_loop.TeamLoop``'s
observer) and records what decides whether that holds:

* **onsets**: each time a robot's filter starts overriding (pass -> override or fail-safe),
  V_set - alpha there, for the detected obstacle with the smallest V_set (the one the
  override is for; a single disc's value: inside a cluster the union's value is lower), and
  the bearing of that obstacle from the robot's heading;
* **interventions**: each supervisor intervention with its state relative to the obstacle,
  whether it was a false positive, V_set - alpha there (> 0: the filter had not acted
  there, the case the prediction counts), the bearing, and whether this robot's filter had
  already overridden for this obstacle in the same approach (the supervisor's encounter,
  ``sim.watcher``): an FP after an override comes from a robot skirting the obstacle after
  its avoid turn, a state Phase II's straight approaches never show.

Bearing = the angle between the robot's heading and the direction to the obstacle's centre,
in degrees: head-on below ``HEAD_ON``, tangential from ``TANGENTIAL``, oblique between.
"""
from __future__ import annotations

import math

import numpy as np

HEAD_ON = 20.0          # deg
TANGENTIAL = 60.0       # deg
BEARINGS = ('head-on', 'oblique', 'tangential')


def bearing_deg(rel_state) -> float:
    """|angle| between the heading and the direction to the obstacle (at the origin) [deg]."""
    x, y, th = (float(v) for v in rel_state)
    d = math.atan2(-y, -x) - th
    return abs(math.degrees(math.atan2(math.sin(d), math.cos(d))))


def bearing_class(deg: float) -> str:
    return 'head-on' if deg < HEAD_ON else 'tangential' if deg >= TANGENTIAL else 'oblique'


class GameTrace:
    """The observer of one ``TeamLoop`` game (see the module doc); ``to_dict`` for the record."""

    def __init__(self):
        self.onsets = {'v_minus_alpha': [], 'bearing': [], 'time': []}
        self.interventions = []
        self._acting: dict = {}          # robot -> its filter overrode last step
        self._overrode: dict = {}        # (robot, obstacle) -> the watcher's approach number

    def step(self, loop, t: float, name: str, state, ids, xy, action: str) -> None:
        acting = action != 'pass'
        was = self._acting.get(name, False)
        self._acting[name] = acting
        if not acting or len(ids) == 0:
            return
        rel = np.column_stack([state[0] - xy[:, 0], state[1] - xy[:, 1], np.full(len(ids), state[2])])
        values = loop.safe_set.vf.value(rel)
        k = int(np.argmin(values))
        oid = int(ids[k])
        if loop.watcher is not None:
            self._overrode[(name, oid)] = loop.watcher.encounters.get((name, oid), 0)
        if not was:
            self.onsets['v_minus_alpha'].append(round(float(values[k] - loop.safe_set.alpha), 4))
            self.onsets['bearing'].append(round(bearing_deg(rel[k]), 2))
            self.onsets['time'].append(round(float(t), 3))

    def intervention(self, loop, decision, record) -> None:
        rel = np.asarray(decision.rel_state, dtype=float)
        key = (decision.robot, int(decision.obstacle_id))
        approach = loop.watcher.encounters.get(key, 0) if loop.watcher is not None else None
        self.interventions.append({
            'time': round(float(decision.time), 3), 'robot': decision.robot,
            'obstacle': int(decision.obstacle_id), 'false_positive': bool(record.false_positive),
            'state': [round(float(v), 4) for v in rel],
            'v_minus_alpha': round(float(loop.safe_set.vf.value(rel[None])[0] - loop.safe_set.alpha), 4),
            'bearing': round(bearing_deg(rel), 2),
            'after_override': key in self._overrode and self._overrode[key] == approach})

    def to_dict(self) -> dict:
        return {'onsets': self.onsets, 'interventions': self.interventions}
