"""The estimators: the paper's pinned to its definition, the first-passage one recovering
synthetic supervisors, the conservative prior, alpha and false positives."""
import json
import math

import numpy as np
import pytest
from scipy import stats

from supersafe_ros.learning import estimators as E
from supersafe_ros.learning.data import (Encounter, PHASE2_OFFSETS, intervention_states,
                                         phase2_encounters)
from supersafe_ros.learning.supervisor import NoisySupervisor
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.value_function import ValueFunction

OMEGAS = (0.0, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0, 1.5, 2.0, 2.5, 3.0)


@pytest.fixture(scope='session')
def coarse_library(tmp_path_factory):
    """The paper's library (speed 3, radius 1.8, horizon 3) on a coarse 41 x 41 x 24 grid."""
    grid = Grid((-8.0, -8.0), (8.0, 8.0), (41, 41, 24))
    cache = tmp_path_factory.getbasetemp() / 'learning-vf-cache'
    cache.mkdir(exist_ok=True)
    from supersafe_ros.reach.library import load_or_solve
    return [load_or_solve(grid, 3.0, w, 1.8, 3.0, cache_dir=cache) for w in OMEGAS]


def linear_vf(a=1.0, b=0.0, c=0.0, shape=(17, 17, 8), lo=(-8.0, -8.0), hi=(8.0, 8.0), omega=None):
    """V = a x + b y + c (exact under trilinear interpolation)."""
    g = Grid(lo, hi, shape)
    X, Y, _ = g.mesh()
    return ValueFunction(g, a * X + b * Y + c, {} if omega is None else {'omega_max': omega})


# -- the paper's estimator ---------------------------------------------------------------------
def test_paper_estimates_follow_the_definition_on_hand_made_values():
    values = np.array([[1.0, 2.0, 3.0, 6.0],
                       [-1.0, -2.0, 0.5, 0.5],       # negative mean: mu clamps to 0
                       [0.3, 0.3, 0.3, 0.3]])        # degenerate: sigma floored
    mu, sigma, ll, floored = E.paper_estimates(values)
    for i, v in enumerate(values):
        m = max(v.mean(), 0.0)
        s = max(math.sqrt(np.mean((v - m) ** 2)), E.SIGMA_FLOOR)   # about mu after the clamp
        assert mu[i] == pytest.approx(m)
        assert sigma[i] == pytest.approx(s)
        assert ll[i] == pytest.approx(stats.norm.logpdf(v, m, s).sum())
    assert sigma[1] > values[1].std()                # the clamp widens sigma: not the sample std
    assert floored.tolist() == [False, False, True]


def test_fit_paper_scores_each_entry_from_its_values_at_the_intervention_states():
    entries = [linear_vf(1.0, 0.0, 0.0, omega=0.5), linear_vf(0.2, 0.0, 1.0, omega=1.0),
               linear_vf(0.0, 1.0, -5.0, omega=2.0)]
    states = np.array([[-1.0, 0.5, 0.0], [0.5, 0.0, 1.0], [2.0, -1.0, 3.0], [1.5, 2.0, -2.0]])
    res = E.fit_paper(entries, states)
    direct = []
    for e, (a, b, c) in zip(entries, [(1.0, 0.0, 0.0), (0.2, 0.0, 1.0), (0.0, 1.0, -5.0)]):
        v = a * states[:, 0] + b * states[:, 1] + c
        m = max(v.mean(), 0.0)
        s = math.sqrt(np.mean((v - m) ** 2))
        direct.append((m, s, stats.norm.logpdf(v, m, s).sum()))
    for cand, (m, s, ll) in zip(res.candidates, direct):
        assert (cand['mu'], cand['sigma'], cand['log_likelihood']) == pytest.approx((m, s, ll))
    best = int(np.argmax([d[2] for d in direct]))
    assert res.index == best and res.omega_max == OMEGAS_OF(entries)[best]
    assert res.mu == pytest.approx(direct[best][0]) and res.alpha == pytest.approx(res.mu)
    assert res.value_function is entries[best] and res.interventions == 4
    k2 = E.fit_paper(entries, states, alpha_k=2.0)
    assert k2.alpha == pytest.approx(k2.mu + 2.0 * k2.sigma)


