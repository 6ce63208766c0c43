"""The study's bookkeeping and statistics, as in the paper's Sec. V.

Table 1 (left, predicted): an intervention state x of Phase II lies *inside* a
safe set when the robots' filter would not act there, V_set(x) > alpha_set; in
Phase III such a state is left alone by the robot, so a supervisor who would
intervene there produces a false positive. Predicted FP relative to Standard =
(interventions inside the set) / (interventions inside Standard), pooled over
subjects as in the paper.

Table 1 (right, observed): mean false positives per subject in each condition's
game, and that mean relative to Standard's.

Statistics: one-way repeated-measures ANOVA over the conditions (statsmodels
AnovaRM, subject as the repeated factor), as the paper reports. Pairs: the paired tests of
``posthoc`` (Holm); Tukey's HSD (scipy.stats.tukey_hsd, what the paper reports) treats the
conditions as independent groups and is kept only as a labelled reference (``tukey_pairs``).

Conditions: Standard, Learned (the paper's estimator, eqs. 3-4, alpha = mu), Learned FP
(the first-passage estimator, alpha = mu), Learned online (Learned FP's set, refitted
during the game from the team's own encounters: ``online``) and Conservative; a study may
run any subset
(``--conditions``), and every function here works on the conditions it is given, in
``CONDITIONS`` order.

H2 (efficiency): per game, the measures of ``sim/efficiency.py``; the paper's comparison
is per subject: "for 9 of 11 participants, the Learned safe set had shorter avoidance
arcs than the Conservative set" (``shorter_count``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CONDITIONS = ('standard', 'learned', 'learned_fp', 'learned_online', 'conservative')
LABELS = {'standard': 'Standard', 'learned': 'Learned', 'learned_fp': 'Learned FP',
          'learned_online': 'Learned online', 'conservative': 'Conservative'}
H2_MEASURES = ('path_per_trip', 'avoidance_length', 'override_fraction', 'min_clearance')

# The paper's Table 1 (Sec. V, 11 participants) and its statistics, for side-by-side reports.
PAPER_TABLE1 = {
    'standard': {'inside': 397, 'total': 440, 'predicted_fp_ratio': 1.0, 'average_fp': 12.54,
                 'observed_fp_ratio': 1.0},
    'learned': {'inside': 220, 'total': 440, 'predicted_fp_ratio': 0.554, 'average_fp': 7.31,
                'observed_fp_ratio': 0.583},
    'conservative': {'inside': 115, 'total': 440, 'predicted_fp_ratio': 0.29, 'average_fp': 4.68,
                     'observed_fp_ratio': 0.373},
}
PAPER_STATS = {'anova': 'F(2, 20) = 8.72, p < 0.01',
               'tukey': {'standard-learned': 'p = 0.0328', 'standard-conservative': 'p < 0.01',
                         'learned-conservative': 'n.s.'},
               'h2': '9 of 11 participants: Learned arcs shorter than Conservative'}


def ordered(conditions) -> list:
    """The given conditions in CONDITIONS order (unknown names are an error)."""
    conditions = list(conditions)
    unknown = set(conditions) - set(CONDITIONS)
    if unknown:
        raise ValueError(f'unknown conditions {sorted(unknown)}; known: {", ".join(CONDITIONS)}')
    return [c for c in CONDITIONS if c in conditions]


@dataclass
class SetCount:
    inside: int
    total: int


def interventions_inside(vf, alpha: float, states) -> SetCount:
    """How many intervention states the robots' filter would leave alone (V > alpha)."""
    s = np.asarray(states, dtype=float).reshape(-1, 3)
    if len(s) == 0:
        return SetCount(0, 0)
    return SetCount(int(np.sum(vf.value(s) > alpha)), len(s))


def table1(inside: dict, observed_fp: dict) -> dict:
    """Table 1 from pooled Phase II counts and per-subject Phase III false positives.

    inside: condition -> SetCount pooled over subjects.
    observed_fp: condition -> list of false positives, one per subject.
    """
    std_in = inside['standard'].inside if 'standard' in inside else 0
    std = observed_fp.get('standard', [])
    std_fp = float(np.mean(std)) if len(std) else float('nan')
    rows = {}
    for c in ordered(inside):
        mean_fp = float(np.mean(observed_fp[c])) if len(observed_fp[c]) else float('nan')
        rows[c] = {
            'inside': inside[c].inside,
            'total': inside[c].total,
            'predicted_fp_ratio': (inside[c].inside / std_in) if std_in else float('nan'),
            'average_fp': mean_fp,
            'observed_fp_ratio': (mean_fp / std_fp) if std_fp and np.isfinite(std_fp) else float('nan'),
        }
    return rows


