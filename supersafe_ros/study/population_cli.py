"""`supersafe population`: populations of simulated subjects for `supersafe study --population`.

* ``calibrate --target paper --out FILE.json``: the population whose Phase II reproduces
  the paper's Table 1 and Fig. 6 mix (``calibrate``; the method is in its docstring and
  docs/study.md), with the shares it achieves in expectation and in a seeded simulation of
  the study's Phase II. The package ships the result as ``study/data/paper_population.json``
  (``--population paper``).
* ``from-sessions DIR... --out FILE.json``: a population of real participants, one member
  per ``subject.json`` found under the folders (``supersafe session`` writes them; a
  simulated study's ``<out>/subjects`` too): the participant's fitted supervisor (the
  first-passage fit, which recovers w_S and mu, else the paper's), its learned set's type.
"""
from __future__ import annotations

import json
from pathlib import Path
import sys
import time

from .population import POPULATION_FORMAT

# a record's fits, by estimator: a session's keys, then a simulated study's
FIT_KEYS = {'first-passage': ('first_passage', 'learned_fp'), 'paper': ('paper', 'learned')}


def subject_fit(record: dict, estimator: str) -> dict | None:
    """The fit of ``estimator`` in a subject.json record (None if it has none)."""
    fits = record.get('fits') or {}
    for key in FIT_KEYS[estimator]:
        f = fits.get(key)
        if f and all(f.get(k) is not None for k in ('omega_max', 'mu', 'sigma')):
            return f
    return None


def from_subject_files(dirs, estimator: str = 'first-passage') -> dict:
    """A population file's content from every subject.json under ``dirs`` (module doc)."""
    from ..reach.library import load_or_build_library
    from .protocol import reference_sets
    from .set_types import count_types, set_shape
    standard_vf, conservative_vf = reference_sets()
    lib = load_or_build_library()
    files = sorted({p for d in dirs for p in Path(d).rglob('subject.json')})
    members, skipped = [], []
    for path in files:
        try:
            rec = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            skipped.append(f'{path}: unreadable ({exc})')
            continue
        fit = subject_fit(rec, estimator) or (subject_fit(rec, 'paper') if estimator != 'paper' else None)
        if fit is None:
            skipped.append(f'{path}: no fit (fewer than 3 interventions?)')
            continue
        subject = rec.get('subject') or {}
        name = str(subject.get('participant', subject.get('index', path.parent.name)))
        omega, mu, sigma = float(fit['omega_max']), max(float(fit['mu']), 0.0), float(fit['sigma'])
        try:
            kind = set_shape(lib.entry(omega), mu, standard_vf, conservative_vf).type
        except KeyError:
            skipped.append(f'{path}: omega_max {omega:g} is not in the library')
            continue
        members.append({'name': name, 'type': kind, 'weight': 1, 'omega_max': omega, 'mu': mu, 'sigma': sigma,
                        'estimator': fit.get('estimator', estimator), 'file': str(path)})
    if not members:
        raise ValueError(f'no subject.json with a fit under {[str(d) for d in dirs]}'
                         + (f' ({"; ".join(skipped[:3])})' if skipped else ''))
    return {'format': POPULATION_FORMAT, 'name': 'participants', 'source': 'supersafe population from-sessions',
            'members': members, 'mix': count_types(m['type'] for m in members), 'skipped': skipped,
            'estimator': estimator}


def add_parser(subparsers):
    p = subparsers.add_parser('population', help='populations of simulated subjects (calibrate, from-sessions)',
                              description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest='population_command', metavar='ACTION')
    cal = sub.add_parser('calibrate', help="a population whose Phase II reproduces a target study's Table 1")
    cal.add_argument('--target', choices=('paper',), default='paper', help='the study to reproduce (paper)')
    cal.add_argument('--out', type=Path, required=True, help='population FILE.json to write')
    cal.add_argument('--seed', type=int, default=0, help='seed of the realisations and of the check')
    cal.add_argument('--step', type=float, default=0.2, help="Phase II pose step [s] (the study's, 0.2)")
    cal.add_argument('--check-subjects', type=int, default=12, help='subjects per simulated check study (12)')
    cal.add_argument('--check-seeds', type=int, default=5, help='simulated check studies (seeds seed..seed+k-1)')
    cal.set_defaults(func=run_calibrate)
    ses = sub.add_parser('from-sessions', help="a population of real participants' fits (subject.json files)")
    ses.add_argument('dirs', nargs='+', type=Path, help='folders searched for subject.json')
    ses.add_argument('--out', type=Path, required=True, help='population FILE.json to write')
    ses.add_argument('--estimator', choices=tuple(FIT_KEYS), default='first-passage',
                     help='whose fit describes a participant (default first-passage; the paper\'s if absent)')
    ses.set_defaults(func=run_from_sessions)
    p.set_defaults(func=lambda args, out=sys.stdout: (p.print_help(out), 2)[1])
    return p


