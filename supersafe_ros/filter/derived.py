"""What a decision derives from a robot's detections array and keeps for the next decisions while
that array is the same (never an input): a robot's ``RobotFilter.derived`` caches, ``'clusters'``
(``cluster_rows``: the clusters' frames), ``'near_index'`` and ``'near_pick'`` (``nearby``: the
detections' index, the last pick within reach).

They are kept with the detections (their input record's ``derived``, read through
``RobotColumns.detection_inputs``). A decision reads them and writes none: ``Derived``, the
decision's updates, reads a row's cache through the decision's own new values first and keeps
what it fills; ``sent.record_decisions`` applies them with what was sent (``apply``), so the
recorder is the one writer into a filter, and a decision not sent (a lockstepped answer held)
leaves its filters as they were.
"""
from __future__ import annotations

_NONE = {}


class Derived:
    """One decision's updates to its robots' caches, by row of its columns (``gather.RobotColumns``):
    ``get(row, key)``, ``put(row, key, value)``; ``apply(filters)`` writes what was put into the
    filters (``sent.record_decisions``). ``inputs``: per row its detections' input record (their
    ``derived``: the caches kept so far); ``robot_index``: per row its robot's index in the filters
    (None: none, the updates kept by no one)."""

    __slots__ = ('_inputs', '_robot', '_new')

    def __init__(self, inputs=None, robot_index=None):
        self._inputs, self._robot = inputs, robot_index
        self._new = {}      # row -> {key: value}

    def get(self, row, key):
        """Row ``row``'s ``key``: this decision's value, else the one its robot keeps (None: none)."""
        mine = self._new.get(row)
        if mine is not None and key in mine:
            return mine[key]
        return (self._inputs[row].derived if self._inputs is not None else _NONE).get(key)

    def put(self, row, key, value):
        """Row ``row``'s ``key`` is ``value`` from now on (in its filter once applied); ``value``."""
        self._new.setdefault(row, {})[key] = value
        return value

    def apply(self, filters) -> None:
        """Every value put, into its robot's filter's ``derived`` (once): ``filters`` those decided."""
        robot = self._robot
        if robot is not None:
            for row, values in self._new.items():
                filters[int(robot[row])].derived.update(values)
        self._new = {}

    def __len__(self):
        return sum(map(len, self._new.values()))
