"""`supersafe power`: bootstrap power of the study's ANOVA and paired post-hoc tests."""
import json

import numpy as np
import pytest

from supersafe_ros.study import power as P


def study_json(tmp_path, effect: float, n: int = 12, seed: int = 0):
    rng = np.random.default_rng(seed)
    base = rng.normal(20, 4, n)
    conds = {'standard': base + rng.normal(0, 1, n),
             'learned': base - effect + rng.normal(0, 1, n),
             'conservative': base - 2 * effect + rng.normal(0, 1, n)}
    study = {'conditions': {c: {'false_positives': v.round().tolist(),
                                'avoidance_length': [None] + v[1:].tolist()} for c, v in conds.items()}}
    path = tmp_path / 'study.json'
    path.write_text(json.dumps(study))
    return path


def run(path, *extra):
    import argparse
    import io
    parser = argparse.ArgumentParser()
    P.add_parser(parser.add_subparsers())
    args = parser.parse_args(['power', str(path), *extra])
    text = io.StringIO()
    return args.func(args, out=text), text.getvalue()


def test_a_large_effect_reaches_full_power_and_the_curve_is_plotted(tmp_path):
    path = study_json(tmp_path, effect=6.0)
    code, text = run(path, '--sizes', '3,10', '--draws', '10', '--json', str(tmp_path / 'p.json'))
    assert code == 0 and 'ANOVA' in text
    p = json.loads((tmp_path / 'p.json').read_text())
    assert p['sizes'] == [3, 10] and p['draws'] == 10
    assert p['anova'][1] == 1.0 and p['posthoc']['standard-conservative'][1] == 1.0
    assert set(p['posthoc']) == {'standard-learned', 'standard-conservative', 'learned-conservative'}
    assert all(0.0 <= v <= 1.0 for v in p['anova'])
    assert (tmp_path / 'power.png').is_file()


def test_no_effect_rarely_reaches_significance():
    # every condition has the same mean: each subject's three values are a permutation of
    # base + (-3, 0, 3), all six permutations twice
    import itertools
    base = np.random.default_rng(3).normal(20, 4, 12)
    perms = list(itertools.permutations((-3.0, 0.0, 3.0))) * 2
    values = np.array([b + np.array(p) for b, p in zip(base, perms)])
    assert np.allclose(values.mean(axis=0), values.mean())
    power = P.resample_power(['standard', 'learned', 'conservative'], values, [10], draws=10, seed=1)
    assert power['anova'][0] <= 0.4
    assert all(v[0] <= 0.4 for v in power['posthoc'].values())


def test_power_uses_the_paired_tests_a_consistent_small_effect_under_large_spread_is_found():
    # between-subject spread SD 10, a within-subject effect of 2 FP with SD 1: independent
    # groups would need far more subjects; the paired test finds it at 10
    rng = np.random.default_rng(5)
    base = rng.normal(20, 10, 12)
    values = np.column_stack([base, base - 2 + rng.normal(0, 1, 12)])
    power = P.resample_power(['standard', 'learned'], values, [10], draws=20, seed=2)
    assert power['posthoc']['standard-learned'][0] >= 0.9


def test_subjects_missing_a_measure_are_left_out_and_bad_input_is_refused(tmp_path):
    study = json.loads(study_json(tmp_path, effect=1.0).read_text())
    conds, values = P.subject_matrix(study, 'avoidance_length')
    assert conds == ['standard', 'learned', 'conservative'] and values.shape == (11, 3)
    with pytest.raises(ValueError, match='unknown measure'):
        P.subject_matrix(study, 'speed')
    with pytest.raises(ValueError, match='two conditions'):
        P.subject_matrix({'conditions': {'standard': {'false_positives': [1, 2]}}})
    assert P.default_sizes(24) == [3, 6, 9, 12, 15, 18, 21, 24]
    assert run(tmp_path / 'missing.json')[0] == 2
