"""filter.approach: the speed a robot that can stop may drive without its path entering a disc."""
import math

import numpy as np
import pytest

from supersafe_ros.filter import FilterConfig, RobotFilter, SafeSet
from supersafe_ros.filter.approach import allowed_speeds, path_distance
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.sets import Disc
from supersafe_ros.reach.solver import solve_avoid


def sampled_distance(x, y, th, v, w, tau, cx, cy, n=20001):
    """The least distance to (cx, cy) of n points of the path, by the unicycle's flow."""
    t = np.linspace(0.0, tau, n)
    if w == 0.0:
        px, py = x + v * t * math.cos(th), y + v * t * math.sin(th)
    else:
        px = x + v / w * (np.sin(th + w * t) - math.sin(th))
        py = y - v / w * (np.cos(th + w * t) - math.cos(th))
    return float(np.hypot(px - cx, py - cy).min())


def test_path_distance_is_the_paths_least_distance():
    """Exact on arcs, segments, nearly straight arcs and turns past a full circle: never above
    the least distance of 20,001 points of the path (a lower bound: sound), within their spacing."""
    rng = np.random.default_rng(0)
    for _ in range(400):
        x, y, th = rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-4, 4)
        v, tau = rng.uniform(0, 3), rng.uniform(0.05, 5.0)
        w = float(rng.choice([0.0, 1e-6, -1e-6, rng.uniform(-2, 2)]))
        cx, cy = rng.uniform(-5, 5, 2)
        exact = float(path_distance(x, y, th, v, w, tau, cx, cy))
        sampled = sampled_distance(x, y, th, v, w, tau, cx, cy)
        assert exact <= sampled + 1e-9
        assert sampled - exact <= v * tau / 20000 + 1e-5


def one(state, speed, turn, tau, discs):
    discs = np.asarray(discs, dtype=float).reshape(-1, 3)
    v, blocker, away, _ = allowed_speeds(np.array([state], dtype=float), np.array([speed]), np.array([turn]),
                                         np.array([tau]), [discs[:, :2]], [discs[:, 2]])
    return float(v[0]), int(blocker[0]), float(away[0])


def test_a_path_that_would_enter_a_disc_within_tau_is_slowed_one_that_clears_keeps_its_speed():
    disc = [(2.0, 0.0, 1.0)]                     # its rim 1 m ahead
    v, blocker, _ = one((0, 0, 0), 3.0, 0.0, 0.5, disc)       # 1.5 m in 0.5 s: into it
    assert 0.0 < v <= 2.0 and blocker == 0
    assert path_distance(0, 0, 0, v, 0.0, 0.5, 2.0, 0.0) >= 1.0
    assert one((0, 0, 0), 3.0, 0.0, 0.3, disc)[0] == 3.0     # 0.9 m in 0.3 s: short of it
    assert one((0, 0, math.pi / 2), 3.0, 0.0, 0.5, disc)[0] == 3.0   # driving past it


def test_slower_is_a_tighter_arc_the_largest_clear_speed_is_sent():
    """Turning left at 1 rad/s beside a disc on the left: at full speed the wide arc passes
    it, slower arcs curl into it; the full speed is kept (the clear speeds need not be an
    interval)."""
    disc = [(1.0, 1.0, 0.3)]                     # on the arc of radius 1 (1 m/s at 1 rad/s)
    assert path_distance(0, 0, 0, 3.0, 1.0, 2.0, 1.0, 1.0) >= 0.3
    assert path_distance(0, 0, 0, 1.0, 1.0, 2.0, 1.0, 1.0) < 0.3
    assert one((0, 0, 0), 3.0, 1.0, 2.0, disc)[0] == 3.0


def test_speed_zero_is_always_allowed_and_the_robot_turns_away():
    """Against a disc's rim, heading into it: stopped, turning away from the side it is on."""
    v, blocker, away = one((0, 0, 0.1), 3.0, 0.0, 0.2, [(1.01, 0.0, 1.0)])
    assert v == 0.0 and blocker == 0 and away == 1.0          # the disc is right of the heading: turn left
    assert one((0, 0, -0.1), 3.0, 0.0, 0.2, [(1.01, 0.0, 1.0)])[2] == -1.0


def test_inside_a_disc_the_robot_may_back_out_but_not_go_deeper():
    disc = [(0.5, 0.0, 1.0)]                     # the robot's centre is 0.5 m inside its rim
    assert one((0, 0, math.pi), 3.0, 0.0, 0.2, disc)[0] == 3.0   # away from its centre
    assert one((0, 0, 0.0), 3.0, 0.0, 0.2, disc)[0] == 0.0       # toward it


def test_never_faster_than_asked_and_bounded_work_for_a_scan_of_discs():
    """Many robots among thousands of discs: each speed in [0, asked], each path clear."""
    rng = np.random.default_rng(1)
    m, k = 50, 2000
    states = np.column_stack([rng.uniform(-20, 20, (m, 2)), rng.uniform(-np.pi, np.pi, m)])
    asked = rng.uniform(0, 3, m)
    turns = rng.uniform(-1, 1, m)
    discs = [rng.uniform(-25, 25, (k, 2)) for _ in range(m)]
    radii = [rng.uniform(0.1, 0.3, k) for _ in range(m)]
    # the robots outside every disc, as the limiter keeps them
    for i in range(m):
        keep = np.hypot(*(discs[i] - states[i, :2]).T) > radii[i] + 0.01
        discs[i], radii[i] = discs[i][keep], radii[i][keep]
    v, _, _, _ = allowed_speeds(states, asked, turns, np.full(m, 0.5), discs, radii)
    assert np.all(v >= 0.0) and np.all(v <= asked)
    assert (v < asked).any() and (v > 0).any()
    for i in range(m):
        d = path_distance(states[i, 0], states[i, 1], states[i, 2], v[i], turns[i], 0.5, discs[i][:, 0],
                          discs[i][:, 1])
        assert np.all(d >= radii[i])


@pytest.fixture(scope='module')
def standard():
    vf = solve_avoid(Grid((-8, -8), (8, 8), (41, 41, 24)), DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=3.0)
    return SafeSet(vf, 0.0, 'standard')


def test_the_filter_cuts_the_planners_speed_and_says_so(standard):
    """A robot passing (V above alpha beside a small disc) whose planner's path would enter
    it within tau: the speed is cut, the reason says so; off (0), the law's speed goes out."""
    for tbc, cut in ((0.0, False), (2.0, True)):
        f = RobotFilter(FilterConfig(time_before_collision=tbc, control_period=0.1))
        f.update_pose((0.0, 0.0, 0.0), 0.0)
        f.update_detections(np.array([[4.0, 0.0, 0.2]]), 0.0)
        f.update_command(0.0, 0.0, 3.0)
        out = f.step(standard, 0.0)
        assert 0.0 <= out.linear <= 3.0
        assert (out.linear < 3.0) == cut, out
        assert (out.reason.startswith('slowing to') or out.reason.startswith('stopped, turning')) == cut, out.reason


def test_a_constant_speed_robot_cannot_take_it():
    with pytest.raises(ValueError, match='time_before_collision'):
        FilterConfig(fail_safe_command='stop_turn', time_before_collision=0.5)
