"""The study: Phase II, the fits, Phase III, per subject, on one of two engines.

``StudyOptions.engine``: ``core`` (the default) runs the experiment below in this process
with the package's ROS-free modules (``study.engine``: the same parameters and order of
events, deterministic for a seed, ~100x less CPU); ``graph`` runs it through the real
node graph as described here (the through-the-graph validation). Both give the same
records, so the analysis, plots, JSON and power do not care which ran.

Per subject through the graph (a simulated supervisor from ``population.draw_subjects``):

1. Phase II (``run_phase2``): a light graph — sim clock, world (``respawn`` false),
   one robot, supervisor (the subject's w_max, mu, sigma, seed), learner — and the
   study's conductor node (``conductor.Phase2Conductor``) in this process, which
   sets the scene for every offset of the 0.25 m ladder (``/world/set_obstacles``:
   one disc at the origin; ``robot_0/initialpose``: (-8, y0, 0)) and drives the robot
   with u = 0 (it answers every pose with a zero Twist on cmd_vel, which is also the
   lockstep acknowledgement). A scene ends at the supervisor's intervention or when
   the robot has passed the obstacle.
2. Fits (``learned_sets``): both from learner nodes in the Phase II graph. Learned = the
   learner's fit from the interventions it received (``estimator: paper``, alpha = mu);
   Learned FP = a second learner (``learner_fp``, ``estimator: first-passage``, robots
   [robot_0], its own store and topics ``/study/learner_fp/...``), which builds the
   encounters itself from ``robot_0/pose``, ``/obstacle_markers`` and ``/interventions``
   (every scene, intervened or not). ``first_passage_fit`` fits the same estimator
   offline from the conductor's recorded scenes; the runner keeps it as a cross-check
   (``phase2.offline_first_passage`` in the JSON).
3. Phase III (``study.games.GameGraph``): one kept-alive team graph per subject (world,
   2 x (robot, planner, filter), supervisor; no learner), one game per condition and
   alpha-sweep game, reset between games; the condition's safe set reaches the filters
   as a latched value-function message. Same world seed for every condition of a subject.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import functools
import json
import math
import os
from pathlib import Path
import shutil
import sys
import time

import numpy as np

from ..team import Team, team_env, team_layout, node_argv
from ..learning.data import PHASE2_OFFSETS, Encounter
from ..learning.levels import learned_alpha
from .population import Subject

TRUE_RADIUS = 1.8
CONSERVATIVE_RADIUS = 3.6
SPEED = 3.0
TRUE_OMEGA = 1.0
HORIZON = 3.0
GRID_LO, GRID_HI, GRID_SHAPE = (-8.0, -8.0), (8.0, 8.0), (65, 65, 42)
PHASE2_X0 = -8.0
PHASE2_X_END = 2.5


@dataclass
class StudyOptions:
    subjects: int = 12
    seed: int = 0
    step: float = 0.2
    rate_factor: float = 0.0
    game_seconds: float = 120.0
    phase2_offsets: tuple = tuple(float(v) for v in PHASE2_OFFSETS)
    conditions: tuple = ('standard', 'learned', 'learned_fp', 'conservative')
    out_dir: Path = Path('study-out')
    domain_id: int | None = None
    sweep_subjects: int = 2          # observed alpha sweep (extra Learned games) for the first k
    sweep_k: tuple = (0.0, 1.0, 2.0)
    game_timeout: float = 120.0      # wall s per game before giving up on it
    plots: bool = True
    engine: str = 'core'             # core: in this process (study.engine); graph: the node graph
    workers: int = 0                 # core: subjects run in this many processes (0: one per core)


ENGINES = ('core', 'graph')


class Progress:
    """One line per phase: subject i/N, phase, sim time, wall time."""

    def __init__(self, n: int, out=sys.stdout):
        self.n, self.out, self.t0 = n, out, time.monotonic()

    def line(self, i: int, phase: str, sim_time=None, extra: str = ''):
        sim = f'sim {sim_time:7.1f} s' if sim_time is not None else ' ' * 13
        print(f'[subject {i + 1:2d}/{self.n}] {phase:<22s} {sim}  wall {time.monotonic() - self.t0:7.1f} s'
              f'{"  " + extra if extra else ""}', file=self.out, flush=True)


# -- graphs -----------------------------------------------------------------------------
# the Phase II graph's second learner (first-passage): its node name and topics
FP_LEARNER = 'learner_fp'
FP_VF_TOPIC = f'/study/{FP_LEARNER}/value_function'
FP_FIT_TOPIC = f'/study/{FP_LEARNER}/fit'


def _config_params(kind: str) -> dict:
    """ros__parameters of a node's config file (for a renamed node, which the file's
    ``/**/<name>`` key no longer matches)."""
    import yaml
    from ..team import CONFIG_FILES, config_dir
    path = config_dir() / CONFIG_FILES[kind]
    try:
        doc = yaml.safe_load(path.read_text()) or {}
    except OSError:
        return {}
    params = next(iter(doc.values()), {}).get('ros__parameters', {})
    # '' (a default such as cache_dir) cannot be given as -p NAME:=
    return {k: v for k, v in params.items() if v != ''}


def fp_learner_argv(spec, fp_store: Path) -> list:
    """The first-passage learner beside the paper's: the layout's learner spec renamed
    (node ``learner_fp``, so ``~/reset`` is /learner_fp/reset), with its own store and
    its value function and fit status on their own topics."""
    params = {**_config_params('learner'), **spec.params,
              'estimator': 'first-passage', 'robots': ['robot_0'], 'store_path': str(fp_store)}
    remaps = {**spec.remaps, '__node': FP_LEARNER,
              '/safe_set/value_function': FP_VF_TOPIC, '/safe_set/fit': FP_FIT_TOPIC}
    return node_argv('learner', spec.namespace, params, remaps)


def phase2_argvs(subject: Subject, opts: StudyOptions, store: Path, first_offset: float,
                 fp_store: Path | None = None) -> list:
    """Clock, world (no respawn, one disc), one robot, supervisor, learner (paper); with
    ``fp_store`` also the first-passage learner (``fp_learner_argv``). No planner/filter:
    the conductor answers the robot's poses (u = 0)."""
    sup = {'w_max': subject.omega_max, 'mu': subject.mu, 'sigma': subject.sigma,
           'seed': subject.seed, 'robots': ['robot_0']}
    layout = team_layout(1, opts.rate_factor, seed=subject.seed % 1_000_000, step=opts.step,
                         with_filter=False, learner_store=store,
                         overrides={'world': {'respawn': False, 'robots': ['robot_0'], 'n_obstacles': 0},
                                    'learner': {'estimator': 'paper', 'alpha_k': 0.0},
                                    'supervisor': sup})
    argvs = []
    for spec in layout:
        if spec.kind == 'planner':
            continue                      # the conductor drives
        params = dict(spec.params)
        if spec.kind == 'dubins_robot':
            # start where the first scene starts, parked until the conductor's first command
            params.update(initial_x=PHASE2_X0, initial_y=float(first_offset), initial_theta=0.0,
                          timeout_behavior='straight')
        if spec.kind == 'supervisor':
            params['seed'] = subject.seed   # team_layout derives one from the world seed
        argvs.append(node_argv(spec.kind, spec.namespace, params, spec.remaps))
        if spec.kind == 'learner' and fp_store is not None:
            argvs.append(fp_learner_argv(spec, fp_store))
    return argvs


