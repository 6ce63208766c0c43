"""Pairwise comparisons that respect the repeated-measures design: paired tests, Holm.

Every subject plays every condition, so a pair of conditions is compared on the
subjects' own differences d_i = a_i - b_i (``paired_posthoc``):

* paired t-test on d (scipy.stats.ttest_rel), two-sided; the p values of all pairs are
  Holm-corrected together (statsmodels' ``multipletests``; step-down: the k-th smallest
  of m is multiplied by m - k + 1, then made monotone), so the family-wise error stays at
  5 % as with Tukey's method;
* ``mean_difference`` = mean(d) with its 95 % confidence interval mean(d) +- t_{0.975, n-1}
  SD(d) / sqrt(n) (per pair, not adjusted for the family: the Holm p values are);
* effect sizes: Cohen's d_z = mean(d) / SD(d) (``effect_size``, the paired standardised
  difference the t-test itself tests) and Hedges' g_av = mean(d) / ((SD_a + SD_b) / 2) with
  the small-sample correction 1 - 3 / (4 (n - 1) - 1) (comparable with between-subject
  effect sizes);
* the Wilcoxon signed-rank p value (unadjusted) as a check that does not assume normal
  differences.

Why not ``scipy.stats.tukey_hsd`` on the conditions: it treats them as independent groups,
so the between-subject spread (subjects who intervene a lot do so in every condition)
enters its error term and hides consistent within-subject effects. It stays in the
study's JSON as ``tukey`` only as a labelled reference (``TUKEY_REFERENCE``).
"""
from __future__ import annotations

import numpy as np

from .analysis import significance_stars

POSTHOC_METHOD = ('paired t-tests on the per-subject differences, Holm-corrected over all pairs; '
                  "95 % CI of the mean difference; effect size Cohen's d_z (also Hedges' g_av)")
TUKEY_REFERENCE = ('scipy tukey_hsd: the conditions as independent groups (ignores the '
                   'repeated-measures design); a reference only, see posthoc')


def holm(pvalues) -> np.ndarray:
    """Holm-adjusted p values (statsmodels' ``multipletests(method='holm')``: step-down,
    monotone, capped at 1); NaN stays NaN and does not count towards the family's size
    (statsmodels would propagate it, so only the finite p values are passed)."""
    from statsmodels.stats.multitest import multipletests
    p = np.asarray(pvalues, dtype=float)
    out = np.full(p.shape, np.nan)
    ok = np.isfinite(p)
    if ok.any():
        out[ok] = multipletests(p[ok], method='holm')[1]
    return out


def paired_difference(a, b, confidence: float = 0.95, wilcoxon: bool = True) -> dict:
    """Paired comparison of a and b (one value per subject, same order): t-test, CI of the
    mean difference, d_z, g_av, Wilcoxon (unless ``wilcoxon`` is False). Subjects with a
    non-finite value in either are left out."""
    from scipy import stats
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    keep = np.isfinite(a) & np.isfinite(b)
    a, b = a[keep], b[keep]
    n = len(a)
    d = a - b
    out = {'n': int(n), 'mean_difference': float(d.mean()) if n else float('nan'),
           'p_unadjusted': float('nan'), 't': float('nan'), 'df': max(n - 1, 0),
           'ci_low': float('nan'), 'ci_high': float('nan'), 'effect_size': float('nan'),
           'hedges_g_av': float('nan'), 'wilcoxon_p': float('nan'), 'sd_difference': float('nan')}
    if n < 2:
        return out
    sd = float(d.std(ddof=1))
    out['sd_difference'] = sd
    half = float(stats.t.ppf(0.5 + confidence / 2, n - 1)) * sd / np.sqrt(n)
    out['ci_low'], out['ci_high'] = out['mean_difference'] - half, out['mean_difference'] + half
    if sd > 0:
        res = stats.ttest_rel(a, b)
        out['t'], out['p_unadjusted'] = float(res.statistic), float(res.pvalue)
        out['effect_size'] = out['mean_difference'] / sd
    else:       # every subject differs by the same amount: no variance to test against
        out['note'] = 'the differences do not vary: not tested'
    sd_av = (a.std(ddof=1) + b.std(ddof=1)) / 2
    if sd_av > 0:
        out['hedges_g_av'] = float(out['mean_difference'] / sd_av * (1 - 3 / (4 * (n - 1) - 1)))
    if wilcoxon and np.any(d != 0):
        out['wilcoxon_p'] = float(stats.wilcoxon(a, b).pvalue)
    return out


def paired_posthoc(values: dict, conditions=None, wilcoxon: bool = True) -> dict:
    """{method, pairs: {'a-b': {p (Holm), p_unadjusted, mean_difference (mean a - b), ci_low,
    ci_high, effect_size (d_z), hedges_g_av, wilcoxon_p, t, df, n}}} over every pair of the
    conditions (in the given order; default ``values``' order)."""
    conds = list(conditions) if conditions is not None else list(values)
    pairs = {}
    for i in range(len(conds)):
        for j in range(i + 1, len(conds)):
            pairs[f'{conds[i]}-{conds[j]}'] = paired_difference(
                values[conds[i]], values[conds[j]], wilcoxon=wilcoxon)
    adjusted = holm([r['p_unadjusted'] for r in pairs.values()])
    for r, p in zip(pairs.values(), adjusted):
        r['p'] = float(p)
    return {'method': POSTHOC_METHOD, 'correction': 'holm', 'confidence': 0.95, 'pairs': pairs}


def format_posthoc(posthoc: dict, labels: dict, paper: dict | None = None, tukey: dict | None = None) -> str:
    """One line per pair: mean difference [95 % CI], d_z, Holm p, the two conditions' crash
    totals when the pair has them (and the paper's figure, and Tukey's independent-groups p as
    a reference when given)."""
    lines = [f'paired post-hoc ({posthoc["method"]}):']
    for pair, r in posthoc['pairs'].items():
        a, b = pair.split('-')
        ref = (tukey or {}).get(pair)
        lines.append(f'  {labels[a]} - {labels[b]}: {r["mean_difference"]:+.2f} FP [{r["ci_low"]:+.2f}, '
                     f'{r["ci_high"]:+.2f}], d_z {r["effect_size"]:+.2f}, p(Holm) = {r["p"]:.3g} '
                     f'{significance_stars(r["p"])}'
                     + (f', crashes {r["crashes"][0]} / {r["crashes"][1]}' if 'crashes' in r else '')
                     + (f'  (Tukey, independent groups: p = {ref["p"]:.3g})' if ref else '')
                     + (f'   [paper, Tukey: {paper[pair]}]' if paper and pair in paper else ''))
    return '\n'.join(lines)
