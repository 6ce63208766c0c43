r"""Estimators of a supervisor's safe set from interventions, over a value-function library.

Model (``supervisor.py``): the supervisor judges each encounter once, drawing
w ~ N(0, sigma^2), and intervenes at the first frame x_k with V_S(x_k) <= mu + w.
The library is a list of candidate value functions V_i (one per turn-rate bound
omega_max); each estimator scores every entry, maximising over (mu, sigma), and the
best admissible entry wins.

Paper's estimator (``fit_paper``; paper eqs. 3-4 and the MAP prior mu >= 0)
------------------------------------------------------------------------------
Treats the values at the p intervention states as i.i.d. samples of N(mu, sigma^2):

    mu_i      = max( (1/p) sum_j V_i(x_j), 0 )
    sigma_i^2 = (1/p) sum_j (V_i(x_j) - mu_i)^2          (about mu_i after the clamp)
    log L_i   = -p/2 log(2 pi sigma_i^2) - sum_j (V_i(x_j) - mu_i)^2 / (2 sigma_i^2)

(= -p/2 (log(2 pi sigma_i^2) + 1) when sigma_i is not floored). If all values are equal
sigma_i would be 0 and log L_i infinite; sigma_i is floored at ``SIGMA_FLOOR`` and the
candidate is flagged ``sigma_floored``.

This is a density in *value* space. Entries whose values are flat near the
interventions squeeze the sample into a narrow Gaussian and score high, although the
data (where along the approach the supervisor intervened) are no more likely under
them; it also ignores that the intervention is the *first* crossing and that some
encounters end without one.

First-passage estimator (``fit_first_passage``)
-----------------------------------------------
Uses whole encounters. With v_j = V_i(x_j) along an encounter and the running minimum
m_{<k} = min_{j<k} v_j (m_{<0} = +inf), the threshold mu + w of that judgement must lie in

    intervention at frame k:   v_k <= mu + w < m_{<k}
    no intervention:           mu + w < min_j v_j

so each encounter is an interval [lo, hi) for mu + w, and

    log L_i(mu, sigma) = sum_e log( Phi((hi_e - mu)/sigma) - Phi((lo_e - mu)/sigma) ),

an interval-censored Gaussian likelihood in the frames' own terms (it carries the
drop of V_i between frames, the Jacobian the paper's estimator leaves out). In the
natural parameters eta = mu/sigma, tau = 1/sigma each term is
log P(lo tau - eta <= Z < hi tau - eta) with Z ~ N(0, 1), log-concave in (eta, tau)
(Prekopa), so the maximum over mu >= 0, sigma > 0 is unique; all entries are fitted
at once by a vectorised projected Newton method (``newton``: analytic gradient,
finite-difference Hessian, Armijo line search), started from the paper-style
estimate; scipy's L-BFGS-B entry by entry is kept as a cross-check (``method='lbfgsb'``).
An entry under which some recorded intervention is impossible (v_k >= m_{<k}: a
frame earlier in the same encounter was already at or below the intervention's
value) has log L_i = -inf, unless ``lapse`` > 0.

Options:

* ``conditional=True``: for data that record only the encounters that ended in an
  intervention (the pilot files), each term is divided by the probability that the
  encounter had an intervention at all, P(mu + w >= min V_i over the encounter's
  ``full_pass``) = Phi((mu - m_full)/sigma).
* ``lapse`` = lambda in [0, 1): each judgement is, with probability lambda, a lapse
  that picks uniformly among the M + 1 outcomes of the pass (intervene at one of its
  M frames, or never): L_e = (1 - lambda) P_e + lambda / (M + 1). Keeps a single
  inconsistent intervention from ruling out an entry.

alpha (where the robots' filter acts): alpha = mu + k sigma (k = 0 as in the paper's
experiment), or ``alpha_for_fp_rate``: under the model the values at intervention
states are N(mu, sigma^2), so the share of intervention states inside the filter's
safe set {V > alpha} (the predicted false-positive fraction, paper Table 1) is
1 - Phi((alpha - mu)/sigma); alpha = mu + sigma Phi^{-1}(1 - rate) gives ``rate``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np
from scipy import optimize, special

from ..reach.containment import contains
from ..reach.value_function import ValueFunction
from .newton import newton_maximise

SIGMA_FLOOR = 1e-3      # value units (metres of clearance): below this a fit is degenerate
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)


# -- results ---------------------------------------------------------------------------
@dataclass
class FitResult:
    """The chosen library entry and its parameters, plus every entry's scores."""

    omega_max: float
    mu: float
    sigma: float
    alpha: float
    log_likelihood: float
    estimator: str
    interventions: int
    index: int
    candidates: list = field(default_factory=list)
    value_function: ValueFunction | None = field(default=None, repr=False)
    encounters: int | None = None
    notes: list = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-able summary (no arrays; non-finite numbers become None)."""
        d = {
            'omega_max': _num(self.omega_max), 'mu': _num(self.mu), 'sigma': _num(self.sigma),
            'alpha': _num(self.alpha), 'log_likelihood': _num(self.log_likelihood),
            'estimator': self.estimator, 'interventions': int(self.interventions),
            'index': int(self.index),
            'candidates': [{k: (_num(v) if isinstance(v, (float, np.floating)) else
                                bool(v) if isinstance(v, (bool, np.bool_)) else v)
                            for k, v in c.items()} for c in self.candidates],
        }
        if self.encounters is not None:
            d['encounters'] = int(self.encounters)
        if self.notes:
            d['notes'] = list(self.notes)
        return d


def _num(v):
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


# -- helpers shared by both estimators ------------------------------------------------------
def _check_entries(entries):
    entries = list(entries)
    if not entries:
        raise ValueError('the library is empty')
    for i, e in enumerate(entries):
        if not isinstance(e, ValueFunction):
            raise TypeError(f'library entry {i} is a {type(e).__name__}, not a ValueFunction')
    return entries


def _entry_omega(entry):
    w = entry.meta.get('omega_max')
    return float(w) if w is not None else float('nan')


def _check_states(states, what='states'):
    s = np.asarray(states, dtype=float)
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f'{what} must be an (N, 3) array of (x, y, theta), got shape {s.shape}')
    if not np.all(np.isfinite(s)):
        bad = np.flatnonzero(~np.all(np.isfinite(s), axis=1))
        raise ValueError(f'{what} contain NaN or infinite values (rows {bad[:10].tolist()})')
    return s


def admissible_mask(library_entries, true_vf: ValueFunction, tol: float | None = None) -> np.ndarray:
    """bool[n]: entry i is admissible iff its unsafe set contains the true one,
    {V_i <= 0} ⊇ {V_true <= 0}, checked at every node of the true grid with
    V_true <= 0 (V_i <= tol there). V_i is interpolated when the grids differ; a
    true unsafe node outside entry i's rectangle makes it inadmissible (unverifiable).

    tol (value units) absorbs discretisation error between separately solved entries;
    default half the smallest (x, y) spacing of the true grid (0.125 on the paper's
    65 x 65 x 42 grid). There the entries with omega_max <= 1 stay <= 0 on all 9,688
    true-unsafe nodes, while omega_max = 1.5 reaches 0.40 on 792 of them (an earlier
    solver version overshot by up to 0.044 below omega_max 1: hence a tolerance).
    """
    entries = _check_entries(library_entries)
    cache = {}   # the true unsafe nodes, built once for every entry on another grid
    return np.array([contains(e, 0.0, true_vf, 0.0, tol=tol, _nodes_cache=cache).ok for e in entries],
                    dtype=bool)


def _choose(entries, loglik, true_vf, admissible_tol, admissible=None):
    """Index of the best entry (highest log-likelihood among the admissible ones).

    ``admissible``: a precomputed ``admissible_mask`` (an online learner computes it once)."""
    if admissible is not None:
        admissible = np.asarray(admissible, dtype=bool)
        if not admissible.any():
            raise ValueError('no library entry is admissible')
    elif true_vf is None:
        admissible = np.ones(len(entries), dtype=bool)
    else:
        admissible = admissible_mask(entries, true_vf, tol=admissible_tol)
        if not admissible.any():
            raise ValueError('no library entry is admissible: none has an unsafe set containing the '
                             'true unsafe set (check --true-omega-max, or use --no-prior)')
    score = np.where(admissible & np.isfinite(loglik), loglik, -np.inf)
    if not np.isfinite(score).any():
        raise ValueError('no admissible library entry can explain the data (all log-likelihoods are -inf)')
    return int(np.argmax(score)), admissible


def _result(entries, estimator, mu, sigma, loglik, admissible, best, alpha_k, n_interventions,
            extra_cols=None, encounters=None, notes=()):
    candidates = []
    for i, e in enumerate(entries):
        c = {'omega_max': _entry_omega(e), 'mu': float(mu[i]), 'sigma': float(sigma[i]),
             'log_likelihood': float(loglik[i]), 'admissible': bool(admissible[i])}
        for k, col in (extra_cols or {}).items():
            c[k] = col[i]
        candidates.append(c)
    return FitResult(omega_max=_entry_omega(entries[best]), mu=float(mu[best]),
                     sigma=float(sigma[best]), alpha=float(mu[best] + alpha_k * sigma[best]),
                     log_likelihood=float(loglik[best]), estimator=estimator,
                     interventions=int(n_interventions), index=best, candidates=candidates,
                     value_function=entries[best], encounters=encounters, notes=list(notes))


# -- the paper's estimator -----------------------------------------------------------------
def paper_estimates(values) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Paper's MAP estimates for each row of ``values`` (n_entries, p): values of each
    entry at the p intervention states. Returns mu, sigma, log_likelihood, floored."""
    v = np.asarray(values, dtype=float)
    if v.ndim != 2 or v.shape[1] == 0:
        raise ValueError(f'need values of shape (n_entries, p >= 1), got {v.shape}')
    p = v.shape[1]
    mu = np.maximum(v.mean(axis=1), 0.0)
    sq = np.sum((v - mu[:, None]) ** 2, axis=1)
    var = sq / p
    floored = var < SIGMA_FLOOR ** 2
    var = np.maximum(var, SIGMA_FLOOR ** 2)
    loglik = -0.5 * p * np.log(2.0 * np.pi * var) - sq / (2.0 * var)
    return mu, np.sqrt(var), loglik, floored


