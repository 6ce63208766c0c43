"""The study, subject by subject: Phase II, the fits, Phase III, on one of two engines.

``StudyOptions.engine`` names the engine (``engines.engine_named``): ``core`` (the default)
runs every phase in this process with the package's ROS-free modules (the same parameters
and order of events as the graph, deterministic for a seed, ~100x less CPU); ``graph`` runs
them through the real node graph (the through-the-graph validation). The runner asks the
engine (``engines.Engine``) for each subject's Phase II and games; both give the same
records, so the summary, plots, JSON and power do not care which ran. An engine whose
subjects may run in parallel (the core engine) runs them in worker processes
(``opts.workers``) or on a Dask cluster (``opts.scheduler``); the records are the same.

Per subject (a simulated supervisor from ``population.draw_subjects``), ``run_subject``:

1. Phase II: the engine's ``phase2``;
2. the fits: ``fits.learned_value_functions`` (Learned: the paper's estimator, alpha = mu;
   Learned FP: first-passage), and ``fits.offline_cross_check`` beside the latter;
3. Phase III: one game per condition and alpha-sweep game, each the condition's set
   (``protocol.condition_set``) played by the engine's ``games``. Same world seed for every
   condition of a subject (common random numbers: ``phase3`` same-world), or (``phase3``
   paper) the six games of the subject's row of ``design.paper_plan`` (row = the subject's
   index), each on its task version's world, a treatment's counts the mean of its two games.

The records become JSON with ``records``, the study's numbers with ``summary`` and its
figures with ``plots.make_plots``.
"""
from __future__ import annotations

import os
from pathlib import Path
import sys
import time

from ..session.protocol import write_subject
from .analysis import ordered
from .design import paper_plan, treatment_means, version_world_seed
from .engines import Engine, check_conditions, engine_named
from .fits import learned_value_functions, offline_cross_check
from .protocol import StudyOptions, condition_set, sweep_condition
from .records import game_counts


class Progress:
    """One line per phase: subject i/N, phase, sim time, wall time."""

    def __init__(self, n: int, out=sys.stdout):
        self.n, self.out, self.t0 = n, out, time.monotonic()

    def line(self, i: int, phase: str, sim_time=None, extra: str = ''):
        sim = f'sim {sim_time:7.1f} s' if sim_time is not None else ' ' * 13
        print(f'[subject {i + 1:2d}/{self.n}] {phase:<22s} {sim}  wall {time.monotonic() - self.t0:7.1f} s'
              f'{"  " + extra if extra else ""}', file=self.out, flush=True)


def run_study(subjects: list, opts: StudyOptions, out=sys.stdout) -> dict:
    """Run every subject on ``opts.engine``; returns the raw per-subject records (see
    ``summarize``). An engine with ``parallel_subjects`` runs them in parallel processes
    (``opts.workers``) or on a cluster (``opts.scheduler``): subjects are independent, and each
    subject's record depends on its seeds only, so the records are the same whatever the
    number of workers."""
    engine = engine_named(opts.engine)
    conditions = ordered(opts.conditions)
    check_conditions(engine, conditions)
    progress = Progress(len(subjects), out)
    t_start = time.monotonic()
    workers = (opts.workers or os.cpu_count() or 1) if engine.parallel_subjects else 1
    workers = max(1, min(int(workers), len(subjects)))
    if engine.parallel_subjects and opts.scheduler:
        records = on_cluster(engine, subjects, opts, conditions, progress)
    elif workers > 1:
        import concurrent.futures
        import multiprocessing
        # fork: the workers inherit the loaded value functions (an engine whose subjects run
        # in parallel runs no rclpy in this process)
        with concurrent.futures.ProcessPoolExecutor(
                workers, mp_context=multiprocessing.get_context('fork')) as pool:
            jobs = [pool.submit(_worker_subject, engine, i, subject, opts, conditions, progress.n, progress.t0)
                    for i, subject in enumerate(subjects)]
            records = [j.result() for j in jobs]
    else:
        records = [run_subject(engine, i, subject, opts, conditions, progress)
                   for i, subject in enumerate(subjects)]
    for i, rec in enumerate(records):
        # the subject's files, in the layout a human participant's session also writes
        # (session/protocol.py), so the analysis can mix the two
        write_subject(Path(opts.out_dir) / 'subjects' / f's{i:02d}', rec)
    return {'records': records, 'wall': time.monotonic() - t_start}