# -- Phase II ---------------------------------------------------------------------------
@dataclass
class Phase2Result:
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
    cpu_s: float | None = None         # core engine: CPU seconds of the phase


def run_phase2(subject: Subject, opts: StudyOptions, domain_id: int, log_dir: Path,
               progress: Progress | None = None) -> Phase2Result:
    from .conductor import Phase2Conductor
    env = team_env(domain_id)
    log_dir.mkdir(parents=True, exist_ok=True)
    store = log_dir / 'interventions.jsonl'
    with_fp = 'learned_fp' in opts.conditions
    if store.exists():
        store.unlink()
    # the first-passage learner's interventions and encounters (<store>.encounters.jsonl)
    fp_store = log_dir / FP_LEARNER / 'interventions.jsonl' if with_fp else None
    if fp_store is not None and fp_store.parent.exists():
        shutil.rmtree(fp_store.parent)
    offsets = [float(v) for v in opts.phase2_offsets]
    argvs = phase2_argvs(subject, opts, store, offsets[0], fp_store)
    t0 = time.monotonic()
    # world, paper learner, first-passage learner, the conductor itself
    conductor = Phase2Conductor(env, offsets, x0=PHASE2_X0, x_end=PHASE2_X_END, step_length=SPEED * opts.step,
                                readers=4 if with_fp else 3)
    fp_watch = conductor.watch_learner(FP_VF_TOPIC, FP_FIT_TOPIC) if with_fp else None
    fp_msg = fp_fit = None
    team = Team(argvs, env, log_dir)
    notes = []
    try:
        team.start()
        deadline = time.monotonic() + 60.0 + 15.0 * len(offsets)
        while not conductor.done.wait(0.2):
            if team.dead():
                raise RuntimeError(f'Phase II processes exited: {team.dead()} (logs in {log_dir})')
            if time.monotonic() > deadline:
                raise RuntimeError(f'Phase II did not finish in time (scene {conductor.scene_index}, '
                                   f'logs in {log_dir})')
        n = sum(1 for s in conductor.scenes if s['intervened'])
        # the waits end as soon as the fit counts every intervention: long timeouts cost
        # nothing on a quiet machine and let a loaded one (a 710 KB publish per refit) finish
        vf_msg = conductor.wait_for_fit(n, timeout=20.0) if n >= 3 else None
        if n >= 3 and (vf_msg is None or _fit_count(vf_msg) < n):
            # the learner missed some (e.g. sent before its subscription matched): send again
            stored = _stored_frames(store)
            k = conductor.resend(stored)
            notes.append(f'the learner had {len(stored)} of {n} interventions; {k} sent again')
            vf_msg = conductor.wait_for_fit(n, timeout=30.0)
            if vf_msg is None or _fit_count(vf_msg) < n:
                notes.append(f'the learner fitted {_fit_count(vf_msg) if vf_msg else 0} of {n} interventions')
        if fp_watch is not None and n >= 3:
            # every scene is one encounter; the last one becomes final once the robot has
            # passed its obstacle (the graph still runs: the conductor keeps answering) and
            # 2 s of pose time have passed; the wait ends as soon as the fit has them all, so
            # a long timeout costs nothing when the learner is quick, and a loaded machine
            # (a deep pose queue, scipy refits at a third of the learner's time) gets it
            fp_msg, status = fp_watch.wait_for_counts(n, len(conductor.scenes), timeout=60.0)
            fp_fit = first_passage_learner_fit(fp_msg, status)
            if fp_fit is None or (fp_fit['interventions'], fp_fit['encounters']) != (n, len(conductor.scenes)):
                got = (f"{fp_fit['interventions']} interventions in {fp_fit['encounters']} encounters"
                       if fp_fit else f'no fit (status: {status.get("message", "") if status else "none"})')
                notes.append(f'the first-passage learner fitted {got}; '
                             f'the scenes had {n} in {len(conductor.scenes)}')
    finally:
        team.stop()
        conductor.close()
    scenes = conductor.scenes
    states = np.array([s['state'] for s in scenes if s['intervened']], dtype=float).reshape(-1, 3)
    fit = None
    if vf_msg is not None:
        from ..ros_io.vfmsg import msg_metadata
        meta = msg_metadata(vf_msg)
        fit = {k: meta.get(k) for k in ('omega_max', 'mu', 'sigma', 'alpha', 'log_likelihood',
                                        'estimator', 'interventions')}
    # sim time the scenes spanned (the clock also ran, parked, while the graph settled
    # and while the learner fitted)
    span = scenes[-1]['end_time'] - scenes[0]['start_time'] if scenes else 0.0
    return Phase2Result(scenes, states, vf_msg, fit, span, time.monotonic() - t0, notes, fp_msg, fp_fit)