def fit_paper(entries, states, *, true_vf=None, alpha_k=0.0, admissible_tol=None) -> FitResult:
    """The paper's estimator over the library ``entries`` from intervention ``states`` (N, 3).

    true_vf: value function of the true dynamics for the conservative prior (None = no prior).
    alpha_k: alpha = mu + alpha_k * sigma.
    """
    entries = _check_entries(entries)
    s = _check_states(states, 'intervention states')
    if len(s) == 0:
        raise ValueError('no intervention states to fit')
    return fit_paper_values(entries, np.stack([e.value(s) for e in entries]), true_vf=true_vf,
                            alpha_k=alpha_k, admissible_tol=admissible_tol)


def fit_paper_values(entries, values, *, true_vf=None, alpha_k=0.0, admissible_tol=None,
                     admissible=None) -> FitResult:
    """``fit_paper`` from the entries' values at the intervention states, (n_entries, p):
    an online learner evaluates each new intervention once and keeps the columns."""
    entries = _check_entries(entries)
    values = np.asarray(values, dtype=float)
    mu, sigma, loglik, floored = paper_estimates(values)
    best, admissible = _choose(entries, loglik, true_vf, admissible_tol, admissible)
    notes = []
    if floored.any():
        notes.append(f'sigma floored at {SIGMA_FLOOR:g} for {int(floored.sum())} entries '
                     '(all intervention values equal: degenerate data)')
    return _result(entries, 'paper', mu, sigma, loglik, admissible, best, alpha_k, values.shape[1],
                   extra_cols={'sigma_floored': [bool(f) for f in floored]}, notes=notes)


