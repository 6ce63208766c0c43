"""The world's rules at their boundaries (supersafe_ros.sim.world), written against
the survivors of a mutation run (bench/mutation.sh): crash depth and re-entry, trip
lines, the false-positive rule, detection and proximity tolerances, scene resets,
respawns and the configuration's validation."""
import math

import numpy as np
import pytest

from supersafe_ros.sim import World, WorldConfig


def bare_world(robots=('a',), **cfg):
    """A world with no random obstacles; the test places them."""
    return World(WorldConfig(n_obstacles=0, **cfg), list(robots), seed=0)


def place(w, *centres):
    return w.set_obstacles(np.array(centres, dtype=float))


# ---- crashes ---------------------------------------------------------------------------
def test_crash_needs_the_centre_deeper_than_the_tolerance():
    w = bare_world(crash_tolerance=0.05)
    (oid,) = place(w, (3.0, -2.0))
    r = w.config.radius
    w.update_pose('a', [3.0 - r + 0.04, -2.0, 0.0])          # 4 cm inside: a graze
    assert w.stats()['crashes'] == 0
    assert w.update_pose('a', [3.0 - r + 0.06, -2.0, 0.0])['crashed'] == [oid]   # 6 cm: a crash
    assert w.stats()['crashes'] == 1


def test_a_centre_exactly_at_the_tolerance_is_a_graze():
    w = bare_world(crash_tolerance=0.05)          # radius 1.8: 1.75 m is exact in binary
    place(w, (0.0, 0.0))
    assert w.update_pose('a', [-1.75, 0.0, 0.0])['crashed'] == []


def test_one_crash_per_entry_and_a_new_entry_counts_again():
    w = bare_world()
    (oid,) = place(w, (0.0, 0.0))
    for x in (-1.0, -0.5, 0.0):
        w.update_pose('a', [x, 0.0, 0.0])
    assert w.stats()['crashes'] == 1 and w.robots['a'].inside == {oid}
    w.update_pose('a', [-5.0, 0.0, 0.0])                 # out
    assert w.robots['a'].inside == set()
    ev = w.update_pose('a', [-1.0, 0.0, 0.0])            # in again
    assert ev['crashed'] == [oid] and w.stats()['crashes'] == 2


def test_entering_two_overlapping_discs_counts_two_crashes_in_id_order():
    w = bare_world()
    ids = place(w, (0.5, 0.0), (-0.5, 0.0))
    ev = w.update_pose('a', [0.0, 0.0, 0.0])
    assert ev['crashed'] == sorted(ids) and w.stats()['crashes'] == 2


def test_crashes_are_per_robot():
    w = bare_world(robots=('a', 'b'))
    place(w, (0.0, 0.0))
    w.update_pose('a', [0.0, 0.0, 0.0])
    w.update_pose('b', [0.0, 0.5, 0.0])
    assert w.robots['a'].crashes == 1 and w.robots['b'].crashes == 1
    assert w.stats()['crashes'] == 2


# ---- trips and goals -------------------------------------------------------------------
def test_first_goal_is_on_the_far_side_from_the_start():
    w = bare_world(robots=('left', 'right', 'centre', 'right_of_centre'))
    w.update_pose('left', [-17.0, 5.0, 0.0])
    w.update_pose('right', [10.0, -5.0, math.pi])
    w.update_pose('centre', [0.0, 3.0, 0.0])               # x <= 0 counts as the left side
    w.update_pose('right_of_centre', [0.5, -3.0, 0.0])
    gx = w.config.goal_x
    assert w.robots['left'].goal[0] == gx and w.robots['left'].side == 1
    assert w.robots['right'].goal[0] == -gx and w.robots['right'].side == -1
    assert w.robots['centre'].goal[0] == gx
    assert w.robots['right_of_centre'].goal[0] == -gx
    assert w.stats()['trips'] == 0


def test_goal_y_is_random_within_the_field_less_two_metres():
    w = bare_world()
    w.update_pose('a', [-17.0, 0.0, 0.0])
    ys = [w.new_goal('a')[1] for _ in range(2000)]         # seeded: the same draws every run
    limit = w.config.half_height - 2.0
    assert max(ys) <= limit and min(ys) >= -limit
    assert max(ys) > limit - 0.1 and min(ys) < -limit + 0.1   # spread over the whole range
    assert len(set(ys)) == len(ys)


