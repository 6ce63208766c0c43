"""A population calibrated so that its Phase II reproduces a target study (the paper's).

``supersafe population calibrate --target paper --out FILE.json``. What is fitted to what:

* **The population.** One simulated supervisor (w_S, mu, sigma: the noisy idealized
  supervisor of ``sim.watcher``) per set type of the paper's Fig. 6 (``set_types``:
  Standard-like, Conservative-like, gradual), dealt in the paper's mix (3 : 3 : 5). Each
  type's (w_S, mu, sigma) is searched over a grid: w_S among the library's turn rates
  0.25..1 (a conservative supervisor believes the robots no more agile than they are),
  mu in [0, 2.5] m by 0.1, sigma in [0.2, 0.6] m by 0.1.
* **The data it must reproduce.** The paper's Table 1, left half: of the 440 Phase II
  interventions, 397 inside Standard and 115 inside Conservative (V_set > 0 at the
  intervention state), and 440 interventions in 11 x 42 = 462 scenes; and Fig. 6's mix of
  learned sets (the paper's estimator on each subject's Phase II, sorted by ``set_type``).
* **How a candidate is scored.** On the study's own Phase II (its offsets, step and pass,
  ``phase2_frames``) under the supervisor node's rule (``first_passage_states``: the first
  pose with V_S <= mu + w, the reported state interpolated to the crossing, as
  ``sim.watcher`` does):
  - expected interventions and states inside Standard / Conservative per subject, by
    quadrature over w (``QUANTILES`` equal-probability nodes of N(0, sigma^2)): exact in
    expectation, no sampling noise;
  - the chance that the subject's learned set (the paper's estimator, conservative prior,
    alpha = mu, at least 3 interventions: the study's Learned) has each type, from
    ``REALISATIONS`` seeded Phase II draws per candidate (``numpy.random.default_rng(seed)``).
* **The loss** (``loss``), over the three types' candidates together:
  ((S_std - 397/440) / 0.01)^2 + ((S_cons - 115/440) / 0.01)^2 + ((rate - 440/462) / 0.05)^2
  + sum over types of (expected subjects of that type - the mix's) ^ 2
  + sum over types of ((sigma - 0.48) / 0.2)^2,
  with S the pooled shares (the paper pools interventions over subjects) and rate the
  interventions per scene. The last term is a weak prior: among populations that fit
  equally well, the noise nearest the authors' five pilots (sigma 0.40-0.55, fitted from
  real interventions: ``population``) wins.
* **The search**: exhaustive over the grid, each type's candidates restricted to those
  whose learned set has that type at least half the time; deterministic given the seed
  of the realisations.

``calibrate`` returns the population as a dict (``population.population_from_dict``
reads it back) with the target, the achieved shares (expected, and realised by a seeded
simulation of a whole study's Phase II), the mix and the method.

**Every supervisor model** (``sim.supervisor_models``) is calibrated by this one search:
the models differ only in what the robot's turns tell the supervisor, and Phase II's
passes do not turn, so each model's Phase II is the memoryless rule's and the best
population is the same. ``model_agreement`` checks it on the study's own engine (every
scene and intervention state of a whole study's Phase II under each model) and the file
records it (``achieved.model_agreement``).
"""
from __future__ import annotations

from dataclasses import dataclass
import time

import numpy as np
from scipy import special

from ..learning.estimators import admissible_mask, paper_estimates
from .protocol import PHASE2_X0, PHASE2_X_END, SPEED
from .set_types import TYPES, set_shape

QUANTILES = 64
REALISATIONS = 32
MIN_INTERVENTIONS = 3            # the study's learners publish from 3 interventions
ALPHA_STEP = 0.05                # the type table's resolution in alpha
SHARE_TOL, RATE_TOL, SIGMA_PRIOR, SIGMA_TOL = 0.01, 0.05, 0.48, 0.2
GRID = {'omega_max': (0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0),
        'mu': tuple(round(0.1 * k, 2) for k in range(26)),
        'sigma': (0.2, 0.3, 0.4, 0.5, 0.6)}


