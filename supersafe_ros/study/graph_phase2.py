"""Phase II through the node graph (``--engine graph``, and the console session's Phase II).

One light graph per subject: sim clock, world (``respawn`` false), one robot, supervisor
(the subject's w_max, mu, sigma, seed), learner, and the study's conductor node
(``conductor.Phase2Conductor``) in this process, which sets the scene for every offset
of the 0.25 m ladder (``/world/set_obstacles``: one disc at the origin;
``robot_0/initialpose``: (-8, y0, 0)) and drives the robot with u = 0 (it answers every
pose with a zero Twist on cmd_vel, which is also the lockstep acknowledgement). A scene
ends at the supervisor's intervention or when the robot has passed the obstacle.

Both learned sets come from learner nodes in this graph. Learned = the learner's fit from
the interventions it received (``estimator: paper``, alpha = mu); Learned FP = a second
learner (``learner_fp``, ``estimator: first-passage``, robots [robot_0], its own store
and topics ``/study/learner_fp/...``), which builds the encounters itself from
``robot_0/pose``, ``/obstacle_markers`` and ``/interventions`` (every scene, intervened
or not). The core engine's counterpart is ``engine.CoreStudy.phase2``.
"""
from __future__ import annotations

import json
from pathlib import Path
import shutil
import time

import numpy as np

from ..team import Team, node_argv, team_env, team_layout
from .conductor import Phase2Conductor
from .population import Subject
from .protocol import (FIT_KEYS, FP_FIT_TOPIC, FP_LEARNER, FP_VF_TOPIC, PHASE2_X0, PHASE2_X_END, SPEED,
                       Phase2Result, StudyOptions, config_params)


def fp_learner_argv(spec, fp_store: Path) -> list:
    """The first-passage learner beside the paper's: the layout's learner spec renamed
    (node ``learner_fp``, so ``~/reset`` is /learner_fp/reset), with its own store and
    its value function and fit status on their own topics."""
    params = {**config_params('learner'), **spec.params,
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
           'seed': subject.seed, 'robots': ['robot_0'], 'model': opts.supervisor}
    layout = team_layout(1, opts.rate_factor, seed=subject.seed % 1_000_000, step=opts.step,
                         with_filter=False, learner_store=store,
                         overrides={'world': {'respawn': False, 'robots': ['robot_0'], 'n_obstacles': 0},
                                    # every fit as a message: the study reads each fit from it
                                    'learner': {'estimator': 'paper', 'alpha_k': 0.0,
                                                'republish_level_tolerance': 0.0},
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


def run_phase2(subject: Subject, opts: StudyOptions, domain_id: int, log_dir: Path,
               with_fp: bool = True) -> Phase2Result:
    """Phase II of ``subject`` on its own graph (logs in ``log_dir``); ``with_fp``: with the
    first-passage learner (Learned FP) beside the paper's."""
    env = team_env(domain_id)
    log_dir.mkdir(parents=True, exist_ok=True)
    store = log_dir / 'interventions.jsonl'
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
                                readers=4 if with_fp else 3,
                                learners=('learner', FP_LEARNER) if with_fp else ('learner',))
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
        from ..ros_io.vfmsg import msg_metadata    # ROS message types: only when the graph ran
        meta = msg_metadata(vf_msg)
        fit = {k: meta.get(k) for k in ('omega_max', 'mu', 'sigma', 'alpha', 'log_likelihood',
                                        'estimator', 'interventions')}
    # sim time the scenes spanned (the clock also ran, parked, while the graph settled
    # and while the learner fitted)
    span = scenes[-1]['end_time'] - scenes[0]['start_time'] if scenes else 0.0
    return Phase2Result(scenes, states, vf_msg, fit, span, time.monotonic() - t0, notes, fp_msg, fp_fit)


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