def test_robots_draw_their_goals_independently():
    """Each robot has its own goal stream: two robots do not get the same goals (their
    trips would run in step), and one robot's draws do not shift another's."""
    def goals(names, who, k):
        w = World(WorldConfig(n_obstacles=0), names, seed=5)
        for n in names:
            w.update_pose(n, [-17.0, 0.0, 0.0])
        return [float(w.new_goal(who)[1]) for _ in range(k)]
    a, b = goals(['a', 'b'], 'a', 5), goals(['a', 'b'], 'b', 5)
    assert a != b
    assert goals(['a', 'b', 'c'], 'b', 5) == b    # another robot in the team changes nothing


def test_trip_counts_exactly_at_the_goal_line_and_only_once():
    w = bare_world()
    gx = w.config.goal_x
    w.update_pose('a', [-17.0, 0.0, 0.0])
    assert not w.update_pose('a', [gx - 1e-6, 0.0, 0.0])['trip']
    assert w.update_pose('a', [gx, 0.0, 0.0])['trip']
    assert w.robots['a'].side == -1 and w.robots['a'].goal[0] == -gx
    assert not w.update_pose('a', [gx + 1.0, 0.0, 0.0])['trip']     # already across
    assert not w.update_pose('a', [-gx + 1e-6, 0.0, math.pi])['trip']
    assert w.update_pose('a', [-gx, 0.0, math.pi])['trip']
    assert w.stats()['trips'] == 2