# -- the first-passage estimator -----------------------------------------------------------
def log_ndtr_diff(a, b):
    """log(Phi(b) - Phi(a)) for a <= b elementwise (a may be -inf, b may be +inf),
    computed in the tail where it does not cancel: for a > 0 use Phi(-a) - Phi(-b)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    flip = a > 0.0
    lo = np.where(flip, -b, a)
    hi = np.where(flip, -a, b)
    lhi = special.log_ndtr(hi)
    with np.errstate(invalid='ignore'):
        d = special.log_ndtr(lo) - lhi          # <= 0; -inf when lo = -inf
    return lhi + _log1mexp(d)


def _log1mexp(d):
    """log(1 - exp(d)) for d <= 0, accurate near 0 and for very negative d."""
    d = np.minimum(d, 0.0)
    with np.errstate(divide='ignore'):
        return np.where(d > -math.log(2.0), np.log(-np.expm1(d)), np.log1p(-np.exp(d)))


def _log_phi(z):
    return -0.5 * np.square(z) - _LOG_SQRT_2PI


@dataclass
class EncounterIntervals:
    """Per entry and encounter, the interval [lo, hi) that mu + w must lie in.

    lo, hi: (n_entries, n_encounters); m_full: (n_entries, n_encounters) minimum of V
    over each encounter's full pass (for the conditional likelihood) or None;
    outcomes: (n_encounters,) number of possible outcomes M + 1 of each pass (lapse model).
    """

    lo: np.ndarray
    hi: np.ndarray
    m_full: np.ndarray | None
    outcomes: np.ndarray
    intervened: np.ndarray

    @property
    def feasible(self) -> np.ndarray:
        """bool[n_entries]: every encounter's interval is non-empty."""
        return np.all(self.lo < self.hi, axis=1)


