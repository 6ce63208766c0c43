"""ROS-free tests of the per-robot filter state machine (supersafe_ros.filter)."""
import math

import numpy as np
import pytest

from supersafe_ros.filter import FAIL_SAFE, OVERRIDE, PASS, RobotFilter, SafeSet, step_many

from supersafe_ros.filter.law import evaluate_pairs
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.sets import Disc
from supersafe_ros.reach.solver import solve_avoid

from filter_support import OBSTACLE, at, robot

pytestmark = pytest.mark.usefixtures('decision_path')   # every test: robot alone, and in a fleet


@pytest.fixture(scope='module')
def standard():
    vf = solve_avoid(Grid((-8, -8), (8, 8), (41, 41, 24)), DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=3.0)
    return SafeSet(vf, 0.0, 'standard')


def test_far_from_obstacles_passes_the_planner_command(standard):
    f = robot(pose=at(-7.5, 6.0, 0.0), cmd=0.3)
    out = f.step(standard, 0.01)
    assert out.action == PASS and out.omega == 0.3 and out.level == 0
    assert out.value > standard.alpha


def test_no_detections_passes(standard):
    out = robot(pose=at(-1.0, 0.0, 0.0), detections=np.zeros((0, 2)), cmd=-0.2).step(standard, 0.0)
    assert out.action == PASS and out.omega == -0.2 and out.obstacle_index == -1


@pytest.mark.parametrize('side', [1.0, -1.0])
def test_near_obstacle_overrides_and_turns_away(standard, side):
    # heading +x toward the obstacle, slightly to its left (side=+1) or right (side=-1):
    # turning away means turning left (+) on the left side, right (-) on the right side
    f = robot(pose=at(-3.0, 0.6 * side, 0.0), cmd=-0.5 * side)
    out = f.step(standard, 0.0)
    assert out.action == OVERRIDE and out.level == 1
    assert out.omega == pytest.approx(side * 1.0)
    assert out.value <= 0.0 and out.obstacle_index == 0
    assert out.obstacle_xy == OBSTACLE


def test_smallest_value_governs(standard):
    far = (OBSTACLE[0] - 20.0, OBSTACLE[1])
    f = robot(pose=at(-3.0, -0.6, 0.0), detections=[far, OBSTACLE])
    out = f.step(standard, 0.0)
    assert out.action == OVERRIDE and out.obstacle_index == 1 and out.omega == pytest.approx(-1.0)


def test_hysteresis_keeps_overriding_until_clear(standard):
    vf = standard.vf
    f = robot(pose=at(-3.0, 0.6, 0.0), clear_margin=0.5)
    assert f.step(standard, 0.0).action == OVERRIDE
    # a state just above alpha but inside the margin: still overriding
    xs = np.linspace(-7.0, -2.0, 400)
    vals = vf.value(np.stack([xs, np.full_like(xs, 0.6), np.zeros_like(xs)], axis=1))
    band = xs[(vals > 0.1) & (vals < 0.4)]
    clear = xs[vals > 0.6]
    assert band.size and clear.size
    f.update_pose(at(band[0], 0.6, 0.0), 0.1)
    out = f.step(standard, 0.1)
    assert out.action == OVERRIDE and 'not yet clear' in out.reason and out.omega == pytest.approx(1.0)
    f.update_pose(at(clear[0], 0.6, 0.0), 0.2)
    assert f.step(standard, 0.2).action == PASS
    # without a preceding override the same band state passes
    g = robot(pose=at(band[0], 0.6, 0.0), clear_margin=0.5)
    assert g.step(standard, 0.0).action == PASS


