"""ROS-free tests of the simulation core: robot, sensor, world, planner, supervisor watcher."""
import math

import numpy as np
import pytest

from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.value_function import ValueFunction
from supersafe_ros.sim import LossySensor, RobotSim, World, WorldConfig, goal_seeking_turn_rate
from supersafe_ros.sim.watcher import Watcher


# ----- robot ----------------------------------------------------------------------------
def test_robot_drives_straight_and_on_exact_arcs():
    r = RobotSim([0.0, 0.0, 0.0], speed=3.0, omega_max=1.0, command_timeout=10.0)
    r.advance(0.0)
    r.command(0.0, 0.0)
    r.advance(2.0)
    assert r.state == pytest.approx([6.0, 0.0, 0.0])
    # a quarter circle at u = 1: radius 3, from (6, 0) heading 0 to (9, 3) heading pi/2
    r.command(1.0, 2.0)
    for k in range(1, 11):                     # uneven steps, same arc
        r.advance(2.0 + (math.pi / 2) * (k / 10) ** 2)
    assert r.state == pytest.approx([9.0, 3.0, math.pi / 2], abs=1e-9)


def test_robot_clips_turn_rate_and_rejects_nan():
    r = RobotSim([0.0, 0.0, 0.0], omega_max=1.0)
    assert r.command(5.0, 0.0) == 1.0
    assert r.command(-7.0, 0.0) == -1.0
    with pytest.raises(ValueError):
        r.command(float('nan'), 0.1)
    assert r.last_command == -1.0              # the previous command stays in force


def test_robot_parked_until_first_command_then_loiters_on_timeout():
    r = RobotSim([1.0, 2.0, 0.5], speed=3.0, omega_max=1.0, command_timeout=0.5)
    r.advance(0.0)
    r.advance(1.0)
    assert r.mode(1.0) == 'parked'
    assert r.state == pytest.approx([1.0, 2.0, 0.5])
    r.command(0.0, 1.0)
    r.advance(1.5)
    assert r.mode(1.5) == 'commanded'
    r.advance(1.6)
    assert r.mode(1.6) == 'timeout'
    start = r.state.copy()
    for k in range(1, 200):
        r.advance(1.6 + 0.05 * k)
        # loitering at w_max keeps it on a circle of radius v / w_max = 3
        assert np.hypot(*(r.state[:2] - start[:2])) <= 6.0 + 1e-9


def test_robot_sim_time_jump_moves_at_most_one_step_then_pauses():
    step, speed = 0.1, 3.0
    r = RobotSim([0.0, 0.0, 0.0], speed=speed, omega_max=1.0, command_timeout=0.5, max_step=step)
    r.advance(0.0)
    t = 0.0
    for _ in range(10):                        # normal steps: full motion
        r.command(0.0, t)
        t += step
        r.advance(t)
    assert r.state[0] == pytest.approx(10 * step * speed)
    assert r.paused == 0.0
    # sim time jumps 0.7 s (the clock went on without this robot): one step of motion
    r.command(0.0, t)
    before = r.state.copy()
    t += 0.7
    r.advance(t)
    moved = np.hypot(*(r.state[:2] - before[:2]))
    assert moved == pytest.approx(speed * step)          # not 0.7 * 3 = 2.1 m
    assert r.last_pause == pytest.approx(0.6) and r.paused == pytest.approx(0.6)
    # the pause does not age the command: still commanded, no loiter after the jump
    assert r.mode(t) == 'commanded'
    # a jump under a turn command: one step of the arc, as the filter judged it
    r.command(1.0, t)
    before = r.state.copy()
    r.advance(t + 5.0)
    assert r.state[2] - before[2] == pytest.approx(1.0 * step)
    assert np.hypot(*(r.state[:2] - before[:2])) <= speed * step + 1e-12
    with pytest.raises(ValueError):
        RobotSim([0.0, 0.0, 0.0], max_step=0.0)


def test_robot_rejects_bad_parameters():
    with pytest.raises(ValueError):
        RobotSim([0.0, float('nan'), 0.0])
    with pytest.raises(ValueError):
        RobotSim([0.0, 0.0, 0.0], speed=-1.0)
    with pytest.raises(ValueError):
        RobotSim([0.0, 0.0, 0.0], timeout_behavior='spin')