def encounter_intervals(entries, encounters, conditional=False) -> EncounterIntervals:
    """Evaluate every entry along every encounter once and reduce to intervals."""
    entries = _check_entries(entries)
    encounters = list(encounters)
    if not encounters:
        raise ValueError('no encounters to fit')
    lengths = np.array([len(e.states) for e in encounters])
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    last = starts + lengths - 1
    intervened = np.array([e.intervened for e in encounters])
    frames = np.concatenate([e.states for e in encounters])
    if conditional:
        if not intervened.all():
            raise ValueError('the conditional likelihood is for data with interventions only; '
                             f'{int((~intervened).sum())} encounters have none')
        missing = [e.scene for e in encounters if e.full_pass is None]
        if missing:
            raise ValueError(f'the conditional likelihood needs each encounter\'s full_pass; '
                             f'missing for scenes {missing[:5]}')
        full_lengths = np.array([len(e.full_pass) for e in encounters])
        full_starts = np.concatenate([[0], np.cumsum(full_lengths)[:-1]])
        full_frames = np.concatenate([e.full_pass for e in encounters])
    n_outcomes = np.array([len(e.full_pass) if e.full_pass is not None else len(e.states)
                           for e in encounters], dtype=float) + 1.0
    lo = np.empty((len(entries), len(encounters)))
    hi = np.empty_like(lo)
    m_full = np.empty_like(lo) if conditional else None
    for i, entry in enumerate(entries):
        v = entry.value(frames)
        lo[i] = np.where(intervened, v[last], -np.inf)
        # the intervention frame itself does not bound mu + w from above
        before = v.copy()
        before[last[intervened]] = np.inf
        hi[i] = np.minimum.reduceat(before, starts)
        if conditional:
            m_full[i] = np.minimum.reduceat(entry.value(full_frames), full_starts)
    return EncounterIntervals(lo, hi, m_full, n_outcomes, intervened)


def first_passage_loglik(eta, tau, iv: EncounterIntervals, lapse=0.0, grad=False):
    """Log-likelihood per entry (and its gradient wrt eta = mu/sigma, tau = 1/sigma).

    eta, tau: (n_entries,) natural parameters; returns ll (n,) [, d_eta (n,), d_tau (n,)].
    """
    eta = np.asarray(eta, dtype=float)[:, None]
    tau = np.asarray(tau, dtype=float)[:, None]
    with np.errstate(invalid='ignore'):
        a = np.where(np.isneginf(iv.lo), -np.inf, iv.lo * tau - eta)
        b = np.where(np.isposinf(iv.hi), np.inf, iv.hi * tau - eta)
    log_p = log_ndtr_diff(a, b)
    if lapse > 0.0:
        log_q = -np.log(iv.outcomes)[None, :]
        log_l = np.logaddexp(math.log1p(-lapse) + log_p, math.log(lapse) + log_q)
        weight = np.exp(math.log1p(-lapse) + log_p - log_l)     # d log L / d log P
    else:
        log_l, weight = log_p, 1.0
    ll = log_l.sum(axis=1)
    if iv.m_full is not None:
        c = eta - iv.m_full * tau
        log_c = special.log_ndtr(c)
        if lapse > 0.0:
            log_q_any = np.log1p(-1.0 / iv.outcomes)[None, :]     # a lapse intervenes w.p. M/(M+1)
            log_lc = np.logaddexp(math.log1p(-lapse) + log_c, math.log(lapse) + log_q_any)
            weight_c = np.exp(math.log1p(-lapse) + log_c - log_lc)
        else:
            log_lc, weight_c = log_c, 1.0
        ll = ll - log_lc.sum(axis=1)
    if not grad:
        return ll
    with np.errstate(invalid='ignore', over='ignore'):
        ra = np.where(np.isfinite(a), np.exp(_log_phi(a) - log_p), 0.0)   # phi(a) / P
        rb = np.where(np.isfinite(b), np.exp(_log_phi(b) - log_p), 0.0)   # phi(b) / P
        lo_ra = np.where(np.isfinite(a), iv.lo * ra, 0.0)
        hi_rb = np.where(np.isfinite(b), iv.hi * rb, 0.0)
    live = np.isfinite(log_p)                  # impossible encounters (lapse > 0) add no slope
    with np.errstate(invalid='ignore'):
        d_eta = np.sum(np.where(live, weight * (ra - rb), 0.0), axis=1)
        d_tau = np.sum(np.where(live, weight * (hi_rb - lo_ra), 0.0), axis=1)
    if iv.m_full is not None:
        rc = np.exp(_log_phi(c) - log_c)          # phi(c) / Phi(c)
        d_eta = d_eta - np.sum(weight_c * rc, axis=1)
        d_tau = d_tau + np.sum(weight_c * iv.m_full * rc, axis=1)
    return ll, d_eta, d_tau


