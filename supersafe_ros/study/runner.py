"""The study through the real node graph: Phase II, the fit, Phase III, per subject.

Per subject (a simulated supervisor from ``population.draw_subjects``):

1. Phase II (``run_phase2``): a light graph — sim clock, world (``respawn`` false),
   one robot, supervisor (the subject's w_max, mu, sigma, seed), learner — and the
   study's conductor node (``conductor.Phase2Conductor``) in this process, which
   sets the scene for every offset of the 0.25 m ladder (``/world/set_obstacles``:
   one disc at the origin; ``robot_0/initialpose``: (-8, y0, 0)) and drives the robot
   with u = 0 (it answers every pose with a zero Twist on cmd_vel, which is also the
   lockstep acknowledgement). A scene ends at the supervisor's intervention or when
   the robot has passed the obstacle. The learner receives the interventions and fits
   (paper estimator, alpha = mu); the runner takes its last value-function message.
   With ``estimator='first-passage'`` the runner fits ``fit_first_passage`` itself from
   the recorded approaches (every scene, intervened or not) over the same library.
2. Phase III (``run_game``): per condition one game of the full team (world, 2 x
   (robot, planner, filter), supervisor, clock; no learner, so the supervisor's
   interventions cannot refit anything): Standard (the filter's own standard set),
   Conservative (filter radius 3.6), Learned (the runner publishes the learned V,
   latched, on /safe_set/value_function; the filter uses alpha = mu + alpha_offset
   sigma). Same world seed for the three conditions of a subject.

Every game and Phase II is a fresh set of processes (start-up ~2-3 s each); the
lockstep clock runs as fast as the graph allows (rate_factor 0).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import json
import math
from pathlib import Path
import sys
import time

import numpy as np

from ..team import Team, run_team, team_env, team_layout, node_argv
from ..learning.data import PHASE2_OFFSETS, Encounter
from .population import Subject

TRUE_RADIUS = 1.8
CONSERVATIVE_RADIUS = 3.6
SPEED = 3.0
TRUE_OMEGA = 1.0
HORIZON = 3.0
GRID_LO, GRID_HI, GRID_SHAPE = (-8.0, -8.0), (8.0, 8.0), (65, 65, 42)
PHASE2_X0 = -8.0
PHASE2_X_END = 2.5
READY_TOPIC = '/study/learned_set_ready'


@dataclass
class StudyOptions:
    subjects: int = 12
    seed: int = 0
    step: float = 0.2
    rate_factor: float = 0.0
    game_seconds: float = 120.0
    phase2_offsets: tuple = tuple(float(v) for v in PHASE2_OFFSETS)
    estimator: str = 'paper'
    out_dir: Path = Path('study-out')
    domain_id: int | None = None
    sweep_subjects: int = 2          # observed alpha sweep (extra Learned games) for the first k
    sweep_k: tuple = (0.0, 1.0, 2.0)
    game_timeout: float = 120.0      # wall s per game before giving up on it
    plots: bool = True


class Progress:
    """One line per phase: subject i/N, phase, sim time, wall time."""

    def __init__(self, n: int, out=sys.stdout):
        self.n, self.out, self.t0 = n, out, time.monotonic()

    def line(self, i: int, phase: str, sim_time=None, extra: str = ''):
        sim = f'sim {sim_time:7.1f} s' if sim_time is not None else ' ' * 13
        print(f'[subject {i + 1:2d}/{self.n}] {phase:<22s} {sim}  wall {time.monotonic() - self.t0:7.1f} s'
              f'{"  " + extra if extra else ""}', file=self.out, flush=True)


# -- graphs -----------------------------------------------------------------------------
def phase2_argvs(subject: Subject, opts: StudyOptions, store: Path, first_offset: float) -> list:
    """Clock, world (no respawn, one disc), one robot, supervisor, learner; no planner/filter:
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
    return argvs


def game_argvs(condition: str, world_seed: int, subject: Subject, opts: StudyOptions,
               alpha_offset: float = 0.0) -> list:
    filt = {'use_learned': condition == 'learned', 'alpha_offset': float(alpha_offset)}
    if condition == 'conservative':
        filt['radius'] = CONSERVATIVE_RADIUS
    sup = {'w_max': subject.omega_max, 'mu': subject.mu, 'sigma': subject.sigma}
    overrides = {'safety_filter': filt, 'supervisor': sup}
    layout = team_layout(2, opts.rate_factor, seed=world_seed, duration=opts.game_seconds,
                         step=opts.step, with_learner=False, overrides=overrides)
    argvs = []
    for spec in layout:
        params = dict(spec.params)
        if spec.kind == 'supervisor':
            params['seed'] = (subject.seed + 7919 * world_seed) % (2**31 - 1)   # the subject's noise
        if spec.kind == 'sim_clock' and condition == 'learned':
            # the runner opens this gate once both filters have the learned set in force
            params['wait_for_publishers'] = list(params['wait_for_publishers']) + [f'{READY_TOPIC}=1']
        argvs.append(node_argv(spec.kind, spec.namespace, params, spec.remaps))
    return argvs