def test_a_robot_that_follows_its_speed_drives_the_commanded_arc_at_it_and_stops_when_told():
    r = RobotSim([0.0, 0.0, 0.0], speed=3.0, omega_max=1.0, follow_speed=True, timeout_behavior='stop')
    fixed = RobotSim([0.0, 0.0, 0.0], speed=3.0, omega_max=1.0)
    r.advance(0.0)
    fixed.advance(0.0)
    r.command(0.5, 0.0, linear=1.0)
    fixed.command(0.5, 0.0)
    r.advance(0.2)
    fixed.advance(0.2)
    assert r.state[2] == pytest.approx(fixed.state[2]), 'the same turn'
    assert np.allclose(r.state[:2], fixed.state[:2] / 3.0), 'a third of the arc at a third of the speed'
    r.command(0.0, 0.2, linear=7.0)            # clipped to [0, speed]
    assert r.linear(0.2) == 3.0
    r.command(0.0, 0.2, linear=-1.0)
    assert r.linear(0.2) == 0.0
    before = r.state.copy()
    r.advance(0.4)
    assert np.allclose(r.state, before), 'linear.x 0: it stands'
    r.command(0.0, 0.4, linear=2.0)
    assert r.linear(1.5) == 0.0, "timed out with 'stop': it stops"
    with pytest.raises(ValueError):
        r.command(0.0, 0.5, linear=float('nan'))


# ----- sensor ---------------------------------------------------------------------------
def test_sensor_range_and_per_trip_misses():
    sensor = LossySensor(sensor_range=5.0, miss_probability=0.2, seed=1)
    ids = np.arange(4)
    xy = np.array([[1.0, 0.0], [4.9, 0.0], [5.1, 0.0], [0.0, -3.0]])
    missed_fraction = []
    for _ in range(3000):
        sensor.new_trip()
        seen_ids, _ = sensor.sense((0.0, 0.0), ids, xy)
        assert 2 not in seen_ids                              # out of range
        again, _ = sensor.sense((0.0, 0.0), ids, xy)
        assert list(again) == list(seen_ids)                  # same draw within a trip
        missed_fraction.append(1 - len(seen_ids) / 3)
    # 3 in-range obstacles x 3000 trips; binomial sd of the mean ~ 0.0042
    assert np.mean(missed_fraction) == pytest.approx(0.2, abs=0.02)


def test_sensor_rejects_mismatched_sizes():
    with pytest.raises(ValueError):
        LossySensor().sense((0, 0), [1, 2], [[0.0, 0.0]])


# ----- world ----------------------------------------------------------------------------
def test_world_places_spaced_obstacles_between_goal_lines():
    cfg = WorldConfig()
    for seed in range(5):
        w = World(cfg, ['robot_0'], seed=seed)
        assert w.relaxed_spawns == 0
    ids, xy = w.obstacle_arrays()
    assert len(ids) == cfg.n_obstacles
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    assert np.min(d[~np.eye(len(xy), dtype=bool)]) >= 2 * cfg.radius + cfg.spacing
    assert np.all(np.abs(xy[:, 0]) <= cfg.goal_x - cfg.goal_margin)
    assert np.all(np.abs(xy[:, 1]) <= cfg.half_height - cfg.radius)


def test_world_counts_trips_alternating_sides_and_one_crash_per_entry():
    cfg = WorldConfig(n_obstacles=0)
    w = World(cfg, ['a'], seed=0)
    w.obstacles[7] = np.array([0.0, 0.0])
    w.update_pose('a', [-cfg.goal_x - 1, 0.0, 0.0])
    assert w.robots['a'].goal[0] == cfg.goal_x
    for x in np.linspace(-cfg.goal_x, cfg.goal_x + 0.1, 400):
        w.update_pose('a', [x, 0.0, 0.0])
    s = w.stats()
    assert s['crashes'] == 1 and s['trips'] == 1
    assert w.robots['a'].goal[0] == -cfg.goal_x             # next trip goes back
    for x in np.linspace(cfg.goal_x, -cfg.goal_x - 0.1, 400):
        w.update_pose('a', [x, 0.0, math.pi])
    s = w.stats()
    assert s['crashes'] == 2 and s['trips'] == 2
    assert s['score'] == 2 * cfg.trip_reward - 2 * cfg.crash_penalty