def OMEGAS_OF(entries):
    return [e.meta['omega_max'] for e in entries]


def test_fit_result_to_dict_is_json_with_the_cli_keys():
    entries = [linear_vf(omega=0.5), linear_vf(a=0.0, c=0.3, omega=1.0)]   # second: degenerate
    res = E.fit_paper(entries, np.array([[1.0, 0.0, 0.0], [2.0, 1.0, 0.0]]))
    d = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    for key in ('omega_max', 'mu', 'sigma', 'alpha', 'log_likelihood', 'estimator',
                'interventions', 'candidates'):
        assert key in d
    assert set(d['candidates'][0]) >= {'omega_max', 'mu', 'sigma', 'log_likelihood', 'admissible'}
    assert d['candidates'][1]['sigma_floored'] is True and any('floored' in n for n in d['notes'])


def test_estimators_reject_bad_input():
    e = [linear_vf(omega=1.0)]
    with pytest.raises(ValueError, match='NaN'):
        E.fit_paper(e, [[0.0, np.nan, 0.0]])
    with pytest.raises(ValueError, match=r'\(N, 3\)'):
        E.fit_paper(e, np.zeros((3, 2)))
    with pytest.raises(ValueError, match='no intervention'):
        E.fit_paper(e, np.zeros((0, 3)))
    with pytest.raises(ValueError, match='empty'):
        E.fit_paper([], np.zeros((2, 3)))
    with pytest.raises(ValueError, match='no encounters'):
        E.fit_first_passage(e, [])
    with pytest.raises(ValueError, match='lapse'):
        E.fit_first_passage(e, [Encounter(np.zeros((2, 3)), True)], lapse=1.0)


# -- the conservative prior -------------------------------------------------------------------
def test_admissibility_is_decided_from_the_grids_not_the_order():
    true = linear_vf(1.0, 0.0, 0.0)                               # unsafe: x <= 0
    bigger = linear_vf(1.0, 0.0, -1.0, omega=9.0)                 # unsafe x <= 1: contains it
    smaller = linear_vf(1.0, 0.0, 1.0, omega=0.0)                 # unsafe x <= -1: does not
    finer = linear_vf(1.0, 0.0, -0.5, shape=(33, 25, 12))         # other grid: interpolated
    tilted = linear_vf(1.0, 0.3, 0.0, omega=0.5)                  # sticks out where y > 0
    mask = E.admissible_mask([smaller, bigger, finer, tilted, true], true, tol=0.0)
    assert mask.tolist() == [False, True, True, False, True]
    # a library whose omega_max labels say the opposite changes nothing
    assert E.admissible_mask([bigger, smaller], true, tol=0.0).tolist() == [True, False]
    small_grid = linear_vf(1.0, 0.0, -1.0, lo=(-4.0, -4.0), hi=(4.0, 4.0))
    assert not E.admissible_mask([small_grid], true, tol=0.0)[0]  # cannot be verified outside


def test_prior_restricts_the_choice_to_admissible_entries():
    true = linear_vf(1.0, 0.0, 0.0)
    states = np.array([[0.3, 0.0, 0.0], [0.4, 1.0, 0.0], [0.5, -1.0, 0.0]])
    loose = linear_vf(1.0, 0.0, 1.0, omega=3.0)      # not admissible, but fits well
    entries = [linear_vf(5.0, 0.0, -4.0, omega=0.5), loose]
    assert E.fit_paper(entries, states).index == 1
    res = E.fit_paper(entries, states, true_vf=true)
    assert res.index == 0 and [c['admissible'] for c in res.candidates] == [True, False]
    with pytest.raises(ValueError, match='admissible'):
        E.fit_paper([loose], states, true_vf=true)


