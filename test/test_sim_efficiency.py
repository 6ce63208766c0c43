"""The H2 measures (sim/efficiency.py) and the world's bookkeeping of them, without ROS."""
import math

import numpy as np
import pytest

from supersafe_ros.sim.efficiency import EfficiencyMeter, team_efficiency
from supersafe_ros.sim.world import World, WorldConfig


def test_a_straight_run_has_no_arc_and_the_path_is_the_distance():
    m = EfficiencyMeter()
    for k in range(11):
        m.pose((k * 0.6, 0.0, 0.0), 0.2 * k, goal=(16.0, 0.0), overriding=False,
               obstacles_xy=[(3.0, 4.0)], radius=1.8)
    v = m.values()
    assert v['path_length'] == pytest.approx(6.0) and v['robot_time'] == pytest.approx(2.0)
    assert v['avoidance_arcs'] == 0 and v['override_time'] == 0.0
    assert v['min_clearance'] == pytest.approx(4.0 - 1.8)       # at (3, 0), 4 m from (3, 4)


def test_an_override_detour_counts_its_extra_length_over_the_straight_line():
    m = EfficiencyMeter()
    goal = (10.0, 0.0)
    # pass to (2, 0); override: up to (4, 2) and back down to (6, 0); pass on to (8, 0)
    pts = [((0, 0), False), ((2, 0), False), ((4, 2), True), ((6, 0), True), ((8, 0), False)]
    for k, (p, over) in enumerate(pts):
        m.pose((p[0], p[1], 0.0), float(k), goal=goal, overriding=over)
    v = m.values()
    arc = 2 * math.hypot(2, 2)
    assert v['avoidance_arcs'] == 1
    assert v['avoidance_extra'] == pytest.approx(arc - 4.0)     # progress (2,0) -> (6,0) is 4 m
    assert v['override_time'] == pytest.approx(2.0) and v['robot_time'] == pytest.approx(4.0)
    t = team_efficiency([m], trips=0)
    assert t['override_fraction'] == pytest.approx(0.5)
    assert t['avoidance_length'] == pytest.approx(arc - 4.0)
    assert math.isnan(t['path_per_trip'])                       # no trip completed


def test_a_teleport_is_not_driven_and_closes_the_arc():
    m = EfficiencyMeter()
    m.pose((0, 0, 0), 0.0, goal=(10, 0), overriding=False)
    m.pose((0.6, 0.3, 0), 0.2, goal=(10, 0), overriding=True)
    m.pose((-17, 5, 0), 0.4, goal=(10, 0), overriding=True)      # a jump: not a segment
    v = m.values()
    assert v['path_length'] == pytest.approx(math.hypot(0.6, 0.3))
    assert v['avoidance_arcs'] == 1


def test_world_measures_trips_overrides_and_clearance_from_poses():
    w = World(WorldConfig(n_obstacles=0), ['a', 'b'], seed=1)
    w.set_obstacles([(0.0, 5.0)])
    for k in range(60):                      # a: from x = -17 across the goal line x = 16
        x = -17.0 + 0.6 * k
        w.set_filter_action('a', 'override' if 10 <= k < 14 else 'pass')
        w.update_pose('a', (x, 0.0, 0.0), time=0.2 * k)
        w.update_pose('b', (-17.0, -5.0 + 0.0 * k, 0.0), time=0.2 * k)
        if k == 0:
            goal = w.robots['a'].goal.copy()     # the first trip's goal point, on x = 16
    e = w.efficiency()
    assert w.robots['a'].trips == 1
    crossing = next(k for k in range(60) if -17.0 + 0.6 * k >= 16.0)
    assert e['path_per_trip'] == pytest.approx(crossing * 0.6)
    assert e['override_fraction'] == pytest.approx(4 / (2 * 59))     # b sat still but its time counts
    # the arc: poses 9 -> 13 along y = 0; the nominal path is the straight line to the goal
    start, end = np.array([-17.0 + 0.6 * 9, 0.0]), np.array([-17.0 + 0.6 * 13, 0.0])
    progress = np.hypot(*(start - goal)) - np.hypot(*(end - goal))
    assert e['avoidance_arcs'] == 1 and e['avoidance_length'] == pytest.approx(4 * 0.6 - progress)
    nearest = min(math.hypot(-17.0 + 0.6 * k, 5.0) for k in range(crossing + 1))
    assert e['min_clearance'] == pytest.approx(nearest - 1.8)        # a passed (-0.2, 0) below it
    with pytest.raises(KeyError):
        w.set_filter_action('nobody', 'pass')


def test_world_without_times_keeps_its_old_counts_only():
    w = World(WorldConfig(n_obstacles=3), ['a'], seed=2)
    w.update_pose('a', (-17.0, 0.0, 0.0))
    w.update_pose('a', (-16.4, 0.0, 0.0))
    assert w.efficiency()['path_length'] == 0.0
    assert np.isnan(w.efficiency()['override_fraction'])
