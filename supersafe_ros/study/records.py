"""A subject's record as data: its games' counts, its learned sets, and JSON.

A record (``runner.run_subject``; a human participant's from ``session.protocol``):
{'subject', 'phase2', 'states' (Phase II intervention states), 'fits' and 'learned_vfs'
(learned condition -> fit dict / ValueFunction, or None), 'games': {condition: counts
and H2 measures}, 'sweep': {k: counts}}.

* ``game_counts``: a game's entry, from the world's final /world/stats;
* ``record_learned``: condition -> (value function, fit) of a record's learned sets;
* ``jsonable``: nested data made JSON-safe (numpy scalars and arrays; non-finite floats
  become null), ``stored_measure``: an H2 measure read back (null: not measured).
"""
from __future__ import annotations

import math

import numpy as np

H2_KEYS = ('path_per_trip', 'avoidance_length', 'avoidance_total', 'avoidance_arcs',
           'override_fraction', 'min_clearance', 'path_length')


def game_counts(result: dict) -> dict:
    """The world's final counts and H2 measures of one game (from its /world/stats)."""
    stats = result.get('stats') or {}
    log = result.get('interventions') or []

    def num(key):
        v = stats.get(key)
        return int(float(v)) if v is not None else 0

    def real(key):
        try:
            return float(stats[key])
        except (KeyError, TypeError, ValueError):
            return float('nan')
    out = {
        'trips': num('trips'), 'crashes': num('crashes'),
        'interventions': num('interventions'), 'false_positives': num('false_positives'),
        'sim_time': float(stats.get('sim_time', 0.0) or 0.0),
        'logged_interventions': len(log),
        'logged_false_positives': sum(1 for r in log if str(r.get('false_positive')).lower()
                                      in ('true', '1')),
    }
    out.update({k: real(k) for k in H2_KEYS})
    return out


def record_learned(r: dict) -> dict:
    """condition -> (value function, fit) of a record's learned sets (None when not fitted);
    a record with only 'fit'/'learned_vf' is the paper estimator's Learned."""
    if 'learned_vfs' in r:
        return {c: (r['learned_vfs'].get(c), r['fits'].get(c)) for c in r['learned_vfs']}
    return {'learned': (r.get('learned_vf'), r.get('fit'))}


def finite_or_none(v):
    """``v``, or None for a non-finite float (JSON has no NaN or infinity)."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def stored_measure(v) -> float | None:
    """A stored H2 measure as a finite float, or None (not measured: NaN in memory, null in
    JSON, e.g. path per trip in a game without a trip)."""
    return None if v is None else finite_or_none(float(v))


def jsonable(obj):
    """Nested dicts/lists with numpy scalars and non-finite floats made JSON-safe."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        obj = obj.item()
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    return finite_or_none(obj)