def test_stale_pose_fails_safe_with_avoid_control_then_stop_turn(standard):
    f = robot(pose=at(-3.0, -0.6, 0.0), cmd=0.9, pose_timeout=0.5, hold_timeout=1.0, detections_timeout=5.0,
              fail_safe_command='stop_turn')
    first = f.step(standard, 0.0)
    assert first.action == OVERRIDE and first.omega == -1.0
    f.update_detections(np.array([OBSTACLE]), 0.9)
    out = f.step(standard, 0.7)        # pose 0.7 s old: stale, but within the hold window
    assert out.action == FAIL_SAFE and out.level == 2 and 'pose stale' in out.reason
    # the avoid control of the last valid state, moved on by the 0.7 s of right turn sent since
    moved = DubinsCar(3.0, 1.0).flow(np.array([-3.0, -0.6, 0.0]), -1.0, 0.7)
    value, turn = evaluate_pairs(standard.vf, moved[None])
    assert out.pose_age == pytest.approx(0.7) and out.value == pytest.approx(value[0])
    assert out.omega == turn[0]
    out = f.step(standard, 1.5)        # beyond the hold window: stop-turn
    assert out.action == FAIL_SAFE and out.linear == 0.0 and out.omega == pytest.approx(1.0)
    assert 'stop-turn' in out.reason


def test_a_robot_that_can_stop_fails_safe_with_a_zero_twist_at_once(standard):
    """fail_safe_command 'stop' (issue 36): blind, a robot that can stop stops: a zero twist from
    the first decision without valid input, also where the law acts on its last valid state (the
    avoid turn it had before spun a robot in place at speed 0 for as long as it was blind), and
    past hold_timeout; the reason says so and why."""
    f = robot(pose=at(-2.6, -0.3, 0.0), cmd=None, pose_timeout=0.5, hold_timeout=1.0, detections_timeout=5.0)
    f.update_command(0.9, 0.0, 1.2)
    first = f.step(standard, 0.0)
    assert first.action == OVERRIDE and first.omega == -1.0 and first.linear == 1.2
    f.update_detections(np.array([OBSTACLE]), 0.9)
    for t in (0.7, 1.5):        # pose stale, within the hold window and beyond it
        out = f.step(standard, t)
        assert (out.action, out.linear, out.omega) == (FAIL_SAFE, 0.0, 0.0), out.reason
        assert out.reason.startswith(f'stopped: blind for {t:.2g} s') and 'pose stale' in out.reason, out.reason


def test_stale_pose_does_not_forward_the_planner(standard):
    # near enough to be on the obstacle's grid: the avoid control of the last state
    f = robot(pose=at(-7.5, 6.0, 0.0), cmd=0.3, pose_timeout=0.1, fail_safe_command='stop_turn')
    out = f.step(standard, 0.2)
    assert out.action == FAIL_SAFE and abs(out.omega) == 1.0 and 'away from obstacle 0' in out.reason
    # off every obstacle's grid: nothing to avoid, stop-turn
    g = robot(pose=at(-9.0, 6.0, 0.0), cmd=0.3, pose_timeout=0.1, fail_safe_command='stop_turn')
    out = g.step(standard, 0.2)
    assert out.action == FAIL_SAFE and out.linear == 0.0 and out.omega == 1.0 and 'stop-turn' in out.reason
    # a robot that can stop: a zero twist, near the obstacle and off the grid
    for pose in ((-7.5, 6.0, 0.0), (-9.0, 6.0, 0.0)):
        h = robot(pose=at(*pose), cmd=0.3, pose_timeout=0.1)
        out = h.step(standard, 0.2)
        assert (out.action, out.linear, out.omega) == (FAIL_SAFE, 0.0, 0.0), out.reason
        assert out.reason.startswith('stopped: blind for') and 'pose stale' in out.reason


