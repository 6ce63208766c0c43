"""The study's numbers from its records: Table 1, H2, ANOVA, paired post-hoc tests, the alpha sweep.

``summarize`` pools the per-subject records (``records``) with the statistics of
``analysis`` and ``posthoc`` (paired tests; Tukey's independent-groups HSD is kept as a
labelled reference); a human participant's record (``session.protocol``) counts like a
simulated subject's. Crashes stand beside false positives (a supervisor that saves false
positives by missing undetected obstacles is not a better one): each Table 1 row and each
paired test carries the conditions' crash totals.
"""
from __future__ import annotations

import numpy as np

from ..learning.levels import learned_alpha
from .analysis import (H2_MEASURES, SetCount, h2_summary, interventions_inside, ordered,
                       repeated_measures_anova, table1, tukey_pairs)
from .posthoc import TUKEY_REFERENCE, paired_posthoc
from .protocol import sweep_condition
from .records import record_learned, stored_measure
from .online import online_report
from .validity import model_validity


def record_sets(r: dict, standard_vf, conservative_vf) -> dict:
    """condition -> (value function, alpha) of the sets a record's Phase III started with (a
    learned condition without a fit used the Standard set)."""
    learned = record_learned(r)
    sets = {'standard': (standard_vf, 0.0), 'conservative': (conservative_vf, 0.0)}
    for c in ('learned', 'learned_fp', 'learned_online'):
        vf, fit = learned.get(c, (None, None))
        sets[c] = (vf, learned_alpha(fit)) if vf is not None else (standard_vf, 0.0)
    return sets


def count_value(v):
    """A stored count: an int, or the float mean of a treatment's games when not whole."""
    v = float(v)
    return int(v) if v.is_integer() else v


def summarize(records: list, standard_vf, conservative_vf, sweep_k=(0.0, 1.0, 2.0)) -> dict:
    """Aggregate per-subject records into the study's JSON (Table 1, H2, ANOVA, post-hoc, sweep).

    A record: {'subject', 'states' (Phase II intervention states), 'fits' and 'learned_vfs'
    (learned condition -> fit dict / ValueFunction, or None), 'games': {condition: counts
    and H2 measures, the mean of its games when it was played more than once (the paper's
    form: ``design.treatment_means``)}, 'sweep': {k: counts}}. A subject without a fit (fewer than 3
    interventions) is counted with the Standard set in that learned condition (what its
    filter used). The conditions are those the records' games ran.
    """
    conditions = ordered(records[0]['games'])
    inside = {c: SetCount(0, 0) for c in conditions}
    swept = sweep_condition(conditions)
    per_subject_pred = {float(k): [] for k in sweep_k}
    for r in records:
        states = np.asarray(r['states'], dtype=float).reshape(-1, 3)
        learned = record_learned(r)
        sets = record_sets(r, standard_vf, conservative_vf)
        for c in conditions:
            vf, alpha = sets[c]
            n = interventions_inside(vf, alpha, states)
            inside[c] = SetCount(inside[c].inside + n.inside, inside[c].total + n.total)
        vf, fit = learned.get(swept, (None, None)) if swept else (None, None)
        if vf is not None and len(states):
            for k in per_subject_pred:
                n = interventions_inside(vf, learned_alpha(fit, k), states)
                per_subject_pred[k].append(n.inside / n.total)
    # a count per subject: a treatment's games' mean (two games each in the paper's form)
    counts = {c: {key: [count_value(r['games'][c][key]) for r in records]
                  for key in ('false_positives', 'interventions', 'crashes', 'trips')}
              for c in conditions}
    measures = {c: {m: [stored_measure(r['games'][c].get(m)) for r in records]
                    for m in H2_MEASURES + ('avoidance_total', 'avoidance_arcs')}
                for c in conditions}
    fp = {c: counts[c]['false_positives'] for c in conditions}
    rows = table1(inside, fp)
    for c in conditions:     # crashes beside false positives: a supervisor that misses is not better
        rows[c]['crashes'] = int(sum(counts[c]['crashes']))
        rows[c]['trips'] = int(sum(counts[c]['trips']))
    posthoc = paired_posthoc(fp, conditions)
    for pair, r in posthoc['pairs'].items():
        a, b = pair.split('-')
        r['crashes'] = [rows[a]['crashes'], rows[b]['crashes']]
    out_conditions = {}
    for c in conditions:
        # the per-subject counts (lists) over Table 1's totals of the same names
        out_conditions[c] = {**rows[c], **counts[c], **measures[c]}
        if c == 'standard':   # the reference, by definition (other ratios are NaN if it is 0)
            out_conditions[c]['predicted_fp_ratio'] = 1.0
            out_conditions[c]['observed_fp_ratio'] = 1.0
    observed = {}
    for k in per_subject_pred:
        games = [r['sweep'][k] for r in records if k in r.get('sweep', {})]
        observed[k] = [g['false_positives'] for g in games] if games else None
    sweep = {f'mu+{k:g}sigma' if k else 'mu': {
        'k': k, 'condition': swept, 'predicted': per_subject_pred[k], 'observed': observed[k],
        'observed_subjects': [r['subject']['index'] for r in records if k in r.get('sweep', {})],
        'observed_interventions': [r['sweep'][k]['interventions'] for r in records if k in r.get('sweep', {})],
        'observed_crashes': [r['sweep'][k]['crashes'] for r in records if k in r.get('sweep', {})],
    } for k in per_subject_pred}
    h2 = h2_summary({c: measures[c] for c in conditions})
    return {
        'table1': rows,
        'conditions': out_conditions,
        'anova': repeated_measures_anova(fp),
        'posthoc': posthoc,
        'tukey': tukey_pairs(fp),
        'tukey_method': TUKEY_REFERENCE,
        'validity': model_validity(records, lambda r: record_sets(r, standard_vf, conservative_vf), conditions),
        'online': online_report(records, conditions) if 'learned_online' in conditions else None,
        'h2': h2,
        'alpha_sweep': sweep,
        'subjects': [{'subject': r['subject'],
                      'fits': {c: f for c, (_, f) in record_learned(r).items()},
                      'phase2': r.get('phase2', {}),
                      'games': r['games'], 'sweep': {f'{k:g}': v for k, v in r.get('sweep', {}).items()}}
                     for r in records],
    }
