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
AnovaRM, subject as the repeated factor) and Tukey's HSD for all pairs
(scipy.stats.tukey_hsd), as the paper reports.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CONDITIONS = ('standard', 'learned', 'conservative')


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
    std_in = inside['standard'].inside
    std_fp = float(np.mean(observed_fp['standard'])) if len(observed_fp['standard']) else float('nan')
    rows = {}
    for c in CONDITIONS:
        mean_fp = float(np.mean(observed_fp[c])) if len(observed_fp[c]) else float('nan')
        rows[c] = {
            'inside': inside[c].inside,
            'total': inside[c].total,
            'predicted_fp_ratio': (inside[c].inside / std_in) if std_in else float('nan'),
            'average_fp': mean_fp,
            'observed_fp_ratio': (mean_fp / std_fp) if std_fp else float('nan'),
        }
    return rows


def format_table1(rows: dict) -> str:
    lines = [
        f'{"":14s}{"Interventions":>16s}{"Predicted":>12s}{"Average":>10s}{"Observed":>11s}',
        f'{"":14s}{"in safe set":>16s}{"FP vs Std":>12s}{"FP":>10s}{"FP vs Std":>11s}',
    ]
    for c in CONDITIONS:
        r = rows[c]
        lines.append(f'{c.capitalize():14s}{r["inside"]:>9d} / {r["total"]:<4d}'
                     f'{100 * r["predicted_fp_ratio"]:>11.1f}%{r["average_fp"]:>10.2f}'
                     f'{100 * r["observed_fp_ratio"]:>10.1f}%')
    return '\n'.join(lines)


def repeated_measures_anova(values: dict) -> dict:
    """One-way repeated-measures ANOVA of values[condition][subject] (statsmodels AnovaRM)."""
    import pandas as pd
    from statsmodels.stats.anova import AnovaRM

    n = len(values[CONDITIONS[0]])
    rows = [{'subject': i, 'condition': c, 'value': float(values[c][i])}
            for c in CONDITIONS for i in range(n)]
    df = pd.DataFrame(rows)
    if n < 2 or np.allclose(df.groupby('condition')['value'].var().fillna(0), 0) and \
            df['value'].nunique() == 1:
        return {'F': float('nan'), 'df_num': 2, 'df_den': 2 * (n - 1), 'p': float('nan'),
                'note': 'not enough variation to test'}
    res = AnovaRM(df, depvar='value', subject='subject', within=['condition']).fit()
    t = res.anova_table.iloc[0]
    return {'F': float(t['F Value']), 'df_num': float(t['Num DF']), 'df_den': float(t['Den DF']),
            'p': float(t['Pr > F'])}


def tukey_pairs(values: dict) -> dict:
    """All-pairs Tukey HSD (scipy.stats.tukey_hsd); keys like 'standard-learned'."""
    from scipy.stats import tukey_hsd

    groups = [np.asarray(values[c], dtype=float) for c in CONDITIONS]
    if min(len(g) for g in groups) < 2:
        return {}
    res = tukey_hsd(*groups)
    out = {}
    for i in range(len(CONDITIONS)):
        for j in range(i + 1, len(CONDITIONS)):
            out[f'{CONDITIONS[i]}-{CONDITIONS[j]}'] = {
                'mean_difference': float(res.statistic[i, j]),
                'p': float(res.pvalue[i, j]),
            }
    return out


def significance_stars(p: float) -> str:
    if not np.isfinite(p):
        return 'n/a'
    return '***' if p < 0.001 else '**' if p < 0.01 else '*' if p < 0.05 else 'n.s.'
