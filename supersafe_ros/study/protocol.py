"""What both engines of the study share: the protocol's constants, a run's options, the
nodes' parameters, the reference sets, the seeds and what Phase II returns.

* The paper's set-up: the true obstacle radius 1.8 m (Standard) and the conservative
  3.6 m, speed 3 m/s, the true turn-rate bound 1 rad/s, horizon 3 s on the 65 x 65 x 42
  grid over [-8, 8]^2 (``reference_sets``); a Phase II scene runs from x = -8 to 2.5.
* ``StudyOptions``: one run's settings (subjects, seed, step, game length, conditions,
  engine, Phase III form: ``same-world`` or the paper's six games of ``design``);
  ``config_params``: a node's parameters from its config file, as the core engine's
  nodes and the graph's renamed first-passage learner take them.
* ``supervisor_seed``: a subject's noise in Phase III; ``sweep_condition``: the learned
  condition whose alpha the observed sweep raises.
* ``Phase2Result``: Phase II of one subject, from either engine's ``phase2``
  (``engines.Engine``).
* ``ConditionSet`` (``condition_set``): the safe set a condition's game runs, as each
  engine's ``play`` takes it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import functools
from pathlib import Path

import numpy as np

from ..learning.data import PHASE2_OFFSETS
from ..learning.levels import learned_alpha
from ..reach.grid import Grid
from ..reach.library import load_or_solve
from ..sim.supervisor_models import DEFAULT_MODEL
from ..team import CONFIG_FILES, config_dir
from .population import Subject

# the paper's world: Standard is the true obstacle radius, Conservative twice it
TRUE_RADIUS = 1.8
CONSERVATIVE_RADIUS = 3.6
SPEED = 3.0
TRUE_OMEGA = 1.0
HORIZON = 3.0
GRID_LO, GRID_HI, GRID_SHAPE = (-8.0, -8.0), (8.0, 8.0), (65, 65, 42)
# a Phase II scene: from x0 at the offset y0, heading +x, to x_end (past the disc at the origin)
PHASE2_X0 = -8.0
PHASE2_X_END = 2.5

# the Phase II graph's second learner (first-passage): its node name and topics
FP_LEARNER = 'learner_fp'
FP_VF_TOPIC = f'/study/{FP_LEARNER}/value_function'
FP_FIT_TOPIC = f'/study/{FP_LEARNER}/fit'
FIT_KEYS = ('omega_max', 'mu', 'sigma', 'alpha', 'log_likelihood')     # a fit's parameters in a record


@dataclass
class StudyOptions:
    """One run of the study (``supersafe study``'s options, ``cli.options_from_args``)."""

    subjects: int = 12
    seed: int = 0
    step: float = 0.2
    rate_factor: float = 0.0
    game_seconds: float = 120.0
    phase2_offsets: tuple = tuple(float(v) for v in PHASE2_OFFSETS)
    conditions: tuple = ('standard', 'learned', 'learned_fp', 'learned_online', 'conservative')
    out_dir: Path = Path('study-out')
    domain_id: int | None = None
    sweep_subjects: int = 2          # observed alpha sweep (extra Learned games) for the first k
    sweep_k: tuple = (0.0, 1.0, 2.0)
    game_timeout: float = 120.0      # wall s per game before giving up on it
    plots: bool = True
    engine: str = 'core'             # core: in this process (study.engine); graph: the node graph
    workers: int = 0                 # core: subjects run in this many processes (0: one per core)
    scheduler: str = ''              # core: a Dask distributed scheduler's address: subjects run on its workers
    supervisor: str = DEFAULT_MODEL  # the simulated supervisors' model (sim.supervisor_models.MODELS)
    phase3: str = 'same-world'       # same-world: each condition once on the subject's world; paper: study.design


PHASE3_FORMS = ('same-world', 'paper')


def config_params(kind: str) -> dict:
    """ros__parameters of a node's config file (for a renamed node, which the file's
    ``/**/<name>`` key no longer matches)."""
    import yaml
    path = config_dir() / CONFIG_FILES[kind]
    try:
        doc = yaml.safe_load(path.read_text()) or {}
    except OSError:
        return {}
    params = next(iter(doc.values()), {}).get('ros__parameters', {})
    # '' (a default such as cache_dir) cannot be given as -p NAME:=
    return {k: v for k, v in params.items() if v != ''}


@functools.lru_cache(maxsize=1)
def reference_sets():
    """The standard (true, radius 1.8) and conservative (radius 3.6) value functions."""
    g = Grid(GRID_LO, GRID_HI, GRID_SHAPE)
    return (load_or_solve(g, SPEED, TRUE_OMEGA, TRUE_RADIUS, HORIZON),
            load_or_solve(g, SPEED, TRUE_OMEGA, CONSERVATIVE_RADIUS, HORIZON))


def supervisor_seed(subject: Subject, world_seed: int) -> int:
    """The subject's noise in Phase III (the same for every condition of the subject)."""
    return (subject.seed + 7919 * world_seed) % (2**31 - 1)


def sweep_condition(conditions):
    """The learned condition whose alpha the observed sweep raises (the paper's first)."""
    return next((c for c in ('learned', 'learned_fp') if c in conditions), None)


@dataclass
class Phase2Result:
    """Phase II of one subject, on either engine: its scenes, intervention states and fits."""

    scenes: list                       # per offset: {'y0', 'intervened', 'state', 'frames'}
    states: np.ndarray                 # (n, 3) intervention states (relative to the obstacle)
    vf_msg: object                     # the paper learner's value-function message, or None
    fit: dict | None
    sim_time: float
    wall: float
    notes: list = field(default_factory=list)
    fp_msg: object = None              # the first-passage learner's value-function message, or None
    fp_fit: dict | None = None         # its fit (estimator, omega_max, mu, sigma, alpha, counts)
    vf: object = None                  # core engine: the paper fit's ValueFunction (no message)
    fp_vf: object = None               # core engine: the first-passage fit's ValueFunction
    fp_records: list = field(default_factory=list)   # core engine: its Phase II encounters
    cpu_s: float | None = None         # core engine: CPU seconds of the phase


@dataclass(frozen=True)
class ConditionSet:
    """The safe set one game of a condition runs, on either engine."""

    condition: str                     # the condition asked for
    ran: str                           # what runs: the condition, or 'standard' (a learned one without a fit)
    value_function: object
    alpha: float | None                # a learned set's level (mu + k sigma); None: the set's own level
    fit: dict | None = None            # a learned set's fit
    alpha_offset: float = 0.0          # k

    @property
    def learns_during_game(self) -> bool:
        """``learned_online`` at alpha = mu: the set keeps learning from the game (study.online)."""
        return self.ran == 'learned_online' and self.alpha_offset == 0.0


def condition_set(condition: str, learned: dict, alpha_offset: float = 0.0) -> ConditionSet:
    """The set of one condition; ``learned``: condition -> (value function or None, fit or
    None) of the subject's learned sets. Conservative is the radius-3.6 set at level 0; a
    learned condition with a fit its set at alpha = mu + ``alpha_offset`` sigma; a learned
    condition without a fit runs the Standard set (and is counted so)."""
    standard_vf, conservative_vf = reference_sets()
    if condition == 'conservative':
        return ConditionSet(condition, 'conservative', conservative_vf, None, alpha_offset=alpha_offset)
    if condition in learned and learned[condition][0] is not None:
        vf, fit = learned[condition][:2]
        return ConditionSet(condition, condition, vf, learned_alpha(fit, alpha_offset), fit, alpha_offset)
    return ConditionSet(condition, 'standard', standard_vf, None, alpha_offset=alpha_offset)