FIT_KEYS = ('omega_max', 'mu', 'sigma', 'alpha', 'log_likelihood')


def first_passage_learner_fit(vf_msg, status: dict | None) -> dict | None:
    """The fit of the set in force (``vf_msg``), from the learner's newest status when that
    status's fit is the one published (its counts are newer than the message's, which is
    sent only when the set changes), else from the message's own metadata."""
    from ..ros_io.vfmsg import msg_metadata
    if vf_msg is None:
        return None
    meta = msg_metadata(vf_msg)
    fit = {k: meta.get(k) for k in FIT_KEYS}
    fit.update(estimator=meta.get('estimator'), interventions=int(meta.get('interventions') or 0),
               encounters=int(meta.get('encounters') or 0), index=meta.get('index'))
    if status and status.get('index') == status.get('published_index') and \
            status.get('alpha') == status.get('published_alpha'):
        fit.update({k: float(status[k]) for k in FIT_KEYS},
                   interventions=int(status['fitted_interventions']),
                   encounters=int(status['fitted_encounters']))
    if status:
        fit['stored_encounters'] = int(status.get('encounters', 0))
        fit['unmatched_interventions'] = int(status.get('unmatched_interventions', 0))
    return fit


def _fit_count(vf_msg) -> int:
    from ..ros_io.vfmsg import msg_metadata
    return int(msg_metadata(vf_msg).get('interventions') or 0)


