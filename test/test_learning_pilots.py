"""Both estimators on the five pilot supervisors of the paper's experiment software
(../shared/data/s3; no ground truth there, so these tests check the estimators'
definitions and guarantees on real data, not particular answers)."""
from pathlib import Path

import numpy as np
import pytest

from supersafe_ros.learning import estimators as E
from supersafe_ros.learning.data import encounters_from_phase2_interventions, read_interventions_csv
from supersafe_ros.reach.grid import Grid

S3 = Path(__file__).resolve().parents[1] / '..' / 'shared' / 'data' / 's3'
OMEGAS = (0.0, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0, 1.5, 2.0, 2.5, 3.0)


@pytest.fixture(scope='session')
def coarse_library(tmp_path_factory):
    from supersafe_ros.reach.library import load_or_solve
    cache = tmp_path_factory.getbasetemp() / 'learning-vf-cache'
    cache.mkdir(exist_ok=True)
    grid = Grid((-8.0, -8.0), (8.0, 8.0), (41, 41, 24))
    return [load_or_solve(grid, 3.0, w, 1.8, 3.0, cache_dir=cache) for w in OMEGAS]


def pilot_states(n):
    path = S3 / f'pilot{n}_interventions.csv'
    if not path.exists():
        pytest.skip(f'pilot data not found at {S3} (shared/data/s3 next to the repository)')
    return read_interventions_csv(path)


@pytest.mark.parametrize('n', range(1, 6))
def test_paper_fit_of_each_pilot_follows_the_definition(coarse_library, n):
    states = pilot_states(n)
    true = coarse_library[OMEGAS.index(1.0)]
    res = E.fit_paper(coarse_library, states, true_vf=true)
    v = res.value_function.value(states)
    mu = max(v.mean(), 0.0)
    assert res.mu == pytest.approx(mu)
    assert res.sigma == pytest.approx(np.sqrt(np.mean((v - mu) ** 2)))
    admissible = [c for c in res.candidates if c['admissible']]
    assert res.candidates[res.index]['admissible'] and res.omega_max <= 1.0
    assert res.log_likelihood == max(c['log_likelihood'] for c in admissible)
    free = E.fit_paper(coarse_library, states)
    assert free.log_likelihood >= res.log_likelihood     # the prior can only cost likelihood


@pytest.mark.parametrize('n', range(1, 6))
def test_first_passage_on_rebuilt_pilot_approaches(coarse_library, n):
    states = pilot_states(n)
    enc = encounters_from_phase2_interventions(states)
    # an intervention is impossible under entry i when a frame before it on the same
    # approach already had a value at or below the intervention's
    direct = []
    for vf in coarse_library:
        direct.append(sum(vf.value(e.states[-1:])[0] >= vf.value(e.states[:-1]).min()
                          for e in enc if len(e.states) > 1))
    if all(k > 0 for k in direct):
        with pytest.raises(ValueError, match='explain'):
            E.fit_first_passage(coarse_library, enc, conditional=True)
        res = E.fit_first_passage(coarse_library, enc, conditional=True, lapse=0.01)
    else:
        res = E.fit_first_passage(coarse_library, enc, conditional=True)
        assert direct[res.index] == 0
    assert [c['impossible_interventions'] for c in res.candidates] == direct
    assert direct[0] > 0            # omega_max 0: V is flat along a straight approach
    assert res.encounters == res.interventions == len(states)
    assert res.mu >= 0.0 and res.sigma > E.SIGMA_FLOOR and np.isfinite(res.log_likelihood)