@dataclass(frozen=True)
class Target:
    """What a calibrated population's Phase II must reproduce."""

    name: str
    inside_standard: tuple        # (interventions inside Standard, interventions)
    inside_conservative: tuple
    interventions: tuple          # (interventions, scenes)
    mix: dict                     # set type -> subjects

    def shares(self) -> dict:
        return {'inside_standard': self.inside_standard[0] / self.inside_standard[1],
                'inside_conservative': self.inside_conservative[0] / self.inside_conservative[1],
                'intervention_rate': self.interventions[0] / self.interventions[1]}

    def to_dict(self) -> dict:
        return {'name': self.name, 'mix': dict(self.mix), **self.shares(),
                'counts': {'inside_standard': list(self.inside_standard),
                           'inside_conservative': list(self.inside_conservative),
                           'interventions_scenes': list(self.interventions)}}


# the paper: Table 1 (Phase II, 11 participants) and Fig. 6; 42 offsets per participant
PAPER_TARGET = Target('paper', (397, 440), (115, 440), (440, 11 * 42),
                      {'standard': 3, 'conservative': 3, 'gradual': 5})
TARGETS = {'paper': PAPER_TARGET}


# -- Phase II under the supervisor node's rule -----------------------------------------------
def phase2_frames(offsets, step: float, x0: float = PHASE2_X0, x_end: float = PHASE2_X_END,
                  speed: float = SPEED) -> list:
    """The poses of each Phase II pass as the study plays them (``phase2_events``): from
    (x0, y0) heading 0, a pose every ``step``, up to the first pose past x_end."""
    out = []
    for y0 in offsets:
        n = int(np.floor((x_end - x0) / (speed * step) + 1e-9)) + 2
        x = x0 + speed * step * np.arange(n)
        x = x[:int(np.argmax(x > x_end)) + 1]
        out.append(np.column_stack([x, np.full(len(x), float(y0)), np.zeros(len(x))]))
    return out


def first_passage_states(values, frames, thresholds):
    """The supervisor's intervention on one pass for each threshold mu + w: (intervened (Q,),
    states (Q, 3)). The first pose with V_S <= threshold; the state reported is the linear
    crossing between it and the pose before (``sim.watcher.Watcher.judge``), or the pose
    itself when the pass starts below the threshold."""
    v = np.asarray(values, dtype=float)
    c = np.asarray(thresholds, dtype=float)
    running = np.minimum.accumulate(v)
    k = np.searchsorted(-running, -c, side='left')         # first k with min(v[:k+1]) <= c
    hit = k < len(v)
    k = np.minimum(k, len(v) - 1)
    prev = np.maximum(k - 1, 0)
    with np.errstate(divide='ignore', invalid='ignore'):
        f = np.where(k > 0, (v[prev] - c) / (v[prev] - v[k]), 1.0)
    f = np.clip(np.nan_to_num(f, nan=1.0), 0.0, 1.0)
    states = frames[prev] + f[:, None] * (frames[k] - frames[prev])
    return hit, states


def normal_nodes(n: int = QUANTILES) -> np.ndarray:
    """n equal-probability quadrature nodes of N(0, 1) (midpoints of the quantiles)."""
    return special.ndtri((np.arange(n) + 0.5) / n)


