"""Tests that kill the mutants of ``supersafe_ros.filter`` that survived the fast tests.

The filter was one module then, filter/core.py, since split into the modules of filter/ that
decide (inputs, gather, commands, propagation, constraints, pairs, cluster_rows, law, outputs, sent,
decide).

Each test names the mutation it guards against (mutation testing with mutmut,
``bash bench/mutation.sh filter``); the equivalent survivors are listed with a reason in
bench/results/mutation.md. ROS-free and fast, like test_filter_robot_filter.py.
"""
import math

import numpy as np
import pytest

from supersafe_ros.filter import FAIL_SAFE, FilterConfig, OVERRIDE, PASS, RobotFilter, SafeSet, step_many

from supersafe_ros.filter.gather import problem
from supersafe_ros.filter.law import evaluate_pairs

from supersafe_ros.filter.propagation import arc_flow
from supersafe_ros.filter.sent import record_sent, segments_since
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.sets import Disc
from supersafe_ros.reach.solver import solve_avoid

from filter_support import OBSTACLE, at, robot as _robot

pytestmark = pytest.mark.usefixtures('decision_path')   # every test: robot alone, and in a fleet
T = 10.0          # a clock that does not start at 0 (t0 = 0 hides sign errors in time differences)


@pytest.fixture(scope='module')
def standard():
    vf = solve_avoid(Grid((-8, -8), (8, 8), (41, 41, 24)), DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=3.0)
    return SafeSet(vf, 0.0, 'standard')


def robot(t=T, **kw):
    """filter_support's robot (as test_filter_robot_filter.py uses it), on a clock that starts at T."""
    return _robot(t=t, **kw)


# -- the planner's command the lookahead judges (_planned_turn) ---------------------------------
# Right of the obstacle's axis heading +x: a left turn (+0.9) held 0.2 s ends near the disc
# (V ~ 0.05), straight on does not (V ~ 0.46). At level 0.25 the lookahead tells them apart.
RIGHT, HOLD, LEVEL = at(-4.0, -1.0, 0.0), 0.2, 0.25


def test_lookahead_judges_a_fresh_command_on_a_clock_not_starting_at_zero(standard):
    """Kills ``t + command.t <= cmd_timeout`` (a fresh command judged as silent when t > 0)."""
    level = SafeSet(standard.vf, LEVEL)
    out = robot(pose=RIGHT, cmd=0.9, lookahead=HOLD).step(level, T)
    assert out.action == OVERRIDE and 'would bring' in out.reason
    out = robot(pose=RIGHT, cmd=0.0, lookahead=HOLD).step(level, T)
    assert out.action == PASS and out.omega == 0.0


def test_a_silent_planners_stale_command_is_judged_as_the_zero_it_becomes(standard):
    """The filter forwards 0 for a silent planner, so the lookahead judges 0, not the stale
    command (kills ``value is not None or age <= timeout``) nor a +1 (kills ``else 1.0``)."""
    level = SafeSet(standard.vf, LEVEL)
    f = robot(pose=RIGHT, cmd=0.9, lookahead=HOLD, control_period=HOLD, cmd_timeout=0.5)
    f.update_pose(RIGHT, T + 1.0)
    f.update_detections(np.array([OBSTACLE]), T + 1.0)
    out = f.step(level, T + 1.0)
    assert out.action == PASS and out.omega == 0.0 and 'planner silent' in out.reason


def test_a_command_exactly_cmd_timeout_old_is_forwarded_and_judged(standard):
    """At age == cmd_timeout the command is still forwarded, so the lookahead must judge it
    (kills ``age < cmd_timeout`` in _planned_turn: it would judge 0 and forward +0.9)."""
    level = SafeSet(standard.vf, LEVEL)
    f = robot(t=0.0, pose=RIGHT, cmd=0.9, lookahead=HOLD, control_period=HOLD, cmd_timeout=0.5)
    f.update_pose(RIGHT, 0.5)
    f.update_detections(np.array([OBSTACLE]), 0.5)
    out = f.step(level, 0.5)
    assert out.action == OVERRIDE and 'would bring' in out.reason
    # and with a harmless command at the same age: forwarded (not silent)
    g = robot(t=0.0, pose=RIGHT, cmd=-0.9, lookahead=HOLD, control_period=HOLD, cmd_timeout=0.5)
    g.update_pose(RIGHT, 0.5)
    g.update_detections(np.array([OBSTACLE]), 0.5)
    out = g.step(level, 0.5)
    assert out.action == PASS and out.omega == -0.9


# -- staleness: problem() and step_many agree at the boundary -----------------------------------
def test_an_input_exactly_timeout_old_is_not_stale(standard):
    """step_many's rule is ``age > timeout``; problem() must say the same (kills ``>=``)."""
    f = robot(t=0.0, pose=at(-7.5, 6.0, 0.0), cmd=0.3, pose_timeout=0.5, detections_timeout=0.5)
    assert problem(f, 0.5)[0] == ''
    assert f.step(standard, 0.5).action == PASS
    # a stale detections input is reported as such, not as a stale pose
    g = robot(t=0.0, pose=at(-7.5, 6.0, 0.0), cmd=0.3, pose_timeout=0.5, detections_timeout=0.25)
    out = g.step(standard, 0.5)
    assert out.action == FAIL_SAFE and 'detections stale' in out.reason


