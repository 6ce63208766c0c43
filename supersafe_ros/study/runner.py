"""The study, subject by subject: Phase II, the fits, Phase III, on one of two engines.

``StudyOptions.engine``: ``core`` (the default) runs every phase in this process with the
package's ROS-free modules (``engine.CoreStudy``: the same parameters and order of events
as the graph, deterministic for a seed, ~100x less CPU); ``graph`` runs them through the
real node graph (the through-the-graph validation). Both give the same records, so the
summary, plots, JSON and power do not care which ran.

Per subject (a simulated supervisor from ``population.draw_subjects``), ``run_subject``:

1. Phase II: ``engine.CoreStudy.phase2``, or ``graph_phase2.run_phase2`` (a light graph,
   the study's conductor, the paper's and the first-passage learner nodes);
2. the fits: ``fits.learned_value_functions`` (Learned: the paper's estimator, alpha = mu;
   Learned FP: first-passage), and ``fits.offline_cross_check`` beside the latter;
3. Phase III: one game per condition and alpha-sweep game, played by ``CoreGames`` (in
   this process) or ``GraphGames`` (one kept-alive team graph per subject, reset between
   games, ``games.GameGraph``; the condition's safe set reaches the filters as a latched
   value-function message). Same world seed for every condition of a subject (common
   random numbers: ``phase3`` same-world), or (``phase3`` paper) the six games of the
   subject's row of ``design.paper_plan`` (row = the subject's index), each on its task
   version's world, a treatment's counts the mean of its two games.

The records become JSON with ``records``, the study's numbers with ``summary`` and its
figures with ``plots.make_plots``.
"""
from __future__ import annotations

import functools
import os
from pathlib import Path
import sys
import time

from ..session.protocol import write_subject
from ..sim.supervisor_models import DEFAULT_MODEL
from ..team import team_env
from .analysis import ordered
from .design import paper_plan, treatment_means, version_world_seed
from .engine import CoreStudy
from .fits import learned_value_functions, offline_cross_check
from .games import GameGraph, condition_message
from .graph_phase2 import run_phase2
from .population import Subject
from .protocol import ENGINES, StudyOptions, supervisor_seed, sweep_condition
from .records import game_counts


class Progress:
    """One line per phase: subject i/N, phase, sim time, wall time."""

    def __init__(self, n: int, out=sys.stdout):
        self.n, self.out, self.t0 = n, out, time.monotonic()

    def line(self, i: int, phase: str, sim_time=None, extra: str = ''):
        sim = f'sim {sim_time:7.1f} s' if sim_time is not None else ' ' * 13
        print(f'[subject {i + 1:2d}/{self.n}] {phase:<22s} {sim}  wall {time.monotonic() - self.t0:7.1f} s'
              f'{"  " + extra if extra else ""}', file=self.out, flush=True)


def supervisor_params(subject: Subject, model: str = DEFAULT_MODEL) -> dict:
    return {'w_max': subject.omega_max, 'mu': subject.mu, 'sigma': subject.sigma, 'model': model}


class GraphGames:
    """Phase III of one subject through its kept-alive node graph (``games.GameGraph``)."""

    def __init__(self, subject, world_seed: int, opts: StudyOptions, env: dict, log_dir: Path):
        self.subject, self.world_seed, self.opts = subject, world_seed, opts
        self.graph = GameGraph(env, world_seed, supervisor_params(subject, opts.supervisor), opts.step,
                               opts.rate_factor, log_dir)

    def play(self, condition: str, learned: dict, k: float, world_seed: int | None = None):
        """(result dict of ``GameGraph.play``, alpha or None, the set that ran); ``world_seed``:
        another world than the subject's (a task version)."""
        msg, alpha, ran = condition_message(condition, learned, k)
        seed = self.world_seed if world_seed is None else world_seed
        result = self.graph.play(msg, seed, supervisor_seed(self.subject, seed),
                                 self.opts.game_seconds,
                                 self.opts.game_timeout + (120.0 if self.graph.games == 0 else 0.0))
        return result, alpha, ran

    def close(self):
        self.graph.close()


class CoreGames:
    """Phase III of one subject in this process (``engine.CoreStudy.play``); ``phase2``: its
    Phase II (the encounters ``learned_online`` goes on learning from)."""

    def __init__(self, core, subject, world_seed: int, opts: StudyOptions, phase2=None):
        self.core, self.subject, self.world_seed, self.opts = core, subject, world_seed, opts
        self.phase2 = phase2

    def play(self, condition: str, learned: dict, k: float, world_seed: int | None = None):
        safe_set, alpha, ran = self.core.safe_set(condition, learned, k)
        online = (self.phase2.fp_records if condition == 'learned_online' and ran == 'learned_online'
                  and k == 0.0 and self.phase2 is not None else None)
        seed = self.world_seed if world_seed is None else world_seed
        return (self.core.play(self.subject, seed, safe_set, self.opts, online_records=online),
                alpha, ran)

    def close(self):
        pass


