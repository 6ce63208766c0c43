"""``learned_online``: the Learned game's learner keeps learning from the team's own games.

Beyond the paper. Phase II shows the supervisor head-on approaches only; in the team task
the robots meet obstacles at every bearing, turn away at their level and skirt them. The
``learned_online`` game starts from the subject's first-passage Phase II fit (the
``learned_fp`` set) and an ``OnlineLearner`` in the core engine's loop
(``sim.team_loop.TeamLoop``'s ``learner``) does what ``learner_node`` does on the team's
topics:

* an ``EncounterBuilder`` (the node's parameters, learner.yaml; no reorder window: the
  loop delivers every event in order) is fed every robot pose, the supervisor's
  interventions and the world's obstacle set as it changes (stamped with the step);
* every encounter that becomes final is evaluated once (``encounter_intervals``) and
  joined to the Phase II encounters;
* at most every ``refit_period`` sim seconds, when an encounter with an intervention has
  become final since the last refit, the first-passage estimator refits on all of them
  (conservative prior, alpha = mu, warm-started from the last fit) and the set goes into
  force in both robots' filters from the next step if it passes the admissibility check
  and its entry or level changed (as the node republishes).

``history`` lists every refit (time, entry, mu, sigma, counts, whether it went into force),
kept in the game's record (``online``).
"""
from __future__ import annotations

import numpy as np

from ..filter import SafeSet
from ..learning.encounters import EncounterBuilder
from ..learning.estimators import concat_intervals, encounter_intervals, fit_first_passage_intervals

REFIT_PERIOD = 5.0        # sim seconds between refits at most


class OnlineLearner:
    """The first-passage learner of a ``learned_online`` game (see the module doc).

    ``learners``: ``engine.Learners`` (library, prior, builder parameters, publication
    rule); ``phase2_records``: the subject's Phase II encounters (``EncounterRecord``);
    ``start``: the SafeSet in force at the start (the Phase II fit's)."""

    def __init__(self, learners, phase2_records, start: SafeSet, refit_period: float = REFIT_PERIOD):
        self.lr = learners
        self.builder = EncounterBuilder(learners.lo, learners.hi, **{**learners.builder_args, 'reorder': 0.0})
        encounters = [r.to_encounter() for r in phase2_records]
        self.intervals = encounter_intervals(learners.entries, encounters) if encounters else None
        self.phase2 = len(encounters)
        self.refit_period = float(refit_period)
        self.published = (start.vf.meta.get('index'), float(start.alpha))
        self.fit = None
        self.game_encounters = self.game_interventions = 0
        self.game_records = []           # the game's encounters (EncounterRecord), as they became final
        self._fresh = 0                  # encounters with an intervention since the last refit
        self._next_refit = 0.0
        self._seen = 0                   # loop.interventions fed so far
        self._set = None                 # the obstacle set last fed (ids, xy)
        self.history = []

    def step(self, loop, t: float, states: dict):
        """Feed one step of ``loop`` (poses at ``t``, new interventions, the obstacle set);
        returns the new SafeSet when a refit goes into force, else None."""
        b = self.builder
        if self._set is None:
            self._feed_set(loop, t)
        for name, state in states.items():
            b.pose(name, t, state)
        for d, _ in loop.interventions[self._seen:]:
            b.intervention(d.obstacle_id, d.time, d.rel_state)
        self._seen = len(loop.interventions)
        self._feed_set(loop, t)
        finished = b.pop_finished()
        if finished:
            iv = encounter_intervals(self.lr.entries, [r.to_encounter() for r in finished])
            self.intervals = iv if self.intervals is None else concat_intervals([self.intervals, iv])
            self.game_encounters += len(finished)
            self.game_records.extend(finished)
            n = sum(r.intervened for r in finished)
            self.game_interventions += n
            self._fresh += n
        if self._fresh and t >= self._next_refit:
            return self._refit(t)
        return None

    def _feed_set(self, loop, t):
        ids, xy = loop.world.obstacle_arrays()
        if self._set is None or not (np.array_equal(ids, self._set[0]) and np.array_equal(xy, self._set[1])):
            self.builder.set_obstacles(ids, xy, t)
            self._set = (np.array(ids), np.array(xy))

    def _refit(self, t):
        self._fresh = 0
        self._next_refit = t + self.refit_period
        start = None
        if self.fit is not None and self.fit.candidates:
            start = (np.array([c['mu'] for c in self.fit.candidates]),
                     np.array([c['sigma'] for c in self.fit.candidates]))
        try:
            fit = fit_first_passage_intervals(self.lr.entries, self.intervals, alpha_k=self.lr.alpha_k,
                                              admissible=self.lr.admissible, start=start)
        except ValueError as exc:          # nothing admissible explains the data: keep the set
            self.history.append({'time': round(t, 3), 'error': str(exc)})
            return None
        self.fit = fit
        vf = self.lr.publish(fit, online=True)
        changed = vf is not None and (fit.index, float(fit.alpha)) != self.published
        self.history.append({'time': round(t, 3), 'omega_max': fit.omega_max, 'mu': fit.mu, 'sigma': fit.sigma,
                             'alpha': fit.alpha, 'encounters': self.phase2 + self.game_encounters,
                             'game_encounters': self.game_encounters,
                             'game_interventions': self.game_interventions,
                             'admissible': vf is not None, 'in_force': changed})
        if not changed:
            return None
        self.published = (fit.index, float(fit.alpha))
        return SafeSet(vf, float(fit.alpha), 'learned')