def _start(iv: EncounterIntervals):
    """Paper-style start: mean and spread of the intervention values, or of the
    smallest value seen when nobody intervened."""
    point = np.where(iv.intervened[None, :], iv.lo, iv.hi)
    point = np.where(np.isfinite(point), point, 0.0)
    mu0 = np.maximum(point.mean(axis=1), 0.0)
    sd0 = np.maximum(np.sqrt(np.mean((point - mu0[:, None]) ** 2, axis=1)), 0.05)
    return mu0, sd0


def _subset(iv: EncounterIntervals, rows) -> EncounterIntervals:
    return EncounterIntervals(iv.lo[rows], iv.hi[rows], None if iv.m_full is None else iv.m_full[rows],
                              iv.outcomes, iv.intervened)


_TAU_MIN = 1e-6                    # sigma <= 1e6: no bound in practice
_TAU_MAX = 1.0 / SIGMA_FLOOR


def maximise_first_passage(iv: EncounterIntervals, lapse=0.0, rows=None, method='newton', start=None):
    """Maximise the first-passage log-likelihood over mu >= 0, sigma >= SIGMA_FLOOR for the
    entries ``rows`` (default: every entry that can explain the data), in the natural
    parameters eta = mu/sigma, tau = 1/sigma with analytic gradients.

    method 'newton': all entries at once (``newton.newton_maximise``, vectorised); 'lbfgsb': scipy's
    L-BFGS-B entry by entry (slower; kept as a cross-check).
    start: (mu, sigma) arrays (n_entries,) to start from instead of the paper-style
    estimate, e.g. the previous fit of an online learner (non-finite values fall back).
    Returns mu, sigma, loglik (n_entries,): nan, nan, -inf for entries not fitted."""
    n = iv.lo.shape[0]
    if rows is None:
        rows = np.flatnonzero(iv.feasible) if lapse == 0.0 else np.arange(n)
    rows = np.asarray(rows, dtype=int)
    mu = np.full(n, np.nan)
    sigma = np.full(n, np.nan)
    loglik = np.full(n, -np.inf)
    if rows.size == 0:
        return mu, sigma, loglik
    sub = _subset(iv, rows)
    mu0, sd0 = _start(sub)
    if start is not None:
        smu, ssd = (np.asarray(a, dtype=float)[rows] for a in start)
        ok = np.isfinite(smu) & np.isfinite(ssd) & (ssd > 0)
        mu0, sd0 = np.where(ok, np.maximum(smu, 0.0), mu0), np.where(ok, ssd, sd0)
    x0 = np.stack([mu0 / sd0, 1.0 / sd0], axis=1)
    x0[:, 1] = np.clip(x0[:, 1], _TAU_MIN, _TAU_MAX)
    if method == 'newton':
        def fun(x, which=None):
            part = sub if which is None else _subset(sub, which)
            with np.errstate(over='ignore', invalid='ignore'):
                ll, de, dt = first_passage_loglik(x[:, 0], x[:, 1], part, lapse, grad=True)
            bad = ~np.isfinite(ll)
            ll = np.where(bad, -np.inf, ll)
            return ll, np.where(bad[:, None], 0.0, np.stack([de, dt], axis=1))

        x, ll = newton_maximise(fun, x0.copy(),
                                lower=np.array([0.0, _TAU_MIN]), upper=np.array([np.inf, _TAU_MAX]))
    elif method == 'lbfgsb':
        x = np.empty_like(x0)
        scale = float(iv.lo.shape[1])          # keep the objective O(1) for the tolerances
        for k in range(rows.size):
            one = _subset(sub, [k])

            def objective(z):
                l1, de, dt = first_passage_loglik(z[:1], z[1:], one, lapse, grad=True)
                if not np.isfinite(l1[0]):
                    return 1e300, np.zeros(2)
                return -l1[0] / scale, -np.array([de[0], dt[0]]) / scale

            res = optimize.minimize(objective, x0[k], jac=True, method='L-BFGS-B',
                                    bounds=[(0.0, None), (_TAU_MIN, _TAU_MAX)],
                                    options={'maxiter': 500, 'ftol': 1e-14, 'gtol': 1e-10})
            x[k] = res.x
        ll = first_passage_loglik(x[:, 0], x[:, 1], sub, lapse)
    else:
        raise ValueError(f"method must be 'newton' or 'lbfgsb', got {method!r}")
    mu[rows] = x[:, 0] / x[:, 1]
    sigma[rows] = 1.0 / x[:, 1]
    loglik[rows] = ll
    return mu, sigma, loglik