def test_values_and_turns_agree_with_an_independent_computation(standard):
    """Checked against what V means, not against the code's own rule.

    Heading straight away from the disc, the distance only grows: V = |p| - R.
    The avoid turn is the one of +-w_max that ends a short exact arc at the larger V
    (where the two differ clearly; the law takes the sign of dV/dtheta).
    """
    rng = np.random.default_rng(0)
    r, a = rng.uniform(2.0, 6.5, 500), rng.uniform(-np.pi, np.pi, 500)
    away = np.stack([r * np.cos(a), r * np.sin(a), a], axis=1)
    value, _ = evaluate_pairs(standard.vf, away)
    assert np.max(np.abs(value - (r - 1.8))) < 0.03
    rel = np.stack([rng.uniform(-6, 6, 3000), rng.uniform(-6, 6, 3000), rng.uniform(-np.pi, np.pi, 3000)], 1)
    rel = rel[np.hypot(rel[:, 0], rel[:, 1]) > 2.0]
    value, turn = evaluate_pairs(standard.vf, rel)
    car = DubinsCar(3.0, 1.0)
    left, right = (standard.vf.value(car.flow(rel, w, 0.1)) for w in (1.0, -1.0))
    clear = (np.abs(left - right) > 0.05) & (value < 1.0)
    assert clear.sum() > 200
    np.testing.assert_array_equal(turn[clear], np.where(left > right, 1.0, -1.0)[clear])
    # off the grid: never constraining
    value, turn = evaluate_pairs(standard.vf, np.array([[20.0, 0.0, 0.0]]))
    assert value[0] == np.inf and turn[0] == 0.0


def test_head_on_tie_turns_left(standard):
    """At (-3, 0, 0) dV/dtheta is float round-off (-1.4e-8 on 41 x 41 x 24): a tie, so left."""
    grad = standard.vf.grid.interpolate(standard.vf.node_gradient()[..., 2], np.array([-3.0, 0.0, 0.0]))
    assert abs(float(grad)) < 1e-6
    for cmd in (-0.7, 0.7):
        out = robot(pose=at(-3.0, 0.0, 0.0), cmd=cmd).step(standard, 0.0)
        assert out.action == OVERRIDE and out.omega == 1.0


def test_avoid_turn_uses_the_robots_omega_max_not_the_sets(standard):
    half = SafeSet(solve_avoid(Grid((-8, -8), (8, 8), (41, 41, 24)), DubinsCar(3.0, 0.5), Disc(0, 0, 1.8),
                               horizon=3.0), 0.0, 'learned')
    assert half.omega_max == 0.5
    for side in (1.0, -1.0):
        out = robot(pose=at(-3.0, 0.6 * side, 0.0), cmd=0.0, omega_max=1.0).step(half, 0.0)
        assert out.action == OVERRIDE and out.omega == side * 1.0 and out.omega_max_set == 0.5
        out = robot(pose=at(-3.0, 0.6 * side, 0.0), cmd=0.0, omega_max=0.7).step(standard, 0.0)
        assert out.action == OVERRIDE and out.omega == pytest.approx(side * 0.7)


def test_smaller_of_two_real_values_governs(standard):
    # both obstacles on the grid with finite values; they would turn the robot opposite ways
    # (per-obstacle law: clusters off; 5 m apart they would otherwise be judged as one)
    near, other = OBSTACLE, (OBSTACLE[0], OBSTACLE[1] - 5.0)
    pose = at(-3.0, -0.6, 0.0)
    rel = np.array([[pose[0] - c[0], pose[1] - c[1], 0.0] for c in (near, other)])
    value, turn = evaluate_pairs(standard.vf, rel)
    assert np.all(np.isfinite(value)) and value[0] < 0.0 < value[1] and turn[0] == -turn[1]
    for dets, index in (([near, other], 0), ([other, near], 1)):
        out = robot(pose=pose, detections=dets, cmd=0.0, clusters=False).step(standard, 0.0)
        assert out.action == OVERRIDE and out.obstacle_index == index
        assert out.value == pytest.approx(value[0]) and out.omega == turn[0]


@pytest.mark.parametrize('cmd, sent', [(1e30, 1.0), (-1e30, -1.0), (2.5, 1.0), (-0.4, -0.4)])
def test_passed_commands_stay_within_omega_max(standard, cmd, sent):
    f = robot(pose=at(-7.5, 6.0, 0.0), cmd=cmd)
    out = f.step(standard, 0.01)
    assert out.action == PASS and out.omega == sent
    g = robot(pose=at(-7.5, 6.0, 0.0), cmd=cmd, omega_max=0.5)
    assert step_many([g], standard, 0.01)[0].omega == float(np.clip(sent, -0.5, 0.5))


