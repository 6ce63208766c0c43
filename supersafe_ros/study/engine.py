"""The study in one process (``--engine core``, the default): Phase II, fits, Phase III games.

Why: through the node graph each lockstep step costs ~30 ms of CPU over eight rclpy
processes, so 12 subjects take far longer than issue 10's goals on two cores. The
experiment itself is the package's ROS-free core: the same modules, parameters (the
config/*.yaml files the nodes load, with the study's overrides) and order of events as
the graph, without the transport. ``--engine graph`` still runs every game through the
real nodes (the through-the-graph validation); ``bench/bench_study.py --compare`` puts
the two side by side.

* Phase II (``CoreStudy.phase2``): the scenes of ``conductor.Phase2Conductor`` (one robot
  at (-8, y0, 0) with u = 0 towards one disc at the origin, a new obstacle id per scene,
  ids from 0 as the graph's world gives them) as ``learning.phase2_stream.phase2_events``
  generates them, judged by the supervisor node's own rule (``sim.watcher.Watcher``, the
  subject's w_max, mu, sigma and seed, and the study's supervisor model). The two learners fit as the learner node does,
  once on all the data: ``paper`` (``fit_paper_values`` on the intervention states) and
  ``first-passage`` (encounters from ``EncounterBuilder`` fed the poses, obstacle sets and
  interventions, then ``fit_first_passage_intervals``), both with the conservative prior,
  alpha = mu, min_interventions 3, and published only if admissible
  (``check_learned_set`` against the standard set).
* Phase III (``CoreStudy.play``): ``sim.team_loop.TeamLoop`` with the team's two robots,
  the world seed of the subject, the subject's supervisor (seed ``supervisor_seed``, the
  study's model ``opts.supervisor``: ``sim.supervisor_models``) and
  the condition's safe set (``filter_safe_set``), checked for admissibility as each filter
  checks a received set.
* ``CoreEngine``: the two behind the study's interface (``engines.Engine``); its subjects
  may run in parallel processes.

Nothing here imports rclpy or ROS messages.
"""
from __future__ import annotations

from dataclasses import replace
import functools
import os
import time

import numpy as np

from ..filter.admissibility import check_learned_set
from ..filter import FilterConfig, SafeSet
from ..filter.clusters.store import settings_of
from ..learning.encounters import EncounterBuilder
from ..learning.phase2_stream import feed, phase2_events
from ..learning.estimators import (admissible_mask, encounter_intervals, fit_first_passage_intervals,
                                   fit_paper_values)
from ..reach.grid import Grid
from ..reach.library import LibrarySpec, load_or_build_library, load_or_solve
from ..sim.team_loop import RobotParams, TeamLoop, process_cluster_store
from ..sim.supervisor_models import DEFAULT_MODEL, AttentiveParams
from ..sim.watcher import Watcher
from ..sim.world import WorldConfig
from ..team import robot_names, start_poses
from .analysis import CONDITIONS
from .game_trace import GameTrace
from .online import OnlineLearner
from .protocol import (FP_LEARNER, PHASE2_X0, PHASE2_X_END, SPEED, ConditionSet, Phase2Result,
                       condition_set, config_params, reference_sets, supervisor_seed)

N_ROBOTS = 2                     # the team of study.games.GameGraph
MIN_INTERVENTIONS = 3            # learner.yaml min_interventions


# -- parameters: the nodes' config files, with the overrides the study's graphs set ---------
@functools.lru_cache(maxsize=None)
def node_params(kind: str) -> dict:
    return dict(config_params(kind))


def world_config() -> WorldConfig:
    p = node_params('world')
    fields = WorldConfig.__dataclass_fields__
    return WorldConfig(**{k: p[k] for k in fields if k in p})


def robot_params() -> RobotParams:
    r, pl = node_params('dubins_robot'), node_params('planner')
    return RobotParams(speed=r['speed'], w_max=r['w_max'], sensor_range=r['sensor_range'],
                       miss_probability=r['miss_probability'], command_timeout=r['command_timeout'],
                       timeout_behavior=r['timeout_behavior'], planner_gain=pl['gain'],
                       planner_w_max=pl['w_max'])


