"""The simulated population: the five pilot files fitted with the package's estimators,
and the documented table the study falls back to without them."""
import pytest

from supersafe_ros.study import population as P


def test_subjects_are_dealt_from_the_pilots_in_balanced_rounds():
    a, b = P.draw_subjects(12, seed=5), P.draw_subjects(12, seed=5)
    assert a == b and P.draw_subjects(12, seed=6) != a
    names = [s.pilot for s in a]
    assert sorted(names[:5]) == list(P.PILOT_NAMES) and sorted(names[5:10]) == list(P.PILOT_NAMES)
    assert all(names.count(n) in (2, 3) for n in P.PILOT_NAMES)
    for s in a:      # each subject carries its pilot's fitted parameters
        _, w, mu, sigma, _ = P.PILOT_TABLE[s.pilot]
        assert (s.omega_max, s.mu, s.sigma) == (w, mu, sigma)
    assert len({s.seed for s in a}) == 12
    with pytest.raises(ValueError):
        P.draw_subjects(0, seed=1)


def test_without_the_files_the_population_is_the_documented_table(tmp_path):
    fits, source = P.pilot_fits(tmp_path)
    assert 'PILOT_TABLE' in source
    assert [(f.name, f.omega_max, f.mu, f.sigma) for f in fits] == \
        [(n, *P.PILOT_TABLE[n][1:4]) for n in P.PILOT_NAMES]


def test_the_table_is_what_the_estimator_makes_of_the_pilot_files():
    d = P.pilot_dir()
    if not all((d / f'{n}_interventions.csv').is_file() for n in P.PILOT_NAMES):
        pytest.skip(f'pilot files not found at {d} (set SUPERSAFE_PILOT_DATA or put shared/data/s3 '
                    'next to the repository)')
    fits, source = P.pilot_fits(d)
    assert source != 'PILOT_TABLE (pilot files not found)'
    for f in fits:
        n, w, mu, sigma, lapse = P.PILOT_TABLE[f.name]
        assert f.interventions == n and f.omega_max == w and f.lapse == lapse
        assert f.mu == pytest.approx(mu, abs=1e-4) and f.sigma == pytest.approx(sigma, abs=1e-4)


# -- population files -----------------------------------------------------------------------
def population_doc(members):
    return {'format': P.POPULATION_FORMAT, 'name': 'test', 'members': members}


def test_a_population_file_is_dealt_in_proportion_to_its_weights():
    pop = P.population_from_dict(population_doc([
        {'name': 'a', 'type': 'standard', 'weight': 3, 'omega_max': 1.0, 'mu': 0.1, 'sigma': 0.5},
        {'name': 'b', 'type': 'conservative', 'weight': 3, 'omega_max': 0.375, 'mu': 1.3, 'sigma': 0.5},
        {'name': 'c', 'type': 'gradual', 'weight': 5, 'omega_max': 0.875, 'mu': 0.7, 'sigma': 0.5}]), 'x')
    subjects = pop.draw(12, seed=0)
    assert [s.index for s in subjects] == list(range(12))
    names = [s.pilot for s in subjects]
    assert (names.count('a'), names.count('b'), names.count('c')) == (3, 3, 6)   # 12 x 3:3:5, largest remainder
    assert {s.member_type for s in subjects} == {'standard', 'conservative', 'gradual'}
    assert all((s.omega_max, s.mu) == (0.375, 1.3) for s in subjects if s.pilot == 'b')
    assert pop.draw(12, seed=0) == subjects and pop.draw(12, seed=1) != subjects
    assert len({s.seed for s in subjects}) == 12
    assert P.apportion([1, 1], 3, __import__('numpy').random.default_rng(0)) in ([2, 1], [1, 2])


def test_bad_population_files_are_refused_with_the_reason(tmp_path):
    with pytest.raises(ValueError, match='not a population file'):
        P.population_from_dict({'members': []}, 'f.json')
    with pytest.raises(ValueError, match='no members'):
        P.population_from_dict(population_doc([]), 'f.json')
    with pytest.raises(ValueError, match='sigma >= 0'):
        P.population_from_dict(population_doc([{'omega_max': 1, 'mu': 0, 'sigma': -1}]), 'f.json')
    with pytest.raises(ValueError, match='numbers'):
        P.population_from_dict(population_doc([{'omega_max': 'x', 'mu': 0, 'sigma': 1}]), 'f.json')
    with pytest.raises(ValueError, match='cannot read'):
        P.load_population(str(tmp_path / 'missing.json'))
    (tmp_path / 'bad.json').write_text('{')
    with pytest.raises(ValueError, match='not JSON'):
        P.load_population(str(tmp_path / 'bad.json'))


def test_the_shipped_paper_population_records_what_it_achieves():
    pop = P.load_population('paper')
    assert pop.name == 'paper' and [m.type for m in pop.members] == ['standard', 'conservative', 'gradual']
    assert [m.weight for m in pop.members] == [3, 3, 5]
    target, achieved = pop.meta['target'], pop.meta['achieved']
    assert (target['counts']['inside_standard'], target['counts']['inside_conservative']) == ([397, 440], [115, 440])
    for key in ('inside_standard', 'inside_conservative'):
        assert abs(achieved['expected'][key] - target[key]) < 0.01
        assert abs(achieved['simulated'][key] - target[key]) < 0.03
    assert pop.meta['calibration']['seed'] == 0 and 'method' in pop.meta['calibration']