def test_lookahead_judges_the_planners_own_command(standard):
    """Left of the axis heading +x: a right turn (toward the disc) would cross alpha
    within the lookahead, a left turn (away) would not. Non-zero commands both ways."""
    pose, h = at(-4.0, 1.0, 0.0), 0.2
    car = DubinsCar(3.0, 1.0)
    rel = np.array([-4.0, 1.0, 0.0])
    v_now = float(standard.vf.value(rel))
    toward, away = (float(standard.vf.value(car.flow(rel, w, h))) for w in (-0.9, 0.9))
    assert toward < min(v_now, away) - 0.1
    level = SafeSet(standard.vf, (toward + min(v_now, away)) / 2)
    out = robot(pose=pose, cmd=-0.9, lookahead=h).step(level, 0.0)
    assert out.action == OVERRIDE and 'would bring' in out.reason and out.omega == 1.0
    out = robot(pose=pose, cmd=0.9, lookahead=h).step(level, 0.0)
    assert out.action == PASS and out.omega == 0.9


def test_invalid_pose_is_rejected_and_fails_safe_until_a_valid_one(standard):
    f = robot(pose=at(-7.5, 6.0, 0.0), cmd=0.3)
    with pytest.raises(ValueError):
        f.update_pose((math.nan, 0.0, 0.0), 0.01)
    out = f.step(standard, 0.02)
    assert out.action == FAIL_SAFE and 'pose rejected' in out.reason
    f.update_pose(at(-7.5, 6.0, 0.0), 0.03)
    assert f.step(standard, 0.03).action == PASS


def test_invalid_detections_and_commands(standard):
    f = robot(pose=at(-7.5, 6.0, 0.0), cmd=0.3)
    with pytest.raises(ValueError):
        f.update_detections(np.array([[np.inf, 0.0]]), 0.01)
    assert f.step(standard, 0.01).action == FAIL_SAFE
    f.update_detections(np.array([OBSTACLE]), 0.02)
    with pytest.raises(ValueError):
        f.update_command(math.nan, 0.02)
    out = f.step(standard, 0.02)      # a robot that can stop stops on a refused command (issue 36)
    assert (out.action, out.linear, out.omega) == (FAIL_SAFE, 0.0, 0.0)
    assert out.reason.startswith('stopped: planner command rejected: not finite (angular.z=nan'), out.reason
    f.update_command(0.3, 0.03)
    assert f.step(standard, 0.03).action == PASS      # a valid command: filtering again
    g = robot(pose=at(-7.5, 6.0, 0.0), cmd=0.3, fail_safe_command='stop_turn')
    with pytest.raises(ValueError):
        g.update_command(math.nan, 0.02)
    out = g.step(standard, 0.02)
    assert out.action == PASS and out.omega == 0.3    # a constant-speed robot keeps the previous valid command


def test_nothing_received_fails_safe(standard):
    out = RobotFilter().step(standard, 0.0)
    assert out.action == FAIL_SAFE and 'no pose' in out.reason and out.linear == 0.0


def test_silent_planner_gives_a_zero_command(standard):
    f = robot(pose=at(-7.5, 6.0, 0.0), cmd=0.3, cmd_timeout=0.5)
    f.update_pose(at(-7.5, 6.0, 0.0), 1.0)
    f.update_detections(np.array([OBSTACLE]), 1.0)
    out = f.step(standard, 1.0)
    assert out.action == PASS and out.omega == 0.0 and out.linear == 0.0 and 'planner silent' in out.reason


def test_alpha_raises_the_override_level(standard):
    # lookahead off: the level alone decides
    f = robot(pose=at(-6.0, 0.0, 0.0), lookahead=0.0)
    v = f.step(standard, 0.0).value
    assert f.step(SafeSet(standard.vf, v - 0.1), 0.0).action == PASS
    g = robot(pose=at(-6.0, 0.0, 0.0), lookahead=0.0)
    assert g.step(SafeSet(standard.vf, v + 0.1), 0.0).action == OVERRIDE