def filter_config(step: float) -> FilterConfig:
    """safety_filter.yaml with the team's lockstep overrides (team.team_layout): the
    command holds one step, so the look-ahead is max(the step, the config's lookahead); the
    robots are constant-speed Dubins robots (fail_safe_command 'stop_turn')."""
    p = node_params('safety_filter')
    keys = ('speed', 'omega_max', 'radius', 'pose_timeout', 'detections_timeout', 'hold_timeout',
            'cmd_timeout', 'clear_margin', 'lookahead')
    return FilterConfig(**{k: float(p[k]) for k in keys}, cluster_alpha=float(p['standard_alpha']),
                        control_period=float(step), fail_safe_command='stop_turn')


def supervisor_vf(w_max: float):
    """V_S of a supervisor believing ``w_max`` (supervisor_node.supervisor_value_function)."""
    p = node_params('supervisor')
    half, n, nth = p['grid_half_width'], int(p['grid_nxy']), int(p['grid_ntheta'])
    grid = Grid((-half, -half), (half, half), (n, n, nth))
    return load_or_solve(grid, p['speed'], float(w_max), p['radius'], p['horizon'])


def attentive_params() -> AttentiveParams:
    """The attentive model's constants as the supervisor node loads them (supervisor.yaml)."""
    p = node_params('supervisor')
    return AttentiveParams(**{k: float(p[k]) for k in AttentiveParams.__dataclass_fields__ if k in p})


def make_watcher(subject, seed: int, model: str = DEFAULT_MODEL) -> Watcher:
    """The subject's supervisor as the node runs it (``model``: sim.supervisor_models)."""
    return Watcher(supervisor_vf(subject.omega_max), mu=subject.mu, sigma=subject.sigma, seed=int(seed),
                   pending_timeout=node_params('supervisor')['pending_timeout'], model=model,
                   attentive=attentive_params())


# -- the learners ---------------------------------------------------------------------------
class Learners:
    """The learner node's library, prior and publication rule (learner.yaml)."""

    def __init__(self):
        p = node_params('learner')
        horizon = p['library_horizon']
        spec = LibrarySpec(speed=p['library_speed'], radius=p['library_radius'],
                           omegas=tuple(sorted(float(w) for w in p['library_omegas'])),
                           horizon=horizon if horizon > 0 else None, lo=tuple(p['library_lo']),
                           hi=tuple(p['library_hi']), shape=tuple(int(n) for n in p['library_shape']))
        self.entries = list(load_or_build_library(spec).entries)
        self.true_vf = next(e for e in self.entries
                            if abs(float(e.meta['omega_max']) - float(p['true_omega_max'])) < 1e-9)
        self.admissible = (admissible_mask(self.entries, self.true_vf) if p['conservative_prior']
                           else np.ones(len(self.entries), dtype=bool))
        self.alpha_k = float(p['alpha_k'])
        self.standard_alpha = float(p['standard_alpha'])
        self.lo, self.hi = tuple(p['library_lo']), tuple(p['library_hi'])
        self.builder_args = dict(speed=p['library_speed'], jump_distance=p['jump_distance'],
                                 grace=p['intervention_grace'], match_tolerance=p['match_tolerance'],
                                 pending_timeout=p['pending_timeout'], max_frames=int(p['max_encounter_frames']),
                                 removal_delay=p['removal_delay'], reorder=p['reorder_window'])

    def publish(self, fit, **extra):
        """(value function as published, or None if the fit is not admissible)."""
        if not check_learned_set(self.true_vf, self.standard_alpha, fit.value_function, fit.alpha).ok:
            return None
        meta = {k: v for k, v in fit.to_dict().items() if k not in ('candidates', 'notes')}
        meta.update(extra, source='learned', alpha_k=self.alpha_k)
        return replace(fit.value_function, meta={**fit.value_function.meta, **meta})

    def paper(self, states):
        """(value function, fit dict) of the paper's estimator, or (None, None)."""
        if len(states) < MIN_INTERVENTIONS:
            return None, None
        values = np.stack([e.value(states) for e in self.entries])
        fit = fit_paper_values(self.entries, values, alpha_k=self.alpha_k, admissible=self.admissible)
        vf = self.publish(fit)
        if vf is None:
            return None, None
        d = fit.to_dict()
        return vf, {k: d.get(k) for k in ('omega_max', 'mu', 'sigma', 'alpha', 'log_likelihood',
                                          'estimator', 'interventions')}

    def first_passage(self, events):
        """(value function, fit dict, encounter records) of the first-passage estimator on the
        encounters the learner node builds from the same event stream; (None, None, records)
        without an admissible fit."""
        builder = EncounterBuilder(self.lo, self.hi, **self.builder_args)
        feed(builder, events)
        builder.finish_all()
        records = builder.pop_finished()
        encounters = [r.to_encounter() for r in records]
        n_int = sum(1 for e in encounters if e.intervened)
        if n_int < MIN_INTERVENTIONS:
            return None, None, records
        iv = encounter_intervals(self.entries, encounters)
        fit = fit_first_passage_intervals(self.entries, iv, alpha_k=self.alpha_k, admissible=self.admissible)
        vf = self.publish(fit)
        if vf is None:
            return None, None, records
        d = fit.to_dict()
        out = {k: d.get(k) for k in ('omega_max', 'mu', 'sigma', 'alpha', 'log_likelihood')}
        out.update(estimator=d['estimator'], interventions=int(d['interventions']),
                   encounters=int(d.get('encounters') or 0), index=d['index'],
                   stored_encounters=len(records),
                   unmatched_interventions=int(builder.counts['unmatched_interventions']))
        return vf, out, records