def fit_first_passage(entries, encounters, *, true_vf=None, alpha_k=0.0, conditional=False,
                      lapse=0.0, admissible_tol=None) -> FitResult:
    """The first-passage estimator over the library ``entries`` from whole ``encounters``
    (list of data.Encounter). See the module docstring for the likelihood.

    conditional: the data hold only encounters with an intervention (use each
        encounter's full_pass to condition on that).
    lapse: probability of a lapse judgement (0 = the pure model).
    """
    entries = _check_entries(entries)
    iv = encounter_intervals(entries, encounters, conditional=conditional)
    return fit_first_passage_intervals(entries, iv, true_vf=true_vf, alpha_k=alpha_k, lapse=lapse,
                                       admissible_tol=admissible_tol)


def concat_intervals(parts) -> EncounterIntervals:
    """One EncounterIntervals from several (same entries; encounters side by side): an
    online learner computes each encounter's intervals once and joins them per refit."""
    parts = list(parts)
    if not parts:
        raise ValueError('no encounters to fit')
    m_full = None if any(p.m_full is None for p in parts) else np.concatenate([p.m_full for p in parts], 1)
    return EncounterIntervals(np.concatenate([p.lo for p in parts], axis=1),
                              np.concatenate([p.hi for p in parts], axis=1), m_full,
                              np.concatenate([p.outcomes for p in parts]),
                              np.concatenate([p.intervened for p in parts]))


def unexplained_encounters(iv: EncounterIntervals, admissible=None) -> np.ndarray:
    """bool[n_encounters]: encounters that no (admissible) entry can explain, each on its own.

    An encounter's interval [lo, hi) is empty under entry i when its intervention frame is
    no lower in value than an earlier frame of the same approach (v_k >= m_{<k}): the
    supervisor's threshold would have been crossed before. Under every entry that happens
    to an intervention made after the robot's closest approach (the distance growing: a
    hasty click on an obstacle the robot has just passed), and under omega_max = 0 to one
    made where V is flat (a straight line that misses the disc). One such encounter makes
    every log-likelihood -inf (``_choose`` then finds nothing): an online learner sets it
    aside instead (``admissible``: the entries it chooses among; None = all)."""
    empty = iv.lo >= iv.hi
    if admissible is not None:
        empty = empty[np.asarray(admissible, dtype=bool)]
    return empty.all(axis=0)


def conflicting_encounters(iv: EncounterIntervals, admissible=None) -> np.ndarray:
    """bool[n_encounters]: the fewest encounters to set aside so that some (admissible) entry
    explains all the others; none if one already does.

    Each encounter may be explained by some entry and yet no entry explain them all
    (encounter a impossible under entries 1-2, b under 3-13). The entry with the fewest
    impossible encounters (the lowest omega_max on a tie) is the one that the rest of the
    data can be fitted with after its impossible encounters are set aside."""
    empty = iv.lo >= iv.hi
    rows = np.arange(empty.shape[0]) if admissible is None else np.flatnonzero(np.asarray(admissible, bool))
    if rows.size == 0:
        return np.zeros(empty.shape[1], dtype=bool)
    counts = empty[rows].sum(axis=1)
    if counts.min() == 0:
        return np.zeros(empty.shape[1], dtype=bool)
    return empty[rows[int(np.argmin(counts))]].copy()