# -- what the robot did since its pose (segments_since) ------------------------------------------
def sent_filter(cmd=None, sent=(), **cfg):
    f = RobotFilter(FilterConfig(**cfg))
    if cmd is not None:
        f.update_command(cmd, T - 1.0)
    for ts, w in sent:
        record_sent(f, w, ts)
    return f


def segments(f, t0, t1):
    return [(w, round(d, 12)) for w, d, _ in segments_since(f, t0, t1)]


def test_segments_carry_the_speed_each_command_was_sent_with():
    """Each arc at the speed recorded with its command; before any: the planner's speed
    (clipped to [0, speed], not given: the speed), else 0, or a constant-speed robot's speed
    (kills a speed taken from the wrong command, and the idle speed's two branches)."""
    f = sent_filter()
    record_sent(f, 0.4, T, 1.0)
    record_sent(f, -0.6, T + 0.1, 2.5)
    assert [v for _, _, v in segments_since(f, T + 0.05, T + 0.3)] == [1.0, 2.5]
    assert [v for _, _, v in segments_since(sent_filter(), T, T + 0.1)] == [0.0]
    assert [v for _, _, v in segments_since(sent_filter(fail_safe_command='stop_turn'), T, T + 0.1)] == [3.0]
    assert [v for _, _, v in segments_since(sent_filter(cmd=0.2), T, T + 0.1)] == [3.0]
    g = sent_filter()
    for linear, v in ((1.5, 1.5), (-2.0, 0.0), (9.0, 3.0)):
        g.update_command(0.2, T - 1.0, linear)
        assert [s for _, _, s in segments_since(g, T, T + 0.1)] == [v]


def test_segments_before_any_command_sent():
    """Nothing sent yet: the planner's command (clipped) held all along, else 0
    (kills ``before = 0.0`` always, ``else 1.0``)."""
    assert segments(sent_filter(), T, T + 0.3) == [(0.0, 0.3)]
    assert segments(sent_filter(cmd=2.5), T, T + 0.3) == [(1.0, 0.3)]
    assert segments(sent_filter(cmd=-0.4), T, T + 0.3) == [(-0.4, 0.3)]


def test_segments_of_an_empty_interval():
    """t1 == t0: nothing was held (kills ``t1 < t0``)."""
    assert segments(sent_filter(cmd=0.4, sent=[(T, 0.4)]), T + 0.2, T + 0.2) == []


def test_segments_with_commands_sent_in_and_after_the_interval():
    """Durations are differences of times (kills ``ts + start``); commands sent at or after t1
    are skipped, not an end of the search (kills ``>`` for ``>=`` and ``break`` for ``continue``)."""
    f = sent_filter(cmd=0.1, sent=[(T, 0.4), (T + 0.1, -0.6), (T + 0.4, 0.9)])
    assert segments(f, T + 0.05, T + 0.25) == [(0.4, 0.05), (-0.6, 0.15)]
    assert segments(f, T + 0.05, T + 0.4) == [(0.4, 0.05), (-0.6, 0.3)]
    assert segments(f, T + 0.15, T + 0.3) == [(-0.6, 0.15)]


def test_pose_propagated_over_two_commands_on_a_clock_not_starting_at_zero(standard):
    """The decision-level consequence of the segment durations (test_filter_robot_filter's propagation
    test starts at t = 0, where ``ts + start`` equals ``ts - start``)."""
    car = DubinsCar(3.0, 1.0)
    f = robot(pose=at(-6.5, 2.0, -0.3), cmd=0.4, lookahead=0.0)
    assert f.step(standard, T).action == PASS
    f.update_command(-0.6, T + 0.1)
    assert f.step(standard, T + 0.1).omega == -0.6
    out = f.step(standard, T + 0.25)
    expected = car.flow(car.flow(np.array([-6.5, 2.0, -0.3]), 0.4, 0.1), -0.6, 0.15)
    assert out.pose_age == pytest.approx(0.25)
    assert out.value == pytest.approx(float(evaluate_pairs(standard.vf, expected[None])[0][0]), abs=1e-9)


# -- arc_flow ------------------------------------------------------------------------------------
def test_arc_flow_is_straight_and_exact_for_negligible_turns():
    """|omega dt| <= 1e-9 takes the straight-line formula: the arc formula would divide a
    cancelled sine difference by a tiny omega (~1e-7 m of error; kills ``omega / dt``)."""
    s = np.array([[0.3, -0.2, 0.7]])
    for w, dt in ((1e-9, 0.1), (2e-9, 0.2), (0.0, 0.1)):
        got = arc_flow(s, np.array([3.0]), np.array([w]), np.array([dt]))[0]
        assert got[0] == pytest.approx(0.3 + 3.0 * dt * np.cos(0.7), abs=1e-12)
        assert got[1] == pytest.approx(-0.2 + 3.0 * dt * np.sin(0.7), abs=1e-12)


# -- the rule at its boundaries (govern): "override when V <= alpha" ------------------------------
def test_value_exactly_at_alpha_overrides(standard):
    """V == alpha is inside the override set (kills ``V < level`` for entering)."""
    pose = at(-6.0, 0.0, 0.0)
    v = robot(pose=pose, lookahead=0.0).step(standard, T).value
    assert 0.0 < v < 5.0
    out = robot(pose=pose, lookahead=0.0).step(SafeSet(standard.vf, v), T)
    assert out.action == OVERRIDE and out.value == v and ' too close (V=' in out.reason


