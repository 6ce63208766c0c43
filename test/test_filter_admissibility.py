"""The learned set's admissibility check and the containment primitive under it."""
import numpy as np

from supersafe_ros.filter.admissibility import check_learned_set
from supersafe_ros.reach.containment import contains
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.value_function import ValueFunction


def disc_vf(radius, shape=(41, 41, 12), lo=(-8.0, -8.0), hi=(8.0, 8.0)):
    """V = l (w = 0, horizon 0): the signed distance to a disc at the origin."""
    g = Grid(lo, hi, shape)
    x, y, _ = g.mesh()
    return ValueFunction(g, np.hypot(x, y) - radius, {'model': 'dubins'})


def test_more_conservative_set_is_accepted():
    v = check_learned_set(disc_vf(1.8), 0.0, disc_vf(2.5), 0.0)
    assert v.ok, v.reason


def test_a_higher_level_of_the_same_set_is_accepted():
    assert check_learned_set(disc_vf(1.8), 0.0, disc_vf(1.8), 0.7).ok


def test_less_conservative_set_is_rejected_with_the_reason():
    v = check_learned_set(disc_vf(1.8), 0.0, disc_vf(1.0), 0.0)
    assert not v.ok
    assert 'less conservative' in v.reason and v.containment.violations > 0


def test_a_very_negative_level_is_rejected():
    """mu = -100 would put the filter's level far inside the obstacle."""
    assert not check_learned_set(disc_vf(1.8), 0.0, disc_vf(1.8), -100.0).ok


def test_within_half_a_cell_is_accepted_beyond_is_not():
    std = disc_vf(1.8)
    cell = std.grid.spacing[0]
    assert check_learned_set(std, 0.0, disc_vf(1.8 - 0.4 * cell), 0.0).ok
    assert not check_learned_set(std, 0.0, disc_vf(1.8 - 0.7 * cell), 0.0).ok


def test_a_grid_that_does_not_cover_the_standard_unsafe_set_is_rejected():
    small = disc_vf(3.0, lo=(0.5, -8.0), hi=(8.0, 8.0))   # misses the obstacle's left half
    v = check_learned_set(disc_vf(1.8), 0.0, small, 0.0)
    assert not v.ok and v.containment.worst_excess == np.inf


def test_other_grid_is_interpolated():
    assert check_learned_set(disc_vf(1.8), 0.0, disc_vf(2.2, shape=(33, 29, 10)), 0.0).ok


def test_empty_reference_is_contained():
    c = contains(disc_vf(1.0), 0.0, disc_vf(1.0), -50.0)
    assert c.ok and c.checked == 0