# -- Phase II ---------------------------------------------------------------------------
@dataclass
class Phase2Result:
    scenes: list                       # per offset: {'y0', 'intervened', 'state', 'frames'}
    states: np.ndarray                 # (n, 3) intervention states (relative to the obstacle)
    vf_msg: object                     # the learner's (or runner's) value-function message, or None
    fit: dict | None
    sim_time: float
    wall: float
    notes: list = field(default_factory=list)


def run_phase2(subject: Subject, opts: StudyOptions, domain_id: int, log_dir: Path,
               progress: Progress | None = None) -> Phase2Result:
    from .conductor import Phase2Conductor
    env = team_env(domain_id)
    log_dir.mkdir(parents=True, exist_ok=True)
    store = log_dir / 'interventions.jsonl'
    if store.exists():
        store.unlink()
    offsets = [float(v) for v in opts.phase2_offsets]
    argvs = phase2_argvs(subject, opts, store, offsets[0])
    t0 = time.monotonic()
    conductor = Phase2Conductor(env, offsets, x0=PHASE2_X0, x_end=PHASE2_X_END, step_length=SPEED * opts.step)
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
        vf_msg = conductor.wait_for_fit(n, timeout=5.0) if n >= 3 else None
        if n >= 3 and (vf_msg is None or _fit_count(vf_msg) < n):
            # the learner missed some (e.g. sent before its subscription matched): send again
            stored = _stored_frames(store)
            k = conductor.resend(stored)
            notes.append(f'the learner had {len(stored)} of {n} interventions; {k} sent again')
            vf_msg = conductor.wait_for_fit(n, timeout=10.0)
            if vf_msg is None or _fit_count(vf_msg) < n:
                notes.append(f'the learner fitted {_fit_count(vf_msg) if vf_msg else 0} of {n} interventions')
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
    return Phase2Result(scenes, states, vf_msg, fit, span, time.monotonic() - t0, notes)


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


def first_passage_fit(scenes: list):
    """fit_first_passage over the library (conservative prior) -> (message, fit dict)."""
    from ..learning.estimators import fit_first_passage
    from ..reach.library import load_or_build_library
    from ..ros_io.vfmsg import value_function_to_msg
    lib = load_or_build_library()
    true_vf = lib.entry(TRUE_OMEGA)
    fit = fit_first_passage(lib.entries, phase2_encounters_from_scenes(scenes), true_vf=true_vf)
    summary = {k: v for k, v in fit.to_dict().items() if k not in ('candidates', 'notes')}
    msg = value_function_to_msg(fit.value_function, **summary, source='learned')
    return msg, summary


# -- Phase III --------------------------------------------------------------------------
class LatchedValueFunction:
    """Publishes one value-function message, latched, on /safe_set/value_function, and
    opens the gate ``READY_TOPIC`` (a publisher the sim clock waits for) once every
    filter has logged (on /rosout) that the learned set is in force: the first step of
    a Learned game then runs on the learned set, not on the standard one."""

    def __init__(self, env: dict, msg, n_filters: int = 2):
        from ..ros_io.background_node import BackgroundNode
        from rclpy.qos import QoSProfile, DurabilityPolicy, HistoryPolicy, ReliabilityPolicy
        from rcl_interfaces.msg import Log
        from std_msgs.msg import Empty, Float32MultiArray
        from ..ros_io import rosmsg
        self.Empty = Empty
        self.n_filters = n_filters
        self.in_force = set()
        self.gate = None
        self.ros = BackgroundNode('study_learned_set', env['ROS_DOMAIN_ID'])
        self.node = self.ros.node
        rosout_qos = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST,
                                reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(Log, '/rosout', self.on_log, rosout_qos)
        self.pub = self.node.create_publisher(Float32MultiArray, '/safe_set/value_function',
                                              rosmsg.QOS_LATCHED)
        self.pub.publish(msg)
        self.ros.start()

    def on_log(self, log):
        if log.name.endswith('safety_filter') and log.msg.startswith('learned set in force'):
            self.in_force.add(log.name)
            if len(self.in_force) >= self.n_filters and self.gate is None:
                self.gate = self.node.create_publisher(self.Empty, READY_TOPIC, 1)

    def close(self):
        self.ros.close()