def test_lookahead_value_exactly_at_alpha_overrides(standard):
    """V after the planner's hold == alpha also overrides (kills ``V_next < level``)."""
    from filter_support import pair_values
    rel = np.array([[RIGHT[0] - OBSTACLE[0], RIGHT[1] - OBSTACLE[1], RIGHT[2]]])
    one = np.ones(1)
    _, _, v_next = pair_values(standard.vf, rel, 0.9 * one, HOLD * one, 3.0 * one, one)
    level = float(v_next[0])
    f = robot(pose=RIGHT, cmd=0.9, lookahead=HOLD, control_period=HOLD)
    out = f.step(SafeSet(standard.vf, level), T)
    assert out.value > level
    assert out.action == OVERRIDE and 'would bring' in out.reason


def test_value_exactly_at_alpha_plus_margin_keeps_overriding(standard):
    """Hysteresis: overriding continues while V <= alpha + clear_margin (kills ``<``)."""
    pose = at(-6.0, 0.0, 0.0)
    v = robot(pose=pose, lookahead=0.0).step(standard, T).value
    assert 0.0 < v < 5.0
    f = robot(pose=pose, lookahead=0.0, clear_margin=v)      # alpha 0 + margin v == v exactly
    f.overriding = True
    out = f.step(standard, T)
    assert out.action == OVERRIDE and 'not yet clear' in out.reason


# -- which constraint governs (govern on a hand-made table) ---------------------------------------
def table(rows):
    """A constraint table's columns that govern reads: rows of (robot, position, value, level,
    value_next, sound, group)."""
    from types import SimpleNamespace
    tab = SimpleNamespace()
    cols = list(zip(*rows))
    tab.robot, tab.position = np.array(cols[0], np.intp), np.array(cols[1], np.intp)
    tab.value, tab.level, tab.value_next = (np.array(c, float) for c in cols[2:5])
    tab.sound, tab.group = np.array(cols[5], bool), np.array(cols[6], np.intp)
    return tab


def govern(rows, overriding=False, margin=0.2):
    from supersafe_ros.filter.law import govern
    tab = table(rows)
    k, kind = govern(tab, np.array([overriding]), np.array([margin]), int(tab.group.max()) + 1, 1)
    return int(k[0]), int(kind[0])


INF = np.inf


def test_a_clusters_union_constraint_sets_its_members_aside_whatever_makes_it_act():
    """Two members (rows 0, 1; not sound; group 2) and their cluster's union row (row 2, sound,
    group 2). Whenever the union row acts (enters, looks ahead, or holds its hysteresis) it
    governs, even where a member's own row would enter with a smaller V (kills ``enter & ahead``
    and ``ahead & stay`` in ``acts``)."""
    member = lambda pos, v: (0, pos, v, 0.0, INF, False, 2)     # noqa: E731
    # the union row enters (not ahead): it governs, not the member with the smaller V
    assert govern([member(0, -0.5), member(1, 1.0), (0, 2, -0.1, 0.0, 1.0, True, 2)]) == (2, 1)
    # the union row only looks ahead to its level: still it, as 'ahead'
    assert govern([member(0, -0.2), member(1, 1.0), (0, 2, 0.5, 0.0, -0.1, True, 2)]) == (2, 2)
    # the union row only holds its hysteresis: still it, as 'stay'
    assert govern([member(0, -0.1), member(1, 1.0), (0, 2, 0.1, 0.0, INF, True, 2)], overriding=True) == (2, 3)
    # the union row does not act: the members are judged as lone obstacles
    assert govern([member(0, -0.1), member(1, 1.0), (0, 2, 0.5, 0.0, INF, True, 2)]) == (0, 1)


def test_the_smallest_value_above_its_own_level_governs_across_levels():
    """A lone obstacle (level alpha = 0) and a cluster (level cluster_alpha = 0.3): the smaller
    V - level governs, for entering, the lookahead and the hysteresis (kills ``V + level`` in
    each score)."""
    lone_enter, cluster_enter = (0, 0, -0.1, 0.0, INF, False, 0), (0, 1, 0.1, 0.3, INF, True, 1)
    assert govern([lone_enter, cluster_enter]) == (1, 1)        # 0.1 - 0.3 < -0.1 - 0
    lone_ahead, cluster_ahead = (0, 0, 1.0, 0.0, -0.1, False, 0), (0, 1, 1.0, 0.3, 0.1, True, 1)
    assert govern([lone_ahead, cluster_ahead]) == (1, 2)
    lone_stay, cluster_stay = (0, 0, 0.1, 0.0, INF, False, 0), (0, 1, 0.35, 0.3, INF, True, 1)
    assert govern([lone_stay, cluster_stay], overriding=True) == (1, 3)


# -- the lookahead's reach (pair_values) -------------------------------------------------------
def test_a_long_hold_judges_robots_that_start_off_the_grid(standard):
    """With a 2 s hold at 3 m/s a robot 5 m outside the value's grid (V = +inf now) ends its
    hold on the grid, at V below a high level: the lookahead overrides. Pairs are skipped only
    if two holds (2 speed H, + 1 m) cannot reach the grid (kills ``speed / H`` and ``2 / speed``
    in that reach)."""
    pose = at(-13.0, 0.0, 0.0)
    level = SafeSet(standard.vf, 5.5)
    out = robot(pose=pose, cmd=0.0, lookahead=2.0).step(level, T)
    assert out.value == np.inf
    assert out.action == OVERRIDE and 'would bring' in out.reason
    # a short hold from there cannot reach the grid: the command passes
    assert robot(pose=pose, cmd=0.0, lookahead=0.2).step(level, T).action == PASS


