"""The study's engines behind one interface: Phase II of a subject, and one game.

``runner.run_subject`` asks an ``Engine`` for a subject's Phase II (``phase2``), then for
the subject's games (``games``: a ``SubjectGames`` whose ``play`` runs one game, a
condition's safe set, ``protocol.ConditionSet``, on a world); the records are the same
whichever engine ran. ``engine_named`` chooses one by its name (``StudyOptions.engine``):

* ``core`` (``engine.CoreEngine``): every phase in this process on the package's ROS-free
  modules;
* ``graph`` (``graph_engine.GraphEngine``): every phase through the real node graph.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:               # the CLI's parser imports this module: nothing heavy at import
    from .population import Subject
    from .protocol import ConditionSet, Phase2Result, StudyOptions

ENGINES = ('core', 'graph')


class SubjectGames(Protocol):
    """Phase III of one subject: ``play`` its games, then ``close``."""

    def play(self, chosen: ConditionSet, world_seed: int) -> dict:
        """One game of ``opts.game_seconds`` on the world of ``world_seed``: the world's
        ``stats``, the ``interventions`` log, ``wall``, ``wall_running``, ``resends``,
        ``cpu_s`` and ``cpu_by_process`` (``records.game_counts`` reads it)."""

    def close(self) -> None:
        """Free what the games held (a kept-alive graph)."""


class Engine(Protocol):
    """What the study's runner asks of an engine."""

    name: str                  # 'core' or 'graph': each record's ``engine``
    parallel_subjects: bool    # its subjects may run in parallel (forked) processes or on a cluster
    conditions: tuple          # the conditions it can play

    def phase2(self, i: int, subject: Subject, opts: StudyOptions, with_fp: bool) -> Phase2Result:
        """Phase II of subject ``i``: its scenes, intervention states and fits (with the
        first-passage fit if ``with_fp``)."""

    def games(self, i: int, subject: Subject, world_seed: int, phase2: Phase2Result,
              opts: StudyOptions) -> SubjectGames:
        """Phase III of subject ``i`` (``world_seed``: its own world; ``phase2``: its Phase II)."""


def engine_named(name: str) -> Engine:
    """The engine called ``name`` (one of ``ENGINES``)."""
    if name == 'core':
        from .engine import CoreEngine
        return CoreEngine()
    if name == 'graph':
        from .graph_engine import GraphEngine
        return GraphEngine()
    raise ValueError(f"engine '{name}' is not one of {ENGINES}")


def check_conditions(engine: Engine, conditions) -> None:
    """ValueError unless ``engine`` plays every one of ``conditions``."""
    refused = [c for c in conditions if c not in engine.conditions]
    if refused:
        raise ValueError(f'{", ".join(refused)} does not run on the {engine.name} engine '
                         f'(it plays {", ".join(engine.conditions)})')