def explainable_encounters(iv: EncounterIntervals, admissible=None) -> np.ndarray:
    """bool[n_encounters]: the encounters a fit can use, all at once (an offline fit): those
    ``unexplained_encounters`` set aside, then the fewest ``conflicting_encounters`` among the
    rest (the online learner's rule, ``encounter_window``). All False if none is left."""
    keep = ~unexplained_encounters(iv, admissible)
    if keep.any():
        rows = np.flatnonzero(keep)
        keep[rows[conflicting_encounters(select_encounters(iv, keep), admissible)]] = False
    return keep


def select_encounters(iv: EncounterIntervals, keep) -> EncounterIntervals:
    """The encounters ``keep`` (bool or index array over encounters) of ``iv``."""
    keep = np.asarray(keep)
    return EncounterIntervals(iv.lo[:, keep], iv.hi[:, keep], None if iv.m_full is None else iv.m_full[:, keep],
                              iv.outcomes[keep], iv.intervened[keep])


def fit_first_passage_intervals(entries, iv: EncounterIntervals, *, true_vf=None, alpha_k=0.0,
                                lapse=0.0, admissible_tol=None, admissible=None, start=None) -> FitResult:
    """``fit_first_passage`` from precomputed intervals (``encounter_intervals``);
    ``start``: (mu, sigma) per entry to start the maximisation from (a previous fit)."""
    entries = _check_entries(entries)
    if not (0.0 <= lapse < 1.0):
        raise ValueError(f'lapse must be in [0, 1), got {lapse}')
    conditional = iv.m_full is not None
    mu, sigma, loglik = maximise_first_passage(iv, lapse, start=start)
    best, admissible = _choose(entries, loglik, true_vf, admissible_tol, admissible)
    n_int = int(iv.intervened.sum())
    impossible = (iv.lo >= iv.hi).sum(axis=1)
    notes = []
    if lapse == 0.0 and impossible.any():
        notes.append(f'{int((impossible > 0).sum())} entries cannot explain some intervention '
                     '(a value at or below it earlier in the same encounter): log-likelihood -inf')
    at_floor = np.isfinite(sigma) & (sigma <= SIGMA_FLOOR * (1 + 1e-6))
    if at_floor.any():
        notes.append(f'sigma at the floor {SIGMA_FLOOR:g} for {int(at_floor.sum())} entries (degenerate data)')
    unbounded = np.isfinite(sigma) & (sigma >= 0.5 / _TAU_MIN)
    if unbounded.any():
        notes.append(f'sigma unbounded (> {0.5 / _TAU_MIN:g}) for {int(unbounded.sum())} entries: '
                     'the data do not pin the noise down')
    if n_int == 0:
        notes.append('no encounter ended in an intervention: mu and sigma are not identified')
    if conditional:
        notes.append('conditional likelihood: encounters without intervention were not recorded')
    return _result(entries, 'first-passage', mu, sigma, loglik, admissible, best, alpha_k, n_int,
                   extra_cols={'impossible_interventions': [int(k) for k in impossible]},
                   encounters=len(iv.intervened), notes=notes)


# -- alpha and false positives ------------------------------------------------------------
def alpha_for_fp_rate(mu, sigma, rate) -> float:
    """alpha with P(V > alpha) = rate for intervention values V ~ N(mu, sigma^2):
    alpha = mu + sigma Phi^{-1}(1 - rate). rate 0.5 gives mu; rate 0.0228 gives mu + 2 sigma."""
    mu, sigma, rate = float(mu), float(sigma), float(rate)
    if not (0.0 < rate < 1.0):
        raise ValueError(f'rate must be in (0, 1), got {rate}')
    if not (np.isfinite(mu) and np.isfinite(sigma) and sigma >= 0.0):
        raise ValueError(f'need finite mu and sigma >= 0, got mu={mu}, sigma={sigma}')
    return mu - sigma * float(special.ndtri(rate))


def predicted_false_positive_fraction(vf: ValueFunction, alpha, states) -> float:
    """Share of intervention states inside the filter's safe set {V > alpha}: those
    interventions would be false positives with a filter acting at alpha (paper Table 1)."""
    s = _check_states(states, 'intervention states')
    if len(s) == 0:
        raise ValueError('no intervention states')
    return float(np.mean(vf.value(s) > float(alpha)))