def test_an_override_whose_row_turns_zero_still_sends_a_bounded_turn(standard):
    """The case above overrides by a row whose avoid turn is 0 (V = +inf now and both bangs
    held from the state now end off the grid): the command sent is still a turn rate within
    +-w_max (kills ``bang / turn`` for ``bang * turn`` in law.command, which sends +-inf)."""
    out = robot(pose=at(-13.0, 0.0, 0.0), cmd=0.0, lookahead=2.0).step(SafeSet(standard.vf, 5.5), T)
    assert out.action == OVERRIDE
    assert math.isfinite(out.omega) and abs(out.omega) <= 1.0


@pytest.mark.parametrize('lo, hi', [((-4.0, -14.0), (14.0, 4.0)), ((-14.0, -4.0), (4.0, 14.0))])
def test_lookahead_values_on_lopsided_grids_equal_their_definition(lo, hi):
    """V after the planner's 2 s hold and the better bang's next hold (the smaller), computed
    from the definition with DubinsCar's own flow, for robots all around a grid that is
    neither square nor centred: the shortcut that skips pairs too far to reach the grid must
    skip no pair that reaches it (kills bounds read from the wrong axis)."""
    from filter_support import pair_values
    vf = solve_avoid(Grid(lo, hi, (33, 33, 16)), DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=2.0)
    rng = np.random.default_rng(11)
    n, hold = 3000, 2.0
    rel = np.stack([rng.uniform(lo[0] - 14.0, hi[0] + 14.0, n), rng.uniform(lo[1] - 14.0, hi[1] + 14.0, n),
                    rng.uniform(-np.pi, np.pi, n)], axis=1)
    u = rng.uniform(-1.0, 1.0, n)
    one = np.ones(n)
    value, _, got = pair_values(vf, rel, u, hold * one, 3.0 * one, one)
    car = DubinsCar(3.0, 1.0)
    ahead = car.flow(rel, u, hold)
    best = np.maximum(*(vf.value(car.flow(ahead, w, hold), outside=np.inf) for w in (1.0, -1.0)))
    expected = np.minimum(vf.value(ahead, outside=np.inf), best)
    finite = np.isfinite(expected)
    assert 100 < finite.sum() < n - 100          # both kinds, well mixed
    np.testing.assert_array_equal(np.isfinite(got), finite)
    np.testing.assert_allclose(got[finite], expected[finite], atol=1e-6)
    np.testing.assert_array_equal(value, vf.value(rel, outside=np.inf))     # the law's V, from the same read


@pytest.mark.parametrize('turns', [-5, 5])
def test_an_unwrapped_heading_decides_as_the_wrapped_one(standard, turns):
    """A pose may carry an unwrapped yaw (theta + 2 pi k, e.g. from an odometry integrator):
    the decision is the same as for the wrapped heading (kills a skip shortcut that compares
    theta with the grid's y bounds). The heading is off the grid's heading nodes, where V is
    continuous in theta."""
    level = SafeSet(standard.vf, LEVEL)
    pose = (RIGHT[0], RIGHT[1], 0.1)
    wound = (RIGHT[0], RIGHT[1], 0.1 + 2.0 * np.pi * turns)
    for cmd, action in ((0.9, OVERRIDE), (-0.9, PASS)):
        a = robot(pose=pose, cmd=cmd, lookahead=HOLD, control_period=HOLD).step(level, T)
        b = robot(pose=wound, cmd=cmd, lookahead=HOLD, control_period=HOLD).step(level, T)
        assert a.action == b.action == action and a.omega == b.omega
        assert b.value == pytest.approx(a.value, abs=1e-9)


def test_near_the_grids_edge_the_turn_whose_hold_leaves_the_grid_is_taken(standard):
    """Heading out of the grid near its edge, the right turn's hold ends off the grid (V = +inf:
    farther than the grid from the obstacle) and the left one's on it: the avoid turn is the
    right one, though the law's dV/dtheta says left there (kills judging the holds only where
    both end on the grid)."""
    rel, h = np.array([-7.505, 1.086, -2.59]), 0.2
    car = DubinsCar(3.0, 1.0)
    left, right = (float(standard.vf.value(car.flow(rel, w, h)[None], outside=np.inf)[0]) for w in (1.0, -1.0))
    value, law_turn = evaluate_pairs(standard.vf, rel[None])
    assert np.isfinite(left) and right == np.inf and law_turn[0] == 1.0 and value[0] < 6.0
    out = robot(pose=at(*rel), cmd=0.0, lookahead=h, control_period=h).step(SafeSet(standard.vf, 6.0), T)
    assert out.action == OVERRIDE and ' too close (V=' in out.reason and out.omega == -1.0


