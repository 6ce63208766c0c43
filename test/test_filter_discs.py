"""Obstacles of their own radius (filter.discs): the value shift V_r = V_R + (R - r) on solved
sets, the covering ring of discs larger than R, and the filter judging (N, 3) detections."""
import math

import numpy as np
import pytest

from filter_support import at, robot
from supersafe_ros.filter import FilterConfig, RobotFilter, SafeSet, step_many, update_detections_all
from supersafe_ros.filter.cluster import ClusterSettings, ClusterStore
from supersafe_ros.filter.discs import RING_SLACK, checked_discs, covering_ring, ring_size
from supersafe_ros.sim.trials import layout_trials, run_trials
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.sets import Disc
from supersafe_ros.reach.solver import solve_avoid

pytestmark = pytest.mark.usefixtures('decision_path')   # every test: robot alone, and in a fleet
R = 1.8


@pytest.fixture(scope='module')
def standard():
    vf = solve_avoid(Grid((-8, -8), (8, 8), (41, 41, 24)), DubinsCar(3.0, 1.0), Disc(0, 0, R), horizon=3.0)
    return SafeSet(vf, 0.0, 'standard')


def test_the_value_of_a_smaller_disc_is_the_library_value_shifted():
    """Two radii solved on one small grid: V_r = V_R + (R - r) within the grid's error at the
    nodes the boundary cannot reach (and the unshifted value is off by R - r there)."""
    grid = Grid((-6, -6), (6, 6), (49, 49, 24))
    car = DubinsCar(2.0, 1.0)
    big, small = (solve_avoid(grid, car, Disc(0, 0, r), horizon=1.5).values for r in (1.2, 0.6))
    x, y = np.meshgrid(*(np.linspace(-6, 6, 49),) * 2, indexing='ij')
    inner = np.hypot(x, y) <= 3.0         # 1.5 s at 2 m/s from the edge: the edge's error cannot reach
    error = np.abs(small - (big + 0.6))[inner]
    cell = 12 / 48
    assert error.max() <= cell, error.max()
    assert np.median(np.abs(small - big)[inner]) > 0.5      # the shift is not nothing


def test_rings_cover_the_boundary_circle_of_a_larger_disc():
    for r in (1.81, 2.5, 4.0, 12.0, 60.0):
        k = int(ring_size(r, R))
        phi = np.linspace(0, 2 * np.pi, 4001)
        circle = np.stack([3 + r * np.cos(phi), -2 + r * np.sin(phi)], axis=1)
        ring = covering_ring(3.0, -2.0, r, k)
        gap = np.min(np.hypot(*(circle[:, None, :] - ring[None, :, :]).transpose(2, 0, 1)), axis=1).max()
        assert gap <= RING_SLACK * R + 1e-9, (r, k, gap)
        if k > 3:          # the least such k: one fewer leaves a gap
            assert r * math.sin(math.pi / (k - 1)) > RING_SLACK * R


def test_checked_discs():
    c, radii, origin = checked_discs(np.array([[1.0, 2.0], [3.0, 4.0]]), R)
    assert c.shape == (2, 2) and radii is None and origin is None
    c, radii, origin = checked_discs(np.array([[1.0, 2.0, 0.5], [3.0, 4.0, R]]), R)
    assert np.array_equal(radii, [0.5, R]) and origin is None and np.array_equal(c, [[1, 2], [3, 4]])
    c, radii, origin = checked_discs(np.array([[0.0, 0.0, 0.3], [10.0, 0.0, 5.0], [20.0, 0.0, 1.0]]), R)
    k = int(ring_size(5.0, R))
    assert len(c) == k + 2 and np.array_equal(origin, [0] + [1] * k + [2])
    assert np.all(radii[1:k + 1] == R) and radii[0] == 0.3 and radii[-1] == 1.0
    assert np.allclose(np.hypot(c[1:k + 1, 0] - 10.0, c[1:k + 1, 1]), 5.0 * math.cos(math.pi / k))
    for bad in ([[0, 0, 0.0]], [[0, 0, -1.0]], [[0, 0, np.nan]], [[0, 0, np.inf]], [[0, 0, 1, 2]], [1, 2, 3],
                [[0, 0, 1e9]]):
        with pytest.raises(ValueError):
            checked_discs(np.array(bad, dtype=float), R)
    with pytest.raises(ValueError, match='no ring'):         # a configured radius of 0 covers nothing
        checked_discs(np.array([[0.0, 0.0, 0.5]]), 0.0)