def test_the_library_is_admissible_below_the_true_turn_rate(coarse_library):
    true = coarse_library[OMEGAS.index(1.0)]
    order = np.random.default_rng(0).permutation(len(OMEGAS))
    mask = E.admissible_mask([coarse_library[i] for i in order], true)
    assert mask.tolist() == [OMEGAS[i] <= 1.0 for i in order]


# -- first passage -------------------------------------------------------------------------------
def test_log_ndtr_diff_is_accurate_in_both_tails_and_at_infinity():
    a = np.array([-1.0, 10.0, -40.0, 3.0, -np.inf, 2.0, 0.5])
    b = np.array([1.0, 11.0, -39.0, 3.0 + 1e-9, 0.0, np.inf, 0.5])
    got = E.log_ndtr_diff(a, b)
    ref = [np.log(stats.norm.cdf(1) - stats.norm.cdf(-1)),
           stats.norm.logsf(10) + np.log1p(-np.exp(stats.norm.logsf(11) - stats.norm.logsf(10))),
           stats.norm.logcdf(-39) + np.log1p(-np.exp(stats.norm.logcdf(-40) - stats.norm.logcdf(-39))),
           np.log(stats.norm.pdf(3.0) * 1e-9), stats.norm.logcdf(0.0), stats.norm.logsf(2.0), -np.inf]
    assert np.allclose(got[:-1], ref[:-1], rtol=1e-6)
    assert got[-1] == -np.inf


def test_first_passage_likelihood_matches_a_direct_computation():
    # V = -x along passes heading +x: values fall frame by frame.
    vf = linear_vf(-1.0, 0.0, 0.0, omega=1.0)
    x = np.array([-4.0, -3.0, -2.5, -1.0])
    frames = np.stack([x, np.zeros(4), np.zeros(4)], axis=1)
    enc = [Encounter(frames[:3], True), Encounter(frames, False), Encounter(frames[:1], True)]
    mu, sigma = 2.2, 0.7
    direct = (np.log(stats.norm.cdf(3.0, mu, sigma) - stats.norm.cdf(2.5, mu, sigma))
              + stats.norm.logcdf(1.0, mu, sigma)
              + stats.norm.logsf(4.0, mu, sigma))
    iv = E.encounter_intervals([vf], enc)
    assert E.first_passage_loglik([mu / sigma], [1 / sigma], iv)[0] == pytest.approx(direct)
    # conditioning on an intervention divides each term by P(mu + w >= min V of the full pass)
    full = [Encounter(frames[:3], True, full_pass=frames), Encounter(frames[:1], True, full_pass=frames)]
    ivc = E.encounter_intervals([vf], full, conditional=True)
    direct_c = (np.log(stats.norm.cdf(3.0, mu, sigma) - stats.norm.cdf(2.5, mu, sigma))
                + stats.norm.logsf(4.0, mu, sigma) - 2 * stats.norm.logsf(1.0, mu, sigma))
    assert E.first_passage_loglik([mu / sigma], [1 / sigma], ivc)[0] == pytest.approx(direct_c)


@pytest.mark.parametrize('conditional, lapse', [(False, 0.0), (True, 0.0), (False, 0.05), (True, 0.05)])
def test_first_passage_gradient_matches_finite_differences(conditional, lapse):
    rng = np.random.default_rng(1)
    vf = linear_vf(-1.0, 0.0, 0.0, omega=1.0)
    enc = []
    for _ in range(30):
        x = np.sort(rng.uniform(-6, 1, size=8))
        f = np.stack([x, np.zeros(8), np.zeros(8)], axis=1)
        k = int(rng.integers(1, 8))
        enc.append(Encounter(f[:k], True, full_pass=f))
    iv = E.encounter_intervals([vf, linear_vf(-0.7, 0.0, 0.4)], enc, conditional=conditional)
    eta, tau = np.array([1.5, 0.4]), np.array([0.8, 1.7])
    _, de, dt = E.first_passage_loglik(eta, tau, iv, lapse, grad=True)
    h = 1e-6
    fd_e = (E.first_passage_loglik(eta + h, tau, iv, lapse) - E.first_passage_loglik(eta - h, tau, iv, lapse)) / (2 * h)
    fd_t = (E.first_passage_loglik(eta, tau + h, iv, lapse) - E.first_passage_loglik(eta, tau - h, iv, lapse)) / (2 * h)
    assert np.allclose(de, fd_e, rtol=1e-5, atol=1e-5)
    assert np.allclose(dt, fd_t, rtol=1e-5, atol=1e-5)


