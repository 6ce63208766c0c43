"""The offline first-passage fit (the console session's, the study's cross-check) sets aside the
encounters no admissible library entry can explain, as the learner node does, instead of
failing: a click on an obstacle the robot has already passed made every log-likelihood -inf
and ended a participant's session in its fit (seen under load, the page lagging the world)."""
import numpy as np

from supersafe_ros.learning.estimators import encounter_intervals, explainable_encounters
from supersafe_ros.reach.library import load_or_build_library
from supersafe_ros.study.fits import first_passage_fit, first_passage_offline, phase2_encounters_from_scenes


def scene(y, click_x=None, last_x=6.0):
    """A straight pass at offset ``y`` by the obstacle at the origin (heading +x), frames every
    0.3 m from x = -10; ``click_x``: the intervention's x (None: no intervention)."""
    xs = np.arange(-10.0, last_x, 0.3)
    frames = np.stack([xs, np.full_like(xs, y), np.zeros_like(xs)], axis=1)
    if click_x is None:
        return {'frames': frames.ravel().tolist(), 'intervened': False, 'state': None}
    return {'frames': frames.ravel().tolist(), 'intervened': True, 'state': [click_x, y, 0.0]}


def test_a_click_past_the_closest_approach_is_set_aside_not_fatal():
    hasty = scene(2.5, click_x=2.8)         # the robot already past the obstacle: distance growing
    usual = [scene(1.0, click_x=-4.5), scene(0.5, click_x=-5.0), scene(1.5, click_x=-4.0), scene(4.0)]
    lib = load_or_build_library()
    iv = encounter_intervals(lib.entries, phase2_encounters_from_scenes(usual + [hasty]))
    assert explainable_encounters(iv).tolist() == [True] * 4 + [False]

    fit, summary = first_passage_offline(usual + [hasty])
    assert fit is not None and summary['set_aside'] == 1 and summary['encounters'] == 4
    alone, alone_summary = first_passage_offline(usual)
    assert alone_summary['set_aside'] == 0
    assert summary['omega_max'] == alone_summary['omega_max'] and np.isclose(summary['mu'], alone_summary['mu'])

    assert first_passage_offline([hasty]) == (None, None)      # nothing left: no fit, no exception
    assert first_passage_fit([hasty]) == (None, None)
