"""What a decision derives from a robot's detections array and keeps for the next decisions while
that array is the same (never an input): a robot's ``RobotFilter.derived`` caches, ``'clusters'``
(``cluster_rows``: the clusters' frames), ``'near_index'`` and ``'near_pick'`` (``nearby``: the
detections' index, the last pick within reach).

A decision reads them and writes none: ``Derived`` reads a robot's cache through the decision's
own new values first, and keeps what it fills as updates; ``sent.record_decisions`` applies them
with what was sent (``apply``), so the recorder is the one writer into a filter, and a decision
not sent (a lockstepped answer held) leaves its filters as they were.
"""
from __future__ import annotations


class Derived:
    """One decision's view of its robots' caches: ``get(f, key)``, ``put(f, key, value)``; ``apply()``
    writes what was put into the filters (``sent.record_decisions``)."""

    __slots__ = ('_new',)

    def __init__(self):
        self._new = {}      # id(filter) -> (filter, {key: value})

    def get(self, f, key):
        """Robot ``f``'s ``key``: this decision's value, else the one its filter keeps (None: none)."""
        mine = self._new.get(id(f))
        if mine is not None and key in mine[1]:
            return mine[1][key]
        return f.derived.get(key)

    def put(self, f, key, value):
        """Robot ``f``'s ``key`` is ``value`` from now on (in the filter once applied); ``value``."""
        self._new.setdefault(id(f), (f, {}))[1][key] = value
        return value

    def apply(self) -> None:
        """Every value put, into its filter's ``derived`` (once)."""
        for f, values in self._new.values():
            f.derived.update(values)
        self._new = {}

    def __len__(self):
        return sum(len(values) for _, values in self._new.values())