def format_table1(rows: dict, paper: bool = True) -> str:
    """Table 1 as the paper prints it; with ``paper`` the paper's own row beside each."""
    lines = [
        f'{"":22s}{"Interventions":>16s}{"Predicted":>12s}{"Average":>10s}{"Observed":>11s}{"Crashes":>9s}',
        f'{"":22s}{"in safe set":>16s}{"FP vs Std":>12s}{"FP":>10s}{"FP vs Std":>11s}{"(sum)":>9s}',
    ]

    def row(label, r):
        return (f'{label:22s}{r["inside"]:>9d} / {r["total"]:<4d}'
                f'{100 * r["predicted_fp_ratio"]:>11.1f}%{r["average_fp"]:>10.2f}'
                f'{100 * r["observed_fp_ratio"]:>10.1f}%' + (f'{r["crashes"]:>9d}' if 'crashes' in r else ''))
    for c in ordered(rows):
        lines.append(row(LABELS[c], rows[c]))
        if paper and c in PAPER_TABLE1:
            lines.append(row(f'  (paper {LABELS[c]})', PAPER_TABLE1[c]))
    return '\n'.join(lines)


def shorter_count(a, b) -> tuple[int, int]:
    """(subjects with a < b, subjects where both are known): the paper's "9 of 11"."""
    pairs = [(x, y) for x, y in zip(a, b) if x is not None and y is not None
             and np.isfinite(x) and np.isfinite(y)]
    return sum(1 for x, y in pairs if x < y), len(pairs)


def h2_summary(measures: dict) -> dict:
    """measures: condition -> {measure: [one value per subject]} -> mean and sd per
    condition and measure, and the per-subject arc comparisons against Conservative."""
    out = {'means': {}, 'shorter_arcs_than_conservative': {}}
    for c in ordered(measures):
        out['means'][c] = {}
        for m in H2_MEASURES:
            v = np.array([x for x in measures[c].get(m, []) if x is not None], dtype=float)
            v = v[np.isfinite(v)]
            out['means'][c][m] = {'mean': float(v.mean()) if len(v) else float('nan'),
                                  'sd': float(v.std(ddof=1)) if len(v) > 1 else float('nan'),
                                  'n': int(len(v))}
    if 'conservative' in measures:
        for c in ('learned', 'learned_fp', 'learned_online'):
            if c in measures:
                k, n = shorter_count(measures[c]['avoidance_length'],
                                     measures['conservative']['avoidance_length'])
                out['shorter_arcs_than_conservative'][c] = {'shorter': k, 'of': n}
    return out


def format_h2(h2: dict) -> str:
    """The efficiency panel: mean (sd) per condition, and the 9-of-11 comparison."""
    heads = {'path_per_trip': 'Path/trip [m]', 'avoidance_length': 'Arc extra [m]',
             'override_fraction': 'Override time', 'min_clearance': 'Min clear. [m]'}
    lines = [f'{"":14s}' + ''.join(f'{heads[m]:>17s}' for m in H2_MEASURES)]
    for c, ms in h2['means'].items():
        cells = []
        for m in H2_MEASURES:
            v = ms[m]
            scale, unit = (100, '%') if m == 'override_fraction' else (1, '')
            cells.append(f'{scale * v["mean"]:>8.2f}{unit} ({scale * v["sd"]:.2f})'.rjust(17))
        lines.append(f'{LABELS[c]:14s}' + ''.join(cells))
    for c, r in h2['shorter_arcs_than_conservative'].items():
        lines.append(f'{LABELS[c]} arcs shorter than Conservative for {r["shorter"]} of {r["of"]} '
                     'subjects (paper, Learned: 9 of 11)')
    return '\n'.join(lines)


def repeated_measures_anova(values: dict) -> dict:
    """One-way repeated-measures ANOVA of values[condition][subject] (statsmodels AnovaRM)."""
    import pandas as pd
    from statsmodels.stats.anova import AnovaRM

    conds = ordered(values)
    n = len(values[conds[0]])
    rows = [{'subject': i, 'condition': c, 'value': float(values[c][i])}
            for c in conds for i in range(n)]
    df = pd.DataFrame(rows)
    k = len(conds)
    if n < 2 or k < 2 or df['value'].nunique() == 1:
        return {'F': float('nan'), 'df_num': k - 1, 'df_den': (k - 1) * (n - 1), 'p': float('nan'),
                'note': 'not enough variation to test'}
    res = AnovaRM(df, depvar='value', subject='subject', within=['condition']).fit()
    t = res.anova_table.iloc[0]
    return {'F': float(t['F Value']), 'df_num': float(t['Num DF']), 'df_den': float(t['Den DF']),
            'p': float(t['Pr > F'])}


def tukey_pairs(values: dict) -> dict:
    """All-pairs Tukey HSD (scipy.stats.tukey_hsd); keys like 'standard-learned'."""
    from scipy.stats import tukey_hsd

    conds = ordered(values)
    groups = [np.asarray(values[c], dtype=float) for c in conds]
    if len(groups) < 2 or min(len(g) for g in groups) < 2:
        return {}
    res = tukey_hsd(*groups)
    out = {}
    for i in range(len(conds)):
        for j in range(i + 1, len(conds)):
            out[f'{conds[i]}-{conds[j]}'] = {
                'mean_difference': float(res.statistic[i, j]),
                'p': float(res.pvalue[i, j]),
            }
    return out


def significance_stars(p: float) -> str:
    if not np.isfinite(p):
        return 'n/a'
    return '***' if p < 0.001 else '**' if p < 0.01 else '*' if p < 0.05 else 'n.s.'