def test_an_entry_that_cannot_explain_an_intervention_scores_minus_infinity_unless_lapses():
    flat = linear_vf(0.0, 0.0, 1.0, omega=0.0)          # V constant: never a first crossing after frame 0
    falling = linear_vf(-1.0, 0.0, 0.0, omega=1.0)
    x = np.linspace(-6.0, -2.0, 9)
    f = np.stack([x, np.zeros(9), np.zeros(9)], axis=1)
    enc = [Encounter(f[:k], True) for k in (3, 5, 7)]
    res = E.fit_first_passage([flat, falling], enc)
    assert res.candidates[0]['log_likelihood'] == -np.inf and res.index == 1
    assert res.candidates[0]['impossible_interventions'] == 3
    lapsed = E.fit_first_passage([flat, falling], enc, lapse=0.1)
    assert np.isfinite(lapsed.candidates[0]['log_likelihood']) and lapsed.index == 1


SUPERVISORS = [  # (omega_max, mu, sigma): several turn rates, margins, noise levels
    (0.5, 1.0, 0.3),       # the example, where the paper's estimator fails
    (0.25, 0.5, 0.2),
    (0.75, 0.3, 0.1),
    (1.0, 0.8, 0.2),
    (1.5, 1.2, 0.3),
]


def synthetic_phase2(library, omega, mu, sigma, seed, repeats=11):
    sup = NoisySupervisor(library[OMEGAS.index(omega)], mu, sigma, rng=seed)
    return phase2_encounters(sup, np.tile(PHASE2_OFFSETS, repeats), dt=0.02)


@pytest.mark.parametrize('omega, mu, sigma', SUPERVISORS)
def test_first_passage_recovers_synthetic_supervisors(coarse_library, omega, mu, sigma):
    # 418 passes (the 19-offset ladder 22 times); over 10 seeds each of these was recovered
    # 10/10 (bench/bench_fit.py --recovery prints the rates)
    enc = synthetic_phase2(coarse_library, omega, mu, sigma, seed=int(omega * 100 + mu * 10), repeats=22)
    res = E.fit_first_passage(coarse_library, enc)
    assert res.omega_max == omega
    assert res.mu == pytest.approx(mu, abs=0.08)
    assert res.sigma == pytest.approx(sigma, rel=0.15)
    assert res.encounters == len(enc) and res.interventions == sum(e.intervened for e in enc)


def test_paper_estimator_misses_where_first_passage_does_not(coarse_library):
    enc = synthetic_phase2(coarse_library, 0.5, 1.0, 0.3, seed=1)
    paper = E.fit_paper(coarse_library, intervention_states(enc))
    fp = E.fit_first_passage(coarse_library, enc)
    assert fp.omega_max == 0.5
    assert paper.omega_max < 0.5 and paper.mu < 0.85          # flatter entry, smaller margin
    # the same holds with the conservative prior on (both entries are admissible)
    true = coarse_library[OMEGAS.index(1.0)]
    assert E.fit_first_passage(coarse_library, enc, true_vf=true).omega_max == 0.5


