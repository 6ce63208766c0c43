"""`supersafe study` and `supersafe demo`: the paper's study in simulation.

By default (``--engine core``) every phase runs in this process with the package's
ROS-free modules (``study.engine``); ``--engine graph`` runs it through the real node
graph (the through-the-graph validation). See docs/study.md and ``supersafe_ros.study.runner``.
The study's modules are imported when a command runs (scipy, the value functions): `supersafe`
imports this module only to build its parser.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
import sys
import time

from .analysis import CONDITIONS, LABELS, PAPER_STATS, format_h2, format_table1, ordered
from .engines import ENGINES
from .posthoc import format_posthoc
from .online import format_online
from .validity import format_validity

DEMO_SUBJECTS = 3
DEMO_SEED = 7


def _add_common(parser, subjects_default):
    parser.add_argument('--subjects', type=int, default=subjects_default, help='number of simulated subjects')
    parser.add_argument('--seed', type=int, default=0, help='seed of subjects and world layouts')
    parser.add_argument('--out', type=Path, default=Path('study-out'), help='plots, logs and results go here')
    parser.add_argument('--json', type=Path, default=None, help='results JSON (default <out>/study.json)')
    parser.add_argument('--conditions', type=str, default=None,
                        help='comma-separated safe sets to play in Phase III, of '
                             f'{",".join(CONDITIONS)} (default all; the graph engine: all but learned_online): '
                             'learned = the paper\'s estimator (learner node), learned_fp = first-passage (from the '
                             'recorded approaches), learned_online = learned_fp\'s set refitted during the game from '
                             'the team\'s own encounters (core engine)')
    parser.add_argument('--step', type=float, default=0.2,
                        help='sim seconds per lockstep step (default 0.2: ~20x real time on 2 cores; '
                             '0.05 is the team default, ~4x slower)')
    parser.add_argument('--rate-factor', type=float, default=0.0,
                        help='sim seconds per wall second (0: as fast as the graph allows)')
    parser.add_argument('--game-seconds', type=float, default=120.0, help='sim seconds per Phase III game')
    parser.add_argument('--phase2-offsets', type=str, default=None,
                        help='comma-separated lateral offsets [m] (default the 0.25 m ladder in [-2.25, 2.25])')
    parser.add_argument('--sweep-subjects', type=int, default=2,
                        help='observed alpha sweep (extra Learned games at mu+sigma, mu+2sigma) for the '
                             'first k subjects (default 2; 0 = predicted sweep only)')
    parser.add_argument('--phase3', choices=('same-world', 'paper'), default='same-world',
                        help='same-world (default: each condition once on the subject\'s world, common random '
                             'numbers) or paper (six games: three pairwise comparisons on six task versions; '
                             'FP per treatment = the mean of its two games; see docs/study.md)')
    _add_population(parser)
    _add_supervisor(parser)
    _add_engine(parser)
    parser.add_argument('--domain-id', type=int, default=None, help='ROS_DOMAIN_ID (graph engine; '
                        'default inherited)')
    parser.add_argument('--no-plots', action='store_true', help='skip the PNG figures')


def _add_population(parser):
    parser.add_argument('--population', default='pilots', metavar='pilots|paper|FILE.json',
                        help='who the simulated subjects are: pilots (default; the authors\' five pilot '
                             'supervisors, fitted), paper (calibrated so that Phase II reproduces the paper\'s '
                             'Table 1 and Fig. 6 mix), or a population file (supersafe population calibrate / '
                             'from-sessions)')


def _add_supervisor(parser):
    from ..sim.supervisor_models import DEFAULT_MODEL, MODELS
    parser.add_argument('--supervisor', choices=MODELS, default=DEFAULT_MODEL,
                        help=f'how the simulated supervisors decide (default {DEFAULT_MODEL}): memoryless '
                             '(the paper\'s: intervene when V_S <= mu + w, whatever the robot did), attentive '
                             '(no intervention while the robot\'s turns away from that obstacle show it has '
                             'seen it); docs/study.md, "Supervisor models"')


def _add_engine(parser):
    parser.add_argument('--engine', choices=ENGINES, default='core',
                        help='core (default): the same closed loop in this process with the ROS-free '
                             'core modules, deterministic for a seed, ~2 ms of CPU per lockstep step (plus '
                             'each new obstacle cluster\'s value, solved once into the cache); graph: every '
                             'Phase II scene and game through the real ROS node graph (the through-the-graph '
                             'validation, ~30 ms CPU per step over 8 processes)')
    parser.add_argument('--workers', type=int, default=0,
                        help='core engine: subjects run in this many processes (default 0: one per core); '
                             'the results do not depend on it')
    parser.add_argument('--scheduler', default='', metavar='ADDRESS',
                        help='core engine: run the subjects on a Dask distributed cluster, this scheduler\'s '
                             'address (e.g. tcp://10.0.0.5:8786); its workers need supersafe_ros and '
                             '$SUPERSAFE_CACHE; the same records as a local run')


def add_parser(subparsers):
    study = subparsers.add_parser('study', help='the paper study in simulation (Phase II, fit, Phase III)',
                                  description=__doc__.splitlines()[0])
    _add_common(study, 12)
    study.set_defaults(func=run)
    study.epilog = 'engines: see docs/study.md, "Two engines"'

    demo = subparsers.add_parser(
        'demo', help=f'a small study: {DEMO_SUBJECTS} subjects, seed {DEMO_SEED}, out ./study-out',
        description='A small study (3 simulated supervisors); prints Table 1 and where the plots are. '
                    'Builds the value-function cache on first use.')
    _add_population(demo)
    _add_supervisor(demo)
    _add_engine(demo)
    demo.add_argument('--domain-id', type=int, default=None, help='ROS_DOMAIN_ID (graph engine; default '
                      'inherited)')
    demo.add_argument('--out', type=Path, default=Path('study-out'), help='output directory')
    demo.set_defaults(func=run_demo)
    from .population_cli import add_parser as add_population_parser
    add_population_parser(subparsers)
    return study


def run_demo(args) -> int:
    args.subjects, args.seed, args.json = DEMO_SUBJECTS, DEMO_SEED, None
    args.conditions = None           # every condition the engine runs
    args.step, args.rate_factor, args.game_seconds = 0.2, 0.0, 120.0
    args.phase2_offsets, args.sweep_subjects, args.no_plots = None, 1, False
    return run(args)


def parse_conditions(text: str) -> tuple:
    """'standard,learned' -> ('standard', 'learned') in Table 1 order; ValueError if unknown."""
    names = [c.strip() for c in str(text).split(',') if c.strip()]
    if not names:
        raise ValueError('no conditions given')
    return tuple(ordered(names))


def options_from_args(args):
    from .engines import check_conditions, engine_named
    from .protocol import StudyOptions
    engine = engine_named(getattr(args, 'engine', 'core'))
    conditions = args.conditions or ','.join(engine.conditions)
    opts = StudyOptions(subjects=args.subjects, seed=args.seed, step=args.step,
                        rate_factor=args.rate_factor, game_seconds=args.game_seconds,
                        conditions=parse_conditions(conditions),
                        out_dir=Path(args.out), domain_id=args.domain_id,
                        sweep_subjects=max(0, args.sweep_subjects), plots=not args.no_plots,
                        engine=engine.name, workers=max(0, getattr(args, 'workers', 0)),
                        scheduler=getattr(args, 'scheduler', '') or '')
    opts.supervisor = getattr(args, 'supervisor', opts.supervisor)
    if opts.scheduler and not engine.parallel_subjects:
        raise ValueError(f'--scheduler runs subjects in parallel: the {engine.name} engine runs them one at a time')
    check_conditions(engine, opts.conditions)
    opts.phase3 = getattr(args, 'phase3', 'same-world')
    if opts.phase3 == 'paper':
        from .design import TREATMENTS
        if args.conditions and set(opts.conditions) != set(TREATMENTS):
            raise ValueError('--phase3 paper plays the paper\'s three treatments (standard, learned, '
                             'conservative): leave --conditions out')
        opts.conditions = tuple(ordered(TREATMENTS))
    if args.phase2_offsets:
        opts.phase2_offsets = tuple(float(v) for v in args.phase2_offsets.split(',') if v.strip())
    return opts


def run(args, out=sys.stdout) -> int:
    from ..rosenv import ensure_local_ros_env
    ensure_local_ros_env()
    from .population import load_population
    from .plots import make_plots
    from .protocol import reference_sets
    from .records import jsonable
    from .runner import run_study
    from .summary import summarize
    if args.subjects < 1 or args.game_seconds <= 0 or args.step <= 0:
        print('need --subjects >= 1, --game-seconds > 0, --step > 0', file=sys.stderr)
        return 2
    try:
        opts = options_from_args(args)
    except ValueError as exc:
        print(f'supersafe study: {exc}', file=sys.stderr)
        return 2
    t0 = time.monotonic()
    print('preparing the value functions (cached after the first run) ...', file=out, flush=True)
    from ..reach.library import load_or_build_library
    load_or_build_library()          # the learner's library, built once into the cache
    standard_vf, conservative_vf = reference_sets()
    print(f'ready in {time.monotonic() - t0:.1f} s', file=out, flush=True)
    try:
        population = load_population(getattr(args, 'population', 'pilots'))
    except ValueError as exc:
        print(f'supersafe study: {exc}', file=sys.stderr)
        return 2
    if population.name == 'pilots':
        print(f'population: the five pilots fitted from {population.source}', file=out, flush=True)
    else:
        print(f'population: {population.name} ({population.source}): '
              + ', '.join(f'{m.name} x{m.weight:g} (w_S {m.omega_max:g}, mu {m.mu:g}, sigma {m.sigma:g})'
                          for m in population.members), file=out, flush=True)
    print(f'supervisor model: {opts.supervisor} (docs/study.md, "Supervisor models")', file=out, flush=True)
    subjects = population.draw(opts.subjects, opts.seed)
    try:
        raw = run_study(subjects, opts, out=out)
    except KeyboardInterrupt:
        print('study interrupted; every process of the running phase was stopped', file=out)
        return 130
    summary = summarize(raw['records'], standard_vf, conservative_vf, opts.sweep_k)
    total = time.monotonic() - t0
    summary['timing'] = {'study_wall_s': raw['wall'], 'total_wall_s': total,
                         'phase2_wall_s': [r['phase2']['wall'] for r in raw['records']],
                         'game_wall_s': [g['wall'] for r in raw['records']
                                         for g in (r.get('plays') or list(r['games'].values()))
                                         + [v for k, v in r['sweep'].items() if k or r.get('plays')]],
                         'load_average': list(os.getloadavg())}
    summary['population'] = population.describe()
    if population.name == 'pilots':
        summary['population']['pilots'] = summary['population']['members']
    summary['options'] = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(opts).items()}
    out_dir = Path(opts.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = make_plots(out_dir, summary, raw['records'], standard_vf, conservative_vf) if opts.plots else []
    json_path = args.json or out_dir / 'study.json'
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(jsonable(summary), indent=1))
    print('', file=out)
    if opts.phase3 == 'paper':
        print('Phase III as the paper ran it: six games per subject (three pairwise comparisons, six task '
              'versions); average FP per treatment = the mean of its two games', file=out)
    print(format_table1(summary['table1']), file=out)
    a = summary['anova']
    print(f"\nrepeated-measures ANOVA (false positives): F({a['df_num']:g}, {a['df_den']:g}) = "
          f"{a['F']:.3g}, p = {a['p']:.3g}" + (f"  ({a['note']})" if 'note' in a else '')
          + f"   [paper: {PAPER_STATS['anova']}]", file=out)
    print(format_posthoc(summary['posthoc'], LABELS, PAPER_STATS['tukey'], summary['tukey']), file=out)
    print('\nmodel validity (95 % CIs; study.validity):', file=out)
    print(format_validity(summary['validity']), file=out)
    if summary.get('online'):
        print('\nlearning from the games (learned_online; study.online):', file=out)
        print(format_online(summary['online']), file=out)
    print('\nH2, efficiency: mean (sd) over subjects', file=out)
    print(format_h2(summary['h2']), file=out)
    for c, v in summary['conditions'].items():
        print(f"{c:13s} interventions {sum(v['interventions']):6g}  crashes {sum(v['crashes']):5g}  "
              f"trips {sum(v['trips']):6g}  (sums over subjects"
              + ('; per subject the mean of its two games)' if opts.phase3 == 'paper' else ')'), file=out)
    print(f'\n{len(subjects)} subjects in {total:.0f} s wall ({opts.engine} engine); results {json_path}',
          file=out)
    if paths:
        print('plots: ' + ', '.join(str(p) for p in paths), file=out)
    return 0