def game_counts(result: dict) -> dict:
    """The world's final counts of one game (from run_team's result)."""
    stats = result.get('stats') or {}
    log = result.get('interventions') or []

    def num(key):
        v = stats.get(key)
        return int(float(v)) if v is not None else 0
    return {
        'trips': num('trips'), 'crashes': num('crashes'),
        'interventions': num('interventions'), 'false_positives': num('false_positives'),
        'sim_time': float(stats.get('sim_time', 0.0) or 0.0),
        'logged_interventions': len(log),
        'logged_false_positives': sum(1 for r in log if str(r.get('false_positive')).lower()
                                      in ('true', '1')),
    }


def run_game(condition: str, subject: Subject, world_seed: int, opts: StudyOptions,
             domain_id: int, log_dir: Path, vf_msg=None, alpha_offset: float = 0.0) -> dict:
    argvs = game_argvs(condition, world_seed, subject, opts, alpha_offset)
    env = team_env(domain_id)
    latched = LatchedValueFunction(env, vf_msg) if condition == 'learned' else None
    t0 = time.monotonic()
    try:
        with open(log_dir.parent / f'{log_dir.name}.runner.log', 'w') as out:
            result = run_team(argvs, opts.game_seconds, opts.game_timeout, domain_id, log_dir,
                              print_period=1e9, out=out)
    finally:
        if latched:
            latched.close()
    if result['reason'].startswith('signal'):
        raise KeyboardInterrupt(result['reason'])   # Ctrl-C in a game stops the study
    counts = game_counts(result)
    counts.update(wall=time.monotonic() - t0, reason=result['reason'],
                  complete=counts['sim_time'] >= opts.game_seconds - 1e-6)
    return counts


# -- whole study ------------------------------------------------------------------------
def reference_sets():
    """The standard (true, radius 1.8) and conservative (radius 3.6) value functions."""
    from ..reach.grid import Grid
    from ..reach.library import load_or_solve
    g = Grid(GRID_LO, GRID_HI, GRID_SHAPE)
    return (load_or_solve(g, SPEED, TRUE_OMEGA, TRUE_RADIUS, HORIZON),
            load_or_solve(g, SPEED, TRUE_OMEGA, CONSERVATIVE_RADIUS, HORIZON))


def run_study(subjects: list, opts: StudyOptions, out=sys.stdout) -> dict:
    """Run every subject; returns the raw per-subject records (see ``summarize``)."""
    from ..ros_io.vfmsg import msg_to_value_function
    progress = Progress(len(subjects), out)
    domain = opts.domain_id if opts.domain_id is not None else int(team_env()['ROS_DOMAIN_ID'])
    logs = Path(opts.out_dir) / 'logs'
    records = []
    t_start = time.monotonic()
    for i, subject in enumerate(subjects):
        rec = {'subject': subject.to_dict(), 'games': {}, 'sweep': {}}
        progress.line(i, 'phase II', None, f'w_max {subject.omega_max:g} mu {subject.mu:g} '
                      f'sigma {subject.sigma:g}, {len(opts.phase2_offsets)} offsets')
        p2 = run_phase2(subject, opts, domain, logs / f's{i:02d}-phase2', progress)
        rec['phase2'] = {'scenes': [{k: v for k, v in s.items() if k != 'frames'} for s in p2.scenes],
                         'interventions': len(p2.states), 'sim_time': p2.sim_time, 'wall': p2.wall,
                         'notes': p2.notes}
        vf_msg, fit = p2.vf_msg, p2.fit
        if opts.estimator == 'first-passage' and len(p2.states) >= 1:
            vf_msg, fit = first_passage_fit(p2.scenes)
        rec['fit'] = fit
        rec['states'] = p2.states.tolist()
        progress.line(i, 'phase II done', p2.sim_time,
                      f'{len(p2.states)} interventions; fit ' + (
                          f'w {fit["omega_max"]:g} mu {fit["mu"]:.3g} sigma {fit["sigma"]:.3g}'
                          if fit else 'none (too few interventions): Learned = Standard')
                      + ''.join(f'; {n}' for n in p2.notes))
        rec['learned_vf'] = msg_to_value_function(vf_msg) if vf_msg is not None else None
        world_seed = opts.seed * 1000 + i
        for cond in ('standard', 'learned', 'conservative'):
            game_cond = cond if (cond != 'learned' or vf_msg is not None) else 'standard'
            g = run_game(game_cond, subject, world_seed, opts, domain, logs / f's{i:02d}-{cond}', vf_msg)
            rec['games'][cond] = g
            progress.line(i, f'phase III {cond}', g['sim_time'],
                          f'FP {g["false_positives"]} int {g["interventions"]} crashes {g["crashes"]} '
                          f'trips {g["trips"]}' + ('' if g['complete'] else f' INCOMPLETE ({g["reason"]})'))
        if i < opts.sweep_subjects and vf_msg is not None:
            for k in opts.sweep_k:
                if k == 0.0:
                    rec['sweep'][k] = rec['games']['learned']
                    continue
                g = run_game('learned', subject, world_seed, opts, domain,
                             logs / f's{i:02d}-learned-k{k:g}', vf_msg, alpha_offset=k)
                rec['sweep'][k] = g
                progress.line(i, f'sweep mu+{k:g}sigma', g['sim_time'],
                              f'FP {g["false_positives"]} int {g["interventions"]} crashes {g["crashes"]}')
        records.append(rec)
        # the subject's files, in the layout a human participant's session also writes
        # (console/session.py), so the analysis can mix the two
        from ..console.session import write_subject
        write_subject(Path(opts.out_dir) / 'subjects' / f's{i:02d}', rec)
    return {'records': records, 'wall': time.monotonic() - t_start}