def test_a_smaller_disc_acts_later_by_the_difference_of_radii(standard):
    """At the same state, a disc of radius r reads V_R + (R - r): a robot that the library's
    disc overrides passes a smaller one, and the reported value is the shifted one."""
    pose = at(-3.7, 0.0, 0.0)          # heading at the obstacle
    same = robot(pose=pose, cmd=0.0).step(standard, 0.0)
    f = RobotFilter(FilterConfig())
    f.update_pose(pose, 0.0)
    f.update_detections(np.array([[10.0, 5.0, 0.4]]), 0.0)
    f.update_command(0.0, 0.0)
    small = f.step(standard, 0.0)
    assert same.action == 'override' and small.action == 'pass', (same.reason, small.reason)
    assert small.value == pytest.approx(same.value + (R - 0.4))
    # the fleet path (a batched array) reads the same
    g = RobotFilter(FilterConfig())
    g.update_pose(pose, 0.0)
    update_detections_all([g, RobotFilter(FilterConfig())], np.array([[10.0, 5.0, 0.4]]), 0.0)
    g.update_command(0.0, 0.0)
    fleet = step_many([g, RobotFilter(FilterConfig())], standard, 0.0)[0]
    assert fleet.value == small.value and fleet.action == 'pass'


def test_a_larger_disc_is_judged_by_its_ring_and_named_by_its_row(standard):
    """A disc of 4 m radius: a robot 3 m from its rim heading at it is overridden (the
    library's disc at the same centre would be 5.2 m away: a pass), the state names the
    message's row of the large disc."""
    big = np.array([[-30.0, 0.0, R], [10.0, 5.0, 4.0]])
    pose = at(-7.0, 0.0, 0.0)
    f = RobotFilter(FilterConfig(clusters=False))
    f.update_pose(pose, 0.0)
    f.update_detections(big, 0.0)
    f.update_command(0.0, 0.0)
    out = f.step(standard, 0.0)
    assert out.action == 'override' and out.obstacle_index == 1, out.reason
    assert robot(pose=pose, cmd=0.0, clusters=False).step(standard, 0.0).action == 'pass'


def test_malformed_radii_are_rejected_and_fail_safe(standard):
    f = robot(pose=at(-6.0, 0.0, 0.0))
    with pytest.raises(ValueError, match='radii must be > 0'):
        f.update_detections(np.array([[10.0, 5.0, -1.0]]), 0.1)
    out = f.step(standard, 0.1)
    assert out.action == 'fail_safe' and 'radii must be > 0' in out.reason


def test_scan_discs_queue_no_union_solve():
    """Detections taken with solve_clusters=False (discs from a scan, new every message):
    their clusters are judged by the loiter fallback, no union solve is requested."""
    safe = SafeSet(solve_avoid(Grid((-8, -8), (8, 8), (21, 21, 12)), DubinsCar(3.0, 1.0), Disc(0, 0, R),
                               horizon=1.0), 0.0)
    store = ClusterStore(ClusterSettings(), background=False)
    pair = np.array([[10.0, 5.0, 0.5], [12.0, 5.0, 0.5]])
    f = robot(pose=at(-5.0, 0.0, 0.0))
    f.update_detections(pair, 0.0, solve_clusters=False)
    out = f.step(safe, 0.0, store)
    assert store.requested == {} and len(store.values) == 0 and out.clusters_solving == 0
    f.update_detections(pair, 0.05)                     # the same from a static source: solved (inline)
    f.step(safe, 0.05, store)
    assert len(store.values) == 1


def test_discs_of_three_sizes_never_collide(standard):
    """Collision trials through layouts of discs of radius 0.4, 1.8 and 3.5 m (a ring of the
    library's discs, judged as a cluster by its union's value): no entry into any."""
    rng = np.random.default_rng(11)
    layouts = []
    for _ in range(24):
        xs = rng.permutation([-9.0, 0.0, 9.0])
        ys = rng.uniform(-2.0, 2.0, 3)
        layouts.append(np.stack([xs, ys, [0.4, R, 3.5]], axis=1))
    store = ClusterStore(ClusterSettings(), background=False)
    res = run_trials(layout_trials(layouts, rng), lambda fs, t: step_many(fs, standard, t, store), step=0.1,
                     rng=np.random.default_rng(12))
    assert res.collisions == 0 and res.overrides > 0, res.summary()


def test_many_discs_with_radii_are_narrowed_and_named_by_their_rows(standard):
    """More than the 64 a robot judges whole: the nearby search keeps each disc's radius and
    names a ring by its disc's row in the message, as with the large disc alone."""
    far = np.column_stack([np.linspace(60.0, 160.0, 80), np.full(80, 40.0), np.full(80, 0.5)])
    rows = np.vstack([far[:40], [[10.0, 5.0, 4.0]], far[40:]])        # the large disc is row 40
    pose = at(-7.0, 0.0, 0.0)
    outs = []
    for dets in (rows, rows[40:41]):
        f = RobotFilter(FilterConfig(clusters=False))
        f.update_pose(pose, 0.0)
        f.update_detections(dets, 0.0)
        f.update_command(0.0, 0.0)
        outs.append(f.step(standard, 0.0))
    assert outs[0].action == outs[1].action == 'override'
    assert outs[0].obstacle_index == 40 and outs[1].obstacle_index == 0 and outs[0].value == outs[1].value