@functools.lru_cache(maxsize=1)
def learners() -> Learners:
    return Learners()


# -- Phase II -------------------------------------------------------------------------------
def scenes_from_events(events) -> list:
    """The conductor's scene records from a ``phase2_events`` stream: one per obstacle set
    with a disc, its poses as frames, ended by the intervention on it or by the last pose."""
    scenes, cur = [], None
    for ev in events:
        if ev[0] == 'obstacles':
            if cur is not None:
                scenes.append(cur)
                cur = None
            if len(ev[2]):
                cur = {'y0': None, 'intervened': False, 'state': None, 'obstacle': int(ev[2][0]),
                       'start_time': None, 'end_time': None, 'frames': []}
        elif ev[0] == 'pose' and cur is not None:
            x, y, th = (float(v) for v in ev[3])
            if cur['start_time'] is None:
                cur['start_time'], cur['y0'] = ev[2], y
            cur['frames'].append((x, y, th))
            cur['end_time'] = ev[2]
        elif ev[0] == 'intervention' and cur is not None and ev[1] == cur['obstacle']:
            cur['intervened'], cur['state'] = True, [float(v) for v in ev[3]]
            cur['frames'].append(tuple(cur['state']))
    if cur is not None:
        scenes.append(cur)
    return scenes


class CoreStudy:
    """The study's phases in this process, each on what it is given: a subject's Phase II,
    a condition's filter set, one game (``CoreEngine`` serves them to the study's runner)."""

    def phase2(self, subject, opts, with_fp: bool = True) -> Phase2Result:
        t0, cpu0 = time.monotonic(), time.process_time()
        watcher = make_watcher(subject, subject.seed, opts.supervisor)
        # the graph's world numbers obstacles from 0: the first scene's disc is obstacle 0,
        # and the supervisor's draws are keyed by obstacle id
        events = list(phase2_events(watcher, [float(v) for v in opts.phase2_offsets], speed=SPEED,
                                    dt=float(opts.step), x0=PHASE2_X0, x_end=PHASE2_X_END,
                                    first_obstacle=0))
        scenes = scenes_from_events(events)
        states = np.array([s['state'] for s in scenes if s['intervened']], dtype=float).reshape(-1, 3)
        lr = learners()
        vf, fit = lr.paper(states)
        fp_vf, fp_fit, fp_records = lr.first_passage(events) if with_fp else (None, None, [])
        notes = []
        if with_fp and fp_fit is None and len(states) >= MIN_INTERVENTIONS:
            notes.append(f'the {FP_LEARNER} fit was not admissible')
        span = scenes[-1]['end_time'] - scenes[0]['start_time'] if scenes else 0.0
        res = Phase2Result(scenes, states, None, fit, span, time.monotonic() - t0, notes, None, fp_fit)
        res.vf, res.fp_vf, res.fp_records = vf, fp_vf, fp_records
        res.cpu_s = time.process_time() - cpu0
        return res

    # -- Phase III --------------------------------------------------------------------------
    def safe_set(self, condition: str, learned: dict, k: float = 0.0):
        """(SafeSet, alpha or None, what ran) of one condition (``protocol.condition_set``)."""
        chosen = condition_set(condition, learned, k)
        return filter_safe_set(chosen), chosen.alpha, chosen.ran

    def play(self, subject, world_seed: int, safe_set: SafeSet, opts, filtered: bool = True,
             online_records=None) -> dict:
        """One game: the result dict of ``GameGraph.play`` (stats, interventions, wall, cpu).
        ``online_records`` (the Phase II encounters): the set keeps learning during the game
        (``online.OnlineLearner``, the ``learned_online`` condition)."""
        t0, cpu0 = time.monotonic(), time.process_time()
        names = robot_names(N_ROBOTS)
        starts = dict(zip(names, start_poses(N_ROBOTS)))
        # team_layout(seed=world_seed): robot i's sensor seed is seed * 1000 + i + 1
        seeds = {n: world_seed * 1000 + i + 1 for i, n in enumerate(names)}
        watcher = make_watcher(subject, supervisor_seed(subject, world_seed), opts.supervisor)
        cfg = filter_config(opts.step)
        trace = GameTrace()
        online = OnlineLearner(learners(), online_records, safe_set) if online_records is not None else None
        loop = TeamLoop(world_config(), world_seed, starts, seeds, robot_params(), cfg, safe_set, watcher,
                        opts.step, filtered=filtered, clusters=process_cluster_store(settings_of(cfg)),
                        observer=trace, learner=online)
        loop.run(opts.game_seconds)
        stats = loop.stats()
        stats['sim_time'] = f'{opts.game_seconds:.3f}'
        log = [{'obstacle': rec.obstacle_id, 'robot': rec.robot or 'unknown',
                'false_positive': rec.false_positive, 'time': rec.time}
               for _, rec in loop.interventions]
        cpu = time.process_time() - cpu0
        wall = time.monotonic() - t0
        return {'stats': stats, 'interventions': log, 'wall': wall, 'wall_running': wall,
                'resends': 0, 'cpu_s': cpu, 'cpu_by_process': {f'study ({os.getpid()})': round(cpu, 2)},
                'decisions': dict(loop.decisions), 'steps': loop.steps, 'trace': trace.to_dict(),
                'online': online.history if online is not None else None}


