"""`supersafe power STUDY.json`: how many participants a human study needs, from a simulated one.

The simulated subjects of a study (one row each: their false positives, or another
per-subject measure, in every condition) are resampled with replacement, keeping each
subject's conditions together (the design is repeated measures). For each number of
participants N and each of ``draws`` resamples, the study's own tests run on the sample:
the one-way repeated-measures ANOVA (statsmodels AnovaRM, ``study.analysis``) and the
paired post-hoc tests of every pair (paired t-tests, Holm-corrected over the pairs,
``study.posthoc``). The power at N is the share of resamples with p < 0.05 (for a pair:
its Holm-adjusted p). A draw whose values do not vary cannot be tested and counts as
not significant.

This is a bootstrap of the simulated population: it says how often a study of N people
like these simulated subjects would reach significance, and is no better than the
simulation's population and its supervisor model (docs/study.md, "Supervisor models"):
it names the study's model, says so when that is not the default
(``sim.supervisor_models.DEFAULT_MODEL``, what `supersafe study` runs), and prints the
study's crashes per condition beside the false positives it tests.
"""
from __future__ import annotations

import json
from pathlib import Path
import sys
import time

import numpy as np

from .analysis import H2_MEASURES, LABELS, ordered, repeated_measures_anova
from .posthoc import paired_posthoc

MEASURES = ('false_positives', 'crashes') + H2_MEASURES
ALPHA = 0.05


def subject_matrix(study: dict, measure: str = 'false_positives') -> tuple[list, np.ndarray]:
    """(conditions, values[subject, condition]) from a study JSON; subjects with a missing
    value (e.g. no avoidance arc) in any condition are left out."""
    if measure not in MEASURES:
        raise ValueError(f'unknown measure {measure!r}; one of {", ".join(MEASURES)}')
    conds = ordered(study['conditions'])
    if len(conds) < 2:
        raise ValueError('the study ran fewer than two conditions: nothing to compare')
    cols = []
    for c in conds:
        v = study['conditions'][c].get(measure)
        if v is None:
            raise ValueError(f'the study has no {measure} for {c}')
        cols.append([np.nan if x is None else float(x) for x in v])
    x = np.array(cols, dtype=float).T
    x = x[np.all(np.isfinite(x), axis=1)]
    if len(x) < 2:
        raise ValueError(f'fewer than two subjects with {measure} in every condition')
    return conds, x


def default_sizes(max_subjects: int, count: int = 8) -> list[int]:
    """Up to ``count`` participant numbers from 3 to max_subjects, evenly spread."""
    if max_subjects < 3:
        raise ValueError(f'--max-subjects must be at least 3, got {max_subjects}')
    return sorted({int(round(v)) for v in np.linspace(3, max_subjects, min(count, max_subjects - 2))})


def resample_power(conds, values, sizes, draws: int, seed: int = 0, alpha: float = ALPHA,
                   progress=None) -> dict:
    """Power of the ANOVA and of each pair's paired test (Holm) at each N in ``sizes``
    (bootstrap); ``out['posthoc'][pair]`` per N."""
    if draws < 1:
        raise ValueError(f'draws must be >= 1, got {draws}')
    rng = np.random.default_rng(seed)
    n = len(values)
    pairs = [f'{conds[i]}-{conds[j]}' for i in range(len(conds)) for j in range(i + 1, len(conds))]
    out = {'sizes': [int(s) for s in sizes], 'draws': int(draws), 'alpha': alpha,
           'conditions': list(conds), 'anova': [], 'posthoc': {p: [] for p in pairs},
           'posthoc_method': 'paired t-tests, Holm-corrected'}
    for size in sizes:
        hits = {'anova': 0, **{p: 0 for p in pairs}}
        for _ in range(draws):
            rows = values[rng.integers(0, n, int(size))]
            sample = {c: rows[:, j] for j, c in enumerate(conds)}
            a = repeated_measures_anova(sample)
            hits['anova'] += bool(np.isfinite(a['p']) and a['p'] < alpha)
            t = paired_posthoc(sample, conds, wilcoxon=False)['pairs']
            for p in pairs:
                pv = t[p]['p']
                hits[p] += bool(np.isfinite(pv) and pv < alpha)
        out['anova'].append(hits['anova'] / draws)
        for p in pairs:
            out['posthoc'][p].append(hits[p] / draws)
        if progress:
            progress(size, out)
    return out


