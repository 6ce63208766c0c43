"""`supersafe fit` end to end on a coarse library (41 x 41 x 24, cached for the session)."""
import json
from pathlib import Path

import numpy as np
import pytest

from supersafe_ros.cli import main
from supersafe_ros.learning import estimators as E
from supersafe_ros.learning.data import PHASE2_OFFSETS, phase2_encounters, write_encounters_csv
from supersafe_ros.learning.supervisor import NoisySupervisor

S3 = Path(__file__).resolve().parents[1] / '..' / 'shared' / 'data' / 's3'
COARSE = ['--shape', '41', '41', '24']


@pytest.fixture(scope='session')
def cache_dir(tmp_path_factory):
    d = tmp_path_factory.getbasetemp() / 'learning-vf-cache'
    d.mkdir(exist_ok=True)
    return str(d)


@pytest.fixture(scope='session')
def coarse(cache_dir):
    from supersafe_ros.reach.library import LibrarySpec, load_or_build_library
    return load_or_build_library(LibrarySpec(shape=(41, 41, 24)), cache_dir=cache_dir)


def pilot(n):
    path = S3 / f'pilot{n}_interventions.csv'
    if not path.exists():
        pytest.skip(f'pilot data not found at {S3} (shared/data/s3 next to the repository)')
    return str(path)


def fit_json(capsys, *argv):
    assert main(['fit', *argv, '--json']) == 0
    return json.loads(capsys.readouterr().out)


def test_fit_json_has_the_listed_keys_and_follows_the_prior(capsys, cache_dir, coarse):
    from supersafe_ros.learning.data import read_interventions_csv
    path = pilot(3)
    d = fit_json(capsys, path, *COARSE, '--cache-dir', cache_dir)
    for key in ('omega_max', 'mu', 'sigma', 'alpha', 'log_likelihood', 'estimator',
                'interventions', 'candidates'):
        assert key in d
    assert d['estimator'] == 'paper' and d['interventions'] == 70 and len(d['candidates']) == 13
    adm = [c['admissible'] for c in d['candidates']]
    assert adm == [c['omega_max'] <= 1.0 for c in d['candidates']]        # true omega_max 1
    assert d['omega_max'] <= 1.0 and d['alpha'] == d['mu']
    # the same numbers as the library API gives
    direct = E.fit_paper(coarse.entries, read_interventions_csv(path),
                         true_vf=coarse.entry(1.0))
    assert (d['omega_max'], d['mu'], d['sigma']) == pytest.approx(
        (direct.omega_max, direct.mu, direct.sigma))
    free = fit_json(capsys, path, *COARSE, '--cache-dir', cache_dir, '--no-prior')
    assert all(c['admissible'] for c in free['candidates']) and free['prior'] is None
    best = max(free['candidates'], key=lambda c: c['log_likelihood'])
    assert free['omega_max'] == best['omega_max']
    tight = fit_json(capsys, path, *COARSE, '--cache-dir', cache_dir, '--true-omega-max', '0.5')
    assert tight['omega_max'] <= 0.5


def test_fit_table_and_plot(capsys, cache_dir, tmp_path):
    png = tmp_path / 'fit.png'
    assert main(['fit', pilot(1), *COARSE, '--cache-dir', cache_dir, '--plot', str(png)]) == 0
    out = capsys.readouterr().out
    assert 'chosen: omega_max' in out and 'admissible' in out
    assert sum(line.lstrip(' *').startswith(('0.', '1.', '2.', '3.')) for line in out.splitlines()) == 13
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 10_000


def test_fit_alpha_options(capsys, cache_dir):
    d = fit_json(capsys, pilot(4), *COARSE, '--cache-dir', cache_dir, '--fp-rate', '0.1')
    assert d['alpha'] == pytest.approx(E.alpha_for_fp_rate(d['mu'], d['sigma'], 0.1))
    k = fit_json(capsys, pilot(4), *COARSE, '--cache-dir', cache_dir, '--alpha-k', '2')
    assert k['alpha'] == pytest.approx(k['mu'] + 2 * k['sigma'])


def test_first_passage_from_an_encounters_file(capsys, cache_dir, coarse, tmp_path):
    sup = NoisySupervisor(coarse.entry(0.5), 1.0, 0.3, rng=1)
    path = tmp_path / 'enc.csv'
    write_encounters_csv(path, phase2_encounters(sup, np.tile(PHASE2_OFFSETS, 11)))
    fp = fit_json(capsys, str(path), *COARSE, '--cache-dir', cache_dir, '--estimator', 'first-passage')
    assert fp['estimator'] == 'first-passage' and fp['encounters'] == 209
    assert fp['omega_max'] == 0.5 and fp['mu'] == pytest.approx(1.0, abs=0.1)
    paper = fit_json(capsys, str(path), *COARSE, '--cache-dir', cache_dir)   # intervention frames
    assert paper['interventions'] == fp['interventions'] and paper['omega_max'] < 0.5


def test_first_passage_on_intervention_states_rebuilds_phase2(capsys, cache_dir):
    d = fit_json(capsys, pilot(3), *COARSE, '--cache-dir', cache_dir, '--estimator', 'first-passage')
    assert d['encounters'] == d['interventions'] == 70
    assert any('rebuilt' in n for n in d['notes']) and d['omega_max'] <= 1.0


def test_fit_reports_bad_input(capsys, cache_dir, tmp_path):
    bad = tmp_path / 'bad.csv'
    bad.write_text('t_ms,x,y,theta\n0,nan,0,0\n')
    assert main(['fit', str(bad), *COARSE, '--cache-dir', cache_dir]) == 2
    assert 'bad.csv:2' in capsys.readouterr().err
    assert main(['fit', str(tmp_path / 'missing.csv'), *COARSE, '--cache-dir', cache_dir]) == 2
    assert 'cannot read' in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(['fit', str(bad), '--estimator', 'nonsense'])