# -- which robots are judged, which fail safe, and on what (step_many's input checks) ---------------
@pytest.mark.parametrize('pose_age, det_age', [(0.3, 0.0), (0.0, 0.3), (0.5, 0.0), (0.0, 0.5)])
def test_inputs_older_than_hold_timeout_but_not_stale_are_judged(standard, pose_age, det_age):
    """hold_timeout may be shorter than the staleness timeouts: an input older than it but not
    stale (up to exactly its timeout) is judged like any other, never dropped (kills the quick
    staleness test reading ``t + t_in`` or ``>=``, or sending robots with a pose and detections
    to the full check, which then drops them)."""
    cfg = dict(pose_timeout=0.5, detections_timeout=0.5, hold_timeout=0.2, lookahead=0.0)
    f = RobotFilter(FilterConfig(**cfg))
    f.update_pose(at(-7.5, 6.0, 0.0), 0.5 - pose_age)
    f.update_detections(np.array([OBSTACLE]), 0.5 - det_age)
    f.update_command(0.3, 0.5)
    out = f.step(standard, 0.5)
    assert out.action == PASS and out.omega == 0.3
    # the same on a clock far from 0
    g = RobotFilter(FilterConfig(**cfg))
    g.update_pose(at(-7.5, 6.0, 0.0), T - 0.25 if pose_age else T)
    g.update_detections(np.array([OBSTACLE]), T - 0.25 if det_age else T)
    g.update_command(0.3, T)
    assert g.step(standard, T).action == PASS


@pytest.mark.parametrize('stale', ['pose', 'detections'])
def test_a_last_valid_state_exactly_hold_timeout_old_is_still_avoided_from(standard, stale):
    """Fail safe with the last valid pose and detections up to hold_timeout old, inclusive
    (kills ``<`` for either input)."""
    f = RobotFilter(FilterConfig(pose_timeout=0.5, detections_timeout=0.5, hold_timeout=1.0,
                                 fail_safe_command='stop_turn'))
    f.update_pose(at(-6.0, 3.0, 0.0), 0.0 if stale == 'pose' else 1.0)
    f.update_detections(np.array([OBSTACLE]), 0.0 if stale == 'detections' else 1.0)
    f.update_command(0.0, 1.0)
    out = f.step(standard, 1.0)
    assert out.action == FAIL_SAFE and f'{stale} stale' in out.reason and 'away from obstacle 0' in out.reason
    assert out.linear == 3.0 and abs(out.omega) == 1.0


# -- the output records (_outputs) -----------------------------------------------------------------
def test_the_governing_obstacle_is_named_when_another_has_the_smaller_value(standard):
    """Obstacle 0 governs by the lookahead (the planner's left turn would reach it) while
    obstacle 1 has the smaller V but is not reached: the output names obstacle 0 and turns
    away from it (kills reading only governing rows > 0, which named none and took another
    row's turn)."""
    level = SafeSet(standard.vf, LEVEL)
    other = (RIGHT[0] + 1.5, RIGHT[1] - 2.0)
    cfg = dict(cmd=0.9, lookahead=HOLD, control_period=HOLD, clusters=False)
    alone = robot(pose=RIGHT, **cfg).step(level, T)
    smaller = robot(pose=RIGHT, detections=[other], **cfg).step(level, T)
    assert alone.action == OVERRIDE and smaller.action == PASS and LEVEL < smaller.value < alone.value
    out = robot(pose=RIGHT, detections=[OBSTACLE, other], **cfg).step(level, T)
    assert out.action == OVERRIDE and 'would bring' in out.reason and 'obstacle 0' in out.reason
    assert (out.obstacle_index, out.omega, out.value) == (0, alone.omega, alone.value)


def test_a_set_without_omega_max_in_its_metadata_is_usable(standard):
    """A value function whose metadata lacks omega_max still filters (omega_max_set is NaN)
    (kills converting the missing omega_max with float())."""
    from supersafe_ros.reach.value_function import ValueFunction
    vf = standard.vf
    bare = SafeSet(ValueFunction(vf.grid, vf.values, {k: v for k, v in vf.meta.items() if k != 'omega_max'}), 0.0)
    assert bare.omega_max is None
    for pose, action in ((at(-3.0, 0.6, 0.0), OVERRIDE), (at(-7.5, 6.0, 0.0), PASS)):
        a = robot(pose=pose).step(standard, T)
        b = robot(pose=pose).step(bare, T)
        assert a.action == b.action == action and a.omega == b.omega and np.isnan(b.omega_max_set)


def test_the_loiter_fallback_turns_left_on_an_exact_tie(standard):
    """Heading exactly between the two members of a cluster whose union value is not in force
    (a fallback-only store), the two loiter circles are equally clear: a tie, so the turn is
    left, as everywhere in the filter (kills ``left > right`` in the fallback's turn). The
    circle is clear now (0.2 m) but not after the planner's 0.2 s hold: the fallback governs
    by the lookahead and sets its members' own rows aside."""
    from supersafe_ros.filter.clusters.geometry import ClusterSettings
    from supersafe_ros.filter.clusters.store import ClusterStore
    from supersafe_ros.filter import step_many
    store = ClusterStore(ClusterSettings(), fallback_only=True)
    f = robot(pose=at(-5.0, 0.0, 0.0), detections=[(OBSTACLE[0], OBSTACLE[1] + 4.0), (OBSTACLE[0], OBSTACLE[1] - 4.0)],
              cmd=0.0, lookahead=0.2, control_period=0.2)
    out = step_many([f], standard, T, store)[0]
    assert out.action == OVERRIDE and 'would bring' in out.reason and 'cluster of 2' in out.reason
    assert out.source == 'cluster-fallback' and out.value == pytest.approx(np.hypot(5.0, 1.0) - 4.9)
    assert out.omega == 1.0


