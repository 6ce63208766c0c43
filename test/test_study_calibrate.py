"""The calibrated population (study.calibrate, study.set_types, supersafe population)."""
import json

import numpy as np
import pytest

from supersafe_ros.learning.data import PHASE2_OFFSETS
from supersafe_ros.reach.library import load_or_build_library
from supersafe_ros.sim.supervisor_models import MODELS
from supersafe_ros.sim.watcher import Watcher
from supersafe_ros.study import calibrate as C
from supersafe_ros.study.population import load_population, population_from_dict
from supersafe_ros.study.population_cli import from_subject_files
from supersafe_ros.study.protocol import reference_sets
from supersafe_ros.study.set_types import set_shape


@pytest.fixture(scope='module')
def library():
    return load_or_build_library()


def test_the_expected_phase2_uses_the_supervisor_nodes_own_rule(library):
    """first_passage_states against sim.watcher.Watcher with the same fixed threshold."""
    vf = library.entry(0.5)
    frames = C.phase2_frames([-1.0, 0.5, 2.25], 0.2)
    assert frames[0][0, 0] == -8.0 and frames[0][-1, 0] > 2.5 >= frames[0][-2, 0]
    for f in frames:
        v = vf.value(f)
        thresholds = np.array([-0.5, 0.2, 1.0, 2.5, float(v[0]) + 0.1])
        hit, states = C.first_passage_states(v, f, thresholds)
        for c, h, s in zip(thresholds, hit, states):
            w = Watcher(vf, mu=float(c), sigma=0.0, seed=1)
            decision = None
            for k, x in enumerate(f):
                decision = w.judge('r', x, 0.2 * k, [0], np.zeros((1, 2)))
                if decision is not None:
                    break
            assert h == (decision is not None)
            if h:
                assert np.allclose(s, decision.rel_state, atol=1e-9)


def test_set_types_sort_the_reference_sets_and_a_slow_turner(library):
    std, cons = reference_sets()
    assert set_shape(std, 0.0, std, cons).type == 'standard'
    assert set_shape(cons, 0.0, std, cons).type == 'conservative'
    slow = set_shape(library.entry(0.25), 0.0, std, cons)
    assert slow.type == 'gradual' and slow.extra_reach > 2.0 and abs(slow.width - 1.75) < 0.11
    assert set_shape(library.entry(1.0), 1.8, std, cons).type == 'conservative'


def test_calibration_is_reproducible_and_finds_the_shipped_population_on_a_subgrid():
    """The shipped members are the optimum of the full grid, so a subgrid holding them gives
    them back, with the same expected shares (quadrature: exact, no sampling noise)."""
    shipped = load_population('paper')
    cal = shipped.meta['calibration']
    grid = {'omega_max': sorted({m.omega_max for m in shipped.members}),
            'mu': sorted({m.mu for m in shipped.members} | {0.4}), 'sigma': [0.4, 0.5]}
    doc = C.calibrate(C.PAPER_TARGET, cal['offsets'], cal['step'], seed=cal['seed'], grid=grid)
    assert [(m['omega_max'], m['mu'], m['sigma']) for m in doc['members']] == \
        [(m.omega_max, m.mu, m.sigma) for m in shipped.members]
    for key in ('inside_standard', 'inside_conservative', 'intervention_rate'):
        assert doc['achieved']['expected'][key] == pytest.approx(shipped.meta['achieved']['expected'][key])


def test_the_simulated_check_repeats_the_studys_phase2_exactly():
    pop = load_population('paper')
    run = pop.meta['achieved']['simulated']['runs'][0]
    check = C.simulated_check(pop, run['subjects'], [run['seed']], PHASE2_OFFSETS, 0.2)
    assert check['runs'][0] == run