def test_world_intervention_false_positive_iff_all_near_robots_detected():
    cfg = WorldConfig(n_obstacles=0, near_distance=6.0)
    w = World(cfg, ['a', 'b', 'far'], seed=0)
    w.obstacles[0] = np.array([0.0, 0.0])
    w.obstacles[1] = np.array([0.0, 8.0])
    w.next_id = 2
    w.update_pose('a', [-4.0, 0.0, 0.0])
    w.update_pose('b', [0.0, 3.0, math.pi / 2])
    w.update_pose('far', [-15.0, 10.0, 0.0])
    w.update_detections('a', [[0.1, -0.1]], 1.0)
    w.update_detections('b', [[0.0, 8.0]], 1.0)             # b sees obstacle 1 only
    w.update_detections('far', [], 1.0)
    rec, new_id = w.intervene(0, time=2.0, robot='a')
    assert not rec.false_positive and rec.undetected_by == ('b',)
    assert set(rec.near_robots) == {'a', 'b'}
    assert 0 not in w.obstacles and new_id in w.obstacles
    # the replacement keeps clear of every robot
    for r in w.robots.values():
        assert np.hypot(*(w.obstacles[new_id] - r.position[:2])) >= cfg.respawn_clearance
    # obstacle 1: only b is near (a at distance ~8.9), and b detected it -> false positive
    rec1, _ = w.intervene(1, time=3.0)
    assert rec1.false_positive and rec1.near_robots == ('b',)
    with pytest.raises(KeyError):
        w.intervene(1, time=4.0)
    s = w.stats()
    assert s['interventions'] == 2 and s['false_positives'] == 1
    assert s['score'] == -2 * cfg.intervention_penalty


def test_world_rejects_nan_pose():
    w = World(WorldConfig(), ['a'])
    with pytest.raises(ValueError):
        w.update_pose('a', [float('nan'), 0.0, 0.0])


# ----- planner --------------------------------------------------------------------------
def test_planner_turns_towards_goal_saturated():
    assert goal_seeking_turn_rate([0, 0, 0], [10, 0]) == 0.0
    assert goal_seeking_turn_rate([0, 0, 0], [0, 10], omega_max=1.0) == 1.0
    assert goal_seeking_turn_rate([0, 0, 0], [0, -10], omega_max=0.5) == -0.5
    assert goal_seeking_turn_rate([0, 0, 0], [10, 1], gain=1.0) == pytest.approx(math.atan2(1, 10))
    with pytest.raises(ValueError):
        goal_seeking_turn_rate([0, 0, float('inf')], [1, 1])


def test_planner_reaches_goal_line_in_closed_loop():
    r = RobotSim([-16.0, 8.0, math.pi], command_timeout=1.0)   # facing away from the goal
    r.advance(0.0)
    t = 0.0
    while r.state[0] < 16.0 and t < 60.0:
        r.command(goal_seeking_turn_rate(r.state, [16.0, -5.0]), t)
        t += 0.05
        r.advance(t)
    assert r.state[0] >= 16.0 and t < 20.0


# ----- supervisor watcher ---------------------------------------------------------------
def distance_vf():
    """V = distance - 1.8 (a keep-out disc with no dynamics): easy to reason about."""
    grid = Grid((-8.0, -8.0), (8.0, 8.0), (33, 33, 8))
    X, Y, _ = grid.mesh()
    return ValueFunction(grid, np.hypot(X, Y) - 1.8, {'omega_max': 1.0})


def test_watcher_intervenes_at_its_level_once_per_obstacle():
    w = Watcher(distance_vf(), mu=1.0, sigma=0.0)
    ids, xy = [5], np.array([[10.0, 0.0]])
    hits = []
    for x in np.arange(0.0, 9.0, 0.3):                      # coarse samples
        d = w.judge('a', [x, 0.0, 0.0], x, ids, xy)
        if d is not None:
            hits.append(d)
    assert len(hits) == 1
    d = hits[0]
    assert d.obstacle_id == 5 and d.robot == 'a'
    # the crossing of the level, interpolated between poses 0.05 m apart: V = 1 at x = 7.2
    assert d.value == pytest.approx(1.0, abs=1e-3) and d.threshold == 1.0
    assert d.rel_state == pytest.approx([-2.8, 0.0, 0.0], abs=1e-3)
    assert d.time == pytest.approx(7.2, abs=1e-3)        # time = x in this test
    assert w.judge('b', [9.0, 0.0, 0.0], 9.0, ids, xy) is None   # pending removal
    w.obstacles_changed([])
    assert not w.pending


