"""A subject's learned sets after Phase II, whichever engine fitted them.

``learned_sets`` and ``learned_value_functions``: condition -> (set, fit) of the two
learned conditions, Learned (the paper's estimator) and Learned FP (first-passage): the
graph learners' last messages, or the core engine's value functions. ``first_passage_fit``
fits the first-passage estimator offline from recorded scenes, without a learner node
(the console session's fit; ``offline_cross_check`` puts it beside the first-passage
learner's in the study's JSON, ``phase2.offline_first_passage``).
"""
from __future__ import annotations

import numpy as np

from ..learning.data import Encounter
from ..learning.estimators import (admissible_mask, encounter_intervals, explainable_encounters,
                                   fit_first_passage_intervals, select_encounters)
from ..reach.library import load_or_build_library
from .protocol import FIT_KEYS, TRUE_OMEGA, Phase2Result


def phase2_encounters_from_scenes(scenes: list) -> list:
    """Encounters (relative frames, obstacle at the origin) of the recorded scenes."""
    out = []
    for k, s in enumerate(scenes):
        frames = np.asarray(s['frames'], dtype=float).reshape(-1, 3)
        if s['intervened']:
            frames = np.vstack([frames[frames[:, 0] < s['state'][0]], np.asarray(s['state'])[None]])
        if len(frames) == 0:
            continue
        out.append(Encounter(frames, bool(s['intervened']), k))
    return out


def first_passage_offline(scenes: list):
    """fit_first_passage over the library (conservative prior) -> (FitResult, fit dict), or
    (None, None) when no encounter is left to fit; no ROS message (the core engine's
    cross-check). Encounters no admissible entry can explain (a click on an obstacle the
    robot had already passed) are set aside as the learner node sets them aside
    (``estimators.explainable_encounters``), and counted in the dict's ``set_aside``."""
    lib = load_or_build_library()
    true_vf = lib.entry(TRUE_OMEGA)
    iv = encounter_intervals(lib.entries, phase2_encounters_from_scenes(scenes))
    admissible = admissible_mask(lib.entries, true_vf)
    keep = explainable_encounters(iv, admissible)
    if not keep.any():
        return None, None
    fit = fit_first_passage_intervals(lib.entries, select_encounters(iv, keep), true_vf=true_vf,
                                      admissible=admissible)
    summary = {k: v for k, v in fit.to_dict().items() if k not in ('candidates', 'notes')}
    summary['set_aside'] = int((~keep).sum())
    return fit, summary


def first_passage_fit(scenes: list):
    """fit_first_passage over the library (conservative prior) -> (message, fit dict), or
    (None, None) when no encounter can be fitted (``first_passage_offline``)."""
    from ..ros_io.vfmsg import value_function_to_msg    # ROS message types: not in the core engine
    fit, summary = first_passage_offline(scenes)
    if fit is None:
        return None, None
    msg = value_function_to_msg(fit.value_function, **summary, source='learned')
    return msg, summary


def learned_sets(p2: Phase2Result, conditions) -> dict:
    """condition -> (value function message or None, fit dict or None) of one subject.

    learned: the paper learner node's fit (alpha = mu); learned_fp: the first-passage
    learner node's (alpha = mu, over every encounter, intervened or not). Both are the
    nodes' last messages, taken from the Phase II graph.
    """
    out = {}
    if 'learned' in conditions:
        out['learned'] = (p2.vf_msg, p2.fit)
    for c in ('learned_fp', 'learned_online'):     # learned_online starts from the first-passage fit
        if c in conditions:
            out[c] = (p2.fp_msg, p2.fp_fit)
    return out


def offline_cross_check(p2: Phase2Result) -> dict | None:
    """The first-passage fit done offline from the conductor's recorded scenes, beside the
    learner node's (the two see the same scenes; they differ only by what the node
    receives on topics): chosen omega_max, mu, sigma, counts."""
    if not len(p2.states):
        return None
    _, fit = first_passage_offline(p2.scenes)
    if fit is None:
        return None
    return {k: fit.get(k) for k in FIT_KEYS + ('interventions', 'encounters', 'set_aside')}


def learned_value_functions(p2: Phase2Result, conditions) -> dict:
    """condition -> (ValueFunction or None, fit or None): the core engine's value functions,
    or the graph learners' messages decoded."""
    out = {}
    for c, (msg, fit) in learned_sets(p2, conditions).items():
        vf = p2.vf if c == 'learned' else p2.fp_vf
        if vf is None and msg is not None:
            from ..ros_io.vfmsg import msg_to_value_function    # the graph's messages only
            vf = msg_to_value_function(msg)
        out[c] = (vf, fit if vf is not None else None)
    return out
