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