def test_new_detections_replace_the_clusters_of_the_old_ones(standard):
    """The cluster frames cached for a detections array are used only for that array: after
    new detections (the pair moved 30 m away) the old cluster no longer constrains the robot
    (kills reusing the cache when the array is not the cached one)."""
    from supersafe_ros.filter.clusters.geometry import ClusterSettings
    from supersafe_ros.filter.clusters.store import ClusterStore
    from supersafe_ros.filter import step_many
    store = ClusterStore(ClusterSettings(), fallback_only=True)
    pair = np.array([(OBSTACLE[0], OBSTACLE[1] + 4.0), (OBSTACLE[0], OBSTACLE[1] - 4.0)])
    f = robot(pose=at(-5.0, 0.0, 0.0), detections=pair, cmd=0.0, lookahead=0.2, control_period=0.2)
    assert step_many([f], standard, T, store)[0].source == 'cluster-fallback'
    f.update_pose(at(-5.0, 0.0, 0.0), T + 0.02)
    f.update_detections(pair + 30.0, T + 0.02)
    f.update_command(0.0, T + 0.02)
    out = step_many([f], standard, T + 0.02, store)[0]
    assert out.action == PASS and out.value > 30.0     # the moved cluster's loiter clearance


def test_a_diagonal_clusters_union_value_is_read_in_its_canonical_frame(standard, monkeypatch):
    """A pair of obstacles on a diagonal (its canonical frame is rotated: sin(angle) != 0, unlike
    the axis-aligned layouts elsewhere): the V the filter reports for the cluster is the union
    value at the robot's state mapped by ``geometry.to_frame`` (kills sign and operator errors
    in the vectorised frame transform). ``RobotFilter.step`` uses the store it is given, not
    the process's default one (here a fallback-only store without the union value)."""
    from supersafe_ros.filter.clusters import store as cluster_store
    from supersafe_ros.filter.clusters.geometry import ClusterSettings, ClusterValue, canonical, to_frame
    from supersafe_ros.filter.clusters.store import ClusterStore, solve_cluster
    from supersafe_ros.filter import step_many
    default = ClusterSettings(radius=1.8, speed=3.0, omega_max=1.0, link=0.0)
    monkeypatch.setitem(cluster_store._STORES, default, ClusterStore(default, fallback_only=True))
    settings = ClusterSettings(cell=0.8, headings=12, reach=5.0, disk_cache=False)
    dets = np.array([OBSTACLE, (OBSTACLE[0] + 3.0, OBSTACLE[1] + 3.0)])
    key, origin, angle, centres = canonical(dets, settings.key_resolution)
    assert abs(np.sin(angle)) > 0.3
    vf, seconds = solve_cluster(settings, centres)
    store = ClusterStore(settings, fallback_only=True)
    store.values[key] = value = ClusterValue(vf, centres, seconds, lower=settings.lower_bound)
    checked = 0
    for pose in (at(-3.0, 1.0, 0.4), at(1.5, -2.5, 1.2), at(4.0, 6.5, -2.0), at(-1.0, 5.0, -0.7)):
        expected = float(value.evaluate(to_frame(np.array(pose), origin, angle))[0][0])
        if not np.isfinite(expected):
            continue
        f = robot(pose=pose, detections=dets, cmd=0.0, lookahead=0.0, cluster_alpha=50.0)
        out = step_many([f], standard, T, store)[0]
        assert out.action == OVERRIDE and out.source == 'cluster'
        assert out.value == pytest.approx(expected, abs=1e-9)
        g = robot(pose=pose, detections=dets, cmd=0.0, lookahead=0.0, cluster_alpha=50.0)
        assert g.step(standard, T, store).value == out.value
        checked += 1
    assert checked >= 3


def test_robots_with_different_cluster_stores_keep_their_own_fallback(standard, monkeypatch):
    """Robots of different turn rates use different default cluster stores (loiter circles of
    radius 3 m and 6 m). Stepped together, each robot's loiter fallback is computed with its
    own store's settings, exactly as when stepped alone (kills selecting every fallback row
    for every store, where the last store's circles win)."""
    from supersafe_ros.filter.clusters import store as cluster_store
    from supersafe_ros.filter.clusters.geometry import ClusterSettings
    from supersafe_ros.filter.clusters.store import ClusterStore
    for w in (1.0, 0.5):       # fallback-only default stores: no background solves in a test
        cfg = FilterConfig(omega_max=w)
        settings = ClusterSettings(radius=cfg.radius, speed=cfg.speed, omega_max=w, link=cfg.cluster_link)
        monkeypatch.setitem(cluster_store._STORES, settings, ClusterStore(settings, fallback_only=True))

    def fleet():
        out = []
        for w, dx in ((1.0, 0.0), (0.5, 100.0)):
            pair = [(OBSTACLE[0] + dx, OBSTACLE[1] + 4.0), (OBSTACLE[0] + dx, OBSTACLE[1] - 4.0)]
            out.append(robot(pose=at(-5.0 + dx, 0.0, 0.0), detections=pair, cmd=0.0, lookahead=0.2,
                             control_period=0.2, omega_max=w))
        return out

    alone = [step_many([f], standard, T)[0] for f in fleet()]
    together = step_many(fleet(), standard, T)
    assert alone[0].source == 'cluster-fallback' and alone[0].value == pytest.approx(np.hypot(5.0, 1.0) - 4.9)
    for a, b in zip(alone, together):
        assert (a.action, a.omega, a.value, a.source, a.obstacle_index) == (b.action, b.omega, b.value, b.source,
                                                                            b.obstacle_index)


