"""The questionnaire after each pairwise comparison and its analysis (the paper's Sec. IV
"Subjective Measures" and Sec. V, H1 and H2).

After each comparison (two games with two teams) the participant rates statements on a
7-point Likert scale (1 strongly disagree ... 7 strongly agree): five statements about
each team (``TEAM_ITEMS``: trust, perceived performance, interpretability, confidence,
team fluency), each rated for both games of the comparison, and one about the pair
(``PREFERENCE``: "I preferred the team of Game 4 to the team of Game 3", 4 = neutral).

An answer: {'comparison': 'standard-learned', 'treatments': [first game's, second's],
'games': [3, 4], 'values': {item: [first game, second game] for TEAM_ITEMS,
'preference': 1..7}}.

The analysis of comparison "x-y" (``COMPARISONS`` order, e.g. standard-learned):

* per team item, a one-way repeated-measures ANOVA of the ratings of team x against team
  y over participants (two levels: F(1, n - 1) = the paired t squared), as the paper ran
  on the Learned and Standard teams (trust F(1, 9) = 1.86, p = 0.21);
* preference, turned to "y over x" (8 - v when y was the first game), tested against the
  neutral 4 with a one-sample t-test, as the paper did (p = 0.8).

Below ``MIN_SUBJECTS`` participants only the means are given.
"""
from __future__ import annotations

import math

import numpy as np

from .design import COMPARISONS, comparison_name

TEAM_ITEMS = (
    ('trust', 'I trusted the robots to avoid the obstacles.'),
    ('performance', 'The team performed well.'),
    ('interpretability', 'I could tell what the robots were going to do.'),
    ('confidence', 'I was confident in my decisions to intervene.'),
    ('fluency', 'The robots and I worked together fluently as a team.'),
)
PREFERENCE = ('preference', 'I preferred the team of {second} to the team of {first}.')
ITEMS = tuple(k for k, _ in TEAM_ITEMS) + (PREFERENCE[0],)
POINTS = 7
NEUTRAL = 4
MIN_SUBJECTS = 3
SCALE = '1 = strongly disagree, 4 = neither, 7 = strongly agree'


def _point(v, what):
    if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= POINTS:
        raise ValueError(f'answer "{what}" must be an integer 1..{POINTS}')
    return v


def check_answers(values: dict) -> dict:
    """{team item: [first game, second game], 'preference': v}, every value 1..7, or a
    ValueError saying what is wrong."""
    if not isinstance(values, dict):
        raise ValueError('answers must be an object {item: [1..7, 1..7], preference: 1..7}')
    extra = set(values) - set(ITEMS)
    if extra:
        raise ValueError(f'unknown items {sorted(extra)}')
    out = {}
    for key, _ in TEAM_ITEMS:
        v = values.get(key)
        if not isinstance(v, list) or len(v) != 2:
            raise ValueError(f'answer "{key}" must be two ratings [first game, second game]')
        out[key] = [_point(v[0], key), _point(v[1], key)]
    out[PREFERENCE[0]] = _point(values.get(PREFERENCE[0]), PREFERENCE[0])
    return out


def ratings(answer: dict, comparison: str):
    """(x ratings, y ratings, preference for y over x) of one answer to ``comparison``
    'x-y', or None when the answer is to another comparison (or of an older form)."""
    treatments = answer.get('treatments')
    values = answer.get('values') or {}
    if not treatments or len(treatments) != 2 or answer.get('comparison') != comparison:
        return None
    if not all(isinstance(values.get(k), list) for k, _ in TEAM_ITEMS):
        return None
    x, y = comparison.split('-')
    ix = 0 if treatments[0] == x else 1
    xr = {k: values[k][ix] for k, _ in TEAM_ITEMS}
    yr = {k: values[k][1 - ix] for k, _ in TEAM_ITEMS}
    pref = values.get(PREFERENCE[0])
    pref_y = None if pref is None else (pref if treatments[1] == y else POINTS + 1 - pref)
    return xr, yr, pref_y


def _mean(v):
    return float(np.mean(v)) if len(v) else float('nan')


def one_sample_t(values, mu: float) -> dict:
    from scipy.stats import ttest_1samp
    v = np.asarray(values, dtype=float)
    if len(v) < 2 or np.all(v == v[0]):
        return {'t': float('nan'), 'df': max(0, len(v) - 1), 'p': float('nan'),
                'note': 'not enough variation to test'}
    res = ttest_1samp(v, mu)
    return {'t': float(res.statistic), 'df': len(v) - 1, 'p': float(res.pvalue)}


def subjective_analysis(answer_lists: list) -> dict:
    """``answer_lists``: one list of answers per participant. Per comparison: n, per team
    item the means of both teams and (from MIN_SUBJECTS on) the repeated-measures ANOVA,
    and preference for the second-named treatment with its t-test against neutral."""
    from .analysis import repeated_measures_anova
    out = {}
    for pair in COMPARISONS:
        name = comparison_name(*pair)
        x, y = pair
        rows = []
        for answers in answer_lists:
            got = next((r for r in (ratings(a, name) for a in answers or []) if r), None)
            if got:
                rows.append(got)
        n = len(rows)
        items = {}
        for key, _ in TEAM_ITEMS:
            xs, ys = [r[0][key] for r in rows], [r[1][key] for r in rows]
            items[key] = {x: _mean(xs), y: _mean(ys), 'n': n,
                          'anova': repeated_measures_anova({x: xs, y: ys}) if n >= MIN_SUBJECTS else None}
        prefs = [r[2] for r in rows if r[2] is not None]
        items[PREFERENCE[0]] = {'for': y, 'over': x, 'mean': _mean(prefs), 'n': len(prefs),
                                'neutral': NEUTRAL,
                                'ttest': one_sample_t(prefs, NEUTRAL) if len(prefs) >= MIN_SUBJECTS else None}
        out[name] = {'n': n, 'items': items}
    return out


def _num(v, fmt='.2f'):
    return format(v, fmt) if isinstance(v, (int, float)) and math.isfinite(v) else '-'


def format_subjective(result: dict, labels: dict) -> str:
    """One block per comparison: the items' means per team and the paper's tests."""
    lines = []
    for name, comp in result.items():
        x, y = name.split('-')
        lines.append(f'{labels[x]} vs {labels[y]} ({comp["n"]} participant{"s" if comp["n"] != 1 else ""} '
                     'answered):')
        if not comp['n']:
            continue
        for key, _ in TEAM_ITEMS:
            it = comp['items'][key]
            a = it['anova']
            test = (f'F({a["df_num"]:g}, {a["df_den"]:g}) = {_num(a["F"], ".3g")}, p = {_num(a["p"], ".3g")}'
                    if a else 'no test (fewer than 3)')
            lines.append(f'  {key:17s}{labels[x]} {_num(it[x])}  {labels[y]} {_num(it[y])}   {test}')
        p = comp['items'][PREFERENCE[0]]
        t = p['ttest']
        test = (f't({t["df"]}) = {_num(t["t"], ".3g")} against neutral {NEUTRAL}, p = {_num(t["p"], ".3g")}'
                if t else 'no test (fewer than 3)')
        lines.append(f'  {"preference":17s}{labels[y]} over {labels[x]}: {_num(p["mean"])} (4 = neutral)   {test}')
    return '\n'.join(lines)