def test_lookahead_overrides_before_the_planner_crosses_alpha(standard):
    """Head-on at V just above alpha: one control period of the planner's command
    would end below alpha, so the filter acts now rather than a period too late."""
    probe = robot(pose=at(-6.0, 0.0, 0.0), cmd=0.0, lookahead=0.0)
    v = probe.step(standard, 0.0).value
    level = SafeSet(standard.vf, v - 0.05)
    late = robot(pose=at(-6.0, 0.0, 0.0), cmd=0.0, lookahead=0.0).step(level, 0.0)
    assert late.action == PASS
    early = robot(pose=at(-6.0, 0.0, 0.0), cmd=0.0, lookahead=0.1).step(level, 0.0)
    assert early.action == OVERRIDE and 'would bring' in early.reason
    # alpha further below than one period can lose: nothing to prevent, the command passes
    away = robot(pose=at(-6.0, 0.0, 0.0), cmd=0.0, lookahead=0.1).step(SafeSet(standard.vf, v - 0.6), 0.0)
    assert away.action == PASS


def test_step_many_matches_single_steps(standard):
    rng = np.random.default_rng(3)
    filters, singles = [], []
    for i in range(40):
        pose = at(rng.uniform(-6, 6), rng.uniform(-6, 6), rng.uniform(-np.pi, np.pi))
        dets = [OBSTACLE] if i % 3 else [OBSTACLE, (OBSTACLE[0] + 4.0, OBSTACLE[1])]
        filters.append(robot(pose=pose, detections=dets, cmd=0.1 * (i % 5), clusters=False))
        singles.append(robot(pose=pose, detections=dets, cmd=0.1 * (i % 5), clusters=False))
    many = step_many(filters, standard, 0.0)
    actions = set()
    for f, out in zip(singles, many):
        one = f.step(standard, 0.0)
        actions.add(one.action)
        assert (one.action, one.omega, one.obstacle_index) == (out.action, out.omega, out.obstacle_index)
    assert actions == {PASS, OVERRIDE}


# -- every decision on the pose it is for -------------------------------------------------------
def test_pose_is_propagated_over_its_age_under_the_commands_sent(standard):
    """The robot moved on since its pose's stamp under what the filter sent: judged there."""
    car = DubinsCar(3.0, 1.0)
    f = robot(pose=at(-6.5, 2.0, -0.3), cmd=0.4, lookahead=0.0)
    assert f.step(standard, 0.0).action == PASS          # sends 0.4 at t = 0
    f.update_command(-0.6, 0.1)
    assert f.step(standard, 0.1).omega == -0.6            # sends -0.6 at t = 0.1
    out = f.step(standard, 0.25)                          # still the pose of t = 0
    expected = car.flow(car.flow(np.array([-6.5, 2.0, -0.3]), 0.4, 0.1), -0.6, 0.15)
    assert out.pose_age == pytest.approx(0.25)
    assert out.value == pytest.approx(float(evaluate_pairs(standard.vf, expected[None])[0][0]), abs=1e-9)
    # a stamped pose: propagated from its stamp, not from its arrival
    g = robot(pose=at(-6.5, 2.0, -0.3), cmd=0.4, lookahead=0.0)
    g.step(standard, 0.0)
    g.update_pose(at(-6.5, 2.0, -0.3), 0.3, stamp=0.1)
    assert g.step(standard, 0.3).pose_age == pytest.approx(0.2)
    # a stamp ahead of the filter's clock is not believed: age from arrival
    g.update_pose(at(-6.5, 2.0, -0.3), 0.4, stamp=0.9)
    assert g.step(standard, 0.4).pose_age == 0.0
    with pytest.raises(ValueError):
        g.update_pose(at(-6.5, 2.0, -0.3), 0.5, stamp=math.nan)