# -- one candidate ----------------------------------------------------------------------------
class Scorer:
    """Scores candidate supervisors on a Phase II protocol (see the module doc)."""

    def __init__(self, frames, entries, standard_vf, conservative_vf, seed: int = 0,
                 quantiles: int = QUANTILES, realisations: int = REALISATIONS):
        self.frames = frames
        self.entries = list(entries)
        self.omegas = np.array([float(e.meta['omega_max']) for e in self.entries])
        self.standard_vf, self.conservative_vf = standard_vf, conservative_vf
        self.true_index = int(np.argmin(np.abs(self.omegas - 1.0)))
        self.admissible = admissible_mask(self.entries, self.entries[self.true_index])
        self.nodes = normal_nodes(quantiles)
        self.draws = np.random.default_rng(seed).standard_normal((realisations, len(frames)))
        self._pass_values = {}
        self._types = {}

    def entry(self, omega: float):
        return self.entries[int(np.argmin(np.abs(self.omegas - omega)))]

    def pass_values(self, omega: float) -> list:
        if omega not in self._pass_values:
            vf = self.entry(omega)
            self._pass_values[omega] = [vf.value(f) for f in self.frames]
        return self._pass_values[omega]

    def interventions(self, omega, mu, sigma, z):
        """Intervention states for noise draws z[(R,) per pass]: (hit (R, P), states (R, P, 3))."""
        hits, states = [], []
        for v, f, zp in zip(self.pass_values(omega), self.frames, np.asarray(z).T):
            h, s = first_passage_states(v, f, mu + sigma * zp)
            hits.append(h)
            states.append(s)
        return np.stack(hits, 1), np.stack(states, 1)

    def set_type(self, index: int, alpha: float) -> str:
        """The type of library entry ``index`` at level alpha (on ALPHA_STEP bins)."""
        key = (index, int(round(max(alpha, 0.0) / ALPHA_STEP)))
        if key not in self._types:
            self._types[key] = set_shape(self.entries[index], key[1] * ALPHA_STEP, self.standard_vf,
                                         self.conservative_vf).type
        return self._types[key]

    def learned_type(self, values) -> str:
        """The type of the paper's fit to the library's values at a subject's intervention
        states, (entries, interventions) (the Standard set with fewer than 3)."""
        if values.shape[1] < MIN_INTERVENTIONS:
            return 'standard'
        mu, _, loglik, _ = paper_estimates(values)
        best = int(np.argmax(np.where(self.admissible & np.isfinite(loglik), loglik, -np.inf)))
        return self.set_type(best, mu[best])

    def score(self, omega, mu, sigma) -> dict:
        """Expected per-subject counts (quadrature) and the learned set's type shares."""
        z = np.broadcast_to(self.nodes[:, None], (len(self.nodes), len(self.frames)))
        hit, states = self.interventions(omega, mu, sigma, z)
        s = states[hit]
        n_q = len(self.nodes)
        out = {'omega_max': omega, 'mu': mu, 'sigma': sigma,
               'interventions': hit.sum() / n_q,
               'inside_standard': np.count_nonzero(self.standard_vf.value(s) > 0) / n_q if len(s) else 0.0,
               'inside_conservative': np.count_nonzero(self.conservative_vf.value(s) > 0) / n_q if len(s) else 0.0}
        hit_r, states_r = self.interventions(omega, mu, sigma, self.draws)
        values = np.stack([e.value(states_r.reshape(-1, 3)) for e in self.entries]).reshape(
            len(self.entries), *hit_r.shape)
        types = [self.learned_type(values[:, r, hit_r[r]]) for r in range(len(self.draws))]
        out['type_share'] = {t: types.count(t) / len(types) for t in TYPES}
        return out


# -- the search --------------------------------------------------------------------------------
def loss(target: Target, counts: dict, parts, n_scenes: int) -> np.ndarray:
    """The calibration loss (module doc) for populations made of ``parts``: per type slot,
    arrays over candidates of {'interventions', 'inside_standard', 'inside_conservative',
    'sigma', 'p_<type>'}, broadcast against each other."""
    goal = target.shares()
    n = sum(counts.values())
    ints = sum(counts[t] * p['interventions'] for t, p in parts.items())
    std = sum(counts[t] * p['inside_standard'] for t, p in parts.items())
    cons = sum(counts[t] * p['inside_conservative'] for t, p in parts.items())
    with np.errstate(divide='ignore', invalid='ignore'):
        out = (((std / ints - goal['inside_standard']) / SHARE_TOL) ** 2
               + ((cons / ints - goal['inside_conservative']) / SHARE_TOL) ** 2
               + ((ints / (n * n_scenes) - goal['intervention_rate']) / RATE_TOL) ** 2)
    for k in TYPES:
        expected = sum(counts[t] * p[f'p_{k}'] for t, p in parts.items())
        out = out + (expected - target.mix.get(k, 0) * n / sum(target.mix.values())) ** 2
    for p in parts.values():
        out = out + ((p['sigma'] - SIGMA_PRIOR) / SIGMA_TOL) ** 2
    return np.where(np.isfinite(out), out, np.inf)


