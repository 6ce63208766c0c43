"""The study through the real node graph (``--engine graph``): the through-the-graph validation.

``GraphEngine`` serves the study's interface (``engines.Engine``) with the graph modules:

* Phase II: ``graph_phase2.run_phase2``, a light graph per subject (clock, world, one
  robot, supervisor, the learners; the study's ``conductor.Phase2Conductor`` in this
  process), logs in ``<out>/logs/sNN-phase2``;
* Phase III: ``GraphGames``, one kept-alive team graph per subject (``games.GameGraph``,
  started on the subject's world, reset between games), logs in ``<out>/logs/sNN-phase3``;
  a condition's set reaches the filters as a latched value-function message
  (``games.set_message``), the subject's supervisor as the supervisor node's parameters
  (``supervisor_params``).

Every graph runs in the ROS domain ``opts.domain_id`` (default: this process's), so the
subjects run one after the other. ``learned_online`` does not run here (its learner would
have to run in the Phase III graph).
"""
from __future__ import annotations

from pathlib import Path

from ..sim.supervisor_models import DEFAULT_MODEL
from ..team import team_env
from .analysis import CONDITIONS
from .games import GameGraph, set_message
from .graph_phase2 import run_phase2
from .population import Subject
from .protocol import ConditionSet, Phase2Result, StudyOptions, supervisor_seed

FIRST_GAME_S = 120.0      # wall seconds the first game of a graph may take beyond opts.game_timeout (start-up)


def supervisor_params(subject: Subject, model: str = DEFAULT_MODEL) -> dict:
    """The supervisor node's parameters of a subject (the games' graph)."""
    return {'w_max': subject.omega_max, 'mu': subject.mu, 'sigma': subject.sigma, 'model': model}


def domain_id(opts: StudyOptions) -> int:
    """The ROS domain of the study's graphs: ``opts.domain_id``, else this process's."""
    return opts.domain_id if opts.domain_id is not None else int(team_env()['ROS_DOMAIN_ID'])


def log_dir(opts: StudyOptions, i: int, phase: str) -> Path:
    return Path(opts.out_dir) / 'logs' / f's{i:02d}-{phase}'


class GraphEngine:
    """The study's engine through the node graph (``engines.Engine``)."""

    name = 'graph'
    parallel_subjects = False
    conditions = tuple(c for c in CONDITIONS if c != 'learned_online')

    def phase2(self, i: int, subject: Subject, opts: StudyOptions, with_fp: bool) -> Phase2Result:
        return run_phase2(subject, opts, domain_id(opts), log_dir(opts, i, 'phase2'), with_fp)

    def games(self, i: int, subject: Subject, world_seed: int, phase2: Phase2Result,
              opts: StudyOptions) -> 'GraphGames':
        return GraphGames(subject, world_seed, opts, team_env(domain_id(opts)), log_dir(opts, i, 'phase3'))


class GraphGames:
    """Phase III of one subject through its kept-alive node graph (``games.GameGraph``)."""

    def __init__(self, subject: Subject, world_seed: int, opts: StudyOptions, env: dict, logs: Path):
        self.subject, self.opts = subject, opts
        self.graph = GameGraph(env, world_seed, supervisor_params(subject, opts.supervisor), opts.step,
                               opts.rate_factor, logs)

    def play(self, chosen: ConditionSet, world_seed: int) -> dict:
        """The result dict of ``GameGraph.play``."""
        timeout = self.opts.game_timeout + (FIRST_GAME_S if self.graph.games == 0 else 0.0)
        return self.graph.play(set_message(chosen), world_seed, supervisor_seed(self.subject, world_seed),
                               self.opts.game_seconds, timeout)

    def close(self):
        self.graph.close()