# -- the report -----------------------------------------------------------------------------------
QUARTERS = 4


def fp_by_quarter(game: dict) -> list | None:
    """False positives in each quarter of a game (its trace), or None without a trace."""
    trace = (game or {}).get('trace')
    if not trace:
        return None
    span = float(game.get('sim_time') or 0.0) or max((i['time'] for i in trace['interventions']), default=1.0)
    counts = [0] * QUARTERS
    for i in trace['interventions']:
        if i['false_positive']:
            counts[min(int(QUARTERS * i['time'] / span), QUARTERS - 1)] += 1
    return counts


def online_report(records: list, conditions) -> dict:
    """Whether learning from the games pays: FP per quarter of the game per condition (mean
    over subjects), the change from the first half to the second, per subject, of
    learned_online against learned_fp (the same set at the start) and learned (paired), and
    each subject's last online fit beside its hidden supervisor."""
    from .posthoc import paired_difference
    quarters, halves = {}, {}
    for c in conditions:
        rows = [fp_by_quarter(r['games'].get(c)) for r in records]
        if any(q is None for q in rows):
            continue
        quarters[c] = [float(np.mean([q[k] for q in rows])) for k in range(QUARTERS)]
        half = QUARTERS // 2
        halves[c] = [sum(q[half:]) - sum(q[:half]) for q in rows]
    out = {'fp_per_quarter': quarters, 'second_minus_first_half': halves, 'comparisons': {}, 'fits': []}
    if 'learned_online' in halves:
        for other in ('learned_fp', 'learned'):
            if other in halves:
                out['comparisons'][f'learned_online-{other}'] = {
                    'change': paired_difference(halves['learned_online'], halves[other]),
                    'total': paired_difference([r['games']['learned_online']['false_positives'] for r in records],
                                               [r['games'][other]['false_positives'] for r in records])}
    for r in records:
        history = [h for h in (r['games'].get('learned_online') or {}).get('online') or [] if 'omega_max' in h]
        s = r['subject']
        out['fits'].append({'subject': s.get('index'), 'hidden': {k: s.get(k) for k in ('omega_max', 'mu', 'sigma')},
                            'phase2': {k: (r['fits'].get('learned_fp') or {}).get(k) for k in ('omega_max', 'mu')},
                            'refits': len(history),
                            'last': {k: history[-1][k] for k in ('omega_max', 'mu', 'sigma', 'game_encounters')}
                            if history else None})
    return out


def format_online(report: dict) -> str:
    from .analysis import LABELS
    lines = [f'{"FP per quarter of the game":28s}' + ''.join(f'{f"Q{k + 1}":>7s}' for k in range(QUARTERS))]
    for c, q in report['fp_per_quarter'].items():
        lines.append(f'{LABELS[c]:28s}' + ''.join(f'{v:>7.2f}' for v in q))
    for pair, comp in report['comparisons'].items():
        a, b = pair.split('-')
        ch, tot = comp['change'], comp['total']
        lines.append(f'{LABELS[a]} vs {LABELS[b]}: second-half minus first-half FP {ch["mean_difference"]:+.2f} '
                     f'[{ch["ci_low"]:+.2f}, {ch["ci_high"]:+.2f}] (p = {ch["p_unadjusted"]:.3g}); '
                     f'whole game {tot["mean_difference"]:+.2f} FP [{tot["ci_low"]:+.2f}, {tot["ci_high"]:+.2f}] '
                     f'(p = {tot["p_unadjusted"]:.3g})')
    return '\n'.join(lines)