def run_study(subjects: list, opts: StudyOptions, out=sys.stdout) -> dict:
    """Run every subject on ``opts.engine``; returns the raw per-subject records (see
    ``summarize``). The core engine runs subjects in parallel processes (``opts.workers``):
    subjects are independent, and each subject's record depends on its seeds only, so the
    records are the same whatever the number of workers."""
    if opts.engine not in ENGINES:
        raise ValueError(f"engine '{opts.engine}' is not one of {ENGINES}")
    conditions = ordered(opts.conditions)
    if opts.engine == 'graph' and 'learned_online' in conditions:
        raise ValueError('learned_online runs on the core engine only (its learner refits inside the game loop)')
    progress = Progress(len(subjects), out)
    t_start = time.monotonic()
    if opts.engine == 'core' and opts.scheduler:
        records = on_cluster(subjects, opts, conditions, progress)
    elif opts.engine == 'core':
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
            player = lambda world_seed, p2, i=i, subject=subject: GraphGames(  # noqa: E731
                subject, world_seed, opts, env, Path(opts.out_dir) / 'logs' / f's{i:02d}-phase3')
            phase2 = lambda subject, i=i: run_phase2(  # noqa: E731
                subject, opts, domain, Path(opts.out_dir) / 'logs' / f's{i:02d}-phase2', progress)
            records.append(run_subject(i, subject, opts, conditions, progress, phase2, player))
    for i, rec in enumerate(records):
        # the subject's files, in the layout a human participant's session also writes
        # (session/protocol.py), so the analysis can mix the two
        write_subject(Path(opts.out_dir) / 'subjects' / f's{i:02d}', rec)
    return {'records': records, 'wall': time.monotonic() - t_start}


def on_cluster(subjects, opts, conditions, progress) -> list:
    """The core engine's subjects as tasks on a Dask distributed cluster (``opts.scheduler``:
    its scheduler's address). A subject's record depends on its seeds only, so the records
    are those of a local run. The workers need this package and its value-function cache
    (``$SUPERSAFE_CACHE``) as this process has them; each prints its subjects' progress in its
    own log, and this process one line per finished subject."""
    from distributed import Client, as_completed
    records = [None] * len(subjects)
    with Client(opts.scheduler, timeout=60) as client:
        futures = {client.submit(_core_subject, i, subject, opts, conditions, progress.t0, pure=False,
                                 key=f'supersafe-subject-{opts.seed}-{i}-{time.time_ns()}'): i
                   for i, subject in enumerate(subjects)}
        for future in as_completed(futures):
            i = futures[future]
            records[i] = future.result()
            games = records[i]['games']
            progress.line(i, 'done on the cluster', None,
                          ', '.join(f'{c} FP {g["false_positives"]}' for c, g in games.items()))
    return records


@functools.lru_cache(maxsize=1)
def _core():
    return CoreStudy()


def _core_subject(i, subject, opts, conditions, t0, out=None):
    """One subject on the core engine (in a worker process, or here)."""
    progress = Progress(opts.subjects if opts.subjects else 1, out or sys.stdout)
    progress.t0 = t0
    core = _core()
    return run_subject(i, subject, opts, conditions, progress,
                       lambda subject: core.phase2(subject, opts, with_fp=bool({'learned_fp', 'learned_online'}
                                                                               & set(conditions))),
                       lambda world_seed, p2: CoreGames(core, subject, world_seed, opts, p2))


def run_subject(i, subject, opts, conditions, progress, phase2, player_for) -> dict:
    """Phase II, fits and Phase III of one subject; ``phase2(subject)`` -> Phase2Result,
    ``player_for(world_seed, phase2 result)`` -> GraphGames | CoreGames."""
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
    player = player_for(world_seed, p2)
    try:
        for cond, k, planned in games:
            seed = version_world_seed(planned['version'], opts.seed) if planned else None
            result, alpha, ran = player.play(cond, learned, k, seed)
            g = game_counts(result)
            g.update(wall=result['wall'], wall_running=result['wall_running'], cpu_s=result['cpu_s'],
                     cpu_by_process=result['cpu_by_process'],
                     resends=result['resends'], set=ran, engine=opts.engine,
                     alpha=alpha, complete=g['sim_time'] >= opts.game_seconds - 1e-6,
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
        player.close()
    return rec