def test_every_supervisor_model_has_the_same_phase2_so_one_population_fits_them_all():
    """Phase II passes do not turn: the attentive model is the memoryless one there (the
    shipped file records it for a whole study; here three subjects, re-run)."""
    pop = load_population('paper')
    shipped = pop.meta['achieved']['model_agreement']
    assert all(r['same_as_memoryless'] for r in shipped['models'].values())
    assert set(shipped['models']) == set(MODELS)
    again = C.model_agreement(pop, 3, shipped['seed'], PHASE2_OFFSETS, 0.2)
    assert {m: r['same_as_memoryless'] for m, r in again['models'].items()} == {m: True for m in MODELS}
    assert all(r['interventions'] > 0 for r in again['models'].values())


def test_a_population_of_participants_from_their_subject_files(tmp_path):
    # a session's record (fits by estimator) and a simulated study's (fits by condition)
    human = {'subject': {'participant': 'P01', 'kind': 'human'},
             'fits': {'paper': {'omega_max': 0.75, 'mu': 0.2, 'sigma': 0.3},
                      'first_passage': {'omega_max': 0.5, 'mu': 0.2, 'sigma': 0.25, 'estimator': 'first-passage'}}}
    simulated = {'subject': {'index': 3}, 'fits': {'learned': {'omega_max': 1.0, 'mu': 0.1, 'sigma': 0.4},
                                                   'learned_fp': None}}
    empty = {'subject': {'index': 4}, 'fits': {'learned': None}}
    for name, rec in (('a', human), ('b', simulated), ('c', empty)):
        (tmp_path / name).mkdir()
        (tmp_path / name / 'subject.json').write_text(json.dumps(rec))
    doc = from_subject_files([tmp_path])
    members = {m['name']: m for m in doc['members']}
    assert set(members) == {'P01', '3'} and len(doc['skipped']) == 1
    assert (members['P01']['omega_max'], members['P01']['mu']) == (0.5, 0.2)     # first-passage preferred
    assert (members['3']['omega_max'], members['3']['mu']) == (1.0, 0.1)         # the paper fit when alone
    assert members['3']['type'] == 'standard' and members['P01']['type'] == 'gradual'
    pop = population_from_dict(json.loads(json.dumps(doc)), 'x')
    assert sorted(s.pilot for s in pop.draw(4, seed=0)) == ['3', '3', 'P01', 'P01']
    with pytest.raises(ValueError, match='no subject.json'):
        from_subject_files([tmp_path / 'c'])


def test_study_and_population_commands_refuse_a_bad_population(tmp_path, capsys):
    from supersafe_ros.cli import build_parser
    args = build_parser().parse_args(['study', '--subjects', '1', '--population', str(tmp_path / 'none.json'),
                                      '--out', str(tmp_path)])
    assert args.func(args) == 2 and 'cannot read' in capsys.readouterr().err
    args = build_parser().parse_args(['population', 'from-sessions', str(tmp_path), '--out', str(tmp_path / 'p.json')])
    assert args.func(args) == 2 and not (tmp_path / 'p.json').exists()


def test_the_simulated_supervisor_draws_its_noise_once_per_approach_as_the_paper_models(library):
    """V_S at the intervention ~ N(mu, sigma^2) (the paper's eq. 2) whatever the pose rate: one
    w per approach, fixed over its frames (a draw per frame would depend on the frame rate)."""
    vf = library.entry(1.0)
    mu, sigma = 0.5, 0.3
    for step in (0.05, 0.2):
        frames = C.phase2_frames([0.0], step)[0]
        values = []
        for seed in range(120):
            w = Watcher(vf, mu=mu, sigma=sigma, seed=seed)
            thresholds = set()
            for k, x in enumerate(frames):
                decision = w.judge('r', x, step * k, [0], np.zeros((1, 2)))
                if decision is not None:
                    values.append(decision.value)
                    thresholds.add(decision.threshold)
                    break
                thresholds.add(w.thresholds[('r', 0)])
            assert len(thresholds) == 1
        assert abs(np.mean(values) - mu) < 0.06 and abs(np.std(values) - sigma) < 0.05