def _stored_frames(store: Path) -> set:
    """Obstacle frames of the interventions in the learner's store (JSON lines)."""
    out = set()
    try:
        for line in store.read_text().splitlines():
            try:
                out.add(json.loads(line).get('frame'))
            except ValueError:
                pass
    except OSError:
        pass
    return out


def phase2_encounters_from_scenes(scenes: list) -> list:
    """Encounters (relative frames, obstacle at the origin) of the recorded scenes."""
    out = []
    for k, s in enumerate(scenes):
        frames = np.asarray(s['frames'], dtype=float).reshape(-1, 3)
        if s['intervened']:
            frames = np.vstack([frames[frames[:, 0] < s['state'][0]], np.asarray(s['state'])[None]])
        if len(frames) == 0:
            continue
        out.append(Encounter(frames, bool(s['intervened']), k))
    return out


def first_passage_offline(scenes: list):
    """fit_first_passage over the library (conservative prior) -> (FitResult, fit dict);
    no ROS message (the core engine's cross-check)."""
    from ..learning.estimators import fit_first_passage
    from ..reach.library import load_or_build_library
    lib = load_or_build_library()
    true_vf = lib.entry(TRUE_OMEGA)
    fit = fit_first_passage(lib.entries, phase2_encounters_from_scenes(scenes), true_vf=true_vf)
    return fit, {k: v for k, v in fit.to_dict().items() if k not in ('candidates', 'notes')}


def first_passage_fit(scenes: list):
    """fit_first_passage over the library (conservative prior) -> (message, fit dict)."""
    from ..ros_io.vfmsg import value_function_to_msg
    fit, summary = first_passage_offline(scenes)
    msg = value_function_to_msg(fit.value_function, **summary, source='learned')
    return msg, summary


# -- Phase III --------------------------------------------------------------------------
H2_KEYS = ('path_per_trip', 'avoidance_length', 'avoidance_total', 'avoidance_arcs',
           'override_fraction', 'min_clearance', 'path_length')


def game_counts(result: dict) -> dict:
    """The world's final counts and H2 measures of one game (from its /world/stats)."""
    stats = result.get('stats') or {}
    log = result.get('interventions') or []

    def num(key):
        v = stats.get(key)
        return int(float(v)) if v is not None else 0

    def real(key):
        try:
            return float(stats[key])
        except (KeyError, TypeError, ValueError):
            return float('nan')
    out = {
        'trips': num('trips'), 'crashes': num('crashes'),
        'interventions': num('interventions'), 'false_positives': num('false_positives'),
        'sim_time': float(stats.get('sim_time', 0.0) or 0.0),
        'logged_interventions': len(log),
        'logged_false_positives': sum(1 for r in log if str(r.get('false_positive')).lower()
                                      in ('true', '1')),
    }
    out.update({k: real(k) for k in H2_KEYS})
    return out


def supervisor_params(subject: Subject) -> dict:
    return {'w_max': subject.omega_max, 'mu': subject.mu, 'sigma': subject.sigma}


def supervisor_seed(subject: Subject, world_seed: int) -> int:
    """The subject's noise in Phase III (the same for every condition of the subject)."""
    return (subject.seed + 7919 * world_seed) % (2**31 - 1)