def _write(path: Path, doc: dict) -> None:
    from .records import jsonable
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(jsonable(doc), indent=1) + '\n')


def run_calibrate(args, out=sys.stdout) -> int:
    from ..learning.data import PHASE2_OFFSETS
    from .calibrate import TARGETS, calibrate, model_agreement, simulated_check
    from .population import population_from_dict
    if args.step <= 0 or args.check_subjects < 1 or args.check_seeds < 0:
        print('need --step > 0, --check-subjects >= 1, --check-seeds >= 0', file=sys.stderr)
        return 2
    t0 = time.monotonic()
    offsets = [float(v) for v in PHASE2_OFFSETS]
    doc = calibrate(TARGETS[args.target], offsets, args.step, args.seed,
                    progress=lambda line: print(line, file=out, flush=True))
    if args.check_seeds:
        pop = population_from_dict(doc, str(args.out))
        doc['achieved']['simulated'] = simulated_check(pop, args.check_subjects,
                                                       range(args.seed, args.seed + args.check_seeds),
                                                       offsets, args.step)
        doc['achieved']['model_agreement'] = model_agreement(pop, args.check_subjects, args.seed, offsets,
                                                             args.step)
    doc['calibration']['wall_s'] = round(time.monotonic() - t0, 1)
    _write(args.out, doc)
    print(format_population(doc), file=out)
    print(f'population written to {args.out} ({time.monotonic() - t0:.0f} s)', file=out)
    return 0


def run_from_sessions(args, out=sys.stdout) -> int:
    try:
        doc = from_subject_files(args.dirs, args.estimator)
    except ValueError as exc:
        print(f'supersafe population: {exc}', file=sys.stderr)
        return 2
    _write(args.out, doc)
    print(format_population(doc), file=out)
    for line in doc['skipped']:
        print(f'skipped {line}', file=out)
    print(f'population of {len(doc["members"])} participants written to {args.out}', file=out)
    return 0


def format_population(doc: dict) -> str:
    """Members, and the target and achieved shares when calibrated."""
    lines = [f'{"member":>18s} {"type":>13s} {"weight":>6s} {"w_S":>6s} {"mu":>6s} {"sigma":>6s}']
    for m in doc['members']:
        lines.append(f'{m["name"]:>18s} {m.get("type", ""):>13s} {m.get("weight", 1):>6g} {m["omega_max"]:>6g} '
                     f'{m["mu"]:>6.3g} {m["sigma"]:>6.3g}')
    if 'target' in doc:
        t, a = doc['target'], doc['achieved']
        rows = [('target', t), ('expected', a['expected'])]
        if 'simulated' in a:
            rows.append((f'simulated ({len(a["simulated"]["seeds"])} x {a["simulated"]["subjects"]})',
                         {**a['simulated'], 'mix': a['simulated']['mix_per_study']}))
        lines.append(f'{"":>22s}{"inside Std":>12s}{"inside Cons":>12s}{"int./scene":>12s}   mix (Std/Cons/grad.)')
        for label, r in rows:
            mix = r.get('mix', {})
            lines.append(f'{label:>22s}{100 * r["inside_standard"]:>11.1f}%{100 * r["inside_conservative"]:>11.1f}%'
                         f'{100 * r["intervention_rate"]:>11.1f}%   '
                         + ' / '.join(f'{float(mix.get(k, 0)):.2g}' for k in ('standard', 'conservative', 'gradual')))
        agree = a.get('model_agreement')
        if agree:
            lines.append(f'Phase II under each supervisor model ({agree["subjects"]} subjects, seed {agree["seed"]}): '
                         + ', '.join(f'{m} {r["interventions"]} interventions, '
                                     + ('the same as memoryless' if r['same_as_memoryless']
                                        else f'differs (up to {r["max_state_difference"]:.3g})')
                                     for m, r in agree['models'].items()))
    return '\n'.join(lines)
