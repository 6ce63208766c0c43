"""Sampled keep-out fields (reach.field) and the reusable solver (reach.solver.AvoidSolver)."""
import json
import math

import numpy as np
import pytest

from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.field import FREE, FieldKeepout, occupancy_field
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.library import LibrarySpec
from supersafe_ros.reach.sets import Disc, Union
from supersafe_ros.reach.solver import AvoidSolver, solve_avoid
from solver_oracle import solve_avoid_before


def random_field(rng, shape=(37, 29)):
    return FieldKeepout((-1.3, 0.7), 0.05, rng.normal(0.0, 2.0, shape), outside=7.5)


def test_the_separable_path_equals_the_general_one_inside_outside_and_broadcast():
    rng = np.random.default_rng(0)
    f = random_field(rng)
    (x0, y0), (x1, y1) = f.lo, f.hi
    # the solver's call: (K, n, 1) against (K, 1, m), points inside, on the rim and beyond it
    xs = np.concatenate([rng.uniform(x0 - 0.2, x1 + 0.2, 40), [x0, x1, x0 - 1e-9, x1 + 1e-9]])
    ys = np.concatenate([rng.uniform(y0 - 0.2, y1 + 0.2, 30), [y0, y1]])
    shift = rng.normal(0.0, 0.1, (12, 2))
    x = xs[None, :, None] + shift[:, 0, None, None]
    y = ys[None, None, :] + shift[:, 1, None, None]
    fast = f.signed_distance_xy(x, y)
    general = f._general(*np.broadcast_arrays(x, y))
    assert fast.shape == general.shape == (12, 44, 32)
    assert np.all(np.abs(fast - general) <= 1e-6 * (1.0 + np.abs(general)))
    assert np.any(general == 7.5) and np.any(general != 7.5)       # both regions were read
    # leading axes that broadcast: one x column for every y slice
    fast = f.signed_distance_xy(xs[None, :, None], y)
    one_column = f._general(*np.broadcast_arrays(xs[None, :, None], y))
    assert fast.shape == (12, 44, 32) and np.all(np.abs(fast - one_column) <= 1e-6 * (1.0 + np.abs(one_column)))
    # and the (..., 2) entry point is the general one
    pts = np.stack(np.broadcast_arrays(x, y), axis=-1)
    assert np.array_equal(f.signed_distance(pts), general)


def test_bilinear_between_nodes_exact_at_nodes_and_on_planes():
    f = FieldKeepout((1.0, -2.0), 0.25, np.arange(12.0).reshape(3, 4))
    assert f.hi == (1.5, -1.25)
    assert f.signed_distance_xy(1.25, -1.5) == 6.0        # node (1, 2)
    plane = FieldKeepout((0.0, 0.0), 0.1, 2.0 * np.arange(5)[:, None] - 3.0 * np.arange(6)[None, :] + 1.0)
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0.0, 0.4, 50), rng.uniform(0.0, 0.5, 50)
    assert np.allclose(plane.signed_distance_xy(x, y), 20.0 * x - 30.0 * y + 1.0, atol=1e-12)
    assert plane.signed_distance_xy(0.41, 0.2) == FREE and plane.signed_distance_xy(0.2, -0.01) == FREE
    grown = plane.inflated(0.5)
    assert np.allclose(grown.signed_distance_xy(x, y), 20.0 * x - 30.0 * y + 0.5) and grown.outside == FREE - 0.5
    assert plane.discs() == () and plane.params()['type'] == 'field'


def test_fields_refuse_what_they_cannot_hold():
    with pytest.raises(ValueError, match='shape'):
        FieldKeepout((0, 0), 0.1, np.zeros(5))
    with pytest.raises(ValueError, match='cell'):
        FieldKeepout((0, 0), 0.0, np.zeros((3, 3)))
    with pytest.raises(ValueError, match='finite'):
        FieldKeepout((0, 0), 0.1, np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match='2 x 2'):
        occupancy_field((0, 0), 0.1, np.zeros(4, bool))


def distance_to_cells(points, origin, cell, occupied):
    """Exact distance from each point to the nearest occupied square (brute force)."""
    i, j = np.nonzero(occupied)
    lo_x, lo_y = origin[0] + i * cell, origin[1] + j * cell
    px, py = points[:, 0, None], points[:, 1, None]
    dx = np.maximum(np.maximum(lo_x - px, px - (lo_x + cell)), 0.0)
    dy = np.maximum(np.maximum(lo_y - py, py - (lo_y + cell)), 0.0)
    return np.hypot(dx, dy).min(axis=1)


@pytest.mark.parametrize('seed', range(4))
def test_the_occupancy_field_is_a_lower_bound_at_its_nodes_and_within_a_half_diagonal_between(seed):
    rng = np.random.default_rng(seed)
    cell, clearance, origin = 0.05, 0.2, (-0.35, 1.2)
    occupied = rng.random((31, 27)) < rng.uniform(0.005, 0.05)
    occupied[rng.integers(0, 31), rng.integers(0, 27)] = True
    lo, values = occupancy_field(origin, cell, occupied, clearance)
    assert lo == pytest.approx((origin[0] + cell / 2, origin[1] + cell / 2))
    X, Y = np.meshgrid(lo[0] + cell * np.arange(31), lo[1] + cell * np.arange(27), indexing='ij')
    nodes = np.stack([X.ravel(), Y.ravel()], axis=-1)
    true = distance_to_cells(nodes, origin, cell, occupied) - clearance
    l_nodes = values.ravel()
    assert np.all(l_nodes <= true + 1e-9)                                   # a lower bound at nodes
    assert np.all(l_nodes >= true - cell * math.sqrt(2) / 2 - 1e-9)        # loose by at most the half diagonal
    # between nodes the interpolant may exceed the true clearance, by at most the half diagonal
    field = FieldKeepout(lo, cell, values)
    pts = np.stack([rng.uniform(lo[0], lo[0] + 30 * cell, 4000), rng.uniform(lo[1], lo[1] + 26 * cell, 4000)], -1)
    between = field.signed_distance(pts) - (distance_to_cells(pts, origin, cell, occupied) - clearance)
    assert between.max() <= cell * math.sqrt(2) / 2 + 1e-9
    assert between.max() > 0.0          # the interpolation term exists: the bound is not vacuous


