"""Paired post-hoc tests (study.posthoc): the repeated-measures design, Holm, effect sizes, CIs."""
import numpy as np
from scipy import stats

from supersafe_ros.study.analysis import tukey_pairs
from supersafe_ros.study.posthoc import format_posthoc, holm, paired_difference, paired_posthoc


def test_holm_adjusts_step_down_and_keeps_the_order():
    p = [0.01, 0.04, 0.03, 0.5]
    # sorted 0.01, 0.03, 0.04, 0.5 -> 4 x 0.01, 3 x 0.03, 2 x 0.04 -> monotone 0.09, 1 x 0.5
    assert np.allclose(holm(p), [0.04, 0.09, 0.09, 0.5])
    assert np.allclose(holm([0.5, 0.9]), [1.0, 1.0])
    out = holm([0.02, np.nan, 0.01])
    assert np.isnan(out[1]) and np.allclose(out[[0, 2]], [0.02, 0.02])


def test_paired_difference_matches_the_textbook_formulas():
    rng = np.random.default_rng(1)
    a = rng.normal(10, 3, 12)
    b = a - 1.5 + rng.normal(0, 1, 12)
    r = paired_difference(a, b)
    d = a - b
    assert r['n'] == 12 and np.isclose(r['mean_difference'], d.mean())
    assert np.isclose(r['p_unadjusted'], stats.ttest_rel(a, b).pvalue)
    half = stats.t.ppf(0.975, 11) * d.std(ddof=1) / np.sqrt(12)
    assert np.isclose(r['ci_low'], d.mean() - half) and np.isclose(r['ci_high'], d.mean() + half)
    assert np.isclose(r['effect_size'], d.mean() / d.std(ddof=1))
    g = d.mean() / ((a.std(ddof=1) + b.std(ddof=1)) / 2) * (1 - 3 / (4 * 11 - 1))
    assert np.isclose(r['hedges_g_av'], g)
    assert np.isclose(r['wilcoxon_p'], stats.wilcoxon(a, b).pvalue)


def test_paired_tests_find_a_within_subject_effect_that_independent_groups_hide():
    # the situation: large between-subject spread, a consistent small effect
    rng = np.random.default_rng(0)
    base = rng.normal(12, 13, 12)
    fp = {'standard': base + rng.normal(0, 1.5, 12), 'learned': base - 2.5 + rng.normal(0, 1.5, 12),
          'conservative': base - 8 + rng.normal(0, 1.5, 12)}
    post = paired_posthoc(fp, ['standard', 'learned', 'conservative'])
    assert set(post['pairs']) == {'standard-learned', 'standard-conservative', 'learned-conservative'}
    assert post['pairs']['standard-learned']['p'] < 0.05
    assert tukey_pairs(fp)['standard-learned']['p'] > 0.2          # the reference misses it
    # Holm-adjusted p values are never below the unadjusted ones
    assert all(r['p'] >= r['p_unadjusted'] for r in post['pairs'].values())
    assert post['pairs']['standard-learned']['ci_low'] > 0


def test_no_effect_and_degenerate_pairs_are_reported_not_invented():
    rng = np.random.default_rng(2)
    base = rng.normal(10, 2, 12)
    post = paired_posthoc({'standard': base + rng.normal(0, 1, 12), 'learned': base + rng.normal(0, 1, 12)})
    assert post['pairs']['standard-learned']['p'] > 0.05
    same = paired_difference(base, base)
    assert same['mean_difference'] == 0 and np.isnan(same['p_unadjusted']) and np.isnan(same['wilcoxon_p'])
    shifted = paired_difference(base + 1, base)                  # every subject exactly +1: no variance
    assert np.isnan(shifted['p_unadjusted']) and shifted['ci_low'] == shifted['ci_high'] == 1.0
    assert 'not tested' in shifted['note']
    one = paired_difference([1.0, np.nan], [2.0, 3.0])
    assert one['n'] == 1 and np.isnan(one['p_unadjusted'])
    text = format_posthoc(post, {'standard': 'Standard', 'learned': 'Learned'})
    assert 'Standard - Learned' in text and 'p(Holm)' in text