def test_a_pose_of_the_wrong_size_or_nan_is_refused():
    w = bare_world()
    for bad in ([0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [math.inf, 0.0, 0.0], [0.0, math.nan, 0.0]):
        with pytest.raises(ValueError):
            w.update_pose('a', bad)
    assert w.robots['a'].position is None


# ---- detections and the false-positive rule ---------------------------------------------
def test_detection_names_an_obstacle_within_its_tolerance_only():
    w = bare_world(detection_tolerance=0.5)
    (oid,) = place(w, (2.0, 3.0))
    w.update_detections('a', [[2.0, 3.49]], 0.0)
    assert w.had_detected('a', oid)
    w.update_detections('a', [[2.0, 3.5]], 0.0)           # exactly at the tolerance: named
    assert w.had_detected('a', oid)
    w.update_detections('a', [[2.0, 3.51]], 0.0)
    assert not w.had_detected('a', oid)
    w.update_detections('a', [[9.0, 9.0], [2.3, 3.3]], 0.0)   # any detection may name it
    assert w.had_detected('a', oid)
    w.update_detections('a', np.zeros((0, 2)), 0.0)
    assert not w.had_detected('a', oid)


def test_detections_are_replaced_not_accumulated_and_nan_is_refused():
    w = bare_world()
    (oid,) = place(w, (0.0, 0.0))
    w.update_detections('a', [[0.0, 0.0]], 1.0)
    w.update_detections('a', [[5.0, 5.0]], 2.0)
    assert not w.had_detected('a', oid) and w.robots['a'].detections_time == 2.0
    with pytest.raises(ValueError):
        w.update_detections('a', [[0.0, math.nan]], 3.0)
    assert w.robots['a'].detections_time == 2.0


def test_no_robot_near_means_false_positive():
    w = bare_world(near_distance=6.0)
    (oid,) = place(w, (0.0, 0.0))
    w.update_pose('a', [-10.0, 0.0, 0.0])
    fp, near, undetected = w.classify(oid)
    assert fp and near == () and undetected == ()


def test_a_near_robot_that_missed_it_makes_the_intervention_needed():
    w = bare_world(near_distance=6.0)
    (oid,) = place(w, (0.0, 0.0))
    w.update_pose('a', [-5.9, 0.0, 0.0])
    fp, near, undetected = w.classify(oid)
    assert not fp and near == ('a',) and undetected == ('a',)
    w.update_detections('a', [[0.0, 0.0]], 0.0)
    assert w.classify(oid)[0]


def test_near_distance_is_inclusive_and_robots_without_a_pose_are_not_near():
    w = bare_world(robots=('edge', 'ghost'), near_distance=6.0)
    (oid,) = place(w, (0.0, 0.0))
    w.update_pose('edge', [-6.0, 0.0, 0.0])
    assert w.classify(oid)[1] == ('edge',)
    w.update_pose('edge', [-6.01, 0.0, 0.0])
    assert w.classify(oid)[1] == ()


def test_intervention_removes_the_obstacle_and_forgets_being_inside_it():
    w = bare_world()
    (oid,) = place(w, (0.0, 0.0))
    w.update_pose('a', [0.0, 0.0, 0.0])
    rec, new_id = w.intervene(oid, time=4.5, robot='a', respawn=False)
    assert new_id is None and oid not in w.obstacles and w.robots['a'].inside == set()
    assert (rec.obstacle_id, rec.robot, rec.time) == (oid, 'a', 4.5)
    assert not rec.false_positive
    s = w.stats()
    assert s['interventions'] == 1 and s['false_positives'] == 0
    assert s['score'] == -w.config.intervention_penalty - w.config.crash_penalty


def test_respawn_keeps_the_spacing_from_other_obstacles_and_the_robots():
    for seed in range(5):
        w = World(WorldConfig(), ['a', 'b'], seed=seed)
        w.update_pose('a', [-10.0, 0.0, 0.0])
        w.update_pose('b', [10.0, 5.0, 0.0])
        ids, _ = w.obstacle_arrays()
        _, new_id = w.intervene(int(ids[0]), time=1.0)
        c = w.config
        others = np.array([p for i, p in w.obstacles.items() if i != new_id])
        p = w.obstacles[new_id]
        assert np.min(np.hypot(*(others - p).T)) >= 2 * c.radius + c.spacing
        for r in w.robots.values():
            assert np.hypot(*(r.position[:2] - p)) >= c.respawn_clearance
        assert abs(p[0]) <= c.goal_x - c.goal_margin and abs(p[1]) <= c.half_height - c.radius
        assert w.relaxed_spawns == 0


def test_a_crowded_field_relaxes_the_spacing_and_says_so():
    w = World(WorldConfig(n_obstacles=40, max_tries=50), ['a'], seed=0)
    assert len(w.obstacles) == 40 and w.relaxed_spawns > 0


def test_obstacle_arrays_follow_every_change():
    w = bare_world()
    ids = place(w, (1.0, 1.0), (5.0, 5.0))
    got_ids, xy = w.obstacle_arrays()
    assert got_ids.tolist() == ids and xy.tolist() == [[1.0, 1.0], [5.0, 5.0]]
    w.intervene(ids[0], time=0.0, respawn=False)
    got_ids, xy = w.obstacle_arrays()
    assert got_ids.tolist() == [ids[1]] and xy.tolist() == [[5.0, 5.0]]


# ---- scene resets and the robot finder ----------------------------------------------
def test_set_obstacles_replaces_everything_with_fresh_ids():
    w = World(WorldConfig(n_obstacles=3), ['a'], seed=0)
    before = set(w.obstacles)
    w.update_pose('a', list(w.obstacles[min(before)]) + [0.0])    # inside one
    new = w.set_obstacles([[0.0, 0.0], [4.0, 0.0]])
    assert set(w.obstacles) == set(new) and not (before & set(new))
    assert new == sorted(new) and new[0] > max(before)
    assert w.robots['a'].inside == set()
    with pytest.raises(ValueError):
        w.set_obstacles([[0.0, math.inf]])
    assert set(w.obstacles) == set(new)                           # unchanged on bad input


def test_robot_at_finds_the_closest_within_the_tolerance():
    w = bare_world(robots=('c', 'a', 'b'))                 # c has no pose and comes first
    w.update_pose('a', [0.0, 0.0, 0.0])
    w.update_pose('b', [0.6, 0.0, 0.0])
    assert w.robot_at([0.4, 0.0]) == 'b'
    assert w.robot_at([-0.9, 0.0]) == 'a'
    assert w.robot_at([-1.0, 0.0], tolerance=1.0) == 'a'          # inclusive
    assert w.robot_at([-1.01, 0.0], tolerance=1.0) is None
    assert w.robot_at([5.0, 5.0], tolerance=10.0) == 'b'
    assert w.robot_at([1.8, 0.0]) is None                          # default tolerance 1 m
    assert w.robot_at([1.8, 0.0], tolerance=1.3) == "b"


def test_obstacle_ids_start_at_zero_and_are_consecutive():
    w = World(WorldConfig(n_obstacles=4), ['a'])
    assert sorted(w.obstacles) == [0, 1, 2, 3]
    assert w.set_obstacles([[0.0, 0.0], [5.0, 0.0]]) == [4, 5]
    assert w.intervene(4, time=0.0)[1] == 6


def test_the_default_seed_is_zero():
    a, b = World(WorldConfig(), ['a']), World(WorldConfig(), ['a'], seed=0)
    assert all(np.array_equal(a.obstacles[i], b.obstacles[i]) for i in a.obstacles)


def test_an_impossible_clearance_is_halved_once_per_round_until_a_place_is_found():
    """Clearance 24 m from a robot at the centre fits nowhere between the goal lines;
    halved once (12 m) it fits, so each respawn relaxes exactly once."""
    w = World(WorldConfig(n_obstacles=2, respawn_clearance=24.0), ['a'], seed=0)
    w.update_pose('a', [0.0, 0.0, 0.0])
    for k in (1, 2):
        _, new_id = w.intervene(min(w.obstacles), time=float(k))
        assert np.hypot(*w.obstacles[new_id]) >= 12.0
        assert w.relaxed_spawns == k


def test_a_clearance_that_needs_many_halvings_still_terminates():
    w = World(WorldConfig(n_obstacles=2, respawn_clearance=500.0), ['a'], seed=0)
    w.update_pose('a', [0.0, 0.0, 0.0])
    _, new_id = w.intervene(0, time=0.0)
    assert new_id in w.obstacles and w.relaxed_spawns >= 5


# ---- configuration ----------------------------------------------------------------------
@pytest.mark.parametrize('bad', [
    dict(half_width=0.0), dict(half_height=-1.0), dict(goal_x=math.nan), dict(radius=0.0),
    dict(near_distance=math.inf), dict(detection_tolerance=0.0),
    dict(goal_x=20.0, half_width=20.0), dict(goal_x=5.0, goal_margin=3.2, radius=1.8),
    dict(goal_x=4.0, goal_margin=2.0, radius=2.0), dict(n_obstacles=-1)])
def test_config_refuses_impossible_fields(bad):
    with pytest.raises(ValueError):
        WorldConfig(**bad)


def test_config_accepts_the_limits():
    WorldConfig(goal_x=19.9, half_width=20.0)
    WorldConfig(goal_x=5.0, goal_margin=3.1, radius=1.8)
    WorldConfig(n_obstacles=0)


def test_the_world_needs_a_robot():
    with pytest.raises(ValueError):
        World(WorldConfig(), [])


def test_a_world_of_several_sizes_counts_each_obstacle_by_its_own_radius():
    from supersafe_ros.sim.world import World, WorldConfig
    cfg = WorldConfig(n_obstacles=6, radii=(0.8, 1.8, 2.6))
    w = World(cfg, ['r0'], seed=3)
    ids, xy = w.obstacle_arrays()
    assert cfg.radius_of(ids).tolist() == [0.8, 1.8, 2.6, 0.8, 1.8, 2.6]
    big = int(ids[2])
    centre = xy[2]
    assert w.update_pose('r0', (centre[0] + 2.0, centre[1], 0.0))['crashed'] == [big], 'inside 2.6 (not 1.8)'
    small = int(ids[0])
    w.update_pose('r0', (-30.0, 0.0, 0.0))
    assert w.update_pose('r0', (xy[0][0] + 1.0, xy[0][1], 0.0))['crashed'] == [], 'outside 0.8'
    assert small != big
    assert WorldConfig().radii == () and WorldConfig().radius_of([0, 5]).tolist() == [1.8, 1.8], 'the study\'s world'
    assert WorldConfig(radii=(0.0,)).radii == (), "config/world.yaml's [0.0]: one radius"
    with pytest.raises(ValueError, match='radii'):
        WorldConfig(radii=(1.0, -1.0))