def filter_safe_set(chosen: ConditionSet) -> SafeSet:
    """The filters' SafeSet of a condition's set: Standard at the filters' standard level,
    any other set at its level (None: 0) after the admissibility check each filter makes on
    a received set. A set the filters would reject is an error, as it stops the graph's
    game."""
    std_alpha = float(node_params('safety_filter')['standard_alpha'])
    if chosen.ran == 'standard':
        return SafeSet(chosen.value_function, std_alpha, 'standard')
    level = 0.0 if chosen.alpha is None else chosen.alpha
    standard_vf, _ = reference_sets()
    verdict = check_learned_set(standard_vf, std_alpha, chosen.value_function, level)
    if not verdict.ok:
        raise RuntimeError(f'the filters would reject the {chosen.condition} set: {verdict.reason}')
    return SafeSet(chosen.value_function, level, 'learned')


class CoreEngine:
    """The study's engine in this process (``engines.Engine``): ``CoreStudy``'s Phase II and
    games. Each subject's record depends on its seeds only and no ROS runs here, so its
    subjects may run in parallel (forked) processes or on a cluster."""

    name = 'core'
    parallel_subjects = True
    conditions = CONDITIONS

    def __init__(self):
        self.study = CoreStudy()

    def phase2(self, i: int, subject, opts, with_fp: bool) -> Phase2Result:
        return self.study.phase2(subject, opts, with_fp=with_fp)

    def games(self, i: int, subject, world_seed: int, phase2: Phase2Result, opts) -> 'CoreGames':
        return CoreGames(self.study, subject, phase2, opts)


class CoreGames:
    """Phase III of one subject in this process; ``phase2``: its Phase II (the encounters a
    set that learns during its game starts from)."""

    def __init__(self, study: CoreStudy, subject, phase2: Phase2Result, opts):
        self.study, self.subject, self.phase2, self.opts = study, subject, phase2, opts

    def play(self, chosen: ConditionSet, world_seed: int) -> dict:
        online = self.phase2.fp_records if chosen.learns_during_game else None
        return self.study.play(self.subject, world_seed, filter_safe_set(chosen), self.opts,
                               online_records=online)

    def close(self):
        pass