def condition_message(condition: str, learned: dict, alpha_offset: float = 0.0):
    """(message, alpha or None, what ran) of one condition; ``learned``: condition ->
    (value function, fit) of the subject's learned sets. A learned condition without a
    fit runs the Standard set (and is counted so)."""
    from .games import game_message
    standard_vf, conservative_vf = reference_sets()
    if condition == 'conservative':
        return game_message(conservative_vf, None, condition), None, 'conservative'
    if condition in learned and learned[condition][0] is not None:
        vf, fit = learned[condition]
        alpha = learned_alpha(fit, alpha_offset)
        return game_message(vf, alpha, condition, fit_mu=fit['mu'], fit_sigma=fit['sigma'],
                            omega_max=fit['omega_max']), alpha, condition
    return game_message(standard_vf, None, 'standard'), None, 'standard'


# -- whole study ------------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def reference_sets():
    """The standard (true, radius 1.8) and conservative (radius 3.6) value functions."""
    from ..reach.grid import Grid
    from ..reach.library import load_or_solve
    g = Grid(GRID_LO, GRID_HI, GRID_SHAPE)
    return (load_or_solve(g, SPEED, TRUE_OMEGA, TRUE_RADIUS, HORIZON),
            load_or_solve(g, SPEED, TRUE_OMEGA, CONSERVATIVE_RADIUS, HORIZON))


def learned_sets(p2: Phase2Result, conditions) -> dict:
    """condition -> (value function message or None, fit dict or None) of one subject.

    learned: the paper learner node's fit (alpha = mu); learned_fp: the first-passage
    learner node's (alpha = mu, over every encounter, intervened or not). Both are the
    nodes' last messages, taken from the Phase II graph.
    """
    out = {}
    if 'learned' in conditions:
        out['learned'] = (p2.vf_msg, p2.fit)
    if 'learned_fp' in conditions:
        out['learned_fp'] = (p2.fp_msg, p2.fp_fit)
    return out


def offline_cross_check(p2: Phase2Result) -> dict | None:
    """The first-passage fit done offline from the conductor's recorded scenes, beside the
    learner node's (the two see the same scenes; they differ only by what the node
    receives on topics): chosen omega_max, mu, sigma, counts."""
    if not len(p2.states):
        return None
    _, fit = first_passage_offline(p2.scenes)
    return {k: fit.get(k) for k in FIT_KEYS + ('interventions', 'encounters')}


def learned_value_functions(p2: Phase2Result, conditions) -> dict:
    """condition -> (ValueFunction or None, fit or None): the core engine's value functions,
    or the graph learners' messages decoded."""
    out = {}
    for c, (msg, fit) in learned_sets(p2, conditions).items():
        vf = p2.vf if c == 'learned' else p2.fp_vf
        if vf is None and msg is not None:
            from ..ros_io.vfmsg import msg_to_value_function
            vf = msg_to_value_function(msg)
        out[c] = (vf, fit if vf is not None else None)
    return out


def sweep_condition(conditions):
    """The learned condition whose alpha the observed sweep raises (the paper's first)."""
    return next((c for c in ('learned', 'learned_fp') if c in conditions), None)


class GraphGames:
    """Phase III of one subject through its kept-alive node graph (``games.GameGraph``)."""

    def __init__(self, subject, world_seed: int, opts: StudyOptions, env: dict, log_dir: Path):
        from .games import GameGraph
        self.subject, self.world_seed, self.opts = subject, world_seed, opts
        self.graph = GameGraph(env, world_seed, supervisor_params(subject), opts.step, opts.rate_factor,
                               log_dir)

    def play(self, condition: str, learned: dict, k: float):
        """(result dict of ``GameGraph.play``, alpha or None, the set that ran)."""
        msg, alpha, ran = condition_message(condition, learned, k)
        result = self.graph.play(msg, self.world_seed, supervisor_seed(self.subject, self.world_seed),
                                 self.opts.game_seconds,
                                 self.opts.game_timeout + (120.0 if self.graph.games == 0 else 0.0))
        return result, alpha, ran

    def close(self):
        self.graph.close()


class CoreGames:
    """Phase III of one subject in this process (``engine.CoreStudy.play``)."""

    def __init__(self, core, subject, world_seed: int, opts: StudyOptions):
        self.core, self.subject, self.world_seed, self.opts = core, subject, world_seed, opts

    def play(self, condition: str, learned: dict, k: float):
        safe_set, alpha, ran = self.core.safe_set(condition, learned, k)
        return self.core.play(self.subject, self.world_seed, safe_set, self.opts), alpha, ran

    def close(self):
        pass