# -- inputs, batched (update_poses, update_detections_all) and the default cluster store ----------
def test_batched_poses_without_a_stamp_take_the_arrival_time():
    """(kills ``float(stamp)`` for a missing stamp)"""
    from supersafe_ros.filter import update_poses
    filters = [RobotFilter(), RobotFilter()]
    update_poses(filters, [(0.0, 0.0, 0.0), (1.0, 2.0, 3.0)], T)
    assert [f.pose.stamp for f in filters] == [T, T]


def test_batched_poses_with_a_repeated_stamp_do_not_shorten_the_measured_period():
    """A pose stamped as the previous one adds no interval to the control period's median, as
    in update_pose (kills ``>=``: zero intervals would measure a period of 0)."""
    from supersafe_ros.filter import update_poses
    batched, single = RobotFilter(), RobotFilter()
    for stamp in (0.0, 0.2, 0.2, 0.2):
        update_poses([batched], [(0.0, 0.0, 0.0)], stamp + 0.01, stamp=stamp)
        single.update_pose((0.0, 0.0, 0.0), stamp + 0.01, stamp=stamp)
    assert batched.control_period() == single.control_period() == pytest.approx(0.2)


def test_batched_detections_accept_none_and_reject_malformed():
    """No detections is (0, 2); non-finite centres, rows that are neither (x, y) nor (x, y, r)
    and radii that are not > 0 are rejected (kills the empty case read as size 1, replaced by
    None, (1, 2) or (0, 3), and ``and`` for ``or`` in the shape/finite check)."""
    from supersafe_ros.filter import update_detections_all
    filters = [RobotFilter(), RobotFilter()]
    for empty in ([], np.zeros((0, 2))):
        update_detections_all(filters, empty, T)
        assert all(f.detections.value.shape == (0, 2) for f in filters)
    for bad in ([[np.nan, 0.0]], [[0.0, 1.0, 2.0, 3.0]], [0.0, 1.0], [[0.0, 1.0, 0.0]], [[0.0, 1.0, np.nan]]):
        with pytest.raises(ValueError):
            update_detections_all(filters, bad, T)


def test_the_default_cluster_store_follows_the_robots_configuration(monkeypatch):
    """One shared store per robot configuration, with that robot's radius, speed, turn rate and
    link distance (kills every wrong or missing field, and not keeping or creating the store)."""
    from supersafe_ros.filter.clusters import store as cluster_store
    monkeypatch.setattr(cluster_store, '_STORES', {})
    cfg = FilterConfig(radius=1.5, speed=2.0, omega_max=0.8, cluster_link=7.0)
    store = cluster_store.default_cluster_store(cfg)
    st = store.settings
    assert (st.radius, st.speed, st.omega_max, st.link) == (1.5, 2.0, 0.8, 7.0)
    assert cluster_store.default_cluster_store(cfg) is store
    assert cluster_store.default_cluster_store(FilterConfig()) is not store


def test_a_robots_inputs_accept_a_pose_row_and_empty_detections_and_reject_a_bare_number():
    """A pose as one (1, 3) row is a pose; ``[]`` is no detections; a bare number is not a
    detections array (kills ``reshape(None)`` and the empty case read as size 1)."""
    f = RobotFilter()
    f.update_pose(np.array([[1.0, 2.0, 0.5]]), T)
    assert f.pose.value.tolist() == [1.0, 2.0, 0.5]
    f.update_detections([], T)
    assert f.detections.value.shape == (0, 2)
    for bad in ([5.0], np.zeros((2, 3))):
        with pytest.raises(ValueError):
            f.update_detections(bad, T)


def test_the_measured_period_counts_the_planners_command_intervals():
    """Poses every 0.05 s, commands every 0.2 s (each sent twice at once): a command holds
    0.2 s, the larger median (kills never recording a command interval, and recording the
    zero interval of a repeated command)."""
    f = RobotFilter()
    for k in range(9):
        f.update_pose((0.0, 0.0, 0.0), 0.05 * k, stamp=0.05 * k)
        if k % 4 == 0:
            f.update_command(0.1, 0.05 * k)
            f.update_command(0.1, 0.05 * k)
    assert f.control_period() == pytest.approx(0.2)


@pytest.mark.parametrize('source', ['pose', 'command'])
def test_the_measured_period_is_the_median_of_the_last_16_intervals(source):
    """20 intervals of 0.5 s, then 16 of 0.1 s: the period is the recent 0.1 s, not the median
    of the whole history (kills unbounded interval histories)."""
    f = RobotFilter()
    times = np.concatenate([0.5 * np.arange(21), 10.0 + 0.1 * np.arange(1, 17)])
    for t in times:
        if source == 'pose':
            f.update_pose((0.0, 0.0, 0.0), t, stamp=t)
        else:
            f.update_command(0.1, t)
    assert f.control_period() == pytest.approx(0.1)


def test_the_configuration_rejects_negative_and_infinite_times():
    """(kills ``finite or >= 0``)"""
    for bad in (-1.0, math.inf):
        with pytest.raises(ValueError):
            FilterConfig(pose_timeout=bad)


