"""Simulated subjects: noisy idealized supervisors drawn from a documented population.

The paper's twelve people split into supervisors whose learned sets arc like
the Standard set (close to the true agility), ones that arc like the
Conservative set, and ones with gradual, pre-emptive arcs (a low believed
turn rate). The population mirrors that:

* believed turn rate w_S: with probability 0.25 the truth (1.0) or its neighbour
  0.875 ("close to the truth"); otherwise uniform over the library's less agile
  entries {0.25, 0.375, 0.5, 0.625, 0.75} ("believe the robots less agile").
  w_S <= 1 keeps every subject conservative (V_S <= V, so V <= 0 implies
  V_S <= mu for mu >= 0), as the paper's supervisor model requires;
* margin mu ~ Uniform(0.3, 1.5) m: people intervene before the zero level set;
* noise sigma ~ Uniform(0.15, 0.45) m;
* horizon: the library's (3 s).

Everything is drawn from numpy's default_rng(seed): the same seed gives the
same subjects.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

CLOSE_TO_TRUTH = (1.0, 0.875)
LESS_AGILE = (0.25, 0.375, 0.5, 0.625, 0.75)
P_CLOSE = 0.25
MU_RANGE = (0.3, 1.5)
SIGMA_RANGE = (0.15, 0.45)


@dataclass(frozen=True)
class Subject:
    index: int
    omega_max: float
    mu: float
    sigma: float
    seed: int

    def to_dict(self) -> dict:
        return asdict(self)


def draw_subjects(n: int, seed: int) -> list[Subject]:
    """``n`` subjects; the first two are pinned to one of each kind when n >= 2,
    so even a small demo shows both a near-truth and a less-agile supervisor."""
    if n < 1:
        raise ValueError(f'need at least one subject, got {n}')
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        if i == 0 and n >= 2:
            w = float(rng.choice(LESS_AGILE))
        elif i == 1 and n >= 2:
            w = float(rng.choice(CLOSE_TO_TRUTH))
        else:
            w = float(rng.choice(CLOSE_TO_TRUTH) if rng.random() < P_CLOSE else rng.choice(LESS_AGILE))
        mu = float(rng.uniform(*MU_RANGE))
        sigma = float(rng.uniform(*SIGMA_RANGE))
        out.append(Subject(i, w, round(mu, 3), round(sigma, 3), int(rng.integers(0, 2**31 - 1))))
    return out
