"""The filter law as the robots obey it (``filter.law`` through ``step_many``): with no hold
(lookahead 0, no delay compensation) and no hysteresis it is the paper's minimally invasive
law, override iff V <= alpha with u* = w_max sign(dV/dtheta), the smallest V governing."""
import numpy as np
import pytest

from supersafe_ros.filter import OVERRIDE, PASS, FilterConfig, RobotFilter, SafeSet, step_many
from supersafe_ros.filter.law import avoid_turn_at
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.value_function import ValueFunction

GRID = Grid((-4, -3), (4, 5), (17, 21, 12))
T = 10.0
PLANNED = 0.25      # the planner's command: what a pass forwards


def robot(pose, obstacles, omega_max=1.0):
    """A robot at ``pose`` (map) seeing discs at ``obstacles``: the law alone (no hold, no
    propagation, no clusters, no hysteresis)."""
    cfg = FilterConfig(omega_max=omega_max, lookahead=0.0, compensate_delay=False, clusters=False,
                       clear_margin=0.0)
    f = RobotFilter(cfg)
    f.update_pose(pose, T)
    f.update_detections(np.array(obstacles, dtype=float).reshape(-1, 2), T)
    f.update_command(PLANNED, T)
    return f


def uphill_vf():
    X, Y, TH = GRID.mesh()
    return ValueFunction(GRID, X + 0.5 * np.sin(TH))       # V grows with theta near theta = 0


def test_it_overrides_at_the_level_set_and_turns_uphill():
    vf = uphill_vf()
    states = [(2.0, 0.0, 0.0), (0.1, 0.0, 0.0), (-1.0, 0.0, np.pi / 2 + 0.3), (50.0, 0.0, 0.0)]
    out = step_many([robot(s, [(0.0, 0.0)]) for s in states], SafeSet(vf, 0.5), T)
    assert [o.action for o in out] == [PASS, OVERRIDE, OVERRIDE, PASS]
    assert out[1].omega == 1.0            # dV/dth = 0.5 cos(0) > 0
    assert out[2].omega == -1.0           # past pi/2, V falls with theta
    assert out[0].omega == PLANNED and out[3].omega == PLANNED
    assert out[3].value == np.inf         # off the grid: far from the obstacle
    with pytest.raises(ValueError):
        robot((np.nan, 0.0, 0.0), [(0.0, 0.0)])


def test_the_smallest_value_over_the_obstacles_governs():
    vf = uphill_vf()
    heading = np.pi / 2 + 0.6
    # obstacle 1 at relative (-0.2, 0): V ~ 0.1, overriding, turning right; 0 and 2 clear (relative x > 3)
    f = robot((0.0, 0.0, heading), [(-3.5, 0.0), (0.2, 0.0), (-3.8, 0.5)])
    out = step_many([f], SafeSet(vf, 0.5), T)[0]
    assert out.action == OVERRIDE and out.omega == -1.0 and out.obstacle_index == 1
    assert out.value == pytest.approx(float(vf.value(np.array([[-0.2, 0.0, heading]]))[0]))
    clear = step_many([robot((0.0, 0.0, 0.0), [(-1.5, 0.0), (-3.5, 0.0)])], SafeSet(vf, 0.5), T)[0]
    assert clear.action == PASS and clear.obstacle_index == 0       # it names the smallest V
    assert clear.value == pytest.approx(float(vf.value(np.array([[1.5, 0.0, 0.0]]))[0]))


def test_a_robot_without_detections_is_unconstrained_beside_one_that_overrides():
    vf = uphill_vf()
    out = step_many([robot((0.0, 0.0, 0.0), []), robot((-0.2, 0.0, np.pi / 2 + 0.6), [(0.0, 0.0)])],
                    SafeSet(vf, 0.5), T)
    assert [o.action for o in out] == [PASS, OVERRIDE]
    assert out[0].omega == PLANNED and out[0].value == np.inf and out[1].omega == -1.0


def test_it_is_vectorised_over_thousands_of_robots():
    vf = uphill_vf()
    rng = np.random.default_rng(1)
    states = np.stack([rng.uniform(-4, 4, 3000), rng.uniform(-3, 5, 3000), rng.uniform(-3, 3, 3000)], -1)
    out = step_many([robot(s, [(0.0, 0.0)]) for s in states], SafeSet(vf, 0.0), T)
    v = vf.value(states)
    assert np.array_equal(np.array(out.action) == OVERRIDE, v <= 0.0)


def test_it_acts_at_the_level_itself_with_the_robots_bound():
    vf = uphill_vf()
    states = [(0.5, 0.0, 0.4), (3.0, 0.0, 0.0)]
    level = float(vf.value(np.array(states[:1]))[0])
    out = step_many([robot(s, [(0.0, 0.0)], omega_max=2.0) for s in states], SafeSet(vf, level), T)
    assert [o.action for o in out] == [OVERRIDE, PASS]          # V == alpha exactly: override
    assert out[0].omega == 2.0 and out[1].omega == PLANNED      # the robot's w_max; the planner's command


def test_a_ridge_in_theta_turns_left():
    """dV/dtheta = 0 on the nodes at theta = 0 (V symmetric in theta): a tie, turned left."""
    X, Y, TH = GRID.mesh()
    vf = ValueFunction(GRID, X - 0.3 * np.cos(TH))
    out = step_many([robot(s, [(0.0, 0.0)]) for s in ((-1.0, 0.0, 0.0), (-1.0, 0.5, 0.0))], SafeSet(vf, 10.0), T)
    assert [o.omega for o in out] == [1.0, 1.0]


def test_a_tie_is_judged_relative_to_the_gradients_scale():
    """V scaled by 1e4: a dV/dtheta of -0.01 next to the ridge is round-off (a tie: left);
    on the unscaled V the same relative slope would be -1e-6."""
    X, Y, TH = GRID.mesh()
    vf = ValueFunction(GRID, 1e4 * (X - 0.3 * np.cos(TH)))
    dth = GRID.spacing[2]
    g_next = 1e4 * 0.3 * np.sin(dth)             # dV/dtheta at the next heading node (approximately)
    eps = 0.01 * dth / g_next                     # interpolated slope about -0.01 at theta = -eps
    out = step_many([robot((-1.0, 0.0, th), [(0.0, 0.0)]) for th in (-eps, -0.5 * dth)], SafeSet(vf, 1e6), T)
    assert [o.omega for o in out] == [1.0, -1.0]          # a real slope still turns its way
    assert [avoid_turn_at(vf, -1.0, 0.0, th) for th in (-eps, -0.5 * dth)] == [1.0, -1.0]   # one state at a time