def search(scores: list, target: Target, n_scenes: int) -> tuple[dict, float]:
    """The best candidate per type slot (exhaustive; see ``loss``): ({type: score}, loss)."""
    counts = dict(target.mix)
    keys = ('interventions', 'inside_standard', 'inside_conservative', 'sigma') + tuple(f'p_{k}' for k in TYPES)
    table = {k: np.array([s[k] if k in s else s['type_share'][k[2:]] for s in scores], dtype=float)
             for k in keys}
    pools = {t: np.flatnonzero(table[f'p_{t}'] >= 0.5) for t in counts}
    empty = [t for t, p in pools.items() if len(p) == 0]
    if empty:
        raise ValueError(f'no candidate supervisor has a {", ".join(empty)} learned set half the time')
    a, b, c = (pools[t] for t in ('standard', 'conservative', 'gradual'))
    best, best_loss = None, np.inf
    for i in a:
        parts = {'standard': {k: table[k][i] for k in keys},
                 'conservative': {k: table[k][b][:, None] for k in keys},
                 'gradual': {k: table[k][c][None, :] for k in keys}}
        values = loss(target, counts, parts, n_scenes)
        j, k = np.unravel_index(int(np.argmin(values)), values.shape)
        if values[j, k] < best_loss:
            best_loss, best = float(values[j, k]), (int(i), int(b[j]), int(c[k]))
    return dict(zip(('standard', 'conservative', 'gradual'), (scores[i] for i in best))), best_loss


def calibrate(target: Target, offsets, step: float, seed: int = 0, grid: dict | None = None,
              progress=None) -> dict:
    """Calibrate a population to ``target`` on the Phase II of ``offsets`` at ``step``;
    returns the population file's content (without the simulated check: ``population``)."""
    from ..reach.library import load_or_build_library
    from .protocol import reference_sets
    t0 = time.monotonic()
    grid = grid or GRID
    standard_vf, conservative_vf = reference_sets()
    frames = phase2_frames(offsets, step)
    scorer = Scorer(frames, load_or_build_library().entries, standard_vf, conservative_vf, seed)
    scores = []
    for w in grid['omega_max']:
        for mu in grid['mu']:
            for sigma in grid['sigma']:
                scores.append(scorer.score(float(w), float(mu), float(sigma)))
        if progress:
            progress(f'w_S {w:g}: {len(scores)} candidates scored ({time.monotonic() - t0:.0f} s)')
    best, value = search(scores, target, len(frames))
    counts = dict(target.mix)
    n = sum(counts.values())
    ints = sum(counts[t] * best[t]['interventions'] for t in counts)
    expected = {
        'inside_standard': sum(counts[t] * best[t]['inside_standard'] for t in counts) / ints,
        'inside_conservative': sum(counts[t] * best[t]['inside_conservative'] for t in counts) / ints,
        'intervention_rate': ints / (n * len(frames)),
        'mix': {k: sum(counts[t] * best[t]['type_share'][k] for t in counts) for k in TYPES},
    }
    members = [{'name': f'{t}-like' if t != 'gradual' else 'gradual', 'type': t, 'weight': counts[t],
                'omega_max': best[t]['omega_max'], 'mu': best[t]['mu'], 'sigma': best[t]['sigma'],
                'expected': {k: best[t][k] for k in ('interventions', 'inside_standard', 'inside_conservative')},
                'learned_type_share': best[t]['type_share'],
                # the supervisor's own set {V_S <= mu}; the type above is its learned set's
                'own_set': set_shape(scorer.entry(best[t]['omega_max']), best[t]['mu'], standard_vf,
                                     conservative_vf).to_dict()}
               for t in ('standard', 'conservative', 'gradual')]
    return {'format': 'supersafe-population/1', 'name': target.name, 'source': f'calibrated to {target.name}',
            'members': members, 'target': target.to_dict(),
            'achieved': {'expected': expected, 'loss': value},
            'calibration': {'seed': int(seed), 'offsets': [float(v) for v in offsets], 'step': float(step),
                            'grid': {k: list(v) for k, v in grid.items()}, 'quantiles': QUANTILES,
                            'realisations': REALISATIONS, 'candidates': len(scores),
                            'wall_s': round(time.monotonic() - t0, 1),
                            'method': 'supersafe_ros.study.calibrate (docs/study.md, "The paper-like population")'}}