def plot_power(path, power: dict, measure: str, n_sim: int) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    sizes = power['sizes']
    ax.plot(sizes, power['anova'], 'k-o', lw=2, label='repeated-measures ANOVA')
    for pair, v in power['posthoc'].items():
        a, b = pair.split('-')
        ax.plot(sizes, v, '--.', label=f'{LABELS[a]} vs {LABELS[b]} (paired, Holm)')
    ax.axhline(0.8, color='0.6', lw=0.8, ls=':')
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel('participants')
    ax.set_ylabel(f'P(p < {power["alpha"]:g})')
    ax.set_title(f'Power for {measure.replace("_", " ")} (bootstrap of {n_sim} simulated subjects, '
                 f'{power["draws"]} draws)', fontsize=9)
    ax.legend(fontsize=7, loc='lower right')
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def format_power(power: dict) -> str:
    pairs = list(power['posthoc'])
    w = max([len(p) for p in pairs] + [24]) + 2
    head = f'{"N":>4s}{"ANOVA":>8s}' + ''.join(f'{p:>{w}s}' for p in pairs)
    lines = [head]
    for k, size in enumerate(power['sizes']):
        lines.append(f'{size:>4d}{power["anova"][k]:>8.2f}'
                     + ''.join(f'{power["posthoc"][p][k]:>{w}.2f}' for p in pairs))
    return '\n'.join(lines)


def add_parser(subparsers):
    p = subparsers.add_parser('power', help='participants needed: bootstrap power of the ANOVA and '
                              'the paired post-hoc tests from a simulated study',
                              description=__doc__.splitlines()[0])
    p.add_argument('study', type=Path, help='a study JSON (supersafe study --json / <out>/study.json)')
    p.add_argument('--max-subjects', type=int, default=24, help='largest number of participants (24)')
    p.add_argument('--sizes', type=str, default=None,
                   help='comma-separated participant numbers (default: up to 8 from 3 to --max-subjects)')
    p.add_argument('--draws', type=int, default=200, help='resamples per number of participants (200)')
    p.add_argument('--measure', choices=MEASURES, default='false_positives',
                   help='per-subject measure to test (default false_positives, the paper\'s H1; crashes '
                        'beside them)')
    p.add_argument('--seed', type=int, default=0, help='seed of the resampling')
    p.add_argument('--out', type=Path, default=None, help='plot (default <study dir>/power.png)')
    p.add_argument('--json', type=Path, default=None, help='also write the curves here')
    p.set_defaults(func=run)
    return p


def run(args, out=sys.stdout) -> int:
    try:
        study = json.loads(Path(args.study).read_text())
        conds, values = subject_matrix(study, args.measure)
        sizes = ([int(v) for v in args.sizes.split(',') if v.strip()] if args.sizes
                 else default_sizes(args.max_subjects))
        if not sizes or min(sizes) < 2:
            raise ValueError('participant numbers must be at least 2')
    except (OSError, ValueError, KeyError) as exc:
        print(f'supersafe power: {exc}', file=sys.stderr)
        return 2
    from ..sim.supervisor_models import DEFAULT_MODEL
    model = study.get('options', {}).get('supervisor', 'memoryless')
    print(f'{len(values)} simulated subjects, conditions {", ".join(conds)}; {args.measure}; '
          f'{args.draws} draws at N = {sizes}; supervisor model {model}'
          + ('' if model == DEFAULT_MODEL else f' (not the default, {DEFAULT_MODEL})'), file=out, flush=True)
    if all('false_positives' in study['conditions'][c] and 'crashes' in study['conditions'][c] for c in conds):
        print('the study per condition (sums over its subjects): '
              + ', '.join(f'{c} {sum(study["conditions"][c]["false_positives"])} FP / '
                          f'{sum(study["conditions"][c]["crashes"])} crashes' for c in conds), file=out, flush=True)
    t0 = time.monotonic()
    power = resample_power(conds, values, sizes, args.draws, args.seed,
                           progress=lambda n, _: print(f'  N = {n} done ({time.monotonic() - t0:.0f} s)',
                                                       file=out, flush=True))
    power.update(measure=args.measure, simulated_subjects=int(len(values)), study=str(args.study))
    print(format_power(power), file=out)
    path = args.out or Path(args.study).parent / 'power.png'
    plot_power(path, power, args.measure, len(values))
    print(f'plot: {path}', file=out)
    if args.json:
        Path(args.json).write_text(json.dumps(power, indent=1))
        print(f'curves: {args.json}', file=out)
    return 0
