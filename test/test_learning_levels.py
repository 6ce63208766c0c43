"""One learned_alpha for the study and the filter node: mu + k sigma, else the set's alpha, else 0."""
import pytest

from supersafe_ros.learning.levels import learned_alpha


def test_a_fit_is_at_mu_plus_k_sigma():
    fit = {'omega_max': 0.5, 'mu': 1.0, 'sigma': 0.5, 'alpha': 7.0}     # alpha: the fit's own k
    assert learned_alpha(fit) == 1.0
    assert learned_alpha(fit, 2.0) == pytest.approx(2.0)
    assert learned_alpha({'mu': '0.8', 'sigma': '0.3'}, 1.0) == pytest.approx(1.1)   # metadata strings


def test_a_set_without_mu_and_sigma_is_at_its_alpha_else_zero():
    # the study's condition messages: Conservative and Learned carry mu, sigma = None and alpha
    assert learned_alpha({'mu': None, 'sigma': None, 'alpha': 1.4}, 3.0) == pytest.approx(1.4)
    assert learned_alpha({'mu': 0.9, 'alpha': 0.2}, 1.0) == pytest.approx(0.2)
    assert learned_alpha({'alpha': None}) == 0.0
    assert learned_alpha({}, 2.0) == 0.0