def test_watcher_noise_is_drawn_per_encounter():
    w = Watcher(distance_vf(), mu=1.0, sigma=0.5, seed=0)
    levels = []
    for trial in range(200):
        ids, xy = [trial], np.array([[0.0, 0.0]])
        for x in np.arange(-7.9, 0.0, 0.05):
            d = w.judge('a', [x, 0.0, 0.0], x, ids, xy)
            if d is not None:
                levels.append(d.threshold)
                assert d.value == pytest.approx(d.threshold, abs=1e-3)   # at the crossing
                break
        w.obstacles_changed([])
    levels = np.array(levels)
    # thresholds ~ N(1, 0.5^2) (one below -1.8 would be hit at once: probability ~1e-8)
    assert len(levels) == 200
    assert np.mean(levels) == pytest.approx(1.0, abs=0.1)
    assert np.std(levels) == pytest.approx(0.5, abs=0.08)


def test_draws_do_not_depend_on_processing_order():
    """Keyed draws: the same seed gives the same misses and thresholds in any order."""
    ids, xy = np.arange(6), np.array([[float(i), 0.0] for i in range(6)])
    a = LossySensor(sensor_range=50.0, miss_probability=0.5, seed=9)
    b = LossySensor(sensor_range=50.0, miss_probability=0.5, seed=9)
    for _ in range(3):
        a.new_trip()
        b.new_trip()
    seen_a = set(a.sense((0, 0), ids, xy)[0].tolist())
    seen_b = set()
    for i in ids[::-1]:                          # one at a time, reversed
        seen_b |= set(b.sense((0, 0), [i], xy[i:i + 1])[0].tolist())
    assert seen_a == seen_b
    w1 = Watcher(distance_vf(), mu=0.0, sigma=1.0, seed=4)
    w2 = Watcher(distance_vf(), mu=0.0, sigma=1.0, seed=4)
    ids, xy = [1, 2], np.array([[0.0, 0.0], [4.0, 4.0]])
    for robot in ('a', 'b'):
        w1.judge(robot, [6.0, 6.0, 0.0], 0.0, ids, xy)     # inside the grid of both
    for robot in ('b', 'a'):
        w2.judge(robot, [6.0, 6.0, 0.0], 0.0, ids, xy)
    assert w1.thresholds == w2.thresholds and len(w1.thresholds) == 4


def test_world_goals_do_not_depend_on_which_robot_finishes_first():
    cfg = WorldConfig(n_obstacles=3)
    goals = []
    for order in (['a', 'b'], ['b', 'a']):
        w = World(cfg, ['a', 'b'], seed=2)
        for name in order:
            w.update_pose(name, [-17.0, 0.0, 0.0])
        for name in order:
            w.update_pose(name, [16.5, 0.0, 0.0])       # both complete a trip
        goals.append({n: tuple(w.robots[n].goal) for n in 'ab'})
    assert goals[0] == goals[1]


def test_world_intervention_with_no_robot_near_is_a_false_positive():
    cfg = WorldConfig(n_obstacles=0, near_distance=6.0)
    w = World(cfg, ['a'], seed=0)
    w.obstacles[0] = np.array([0.0, 0.0])
    w.next_id = 1
    w.update_pose('a', [-10.0, 0.0, 0.0])                   # 10 m away: not near
    rec, _ = w.intervene(0, time=1.0)
    assert rec.near_robots == () and rec.false_positive     # nobody needed saving


def test_the_laser_sees_the_nearest_surface_within_range():
    from supersafe_ros.sim.laser import beam_angles, ray_cast
    angles = beam_angles(4)                           # -pi, -pi/2, 0, pi/2
    r = ray_cast((0.0, 0.0, 0.0), angles, [(5.0, 0.0), (8.0, 0.0), (0.0, -20.0)], [1.0, 2.0, 1.0], 10.0)
    assert r[2] == pytest.approx(4.0), 'the nearer disc hides the farther'
    assert np.isinf(r[1]), 'beyond range_max: no return'
    assert np.isinf(r[0]) and np.isinf(r[3])
    inside = ray_cast((5.0, 0.0, 0.0), angles, [(5.0, 0.0)], [1.0], 10.0)
    assert np.allclose(inside, 1.0), 'from inside a disc: its far side'


def test_the_planner_slows_near_its_goal_and_stops_on_it():
    from supersafe_ros.sim.planner import approach_speed
    assert approach_speed(20.0, 3.0, 8.0, 1.0) == 3.0
    assert approach_speed(4.0, 3.0, 8.0, 1.0) == pytest.approx(1.5)
    assert approach_speed(1.2, 3.0, 8.0, 1.0) == pytest.approx(0.6), 'the floor: it reaches the goal'
    assert approach_speed(0.9, 3.0, 8.0, 1.0) == 0.0
    assert approach_speed(0.5, 3.0, 0.0, 0.0) == 3.0, 'the defaults: the study\'s constant speed'
