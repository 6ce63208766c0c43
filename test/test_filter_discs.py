"""Obstacles of their own radius (filter.constraints.discs): the value shift V_r = V_R + (R - r) on solved
sets, the covering ring of discs larger than R, and the filter judging (N, 3) detections."""
import math

import numpy as np
import pytest

from filter_support import at, robot
from supersafe_ros.filter import FilterConfig, RobotFilter, SafeSet, step_many, update_detections_all
from supersafe_ros.filter.clusters.geometry import ClusterSettings
from supersafe_ros.filter.clusters.store import ClusterStore
from supersafe_ros.filter.constraints.discs import RING_SLACK, checked_discs, covering_ring, ring_size
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


def disc_fleet(seed, n=90):
    """n robots among discs of radius 0.4 to 4 m (rings): a third given one batched array, a third
    arrays of their own (some beyond the 64 a robot judges whole: narrowed), a third (N, 2) centres
    of the configured radius; poses near the discs, planners turning or not."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-14.0, 14.0, (12, 2))
    layout = np.column_stack([centres, rng.choice([0.4, 1.0, R, 4.0], 12)])
    far = np.column_stack([np.linspace(60.0, 160.0, 70), np.full(70, 40.0), np.full(70, 0.5)])
    filters, batched, messages = [], [], []
    for i in range(n):
        f = RobotFilter(FilterConfig(clusters=bool(i % 4)))
        c = layout[rng.integers(len(layout)), :2]
        f.update_pose((c[0] + rng.uniform(-7, 7), c[1] + rng.uniform(-7, 7), rng.uniform(-np.pi, np.pi)), 0.0)
        kind, own = i % 3, None
        if kind == 0:
            batched.append(f)
        else:
            own = layout[rng.choice(len(layout), int(rng.integers(1, 7)), replace=False)]
            if kind == 1 and rng.random() < 0.3:
                own = np.vstack([far, own])
            own = own if kind == 1 else own[:, :2].copy()
        f.update_command(float(rng.choice([0.0, 0.6, -1.0])), 0.0)
        filters.append(f)
        messages.append(own)

    def detect(t):
        update_detections_all(batched, layout, t)
        for f, own in zip(filters, messages):
            if own is not None:
                f.update_detections(own, t)
    detect(0.0)
    return filters, detect


def test_a_fleet_of_discs_of_their_own_radius_decides_each_robot_as_alone(standard):
    """Robots given discs of several radii (a batched array, arrays of their own, narrowed ones,
    centres without radii) decide in a fleet as each decides alone: the same command, reason,
    value and named row, over closed-loop ticks (the pairs' shifts read per robot or for all
    at once, and only for the pairs near the grid)."""
    store = ClusterStore(ClusterSettings(), fallback_only=True)
    (fleet, detect_fleet), (alone, detect_alone) = disc_fleet(5), disc_fleet(5)
    seen = {'override': 0, 'ring': 0, 'shifted': 0}
    t = 0.0
    for tick in range(4):
        together = step_many(fleet, standard, t, store)
        apart = [step_many([f], standard, t, store)[0] for f in alone]
        for i, (a, b) in enumerate(zip(together, apart)):
            assert repr((a.omega, a.linear, a.action, a.reason, a.obstacle_index, a.value, a.source)) == repr(
                (b.omega, b.linear, b.action, b.reason, b.obstacle_index, b.value, b.source)), (tick, i)
            seen['override'] += a.action == 'override'
            radii = fleet[i].detections.radii
            named = a.obstacle_index
            if named >= 0 and radii is not None and a.source == 'standard':
                kept = fleet[i].detections.kept
                seen['ring'] += kept is not None and int(np.sum(kept == named)) > 1
                seen['shifted'] += float(radii[np.flatnonzero(kept == named)[0] if kept is not None else named]) != R
        t += 0.1
        for filters, outs, detect in ((fleet, together, detect_fleet), (alone, apart, detect_alone)):
            for f, o in zip(filters, outs):
                x, y, th = f.pose.value
                f.update_pose((x + 0.3 * math.cos(th), y + 0.3 * math.sin(th), th + 0.1 * o.omega), t)
                f.update_command(f.command.value, t)
            detect(t)
    assert min(seen.values()) > 3, seen