def test_decision_on_the_previous_steps_pose_acts_on_the_robots_state_now(standard):
    """Head-on, one 0.2 s step before the level: the previous step's pose still looks fine,
    the state now does not. Compensated: override; judged as if current: pass (too late)."""
    xs = np.linspace(-7.5, -3.0, 500)
    values = standard.vf.value(np.stack([xs, np.full_like(xs, 0.3), np.zeros_like(xs)], 1))
    x_old = float(xs[np.argmax(values <= 0.25)])          # V(old) ~ 0.25
    x_now = x_old + 3.0 * 0.2
    assert standard.vf.value(np.array([x_now, 0.3, 0.0])) < 0.0
    for compensate, action in ((True, OVERRIDE), (False, PASS)):
        f = robot(pose=at(x_old, 0.3, 0.0), cmd=0.0, lookahead=0.0, compensate_delay=compensate,
                  control_period=1e-3)
        assert f.step(standard, 0.0).action == PASS       # sent 0 (straight) at the old pose
        f.update_command(0.0, 0.2)
        assert f.step(standard, 0.2).action == action


def test_lookahead_never_falls_below_the_control_period(standard):
    f = robot(pose=at(-6.5, 2.0, 0.0), lookahead=0.1, control_period=0.2)
    assert f.lookahead() == 0.2 and f.step(standard, 0.0).lookahead == 0.2
    assert robot(lookahead=0.3, control_period=0.2).lookahead() == 0.3
    # measured: poses stamped every 0.2 s, commands every 0.05 s -> the robot holds for 0.2 s
    g = robot(pose=at(-6.5, 2.0, 0.0), lookahead=0.0)
    for k in range(1, 6):
        g.update_pose(at(-6.5, 2.0, 0.0), 0.2 * k + 0.01, stamp=0.2 * k)
        for j in range(4):
            g.update_command(0.1, 0.2 * k + 0.05 * j)
    assert g.lookahead() == pytest.approx(0.2)
    assert robot(lookahead=0.1, control_period=0.2, compensate_delay=False).lookahead() == 0.1


def test_equal_detections_in_separate_arrays_share_their_cluster_frames(standard, monkeypatch):
    """Robots sent equal detections in separate messages (the fleet node's per-robot topics)
    compute the cluster frames once; other content gets its own; the cache is bounded; and
    the decisions are those computed without it."""
    import supersafe_ros.filter.constraints.cluster_rows as cluster_rows
    from supersafe_ros.filter.clusters.geometry import ClusterSettings
    from supersafe_ros.filter.clusters.store import ClusterStore
    store = ClusterStore(ClusterSettings(), fallback_only=True)
    pair = [(OBSTACLE[0], OBSTACLE[1]), (OBSTACLE[0] + 4.0, OBSTACLE[1] + 1.0)]      # one cluster
    moved = [(OBSTACLE[0], OBSTACLE[1]), (OBSTACLE[0] + 4.5, OBSTACLE[1] + 1.0)]
    poses = [at(-4.0, 0.5, 0.0), at(-3.0, -1.0, 0.2), at(-5.0, 0.0, -0.1)]
    cluster_rows._FRAMES_BY_CONTENT.clear()
    fleet = [robot(pose=p, detections=d) for p, d in zip(poses, (pair, list(pair), moved))]
    outs = step_many(fleet, standard, 0.0, store)
    a, b, c = (f.derived['clusters'][1] for f in fleet)
    assert fleet[0].detections.value is not fleet[1].detections.value
    assert a is b and a is not c and a.n == c.n == 1 and a.keys != c.keys
    with pytest.raises(ValueError):
        a.frames[0, 0] = 1.0                    # shared, so read-only
    cluster_rows._FRAMES_BY_CONTENT.clear()
    fresh = [robot(pose=p, detections=d) for p, d in zip(poses, (pair, list(pair), moved))]
    again = step_many(fresh, standard, 0.0, store)
    assert [(o.omega, o.action, o.reason) for o in outs] == [(o.omega, o.action, o.reason) for o in again]
    monkeypatch.setattr(cluster_rows, '_FRAMES_KEPT', 8)
    for k in range(30):
        step_many([robot(pose=poses[0], detections=[pair[0], (pair[1][0] + 0.01 * k, pair[1][1])])],
                  standard, 0.0, store)
        assert len(cluster_rows._FRAMES_BY_CONTENT) <= 8


