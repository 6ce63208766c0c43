"""Model validity (the paper's Sec. V-C): the predicted share against the observed FP ratio.

The paper predicts each condition's false positives relative to Standard from Phase II:
the share of intervention states inside the condition's set (V > alpha: the filter leaves
them alone, so a supervisor who intervenes there makes an FP) over the share inside
Standard. ``model_validity`` checks that prediction, per subject and pooled:

* ``predicted``: Phase II states inside the set / inside Standard (per subject; pooled as
  the paper pools, sums over subjects); CI: bootstrap over the subject's interventions
  (per subject) or over subjects (pooled);
* ``observed``: FP in the condition's game / FP in the Standard game; per subject the
  exact CI of a ratio of two Poisson counts (Clopper-Pearson on FP_c / (FP_c + FP_std));
  pooled: mean over mean, bootstrap over subjects;
* ``games_predicted``: the same prediction applied to the games' own intervention states
  (the Standard game's, every bearing, as ``study.game_trace`` records them): inside the
  set / inside Standard. Where it differs from ``predicted``, Phase II's head-on states are
  not the states the supervisor judges in the team task.

``gap``: where the difference comes from, per condition, from the games' traces (core
engine): the onset level (V - alpha where the filter starts to override, head-on and
oblique), and the FP that came after the filter had already overridden for that obstacle
(skirting), at tangential bearings, and at states inside the set (the only ones the
prediction counts). Bootstrap draws come from ``numpy.random.default_rng(seed)``.
"""
from __future__ import annotations

import numpy as np

from .analysis import LABELS, ordered
from .game_trace import bearing_class

DRAWS = 2000


def _ci(samples) -> list:
    s = np.asarray(samples, dtype=float)
    s = s[np.isfinite(s)]
    return [float(np.percentile(s, 2.5)), float(np.percentile(s, 97.5))] if len(s) else [float('nan')] * 2


def poisson_ratio_ci(a: int, b: int, confidence: float = 0.95) -> list:
    """Exact CI of the rate ratio of two Poisson counts a / b (equal exposure)."""
    from scipy.stats import beta
    if a + b == 0:
        return [float('nan'), float('nan')]
    q = (1 - confidence) / 2
    lo = beta.ppf(q, a, b + 1) if a > 0 else 0.0
    hi = beta.ppf(1 - q, a + 1, b) if b > 0 else 1.0
    return [float(lo / (1 - lo)), float(hi / (1 - hi)) if hi < 1 else float('inf')]


def _ratio(num, den) -> float:
    return float(num / den) if den else float('nan')


def pooled_ratio(counts) -> float:
    """Sum of the first column over the sum of the second (the paper's pooling)."""
    den = counts[:, 1].sum()
    return float(counts[:, 0].sum() / den) if den else float('nan')


def _inside(vf, alpha, states) -> np.ndarray:
    s = np.asarray(states, dtype=float).reshape(-1, 3)
    return vf.value(s) > alpha if len(s) else np.zeros(0, dtype=bool)


def _summary(values) -> dict:
    v = np.asarray(values, dtype=float)
    if not len(v):
        return {'n': 0, 'median': float('nan'), 'q25': float('nan'), 'q75': float('nan')}
    return {'n': int(len(v)), 'median': float(np.median(v)), 'q25': float(np.percentile(v, 25)),
            'q75': float(np.percentile(v, 75))}


def trace_gap(games: list) -> dict:
    """Onset levels by bearing and the FP's provenance over a condition's game traces."""
    onsets = {'head-on': [], 'oblique': [], 'tangential': []}
    fp, interventions = [], 0
    for g in games:
        t = (g or {}).get('trace')
        if not t:
            continue
        for v, b in zip(t['onsets']['v_minus_alpha'], t['onsets']['bearing']):
            onsets[bearing_class(b)].append(v)
        interventions += len(t['interventions'])
        fp += [i for i in t['interventions'] if i['false_positive']]
    n = len(fp)
    return {'onset_v_minus_alpha': {k: _summary(v) for k, v in onsets.items()},
            'false_positives': n, 'interventions': interventions,
            'fp_after_override': _ratio(sum(i['after_override'] for i in fp), n),
            'fp_tangential': _ratio(sum(bearing_class(i['bearing']) == 'tangential' for i in fp), n),
            'fp_head_on': _ratio(sum(bearing_class(i['bearing']) == 'head-on' for i in fp), n),
            'fp_inside_set': _ratio(sum(i['v_minus_alpha'] > 0 for i in fp), n)}


