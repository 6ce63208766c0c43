"""Learning a supervisor's safe set from interventions (paper, section II-C; issue 3).

ROS-free: numpy/scipy over the reachability core's value functions.

* ``supervisor``: the noisy idealized supervisor (batch and streaming judgements).
* ``data``: encounters, the CSV formats, the Phase II protocol.
* ``estimators``: the paper's estimator, the first-passage estimator, the
  conservative prior, alpha and the predicted false-positive fraction.
* ``cli``: ``supersafe fit``; ``plots``: the learned-safe-set figure.
"""
from .data import (Encounter, encounters_from_phase2_interventions, intervention_states,
                   phase2_encounters, read_encounters_csv, read_interventions_csv,
                   write_encounters_csv)
from .estimators import (FitResult, admissible_mask, alpha_for_fp_rate, fit_first_passage,
                         fit_paper, predicted_false_positive_fraction)
from .supervisor import NoisySupervisor

__all__ = [
    'Encounter', 'FitResult', 'NoisySupervisor', 'admissible_mask', 'alpha_for_fp_rate',
    'encounters_from_phase2_interventions', 'fit_first_passage', 'fit_paper',
    'intervention_states', 'phase2_encounters', 'predicted_false_positive_fraction',
    'read_encounters_csv', 'read_interventions_csv', 'write_encounters_csv',
]
