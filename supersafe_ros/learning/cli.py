"""`supersafe fit`: learn a supervisor's safe set from interventions (issue 3).

    supersafe fit DATA.csv [--estimator paper|first-passage] --speed V --radius R
        --horizon T --grid-min XMIN YMIN --grid-max XMAX YMAX --shape NX NY NTH
        --omega-max W1 W2 ... [--true-omega-max W | --no-prior] [--json] [--plot FILE.png]

DATA.csv holds intervention states (t_ms,x,y,theta) or encounters
(scene,t,x,y,theta,intervened); the kind is read from the header. The paper's
estimator uses the intervention states of either. The first-passage estimator needs
encounters; given intervention states it rebuilds the Phase II approaches (straight
passes heading 0 from x = -8 at the intervention's y) and conditions on each having
had an intervention, since the passes without one are not in such files.
The library comes from the reachability core's cache (built on first use).
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

DEFAULT_OMEGAS = (0.0, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0, 1.5, 2.0, 2.5, 3.0)


def add_parser(subparsers):
    p = subparsers.add_parser(
        'fit', help="learn a supervisor's safe set from interventions",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('data', metavar='DATA.csv', help='interventions or encounters CSV')
    p.add_argument('--estimator', choices=('paper', 'first-passage'), default='paper')
    lib = p.add_argument_group('library (the reachability core\'s LibrarySpec)')
    lib.add_argument('--speed', type=float, default=3.0, help='robot speed V [m/s]')
    lib.add_argument('--radius', type=float, default=1.8, help='obstacle radius R [m]')
    lib.add_argument('--horizon', type=float, default=3.0, help='avoid horizon T [s]')
    lib.add_argument('--grid-min', type=float, nargs=2, default=(-8.0, -8.0), metavar=('XMIN', 'YMIN'))
    lib.add_argument('--grid-max', type=float, nargs=2, default=(8.0, 8.0), metavar=('XMAX', 'YMAX'))
    lib.add_argument('--shape', type=int, nargs=3, default=(65, 65, 42), metavar=('NX', 'NY', 'NTH'))
    lib.add_argument('--omega-max', type=float, nargs='+', default=list(DEFAULT_OMEGAS),
                     metavar='W', help='turn-rate bounds of the library entries')
    lib.add_argument('--cache-dir', default=None, help='value-function cache (default: the core\'s)')
    prior = p.add_mutually_exclusive_group()
    prior.add_argument('--true-omega-max', type=float, default=1.0, metavar='W',
                       help='true dynamics for the conservative prior')
    prior.add_argument('--no-prior', action='store_true', help='every library entry is admissible')
    lvl = p.add_mutually_exclusive_group()
    lvl.add_argument('--alpha-k', type=float, default=0.0, metavar='K', help='alpha = mu + K sigma')
    lvl.add_argument('--fp-rate', type=float, default=None, metavar='RATE',
                     help='choose alpha for this predicted false-positive rate instead')
    fp = p.add_argument_group('first-passage options')
    fp.add_argument('--lapse', type=float, default=0.0,
                    help='probability of a lapse judgement (robustness; 0 = pure model)')
    fp.add_argument('--phase2-dt', type=float, default=0.02, metavar='DT',
                    help='frame step [s] when rebuilding Phase II approaches from interventions')
    fp.add_argument('--phase2-x0', type=float, default=-8.0, metavar='X0',
                    help='start x of the Phase II passes')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    p.add_argument('--plot', metavar='FILE.png', default=None,
                   help='draw the interventions over the learned value at theta = 0, beside the standard set')
    p.set_defaults(func=run)
    return p


def _error(msg) -> int:
    print(f'supersafe fit: error: {msg}', file=sys.stderr)
    return 2


def run(args) -> int:
    from . import data as D
    from . import estimators as E

    # -- data -------------------------------------------------------------------------
    try:
        kind = D.detect_csv_kind(args.data)
        if kind == 'encounters':
            encounters = D.read_encounters_csv(args.data)
            states = D.intervention_states(encounters)
        else:
            states = D.read_interventions_csv(args.data)
            encounters = None
    except (OSError, ValueError, StopIteration) as exc:
        return _error(f'cannot read {args.data}: {exc}')
    if args.fp_rate is not None and not (0.0 < args.fp_rate < 1.0):
        return _error(f'--fp-rate must be in (0, 1), got {args.fp_rate}')
    if not (0.0 <= args.lapse < 1.0):
        return _error(f'--lapse must be in [0, 1), got {args.lapse}')

    # -- library ----------------------------------------------------------------------
    try:
        library, true_vf, standard = _library(args)
    except (ValueError, OSError) as exc:
        return _error(f'library: {exc}')
    entries = library.entries

    # -- fit ----------------------------------------------------------------------------
    notes = []
    try:
        if args.estimator == 'paper':
            if len(states) == 0:
                return _error(f'{args.data}: no intervention states')
            result = E.fit_paper(entries, states, true_vf=true_vf, alpha_k=args.alpha_k)
        else:
            conditional = False
            if encounters is None:
                encounters = D.encounters_from_phase2_interventions(
                    states, speed=args.speed, radius=args.radius, x0=args.phase2_x0, dt=args.phase2_dt)
                conditional = True
                notes.append('first-passage on intervention states: Phase II approaches rebuilt '
                             f'(straight from x = {args.phase2_x0:g}, heading 0, frames every '
                             f'{args.phase2_dt:g} s) and each conditioned on having an intervention; '
                             'passes without one are not in the file')
            result = E.fit_first_passage(entries, encounters, true_vf=true_vf, alpha_k=args.alpha_k,
                                         conditional=conditional, lapse=args.lapse)
    except ValueError as exc:
        return _error(str(exc))
    result.notes = notes + result.notes
    if args.fp_rate is not None:
        result.alpha = E.alpha_for_fp_rate(result.mu, result.sigma, args.fp_rate)
    fp_fraction = (E.predicted_false_positive_fraction(result.value_function, result.alpha, states)
                   if len(states) else float('nan'))

    if args.plot:
        try:
            from .plots import plot_fit
            plot_fit(args.plot, result.value_function, result.mu, states, standard, alpha=result.alpha,
                     radius=args.radius,
                     title=f'{args.data.rsplit("/", 1)[-1]}: {result.estimator} estimator')
        except (OSError, ValueError) as exc:
            return _error(f'cannot write plot {args.plot}: {exc}')

    if args.json:
        d = result.to_dict()
        d['predicted_false_positive_fraction'] = E._num(fp_fraction)
        d['prior'] = None if args.no_prior else {'true_omega_max': args.true_omega_max}
        print(json.dumps(d))
    else:
        print(format_table(result, args, fp_fraction, len(states)))
    return 0


def _library(args):
    """The library from the core's cache, the true dynamics' value function (None with
    --no-prior) and the standard set for the plot."""
    from ..reach.grid import Grid
    from ..reach.library import LibrarySpec, load_or_build_library, load_or_solve

    omegas = tuple(sorted(set(float(w) for w in args.omega_max)))
    if any(not np.isfinite(w) or w < 0 for w in omegas):
        raise ValueError(f'--omega-max values must be finite and >= 0, got {args.omega_max}')
    spec = LibrarySpec(speed=args.speed, radius=args.radius, omegas=omegas, horizon=args.horizon,
                       lo=tuple(args.grid_min), hi=tuple(args.grid_max), shape=tuple(args.shape))
    library = load_or_build_library(spec, cache_dir=args.cache_dir)
    w_true = float(args.true_omega_max)
    if not (np.isfinite(w_true) and w_true >= 0):
        raise ValueError(f'--true-omega-max must be finite and >= 0, got {w_true}')
    match = [e for e in library.entries if e.meta.get('omega_max') is not None
             and abs(float(e.meta['omega_max']) - w_true) < 1e-12]
    if match:
        true_vf = match[0]
    else:
        grid = Grid(tuple(args.grid_min), tuple(args.grid_max), tuple(args.shape))
        true_vf = load_or_solve(grid, args.speed, w_true, args.radius, args.horizon,
                                cache_dir=args.cache_dir)
    return library, (None if args.no_prior else true_vf), true_vf


def format_table(result, args, fp_fraction, n_states) -> str:
    prior = 'none' if args.no_prior else f'true omega_max {args.true_omega_max:g}'
    what = (f'{result.interventions} interventions' if result.encounters is None else
            f'{result.encounters} encounters, {result.interventions} interventions')
    lines = [f'supersafe fit: {result.estimator} estimator, {what}; library of '
             f'{len(result.candidates)} entries (speed {args.speed:g}, radius {args.radius:g}, '
             f'horizon {args.horizon:g}); conservative prior: {prior}',
             '',
             f'   {"omega_max":>9} {"mu":>8} {"sigma":>8} {"log-lik":>10}  admissible']
    for i, c in enumerate(result.candidates):
        mark = '*' if i == result.index else ' '
        ll = c['log_likelihood']
        lines.append(f' {mark} {c["omega_max"]:9.3f} {_f(c["mu"])} {_f(c["sigma"])} '
                     f'{(f"{ll:10.2f}" if np.isfinite(ll) else "      -inf")}  '
                     f'{"yes" if c["admissible"] else "no"}')
    lines += ['',
              f'chosen: omega_max {result.omega_max:g}, mu {result.mu:.4f}, sigma {result.sigma:.4f}, '
              f'alpha {result.alpha:.4f}',
              f'predicted false positives at alpha: {fp_fraction:.1%} of {n_states} intervention states '
              'inside {V > alpha}']
    lines += [f'note: {n}' for n in result.notes]
    return '\n'.join(lines)


def _f(v):
    return f'{v:8.4f}' if np.isfinite(v) else f'{"-":>8}'
