r"""The level alpha of a learned safe set {V > alpha}: where the robots' filter acts.

A fit gives the supervisor's threshold mu and its spread sigma (intervention values
~ N(mu, sigma^2), ``estimators``); the filter acts at

    alpha = mu + k sigma

with k = 0 in the paper's experiment (the study's observed sweep raises k; a filter node
adds its ``alpha_offset`` as k). A set that carries no (mu, sigma), such as the study's
Conservative set sent with its level only, is at its own ``alpha``, and one without
either is at 0, the standard level. (``estimators.alpha_for_fp_rate`` chooses alpha for
a false-positive rate instead.)

ROS-free: a fit dict or a value function's metadata, nothing else.
"""
from __future__ import annotations

from collections.abc import Mapping


def learned_alpha(fit: Mapping, k: float = 0.0) -> float:
    """alpha = mu + k sigma from ``fit`` (a fit dict, or a value function's metadata);
    without mu or sigma its ``alpha``; without that 0."""
    mu, sigma = fit.get('mu'), fit.get('sigma')
    if mu is not None and sigma is not None:
        return float(mu) + k * float(sigma)
    return float(fit.get('alpha') or 0.0)