def run_study(subjects: list, opts: StudyOptions, out=sys.stdout) -> dict:
    """Run every subject on ``opts.engine``; returns the raw per-subject records (see
    ``summarize``). The core engine runs subjects in parallel processes (``opts.workers``):
    subjects are independent, and each subject's record depends on its seeds only, so the
    records are the same whatever the number of workers."""
    from .analysis import ordered
    if opts.engine not in ENGINES:
        raise ValueError(f"engine '{opts.engine}' is not one of {ENGINES}")
    conditions = ordered(opts.conditions)
    progress = Progress(len(subjects), out)
    t_start = time.monotonic()
    if opts.engine == 'core':
        workers = opts.workers or os.cpu_count() or 1
        workers = max(1, min(int(workers), len(subjects)))
        if workers > 1:
            import concurrent.futures
            import multiprocessing
            # fork: the workers inherit the loaded value functions (no rclpy runs in this
            # process with the core engine)
            with concurrent.futures.ProcessPoolExecutor(
                    workers, mp_context=multiprocessing.get_context('fork')) as pool:
                jobs = [pool.submit(_core_subject, i, subject, opts, conditions, progress.t0)
                        for i, subject in enumerate(subjects)]
                records = [j.result() for j in jobs]
        else:
            records = [_core_subject(i, subject, opts, conditions, progress.t0, out)
                       for i, subject in enumerate(subjects)]
    else:
        domain = opts.domain_id if opts.domain_id is not None else int(team_env()['ROS_DOMAIN_ID'])
        env = team_env(domain)
        records = []
        for i, subject in enumerate(subjects):
            player = lambda world_seed, i=i, subject=subject: GraphGames(  # noqa: E731
                subject, world_seed, opts, env, Path(opts.out_dir) / 'logs' / f's{i:02d}-phase3')
            phase2 = lambda subject, i=i: run_phase2(  # noqa: E731
                subject, opts, domain, Path(opts.out_dir) / 'logs' / f's{i:02d}-phase2', progress)
            records.append(run_subject(i, subject, opts, conditions, progress, phase2, player))
    for i, rec in enumerate(records):
        # the subject's files, in the layout a human participant's session also writes
        # (console/session.py), so the analysis can mix the two
        from ..console.session import write_subject
        write_subject(Path(opts.out_dir) / 'subjects' / f's{i:02d}', rec)
    return {'records': records, 'wall': time.monotonic() - t_start}


@functools.lru_cache(maxsize=1)
def _core():
    from .engine import CoreStudy
    return CoreStudy()


def _core_subject(i, subject, opts, conditions, t0, out=None):
    """One subject on the core engine (in a worker process, or here)."""
    progress = Progress(opts.subjects if opts.subjects else 1, out or sys.stdout)
    progress.t0 = t0
    core = _core()
    return run_subject(i, subject, opts, conditions, progress,
                       lambda subject: core.phase2(subject, opts, with_fp='learned_fp' in conditions),
                       lambda world_seed: CoreGames(core, subject, world_seed, opts))


