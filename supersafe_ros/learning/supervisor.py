"""The noisy idealized supervisor (paper, section II-B) as code.

The supervisor holds an internal value function V_S (a library entry), a margin
mu and a noise level sigma. One *judgement* covers one encounter: the robot's
approach to an obstacle, seen frame by frame as states relative to the obstacle
(obstacle at the origin, axes as the map). For each judgement the supervisor
draws

    w ~ N(0, sigma^2)                     (once per encounter)

and intervenes at the first frame x_k with

    V_S(x_k) <= mu + w,

or never, if the threshold mu + w stays below every value seen. Drawing w once
per encounter (not once per frame) is what makes the intervention a *first
passage*: the frames before x_k were all judged safe with the same threshold,
which is what the first-passage estimator in ``estimators.py`` exploits.
"""
from __future__ import annotations

import numpy as np

from ..reach.value_function import ValueFunction


class NoisySupervisor:
    """Intervene at the first frame with V_S(x) <= mu + w, w ~ N(0, sigma^2) per encounter.

    Two ways to use it:

    * batch: ``judge_encounter(rel_states)`` with the whole approach (T, 3);
    * streaming (a node seeing one frame at a time): ``start_encounter()`` once per
      approach, then ``observe(rel_state)`` per frame; ``True`` means intervene now.
      After an intervention the encounter is over: further ``observe`` calls return
      ``False`` until the next ``start_encounter()``.

    Frames outside V_S's grid take the value at the nearest grid edge (far from the
    obstacle that is a large value, so the supervisor stays calm there).
    """

    def __init__(self, value_function: ValueFunction, mu: float, sigma: float, rng=None):
        if not isinstance(value_function, ValueFunction):
            raise TypeError(f'value_function must be a ValueFunction, got {type(value_function).__name__}')
        mu = float(mu)
        sigma = float(sigma)
        if not np.isfinite(mu):
            raise ValueError(f'mu must be finite, got {mu}')
        if not (np.isfinite(sigma) and sigma >= 0.0):
            raise ValueError(f'sigma must be finite and >= 0, got {sigma}')
        self.value_function = value_function
        self.mu = mu
        self.sigma = sigma
        self.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        self._threshold = None   # mu + w of the current encounter, None between encounters
        self._done = False

    def __repr__(self):
        return (f'NoisySupervisor(omega_max={self.value_function.omega_max}, '
                f'mu={self.mu:g}, sigma={self.sigma:g})')

    def draw_threshold(self) -> float:
        """mu + w for one judgement."""
        return self.mu + self.sigma * float(self.rng.standard_normal())

    # -- batch -------------------------------------------------------------
    def judge_encounter(self, rel_states) -> int | None:
        """Index of the first frame with V_S(x) <= mu + w (one w for the whole
        encounter), or None if the supervisor lets the robot pass."""
        s = _as_frames(rel_states)
        threshold = self.draw_threshold()
        if len(s) == 0:
            return None
        hits = np.flatnonzero(self.value_function.value(s) <= threshold)
        return int(hits[0]) if hits.size else None

    # -- streaming ---------------------------------------------------------
    def start_encounter(self) -> None:
        """Begin a new approach: draw this judgement's threshold mu + w."""
        self._threshold = self.draw_threshold()
        self._done = False

    def observe(self, rel_state) -> bool:
        """Judge one frame of the current encounter; True = intervene now.

        Calling it without ``start_encounter()`` starts an encounter implicitly.
        A non-finite state is rejected with ValueError (the caller logs it and keeps
        the previous decision)."""
        s = np.asarray(rel_state, dtype=float).reshape(-1)
        if s.shape != (3,):
            raise ValueError(f'a frame is one state (x, y, theta), got shape {np.shape(rel_state)}')
        if not np.all(np.isfinite(s)):
            raise ValueError(f'frame contains NaN or infinite values: {s}')
        if self._threshold is None:
            self.start_encounter()
        if self._done:
            return False
        if float(self.value_function.value(s[None, :])[0]) <= self._threshold:
            self._done = True
            return True
        return False

    @property
    def threshold(self):
        """mu + w of the current encounter (None before the first one)."""
        return self._threshold


def _as_frames(rel_states) -> np.ndarray:
    s = np.asarray(rel_states, dtype=float)
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f'an encounter is a (T, 3) array of relative states, got shape {s.shape}')
    if not np.all(np.isfinite(s)):
        raise ValueError('encounter frames contain NaN or infinite values')
    return s
