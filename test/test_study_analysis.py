"""The study's bookkeeping: Table 1 arithmetic, statistics, the subject population."""
import numpy as np
import pytest

from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.value_function import ValueFunction
from supersafe_ros.study.analysis import (SetCount, format_table1, interventions_inside,
                                          repeated_measures_anova, table1, tukey_pairs)


def test_table1_reproduces_the_papers_arithmetic():
    # the paper's pooled counts: 397, 220, 115 of 440; average FP 12.54, 7.31, 4.68
    inside = {'standard': SetCount(397, 440), 'learned': SetCount(220, 440),
              'conservative': SetCount(115, 440)}
    fp = {'standard': [12.54] * 4, 'learned': [7.31] * 4, 'conservative': [4.68] * 4}
    rows = table1(inside, fp)
    assert rows['standard']['predicted_fp_ratio'] == 1.0 and rows['standard']['observed_fp_ratio'] == 1.0
    assert rows['learned']['predicted_fp_ratio'] == pytest.approx(0.554, abs=1e-3)
    assert rows['conservative']['predicted_fp_ratio'] == pytest.approx(0.290, abs=1e-3)
    assert rows['learned']['observed_fp_ratio'] == pytest.approx(0.583, abs=1e-3)
    assert rows['conservative']['observed_fp_ratio'] == pytest.approx(0.373, abs=1e-3)
    text = format_table1(rows)
    assert '397 / 440' in text and '55.4%' in text and '37.3%' in text


def test_interventions_inside_counts_states_the_filter_leaves_alone():
    g = Grid((-5, -5), (5, 5), (11, 11, 8))
    X, Y, TH = g.mesh()
    vf = ValueFunction(g, X)              # V = x
    states = np.array([[-2.0, 0, 0], [0.5, 1, 0], [1.5, 0, 1], [3.0, 0, 2]])
    assert interventions_inside(vf, 1.0, states) == SetCount(2, 4)
    assert interventions_inside(vf, -3.0, states) == SetCount(4, 4)
    assert interventions_inside(vf, 0.0, np.zeros((0, 3))) == SetCount(0, 0)


def test_anova_and_tukey_find_a_real_effect_and_no_fake_one():
    rng = np.random.default_rng(0)
    n = 12
    base = rng.normal(10, 2, n)
    effect = {'standard': base + rng.normal(0, 1, n), 'learned': base - 5 + rng.normal(0, 1, n),
              'conservative': base - 7 + rng.normal(0, 1, n)}
    a = repeated_measures_anova(effect)
    assert a['p'] < 0.001 and a['df_num'] == 2 and a['df_den'] == 22
    t = tukey_pairs(effect)
    assert t['standard-learned']['p'] < 0.05 and t['standard-conservative']['p'] < 0.05
    none = {c: base + rng.normal(0, 1, n) for c in ('standard', 'learned', 'conservative')}
    assert repeated_measures_anova(none)['p'] > 0.01


def test_table1_prints_the_papers_rows_beside_ours_and_any_subset_of_conditions():
    inside = {'standard': SetCount(10, 10), 'learned_fp': SetCount(4, 10)}
    rows = table1(inside, {'standard': [8, 12], 'learned_fp': [4, 6]})
    assert list(rows) == ['standard', 'learned_fp']
    assert rows['learned_fp']['observed_fp_ratio'] == pytest.approx(0.5)
    text = format_table1(rows)
    assert 'Learned FP' in text and '(paper Standard)' in text and '12.54' in text
    assert 'paper Learned ' not in text                 # the paper has no row for a condition not run
    assert '(paper' not in format_table1(rows, paper=False)


def test_h2_counts_subjects_whose_arcs_are_shorter_as_the_paper_does():
    from supersafe_ros.study.analysis import h2_summary, shorter_count
    assert shorter_count([1.0, 2.0, None, float('nan'), 0.5], [2.0, 1.0, 3.0, 1.0, 0.6]) == (2, 3)
    m = {c: {'path_per_trip': [33.0, 35.0], 'avoidance_length': arcs, 'override_fraction': [0.1, 0.3],
             'min_clearance': [0.2, float('nan')]}
         for c, arcs in (('learned', [1.0, 4.0]), ('conservative', [2.0, 3.0]))}
    h = h2_summary(m)
    assert h['shorter_arcs_than_conservative'] == {'learned': {'shorter': 1, 'of': 2}}
    assert h['means']['learned']['path_per_trip']['mean'] == pytest.approx(34.0)
    assert h['means']['conservative']['min_clearance'] == {'mean': 0.2, 'n': 1,
                                                           'sd': pytest.approx(float('nan'), nan_ok=True)}