def test_no_occupied_cell_is_free_everywhere():
    lo, values = occupancy_field((0.0, 0.0), 0.1, np.zeros((10, 12), bool), 0.3)
    assert values.shape == (10, 12) and np.all(values == FREE)


def test_the_fast_path_keeps_the_solve_of_the_general_one():
    rng = np.random.default_rng(5)
    occupied = rng.random((80, 80)) < 0.01
    lo, values = occupancy_field((-2.0, -2.0), 0.05, occupied, 0.25)
    field = FieldKeepout(lo, 0.05, values)

    class General:
        """The same field read only through its general path."""

        def signed_distance(self, xy):
            return field.signed_distance(xy)

        def signed_distance_xy(self, x, y):
            return field._general(*np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float)))

        params, discs = field.params, field.discs

    grid = Grid((-1.5, -1.5), (1.5, 1.5), (31, 31, 16))
    fast = solve_avoid(grid, DubinsCar(0.5, 1.0), field, 2.0).values
    slow = solve_avoid(grid, DubinsCar(0.5, 1.0), General(), 2.0).values
    assert np.max(np.abs(fast - slow)) < 1e-5


# -- the reusable solver keeps solve_avoid's results bit for bit ------------------------------
def test_a_library_entry_and_a_union_are_solved_as_before_bit_for_bit():
    spec = LibrarySpec()
    car = DubinsCar(spec.speed, 1.0)
    entry = solve_avoid(spec.grid, car, Disc(0.0, 0.0, spec.radius), spec.horizon, spec.settings)
    before = solve_avoid_before(spec.grid, car, Disc(0.0, 0.0, spec.radius), spec.horizon, spec.settings)
    assert np.array_equal(entry.values, before.values)
    assert json.dumps({k: v for k, v in entry.meta.items() if k != 'solve_time_s'}, sort_keys=True) == \
        json.dumps({k: v for k, v in before.meta.items() if k != 'solve_time_s'}, sort_keys=True)
    grid = Grid((-8, -8), (8, 8), (33, 33, 20))
    union = Union((Disc(0, 0, 1.8), Disc(2.5, 1.0, 1.8), Disc(-1.0, 3.0, 1.2)))
    slow_car = DubinsCar(3.0, 0.25)      # heading refinement q > 1
    for keepout, dyn, horizon in ((union, car, 3.0), (Disc(0.5, -0.2, 1.1), slow_car, 2.7), (union, car, None)):
        assert np.array_equal(solve_avoid(grid, dyn, keepout, horizon).values,
                              solve_avoid_before(grid, dyn, keepout, horizon).values)


def test_one_solver_reused_for_other_sets_and_places_equals_fresh_solves():
    grid = Grid((-8, -8), (8, 8), (33, 33, 20))
    car = DubinsCar(3.0, 1.0)
    solver = AvoidSolver(grid, car)
    first = solver.solve(Disc(0, 0, 1.8), 3.0)
    solver.solve(Union((Disc(1, 1, 1.0), Disc(-2, 0, 1.5))), 2.0)
    solver.solve(Disc(0, 0, 1.8), 3.0, lo=(-3.0, 2.0))
    again = solver.solve(Disc(0, 0, 1.8), 3.0)
    assert np.array_equal(first.values, again.values)
    assert np.array_equal(again.values, solve_avoid_before(grid, car, Disc(0, 0, 1.8), 3.0).values)
    # a translated grid: the translated problem's values
    moved = solver.solve(Disc(5.0, -6.0, 1.8), 3.0, lo=(-3.0, -14.0))
    assert moved.grid.lo == (-3.0, -14.0) and moved.grid.shape == grid.shape
    assert np.max(np.abs(moved.values - first.values)) < 1e-5


def test_nodes_beyond_the_rim_distance_have_the_values_of_an_unbounded_grid():
    car = DubinsCar(3.0, 1.0)
    keepout = Union((Disc(0.3, 0.2, 1.0), Disc(-2.0, 1.5, 0.8), Disc(4.5, -3.0, 1.2)))
    small = AvoidSolver(Grid((-8, -8), (8, 8), (65, 65, 24)), car)
    large = AvoidSolver(Grid((-16, -16), (16, 16), (129, 129, 24)), car)
    rim = small.rim_distance(1.5)
    assert 1.5 * 3.0 < rim < 8.0                # more than v T: a step reads a cell beyond its arc
    a, b = small.solve(keepout, 1.5), large.solve(keepout, 1.5)
    X, Y = np.meshgrid(a.grid.x, a.grid.y, indexing='ij')
    inner = (np.abs(X) <= 8.0 - rim + 1e-9) & (np.abs(Y) <= 8.0 - rim + 1e-9)
    b_here = b.values[32:97, 32:97]           # the same nodes
    assert np.allclose(b.grid.x[32:97], a.grid.x)
    assert np.max(np.abs(a.values - b_here)[inner]) < 1e-5
    assert np.max(np.abs(a.values - b_here)[~inner]) > 1e-3          # the rim does matter outside
    (x0, y0), (x1, y1) = small.read_bounds()
    assert x0 < -7.0 and x1 > 7.0 and y0 < -7.0 and y1 > 7.0