def on_cluster(engine: Engine, subjects, opts, conditions, progress) -> list:
    """The subjects as tasks on a Dask distributed cluster (``opts.scheduler``: its
    scheduler's address). A subject's record depends on its seeds only, so the records are
    those of a local run. The workers need this package and its value-function cache
    (``$SUPERSAFE_CACHE``) as this process has them; each prints its subjects' progress in its
    own log, and this process one line per finished subject."""
    from distributed import Client, as_completed
    records = [None] * len(subjects)
    with Client(opts.scheduler, timeout=60) as client:
        futures = {client.submit(_worker_subject, engine, i, subject, opts, conditions, progress.n, progress.t0,
                                 pure=False, key=f'supersafe-subject-{opts.seed}-{i}-{time.time_ns()}'): i
                   for i, subject in enumerate(subjects)}
        for future in as_completed(futures):
            i = futures[future]
            records[i] = future.result()
            games = records[i]['games']
            progress.line(i, 'done on the cluster', None,
                          ', '.join(f'{c} FP {g["false_positives"]}' for c, g in games.items()))
    return records


def _worker_subject(engine: Engine, i, subject, opts, conditions, n: int, t0: float) -> dict:
    """One subject in a worker process (its progress lines on the worker's stdout)."""
    progress = Progress(n, sys.stdout)
    progress.t0 = t0
    return run_subject(engine, i, subject, opts, conditions, progress)


def run_subject(engine: Engine, i, subject, opts, conditions, progress) -> dict:
    """Phase II, fits and Phase III of subject ``i`` on ``engine``."""
    rec = {'subject': subject.to_dict(), 'games': {}, 'sweep': {}, 'fits': {}, 'learned_vfs': {}}
    progress.line(i, 'phase II', None, f'w_max {subject.omega_max:g} mu {subject.mu:g} '
                  f'sigma {subject.sigma:g}, {len(opts.phase2_offsets)} offsets')
    p2 = engine.phase2(i, subject, opts, with_fp=bool({'learned_fp', 'learned_online'} & set(conditions)))
    rec['phase2'] = {'scenes': [{k: v for k, v in s.items() if k != 'frames'} for s in p2.scenes],
                     'interventions': len(p2.states), 'sim_time': p2.sim_time, 'wall': p2.wall,
                     'notes': p2.notes, 'engine': engine.name}
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
        for c, f in rec['fits'].items() if c != 'learned_online')   # it starts from learned_fp's
        + ''.join(f'; {n}' for n in p2.notes))
    world_seed = opts.seed * 1000 + i
    learned = {c: (rec['learned_vfs'][c], rec['fits'][c]) for c in fits}
    if opts.phase3 == 'paper':       # the paper's six games, each on its task version
        design = paper_plan(i)
        rec['design'] = {'form': 'paper', 'row': design['row']}
        games = [(g['treatment'], 0.0, g) for g in design['games']]
    else:                            # each condition once on the subject's world
        games = [(c, 0.0, None) for c in conditions]
    swept = sweep_condition(conditions)
    if i < opts.sweep_subjects and swept and rec['fits'].get(swept):
        # on the subject's own world; the paper's form plays its alpha = mu game there too
        # (its Learned games are on other worlds)
        games += [(swept, k, None) for k in opts.sweep_k if k != 0.0 or opts.phase3 == 'paper']
    plays = []
    subject_games = engine.games(i, subject, world_seed, p2, opts)
    try:
        for cond, k, planned in games:
            seed = version_world_seed(planned['version'], opts.seed) if planned else world_seed
            chosen = condition_set(cond, learned, k)
            result = subject_games.play(chosen, seed)
            g = game_counts(result)
            g.update(wall=result['wall'], wall_running=result['wall_running'], cpu_s=result['cpu_s'],
                     cpu_by_process=result['cpu_by_process'],
                     resends=result['resends'], set=chosen.ran, engine=engine.name,
                     alpha=chosen.alpha, complete=g['sim_time'] >= opts.game_seconds - 1e-6,
                     trace=result.get('trace'),         # core engine only (study.game_trace)
                     online=result.get('online'))       # learned_online: its refits (study.online)
            if planned:
                plays.append(dict(g, **planned, world_seed=seed))
                name = f'game {planned["game"]} {cond} v{planned["version"]}'
            elif k == 0.0 and opts.phase3 != 'paper':
                rec['games'][cond] = g
                name = f'phase III {cond}'
            else:
                rec['sweep'][k] = g
                name = f'sweep mu+{k:g}sigma'
            progress.line(i, name, g['sim_time'],
                          f'FP {g["false_positives"]} int {g["interventions"]} crashes {g["crashes"]} '
                          f'trips {g["trips"]} arc {g["avoidance_length"]:.2f} m '
                          f'({g["wall"]:.1f} s)')
        if plays:
            rec['plays'] = plays
            rec['games'] = treatment_means(plays)
        if swept in rec['games'] and rec['sweep'] and 0.0 not in rec['sweep']:
            rec['sweep'][0.0] = rec['games'][swept]
    finally:
        subject_games.close()
    return rec
