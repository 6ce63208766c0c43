"""Encounters that no library entry can explain are set aside, not fitted (issue 29):
``estimators.unexplained_encounters``, ``conflicting_encounters``, ``select_encounters``
and ``learning.encounter_window.EncounterWindow``, on the paper's library (41 x 41 x 24)."""
import numpy as np
import pytest

from supersafe_ros.learning.encounter_window import ALONE, JOINTLY, EncounterWindow
from supersafe_ros.learning.encounters import EncounterBuilder
from supersafe_ros.learning.estimators import (EncounterIntervals, admissible_mask, conflicting_encounters,
                                               fit_first_passage_intervals, select_encounters,
                                               unexplained_encounters)
from supersafe_ros.reach.library import PAPER_OMEGAS, LibrarySpec, load_or_build_library


@pytest.fixture(scope='module')
def library():
    lib = load_or_build_library(LibrarySpec(shape=(41, 41, 24), omegas=tuple(float(w) for w in PAPER_OMEGAS)))
    entries = list(lib.entries)
    return entries, admissible_mask(entries, lib.entry(1.0))


def approach(y0, click_at, obstacle=7, t0=0.0):
    """One straight pass at the obstacle (a pose every 0.2 s from x = -7.4), clicked at pose
    ``click_at`` (stamped with it, its state: what the console sends)."""
    b = EncounterBuilder((-8, -8), (8, 8), 3.0)
    b.set_obstacles([obstacle], [[0.0, 0.0]], 0.0)
    for k in range(30):
        x, t = -7.4 + 0.6 * k, t0 + 0.2 * k
        b.pose('robot_0', t, (x, y0, 0.0))
        if k == click_at:
            b.intervention(obstacle, t, (x, y0, 0.0))
    (record,) = b.pop_finished()
    return record


def test_a_click_after_the_robot_passed_is_explained_by_no_entry(library):
    entries, admissible = library
    from supersafe_ros.learning.estimators import encounter_intervals
    hasty = approach(2.5, click_at=13)            # x = 0.4: the first pose past the obstacle
    fair = approach(2.5, click_at=8)              # x = -2.6: still approaching
    assert hasty.intervened and fair.intervened
    iv = encounter_intervals(entries, [fair.to_encounter(), hasty.to_encounter()])
    assert unexplained_encounters(iv, admissible).tolist() == [False, True]
    with pytest.raises(ValueError, match='all log-likelihoods are -inf'):
        fit_first_passage_intervals(entries, iv, admissible=admissible)
    fit = fit_first_passage_intervals(entries, select_encounters(iv, [0]), admissible=admissible)
    assert np.isfinite(fit.log_likelihood) and fit.encounters == 1


def test_conflicting_encounters_are_the_fewest_that_let_one_entry_explain_the_rest():
    # entry 0 cannot explain encounter 2; entry 1 cannot explain 0 and 1; entry 2 none of 0, 2
    lo = np.array([[0.0, 0.0, 1.0], [1.0, 1.0, 0.0], [1.0, 0.0, 1.0]])
    hi = np.ones((3, 3)) * 0.5
    iv = EncounterIntervals(lo, hi, None, np.full(3, 10.0), np.ones(3, bool))
    assert not unexplained_encounters(iv).any()
    assert conflicting_encounters(iv).tolist() == [False, False, True]
    assert conflicting_encounters(iv, [False, True, True]).tolist() == [True, True, False]
    assert not conflicting_encounters(select_encounters(iv, [0, 1])).any()
    assert not conflicting_encounters(iv, [False, False, False]).any()


def test_the_window_sets_aside_what_no_entry_explains_and_fits_the_rest(library):
    entries, admissible = library
    told = []
    window = EncounterWindow(entries, admissible, size=4, set_aside=lambda r, d: told.append((r, d)))
    window.add([approach(2.5, 8, t0=0.0), approach(2.5, 13, obstacle=8, t0=100.0)])
    assert len(window) == 1 and told[0][0] == ALONE and 'obstacle_8' in told[0][1]
    offsets = (-3.0, -2.5, 2.0, 2.5, 3.0)
    window.add([approach(y0, 7, obstacle=10 + k, t0=200.0 + 100 * k) for k, y0 in enumerate(offsets)])
    assert len(window) == 4 and window.intervals.lo.shape == (len(entries), 4)      # the newest four
    assert [r.obstacle for r in window.records] == [11, 12, 13, 14]
    fit = fit_first_passage_intervals(entries, window.intervals, admissible=admissible)
    assert np.isfinite(fit.log_likelihood)
    window.add([approach(2.0, 13, obstacle=30, t0=900.0)])                  # set aside alone
    assert len(window) == 4 and len(told) == 2 and JOINTLY not in {r for r, _ in told}