def test_decide_many_records_nothing_and_its_record_is_step_many():
    """A decision is written into the filter only when it is recorded (what a lockstepped node does
    once its answer goes out); recorded, it is what ``step_many`` writes."""
    from supersafe_ros.filter.decide import decide_many
    from supersafe_ros.filter.sent import record_decisions
    from supersafe_ros.reach.library import load_or_solve
    vf = load_or_solve(Grid((-10.0, -10.0), (10.0, 10.0), (21, 21, 16)), 3.0, 1.0, 1.8, 2.0)
    safe = SafeSet(vf, 0.5)
    held, sent = (robot(pose=at(-3.0, 0.5, 0.0)) for _ in range(2))   # heading at the obstacle: overridden
    before = (list(held.sent), held.overriding)
    decisions = decide_many([held], safe, 0.05)
    assert decisions[0].action == 'override'
    assert (list(held.sent), held.overriding) == before
    record_decisions([held], decisions)
    step_many([sent], safe, 0.05)
    assert list(held.sent) == list(sent.sent) and len(sent.sent) == len(before[0]) + 1
    assert held.overriding == sent.overriding is True


def test_a_decision_writes_nothing_into_its_filters_until_recorded_caches_included():
    """``decide_many`` leaves every filter as it was, its caches too (the detections' index and
    pick, the clusters' frames: ``filter.derived``); ``record_decisions`` writes them with what was
    sent, and the next decision reads them (the same objects, not built again)."""
    import pickle
    from supersafe_ros.filter.clusters.geometry import ClusterSettings
    from supersafe_ros.filter.clusters.store import ClusterStore
    from supersafe_ros.filter.decide import decide_many
    from supersafe_ros.filter.constraints.nearby import NEAR_QUERY_MIN
    from supersafe_ros.filter.sent import record_decisions
    from supersafe_ros.reach.library import load_or_solve
    vf = load_or_solve(Grid((-10.0, -10.0), (10.0, 10.0), (21, 21, 16)), 3.0, 1.0, 1.8, 2.0)
    safe = SafeSet(vf, 0.5)
    store = ClusterStore(ClusterSettings(disk_cache=False), background=False)
    many = NEAR_QUERY_MIN + 36       # judged through the index (nearby), a close pair among them (a cluster)
    field = np.column_stack([np.arange(many) * 6.0 + 20.0, np.full(many, 40.0)])
    field[:2] = [(OBSTACLE[0] + 1.0, OBSTACLE[1]), (OBSTACLE[0] + 1.0, OBSTACLE[1] + 2.5)]
    fleet = [robot(pose=at(-4.0, 1.0, 0.0), detections=field), robot(pose=at(-3.0, -1.5, 0.2), detections=field),
             robot(pose=at(-4.0, 0.5, 0.0), detections=field[:2])]     # a pair alone: its clusters' frames
    before = [{name: pickle.dumps(value) for name, value in vars(f).items()} for f in fleet]
    decisions = decide_many(fleet, safe, 0.05, store)
    assert len(decisions.derived) > 0
    for f, was in zip(fleet, before):        # every attribute, to its contents
        assert {name: pickle.dumps(value) for name, value in vars(f).items()} == was
    assert all(f.derived == {} for f in fleet)
    record_decisions(fleet, decisions)
    kept = [dict(f.derived) for f in fleet]
    assert [sorted(k) for k in kept] == [['near_index', 'near_pick']] * 2 + [['clusters']]
    again = decide_many(fleet, safe, 0.1, store)
    record_decisions(fleet, again)
    assert all(f.derived[k] is v[k] for f, v in zip(fleet, kept) for k in v)     # read, not built again