def model_validity(records: list, sets_of, conditions, seed: int = 0, draws: int = DRAWS) -> dict:
    """See the module doc. ``sets_of(record)`` -> {condition: (vf, alpha)} (the sets the
    prediction uses; Standard among them)."""
    rng = np.random.default_rng(seed)
    conds = [c for c in ordered(conditions) if c != 'standard']
    n = len(records)
    phase2 = {c: np.zeros((n, 2), dtype=int) for c in conds}        # (inside c, inside std)
    games = {c: np.zeros((n, 2), dtype=int) for c in conds}          # Standard game's states
    fp = {c: np.zeros((n, 2), dtype=int) for c in conds}             # (FP c, FP std)
    per_subject = {c: [] for c in conds}
    for i, r in enumerate(records):
        sets = sets_of(r)
        states = np.asarray(r['states'], dtype=float).reshape(-1, 3)
        std_vf, std_alpha = sets['standard']
        in_std = _inside(std_vf, std_alpha, states)
        std_game = r['games'].get('standard') or {}
        trace = std_game.get('trace') or {}
        g_states = np.array([iv['state'] for iv in trace.get('interventions', [])], dtype=float).reshape(-1, 3)
        g_std = _inside(std_vf, std_alpha, g_states)
        for c in conds:
            vf, alpha = sets[c]
            in_c = _inside(vf, alpha, states)
            phase2[c][i] = (in_c.sum(), in_std.sum())
            games[c][i] = (_inside(vf, alpha, g_states).sum(), g_std.sum())
            # counts, not means: a treatment played twice (the paper's form) gives its total
            fp[c][i] = ((r['games'][c].get('totals') or r['games'][c])['false_positives'],
                        (std_game.get('totals') or std_game).get('false_positives', 0))
            boot = []
            if len(states):
                pick = rng.integers(0, len(states), (200, len(states)))
                num, den = in_c[pick].sum(1), in_std[pick].sum(1)
                boot = np.where(den > 0, num / np.maximum(den, 1), np.nan)
            per_subject[c].append({
                'subject': r['subject'].get('index'), 'type': r['subject'].get('member_type', ''),
                'predicted': _ratio(*phase2[c][i]), 'predicted_ci': _ci(boot),
                'observed': _ratio(*fp[c][i]), 'observed_ci': poisson_ratio_ci(*fp[c][i]),
                'games_predicted': _ratio(*games[c][i])})
    pooled = {}
    idx = rng.integers(0, n, (draws, n)) if n else np.zeros((0, 0), dtype=int)
    for c in conds:
        counts = {'predicted': phase2[c], 'observed': fp[c], 'games_predicted': games[c]}
        boot = {k: [pooled_ratio(a[j]) for j in idx] for k, a in counts.items()}
        pooled[c] = {k: pooled_ratio(a) for k, a in counts.items()}
        pooled[c].update({f'{k}_ci': _ci(v) for k, v in boot.items()})
        diff = [o - p for o, p in zip(boot['observed'], boot['predicted'])]
        pooled[c]['gap'] = pooled[c]['observed'] - pooled[c]['predicted']
        pooled[c]['gap_ci'] = _ci(diff)
    gap = {c: trace_gap([r['games'].get(c) for r in records]) for c in ordered(conditions)}
    for c in gap:        # beside the false positives: what missing the undetected ones cost
        gap[c]['crashes'] = int(sum((r['games'][c].get('totals') or r['games'][c]).get('crashes', 0)
                                    for r in records if r['games'].get(c)))
    return {'per_subject': per_subject, 'pooled': pooled, 'gap': gap, 'draws': draws, 'seed': seed,
            'method': 'predicted: Phase II states inside / inside Standard; observed: FP / FP Standard; '
                      'games_predicted: the Standard games\' intervention states inside / inside Standard; '
                      'CIs 95 %: bootstrap over subjects (pooled), over interventions (per subject predicted), '
                      'exact Poisson ratio (per subject observed)'}


def format_validity(validity: dict) -> str:
    """The pooled prediction against the observation, and the gap's provenance."""
    def pct(v):
        return f'{100 * v:5.1f}%' if np.isfinite(v) else '   n/a'

    def ci(v):
        return f'[{pct(v[0]).strip()}, {pct(v[1]).strip()}]'
    lines = [f'{"":14s}{"predicted (Phase II)":>30s}{"observed FP ratio":>28s}{"predicted (games)":>28s}']
    for c, p in validity['pooled'].items():
        lines.append(f'{LABELS[c]:14s}{pct(p["predicted"]):>12s} {ci(p["predicted_ci"]):>17s}'
                     f'{pct(p["observed"]):>11s} {ci(p["observed_ci"]):>16s}'
                     f'{pct(p["games_predicted"]):>11s} {ci(p["games_predicted_ci"]):>16s}')
    lines.append('where the games differ from the prediction (core engine traces):')
    lines.append(f'{"":14s}{"onset V-alpha head-on":>23s}{"oblique":>9s}{"FP":>5s}{"after override":>16s}'
                 f'{"tangential":>12s}{"inside set":>12s}{"crashes":>9s}')
    for c, g in validity['gap'].items():
        o = g['onset_v_minus_alpha']
        lines.append(f'{LABELS[c]:14s}{o["head-on"]["median"]:>+20.2f} m{o["oblique"]["median"]:>+7.2f} m'
                     f'{g["false_positives"]:>5d}{pct(g["fp_after_override"]):>16s}{pct(g["fp_tangential"]):>12s}'
                     f'{pct(g["fp_inside_set"]):>12s}' + (f'{g["crashes"]:>9d}' if 'crashes' in g else ''))
    return '\n'.join(lines)
