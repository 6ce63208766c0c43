"""Learning a supervisor's safe set from interventions (paper, section II-C; issue 3).

ROS-free: numpy/scipy over the reachability core's value functions.

* ``supervisor``: the noisy idealized supervisor (batch and streaming judgements).
* ``data``: encounters, the CSV formats, the Phase II protocol.
* ``estimators``: the paper's estimator, the first-passage estimator, the
  conservative prior, alpha and the predicted false-positive fraction;
  ``newton``: the vectorised maximiser behind the first-passage fit.
* ``levels``: ``learned_alpha``, the level mu + k sigma at which a filter uses a
  learned set (the filter node's and the study's).
* ``encounters``: encounters built online from poses, obstacle sets and
  interventions (the learner node's first-passage input).
* ``intervention_store``: the durable JSON-lines stores (interventions, encounters).
* ``cli``: ``supersafe fit``; ``plots``: the learned-safe-set figure.
"""
import importlib

# Names are resolved on first use (PEP 562): `supersafe reach` imports this
# package's CLI module, and should not pay for scipy.optimize.
_HOMES = {
    'Encounter': 'data', 'encounters_from_phase2_interventions': 'data',
    'intervention_states': 'data', 'phase2_encounters': 'data', 'read_encounters_csv': 'data',
    'read_interventions_csv': 'data', 'write_encounters_csv': 'data',
    'FitResult': 'estimators', 'admissible_mask': 'estimators', 'alpha_for_fp_rate': 'estimators',
    'fit_first_passage': 'estimators', 'fit_paper': 'estimators',
    'predicted_false_positive_fraction': 'estimators',
    'NoisySupervisor': 'supervisor',
    'EncounterBuilder': 'encounters', 'EncounterRecord': 'encounters', 'phase2_events': 'phase2_stream',
}


def __getattr__(name):
    if name in _HOMES:
        return getattr(importlib.import_module(f'.{_HOMES[name]}', __name__), name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')


__all__ = [
    'Encounter', 'EncounterBuilder', 'EncounterRecord', 'phase2_events', 'FitResult', 'NoisySupervisor',
    'admissible_mask', 'alpha_for_fp_rate',
    'encounters_from_phase2_interventions', 'fit_first_passage', 'fit_paper',
    'intervention_states', 'phase2_encounters', 'predicted_false_positive_fraction',
    'read_encounters_csv', 'read_interventions_csv', 'write_encounters_csv',
]