# -- report -----------------------------------------------------------------------------
def _finite(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


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


def learned_alpha(fit: dict | None, k: float = 0.0) -> float:
    """alpha of a subject's learned set as the filter uses it: mu + k sigma."""
    return float(fit['mu']) + k * float(fit['sigma'])


def summarize(records: list, standard_vf, conservative_vf, sweep_k=(0.0, 1.0, 2.0)) -> dict:
    """Aggregate per-subject records into the study's JSON (Table 1, ANOVA, Tukey, sweep).

    A record: {'subject', 'fit' (mu, sigma, ... or None), 'states' (Phase II intervention
    states), 'learned_vf' (ValueFunction or None), 'games': {condition: counts},
    'sweep': {k: counts}}. A subject without a fit (fewer than 3 interventions) is
    counted with the Standard set in the Learned condition (what its filter used).
    """
    from .analysis import (CONDITIONS, SetCount, interventions_inside, repeated_measures_anova,
                           table1, tukey_pairs)
    inside = {c: SetCount(0, 0) for c in CONDITIONS}
    per_subject_pred = {float(k): [] for k in sweep_k}
    for r in records:
        states = np.asarray(r['states'], dtype=float).reshape(-1, 3)
        sets = {'standard': (standard_vf, 0.0), 'conservative': (conservative_vf, 0.0),
                'learned': ((r['learned_vf'], learned_alpha(r['fit'])) if r.get('learned_vf') is not None
                            else (standard_vf, 0.0))}
        for c, (vf, alpha) in sets.items():
            n = interventions_inside(vf, alpha, states)
            inside[c] = SetCount(inside[c].inside + n.inside, inside[c].total + n.total)
        if r.get('learned_vf') is not None and len(states):
            for k in per_subject_pred:
                n = interventions_inside(r['learned_vf'], learned_alpha(r['fit'], k), states)
                per_subject_pred[k].append(n.inside / n.total)
    counts = {c: {key: [int(r['games'][c][key]) for r in records]
                  for key in ('false_positives', 'interventions', 'crashes', 'trips')}
              for c in CONDITIONS}
    fp = {c: counts[c]['false_positives'] for c in CONDITIONS}
    rows = table1(inside, fp)
    conditions = {}
    for c in CONDITIONS:
        conditions[c] = dict(counts[c], **rows[c])
        if c == 'standard':   # the reference, by definition (other ratios are NaN if it is 0)
            conditions[c]['predicted_fp_ratio'] = 1.0
            conditions[c]['observed_fp_ratio'] = 1.0
    observed = {}
    for k in per_subject_pred:
        games = [r['sweep'][k] for r in records if k in r.get('sweep', {})]
        observed[k] = [g['false_positives'] for g in games] if games else None
    sweep = {f'mu+{k:g}sigma' if k else 'mu': {
        'k': k, 'predicted': per_subject_pred[k], 'observed': observed[k],
        'observed_subjects': [r['subject']['index'] for r in records if k in r.get('sweep', {})],
        'observed_interventions': [r['sweep'][k]['interventions'] for r in records if k in r.get('sweep', {})],
        'observed_crashes': [r['sweep'][k]['crashes'] for r in records if k in r.get('sweep', {})],
    } for k in per_subject_pred}
    return {
        'table1': rows,
        'conditions': conditions,
        'anova': repeated_measures_anova(fp),
        'tukey': tukey_pairs(fp),
        'alpha_sweep': sweep,
        'subjects': [{'subject': r['subject'], 'fit': r.get('fit'),
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
    learned = [(r['learned_vf'], learned_alpha(r['fit']), f"subject {r['subject']['index']}")
               for r in records if r.get('learned_vf') is not None]
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