def test_conditional_likelihood_recovers_from_interventions_only(coarse_library):
    # Drop the passes without intervention, as the pilot files do, and condition on it.
    enc = synthetic_phase2(coarse_library, 0.75, 0.3, 0.25, seed=4)
    kept = [e for e in enc if e.intervened]
    assert len(kept) < len(enc)                                # some passes had none
    res = E.fit_first_passage(coarse_library, kept, conditional=True)
    assert res.omega_max == 0.75
    assert res.mu == pytest.approx(0.3, abs=0.1) and res.sigma == pytest.approx(0.25, rel=0.25)
    with pytest.raises(ValueError, match='interventions only'):
        E.fit_first_passage(coarse_library, enc, conditional=True)


# -- alpha and false positives ------------------------------------------------------------------
def test_alpha_for_fp_rate_inverts_the_gaussian_tail():
    assert E.alpha_for_fp_rate(1.0, 0.3, 0.5) == pytest.approx(1.0)
    assert E.alpha_for_fp_rate(1.0, 0.3, stats.norm.sf(2.0)) == pytest.approx(1.6)
    a = E.alpha_for_fp_rate(0.4, 0.2, 0.1)
    assert stats.norm.sf(a, 0.4, 0.2) == pytest.approx(0.1)
    for bad in (0.0, 1.0, -0.1):
        with pytest.raises(ValueError):
            E.alpha_for_fp_rate(1.0, 0.3, bad)


def test_predicted_false_positive_fraction_counts_states_inside_the_safe_set():
    vf = linear_vf(1.0, 0.0, 0.0)
    states = np.array([[x, 0.0, 0.0] for x in (-1.0, 0.2, 0.5, 0.7, 2.0)])
    assert E.predicted_false_positive_fraction(vf, 0.5, states) == pytest.approx(2 / 5)
    assert E.predicted_false_positive_fraction(vf, -5.0, states) == 1.0


def test_predicted_false_positives_match_the_rate_on_synthetic_data(coarse_library):
    enc = synthetic_phase2(coarse_library, 0.75, 0.6, 0.3, seed=9, repeats=20)
    res = E.fit_first_passage(coarse_library, enc)
    states = intervention_states(enc)
    for rate in (0.5, 0.16, 0.05):
        alpha = E.alpha_for_fp_rate(res.mu, res.sigma, rate)
        got = E.predicted_false_positive_fraction(res.value_function, alpha, states)
        assert got == pytest.approx(rate, abs=0.05)


@pytest.mark.parametrize('conditional, lapse', [(False, 0.0), (True, 0.0), (False, 0.02)])
def test_vectorised_newton_finds_the_same_maximum_as_lbfgsb(coarse_library, conditional, lapse):
    enc = synthetic_phase2(coarse_library, 0.75, 0.5, 0.3, seed=2, repeats=4)
    if conditional:
        enc = [e for e in enc if e.intervened]
    iv = E.encounter_intervals(coarse_library, enc, conditional=conditional)
    mu_n, sd_n, ll_n = E.maximise_first_passage(iv, lapse, method='newton')
    mu_l, sd_l, ll_l = E.maximise_first_passage(iv, lapse, method='lbfgsb')
    fitted = np.isfinite(ll_l)
    assert np.array_equal(np.isfinite(ll_n), fitted) and fitted.sum() >= 10
    assert np.all(ll_n[fitted] >= ll_l[fitted] - 1e-6)           # never a worse optimum
    assert np.allclose(mu_n[fitted], mu_l[fitted], atol=1e-4)
    assert np.allclose(sd_n[fitted], sd_l[fitted], rtol=1e-4)


def test_first_passage_says_so_when_no_encounter_has_an_intervention():
    vf = linear_vf(-1.0, 0.0, 0.0, omega=1.0)
    x = np.linspace(-6.0, -2.0, 9)
    f = np.stack([x, np.zeros(9), np.zeros(9)], axis=1)
    res = E.fit_first_passage([vf], [Encounter(f, False, k) for k in range(5)])
    assert res.interventions == 0 and any('not identified' in n for n in res.notes)