def model_agreement(population, subjects: int, seed: int, offsets, step: float) -> dict:
    """Phase II of ``subjects`` subjects (``engine.CoreStudy.phase2``) under every supervisor
    model: whether each model's scenes, interventions and intervention states are the
    memoryless model's, and the largest state difference [m or rad]."""
    from ..sim.supervisor_models import MODELS
    from .engine import CoreStudy
    from .protocol import StudyOptions
    core = CoreStudy()
    runs = {}
    for model in MODELS:
        opts = StudyOptions(phase2_offsets=tuple(float(v) for v in offsets), step=float(step), supervisor=model)
        runs[model] = [core.phase2(subject, opts, with_fp=False) for subject in population.draw(subjects, int(seed))]
    out = {'subjects': subjects, 'seed': int(seed), 'models': {}}
    for model, res in runs.items():
        same = all([s['intervened'] for s in a.scenes] == [s['intervened'] for s in b.scenes]
                   and a.states.shape == b.states.shape for a, b in zip(res, runs['memoryless']))
        diff = max((float(np.max(np.abs(a.states - b.states))) for a, b in zip(res, runs['memoryless'])
                    if same and len(a.states)), default=0.0)
        out['models'][model] = {'interventions': int(sum(len(r.states) for r in res)),
                                'same_as_memoryless': bool(same and diff == 0.0), 'max_state_difference': diff}
    return out


def simulated_check(population, subjects: int, seeds, offsets, step: float) -> dict:
    """A population's Phase II as the study runs it (``engine.CoreStudy.phase2``: the
    supervisor node's rule, the learner's paper fit), for ``subjects`` subjects and each
    seed: pooled shares inside Standard and Conservative, interventions per scene, and the
    learned sets' types (``set_types``); per seed and pooled over the seeds."""
    from .engine import CoreStudy
    from .protocol import StudyOptions, reference_sets
    standard_vf, conservative_vf = reference_sets()
    core = CoreStudy()
    opts = StudyOptions(phase2_offsets=tuple(float(v) for v in offsets), step=float(step))
    runs = []
    for seed in seeds:
        n = std = cons = scenes = 0
        types = []
        for subject in population.draw(subjects, int(seed)):
            p2 = core.phase2(subject, opts, with_fp=False)
            s = p2.states
            n += len(s)
            scenes += len(p2.scenes)
            if len(s):
                std += int(np.count_nonzero(standard_vf.value(s) > 0))
                cons += int(np.count_nonzero(conservative_vf.value(s) > 0))
            types.append(set_shape(p2.vf, p2.fit['alpha'], standard_vf, conservative_vf).type
                         if p2.vf is not None else 'standard')
        runs.append({'seed': int(seed), 'subjects': subjects, 'interventions': n, 'scenes': scenes,
                     'inside_standard': std, 'inside_conservative': cons,
                     'mix': {t: types.count(t) for t in TYPES}})
    total = {k: sum(r[k] for r in runs) for k in ('interventions', 'scenes', 'inside_standard',
                                                  'inside_conservative')}
    return {'runs': runs, 'seeds': [int(s) for s in seeds], 'subjects': subjects,
            'inside_standard': total['inside_standard'] / max(total['interventions'], 1),
            'inside_conservative': total['inside_conservative'] / max(total['interventions'], 1),
            'intervention_rate': total['interventions'] / max(total['scenes'], 1),
            'mix_per_study': {t: float(np.mean([r['mix'][t] for r in runs])) for t in TYPES}}