def run_subject(i, subject, opts, conditions, progress, phase2, player_for) -> dict:
    """Phase II, fits and Phase III of one subject; ``phase2(subject)`` -> Phase2Result,
    ``player_for(world_seed)`` -> GraphGames | CoreGames."""
    rec = {'subject': subject.to_dict(), 'games': {}, 'sweep': {}, 'fits': {}, 'learned_vfs': {}}
    progress.line(i, 'phase II', None, f'w_max {subject.omega_max:g} mu {subject.mu:g} '
                  f'sigma {subject.sigma:g}, {len(opts.phase2_offsets)} offsets')
    p2 = phase2(subject)
    rec['phase2'] = {'scenes': [{k: v for k, v in s.items() if k != 'frames'} for s in p2.scenes],
                     'interventions': len(p2.states), 'sim_time': p2.sim_time, 'wall': p2.wall,
                     'notes': p2.notes, 'engine': opts.engine}
    rec['states'] = p2.states.tolist()
    fits = learned_value_functions(p2, conditions)
    if 'learned_fp' in fits:
        rec['phase2']['offline_first_passage'] = offline_cross_check(p2)
    for c, (vf, fit) in fits.items():
        rec['fits'][c] = fit
        rec['learned_vfs'][c] = vf
    progress.line(i, 'phase II done', p2.sim_time, f'{len(p2.states)} interventions' + ''.join(
        f'; {c}: ' + (f'w {f["omega_max"]:g} mu {f["mu"]:.3g} sigma {f["sigma"]:.3g}' if f
                      else 'no fit (too few interventions): Standard set')
        for c, f in rec['fits'].items()) + ''.join(f'; {n}' for n in p2.notes))
    world_seed = opts.seed * 1000 + i
    learned = {c: (rec['learned_vfs'][c], rec['fits'][c]) for c in fits}
    games = [(c, 0.0) for c in conditions]
    swept = sweep_condition(conditions)
    if i < opts.sweep_subjects and swept and rec['fits'].get(swept):
        games += [(swept, k) for k in opts.sweep_k if k != 0.0]
    player = player_for(world_seed)
    try:
        for cond, k in games:
            result, alpha, ran = player.play(cond, learned, k)
            g = game_counts(result)
            g.update(wall=result['wall'], wall_running=result['wall_running'], cpu_s=result['cpu_s'],
                     cpu_by_process=result['cpu_by_process'],
                     resends=result['resends'], set=ran, engine=opts.engine,
                     alpha=alpha, complete=g['sim_time'] >= opts.game_seconds - 1e-6)
            if k == 0.0:
                rec['games'][cond] = g
                name = f'phase III {cond}'
            else:
                rec['sweep'][k] = g
                name = f'sweep mu+{k:g}sigma'
            progress.line(i, name, g['sim_time'],
                          f'FP {g["false_positives"]} int {g["interventions"]} crashes {g["crashes"]} '
                          f'trips {g["trips"]} arc {g["avoidance_length"]:.2f} m '
                          f'({g["wall"]:.1f} s)')
        if swept in rec['games'] and rec['sweep']:
            rec['sweep'][0.0] = rec['games'][swept]
    finally:
        player.close()
    return rec