def test_the_first_robot_failing_safe_far_from_obstacles_says_no_obstacle_is_near(standard):
    """A stale pose still within hold_timeout, far from every obstacle: stop-turn, and the
    reason tells the state was valid but clear, also for the fleet's first robot (kills a
    row test that takes row 0 for "no recent valid state")."""
    far = at(OBSTACLE[0] - 30.0, OBSTACLE[1], 0.0)
    f = robot(pose=far, pose_timeout=0.5, hold_timeout=2.0, detections_timeout=5.0, fail_safe_command='stop_turn')
    outs = step_many([f, robot(pose=far)], standard, T + 1.0)
    assert outs[0].action == FAIL_SAFE and outs[0].linear == 0.0
    assert outs[0].reason.startswith('circling (stop-turn)'), outs[0].reason
    assert outs[0].reason.endswith('no obstacle near the last valid state'), outs[0].reason


# -- the planner's speed and the fail-safe command (issue 31) ------------------------------------
def test_no_input_at_all_is_a_zero_twist_or_the_stop_turn(standard):
    """Before any input (the lone node's watchdog): 'stop' sends (0, 0), 'stop_turn' (0, +w_max)
    (kills the spread's branches swapped, and the stop-turn's turn kept for a robot that can
    stop)."""
    for mode, turn in (('stop', 0.0), ('stop_turn', 0.5)):
        out = RobotFilter(FilterConfig(fail_safe_command=mode, omega_max=0.5)).step(standard, T)
        assert (out.action, out.linear, out.omega) == (FAIL_SAFE, 0.0, turn), mode
        assert out.reason.startswith('circling (stop-turn)' if mode == 'stop_turn' else 'stopped: no pose')
    with pytest.raises(ValueError, match='fail_safe_command'):
        FilterConfig(fail_safe_command='spin')


def test_a_robot_that_can_stop_failing_safe_where_the_law_would_act_stops(standard):
    """A robot that can stop, failing safe where the law acts on its last valid state (inside
    the override band): a zero twist, not the avoid turn (issue 36: blind, a robot that can
    stop stops; the avoid turn in place at 0 spun it for as long as it was blind)."""
    f = robot(pose=at(-2.6, -0.3, 0.0), cmd=None, pose_timeout=0.5, hold_timeout=1.0, detections_timeout=5.0)
    f.update_detections(np.array([OBSTACLE]), T + 0.6)
    out = f.step(standard, T + 0.6)
    assert out.action == FAIL_SAFE and out.reason.startswith('stopped: blind for') and 'pose stale' in out.reason
    assert (out.linear, out.omega) == (0.0, 0.0)
    assert out.value < out.alpha + 0.2, 'the state is one the law acts on (else the test shows nothing)'


def test_a_constant_speed_robot_is_propagated_at_its_speed_after_a_stop_turn(standard):
    """The stop-turn sends linear.x 0, but the Dubins robot drives on at its speed: its pose is
    propagated at the speed (kills recording the linear.x sent for a constant-speed robot); a
    robot that can stop sent 0 is propagated standing still."""
    moved = {}
    for mode in ('stop_turn', 'stop'):
        f = RobotFilter(FilterConfig(fail_safe_command=mode, pose_timeout=0.5, hold_timeout=1.0))
        f.step(standard, T)                                  # no input: the fail safe, linear.x 0
        f.update_pose(at(-7.0, 3.0, 0.0), T + 0.05, stamp=T)
        f.update_detections(np.array([OBSTACLE]), T + 0.05)
        f.update_command(0.0, T + 0.05, 2.0)
        moved[mode] = f.step(standard, T + 0.05).value
    expected = DubinsCar(3.0, 1.0).flow(np.array([-7.0, 3.0, 0.0]), 1.0, 0.05)     # the stop-turn, at 3 m/s
    assert moved['stop_turn'] == pytest.approx(evaluate_pairs(standard.vf, expected[None])[0][0])
    assert moved['stop'] == pytest.approx(evaluate_pairs(standard.vf, np.array([[-7.0, 3.0, 0.0]]))[0][0])


def test_an_override_on_a_loiter_fallback_turns_in_place_for_a_robot_that_can_stop(standard):
    """A cluster governed by its loiter fallback (a circle drawn at full speed): a robot that
    can stop turns in place, a constant-speed robot turns at its speed; a union row or a
    pair keeps the planner's speed (kills the fallback test dropped or inverted)."""
    from supersafe_ros.filter.clusters.geometry import ClusterSettings
    from supersafe_ros.filter.clusters.store import ClusterStore
    never = ClusterStore(ClusterSettings(), fallback_only=True)
    row = np.array([[OBSTACLE[0], OBSTACLE[1]], [OBSTACLE[0] + 4.5, OBSTACLE[1]]])     # head on, along the row
    seen = {}
    for mode in ('stop', 'stop_turn'):
        for x in np.linspace(-9.0, -3.0, 25):
            f = robot(pose=at(x, 0.0, 0.0), detections=row, cmd=None, fail_safe_command=mode)
            f.update_command(0.0, T, 1.5)
            out = f.step(standard, T, never)
            if out.action == OVERRIDE:
                seen.setdefault((mode, out.source), out.linear)
    assert seen[('stop', 'cluster-fallback')] == 0.0 and seen[('stop_turn', 'cluster-fallback')] == 3.0
    assert seen.get(('stop', 'standard'), 1.5) == 1.5