# -- report -----------------------------------------------------------------------------
def _finite(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _measure(v) -> float | None:
    """A stored H2 measure as a finite float, or None (not measured: NaN in memory, null in
    JSON, e.g. path per trip in a game without a trip)."""
    return None if v is None else _finite(float(v))


def jsonable(obj):
    """Nested dicts/lists with numpy scalars and non-finite floats made JSON-safe."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        obj = obj.item()
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    return _finite(obj)


def record_learned(r: dict) -> dict:
    """condition -> (value function, fit) of a record's learned sets (None when not fitted);
    a record with only 'fit'/'learned_vf' is the paper estimator's Learned."""
    if 'learned_vfs' in r:
        return {c: (r['learned_vfs'].get(c), r['fits'].get(c)) for c in r['learned_vfs']}
    return {'learned': (r.get('learned_vf'), r.get('fit'))}


def summarize(records: list, standard_vf, conservative_vf, sweep_k=(0.0, 1.0, 2.0)) -> dict:
    """Aggregate per-subject records into the study's JSON (Table 1, H2, ANOVA, Tukey, sweep).

    A record: {'subject', 'states' (Phase II intervention states), 'fits' and 'learned_vfs'
    (learned condition -> fit dict / ValueFunction, or None), 'games': {condition: counts
    and H2 measures}, 'sweep': {k: counts}}. A subject without a fit (fewer than 3
    interventions) is counted with the Standard set in that learned condition (what its
    filter used). The conditions are those the records' games ran.
    """
    from .analysis import (H2_MEASURES, SetCount, h2_summary, interventions_inside, ordered,
                           repeated_measures_anova, table1, tukey_pairs)
    conditions = ordered(records[0]['games'])
    inside = {c: SetCount(0, 0) for c in conditions}
    swept = sweep_condition(conditions)
    per_subject_pred = {float(k): [] for k in sweep_k}
    for r in records:
        states = np.asarray(r['states'], dtype=float).reshape(-1, 3)
        learned = record_learned(r)
        sets = {'standard': (standard_vf, 0.0), 'conservative': (conservative_vf, 0.0)}
        for c in ('learned', 'learned_fp'):
            vf, fit = learned.get(c, (None, None))
            sets[c] = (vf, learned_alpha(fit)) if vf is not None else (standard_vf, 0.0)
        for c in conditions:
            vf, alpha = sets[c]
            n = interventions_inside(vf, alpha, states)
            inside[c] = SetCount(inside[c].inside + n.inside, inside[c].total + n.total)
        vf, fit = learned.get(swept, (None, None)) if swept else (None, None)
        if vf is not None and len(states):
            for k in per_subject_pred:
                n = interventions_inside(vf, learned_alpha(fit, k), states)
                per_subject_pred[k].append(n.inside / n.total)
    counts = {c: {key: [int(r['games'][c][key]) for r in records]
                  for key in ('false_positives', 'interventions', 'crashes', 'trips')}
              for c in conditions}
    measures = {c: {m: [_measure(r['games'][c].get(m)) for r in records]
                    for m in H2_MEASURES + ('avoidance_total', 'avoidance_arcs')}
                for c in conditions}
    fp = {c: counts[c]['false_positives'] for c in conditions}
    rows = table1(inside, fp)
    out_conditions = {}
    for c in conditions:
        out_conditions[c] = dict(counts[c], **measures[c], **rows[c])
        if c == 'standard':   # the reference, by definition (other ratios are NaN if it is 0)
            out_conditions[c]['predicted_fp_ratio'] = 1.0
            out_conditions[c]['observed_fp_ratio'] = 1.0
    observed = {}
    for k in per_subject_pred:
        games = [r['sweep'][k] for r in records if k in r.get('sweep', {})]
        observed[k] = [g['false_positives'] for g in games] if games else None
    sweep = {f'mu+{k:g}sigma' if k else 'mu': {
        'k': k, 'condition': swept, 'predicted': per_subject_pred[k], 'observed': observed[k],
        'observed_subjects': [r['subject']['index'] for r in records if k in r.get('sweep', {})],
        'observed_interventions': [r['sweep'][k]['interventions'] for r in records if k in r.get('sweep', {})],
        'observed_crashes': [r['sweep'][k]['crashes'] for r in records if k in r.get('sweep', {})],
    } for k in per_subject_pred}
    h2 = h2_summary({c: measures[c] for c in conditions})
    return {
        'table1': rows,
        'conditions': out_conditions,
        'anova': repeated_measures_anova(fp),
        'tukey': tukey_pairs(fp),
        'h2': h2,
        'alpha_sweep': sweep,
        'subjects': [{'subject': r['subject'],
                      'fits': {c: f for c, (_, f) in record_learned(r).items()},
                      'phase2': r.get('phase2', {}),
                      'games': r['games'], 'sweep': {f'{k:g}': v for k, v in r.get('sweep', {}).items()}}
                     for r in records],
    }


def make_plots(out_dir: Path, summary: dict, records: list, standard_vf, conservative_vf) -> list:
    from . import plots
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    fp = {c: summary['conditions'][c]['false_positives'] for c in summary['conditions']}
    p = out_dir / 'false_positives.png'
    plots.plot_false_positives(p, fp, summary['tukey'])
    paths.append(p)
    p = out_dir / 'efficiency.png'
    plots.plot_efficiency(p, summary['conditions'], summary['h2'])
    paths.append(p)
    learned = []
    for r in records:
        for c, (vf, fit) in record_learned(r).items():
            if vf is not None:
                learned.append((vf, learned_alpha(fit), f"subject {r['subject']['index']}", c))
    p = out_dir / 'learned_sets.png'
    plots.plot_learned_sets(p, standard_vf, conservative_vf, learned, TRUE_RADIUS)
    paths.append(p)
    states = np.vstack([np.asarray(r['states'], dtype=float).reshape(-1, 3) for r in records])
    p = out_dir / 'phase2_interventions.png'
    plots.plot_phase2(p, states, standard_vf, conservative_vf, TRUE_RADIUS)
    paths.append(p)
    sweep = {label: v for label, v in summary['alpha_sweep'].items() if v['predicted']}
    if sweep:
        p = out_dir / 'alpha_sweep.png'
        plots.plot_alpha_sweep(p, sweep)
        paths.append(p)
    return paths
