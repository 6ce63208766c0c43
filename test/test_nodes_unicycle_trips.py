"""Trips of a differential-drive robot (a unicycle with odometry at 50 Hz, a 360-beam laser at
10 Hz, TwistStamped at 0.5 m/s) through the managed filter as config/nav2_safety_filter.yaml sets
it, at topic level (unicycle_graph_support; the worlds: sim/unicycle_world.py). Stepped by events
on a harness-driven /clock: bounded by steps, not wall time.

Issue 36's trips: through a wall with a 1.2 m door past a box's corner and posts of three sizes,
with no collision, never faster than the planner asked, and where the planner's path keeps clear
by the robot's radius + 0.3 m, within 1.25 times the planner's own time with no turning in place;
and a robot facing a wall it has seen while each faulty input comes: no collision, the cause in a
log line and on /diagnostics, and zero twists where the robot can stop. The messages the harness
sends, faults included, are checked without nodes. Each on both nodes: the managed safety_filter_node
(decided on its inputs) and a managed fleet_safety_filter_node of the robot and an idle second one
(decided on ticks)."""
import math

import numpy as np
import pytest

from supersafe_ros.sim import unicycle_world as uw

import unicycle_graph_support as trips

TRIP_TIME = 40.0           # sim s: over 1.6 times the planner's own time in every trip below
PLANNERS_TIME = 1.25       # the filter's trip takes at most this times the planner's own time


def never_touched_nor_sped(r):
    f = r.figures()
    assert f['collisions'] == 0 and f['least_clearance'] > 0.0, f'the robot touched an obstacle: {f}'
    assert f['speed_excess'] <= 1e-9, f'the filter sent the robot faster than its planner asked: {f}'
    assert r.nonfinite_commands == 0
    assert r.outputs >= r.commands == r.steps
    return f


NODES = pytest.mark.parametrize('fleet', [False, True], ids=['single', 'fleet'])


@pytest.mark.ros
@pytest.mark.slow
@NODES
def test_through_a_door_past_a_box_corner_and_posts_of_three_sizes(ros_context, fleet):
    """The issue's world: a wall with a 1.2 m door (robot radius 0.25), a box turned 45 degrees with
    its corner toward the robot, posts of three sizes; the filter as config/nav2_safety_filter.yaml
    sets it: no collision with anything the scan saw, through the door, never faster than asked,
    and never turning in place (nothing blocks every speed on the planner's path)."""
    scenario = uw.scenario('combined')
    assert len({r for _, _, r in scenario.world.discs}) == 3 and scenario.world.polygons and scenario.world.walls
    r = trips.run_trip(ros_context, 'combined', max_time=TRIP_TIME, fleet=fleet)
    f = never_touched_nor_sped(r)
    assert r.reached, f'not through the door in {TRIP_TIME} s: {f}'
    assert f['ratio'] <= PLANNERS_TIME, f
    assert f['turning_time'] == 0.0, f
    node = '/fleet_safety_filter' if fleet else '/safety_filter'
    assert any(d[2].startswith(node) for d in r.diagnostics), r.diagnostics[:3]


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('name', ['open_field', 'lane', 'door'])
@NODES
def test_a_trip_clear_of_everything_takes_about_the_planners_time(ros_context, name, fleet):
    """Trips whose planner path keeps clear of every obstacle by the robot's radius + 0.3 m (the lane's
    by more, the door's centre line by 0.35 m): at most 1.25 times the planner's own time, no turning
    in place (each trip once took 2 to more than 3 times it, circling at the door)."""
    scenario = uw.scenario(name)
    assert scenario.path_clearance >= 0.3 - 1e-9, scenario.path_clearance
    r = trips.run_trip(ros_context, name, max_time=TRIP_TIME, fleet=fleet)
    f = never_touched_nor_sped(r)
    assert r.reached and f['ratio'] <= PLANNERS_TIME, f
    assert f['turning_time'] == 0.0, f


@pytest.mark.ros
@NODES
def test_with_nothing_in_the_way_the_trip_is_the_planners_own(ros_context, fleet):
    # the harness adds no delay: each command is passed and applied over its own step
    empty = uw.Scenario('empty', uw.World(), (0.0, 0.0, 0.0), ((0.0, 0.0), (2.0, 0.0), (2.0, 1.5)), (2.0, 1.5),
                        math.inf)
    r = trips.run_trip(ros_context, empty, max_time=20.0, ns='/robot_0_fleet' if fleet else '/robot_0', fleet=fleet)
    assert r.reached and r.time == pytest.approx(uw.planner_time(empty), abs=1e-9)
    assert np.array_equal(r.sent, r.asked), 'every command passed unchanged'
    assert set(r.actions[1:]) == {'pass'}


# (fault, detections, what the log and /diagnostics say, whether the robot stops): each fault from
# step 25 (0.5 s), the robot 1.5 m from a wall it has seen, the planner driving straight at it
FAULT_CASES = [
    ('scan_nan', 'scan', 'NaN', True),                       # every beam NaN: said nothing, blind
    ('scan_negative', 'scan', 'below range_min', True),      # every beam < range_min: said nothing, blind
    ('scan_range_min_above_max', 'scan', 'range_min', True),  # refused: blind
    ('scan_angle_increment_0', 'scan', 'angle_increment', True),   # refused: blind
    ('scan_neg_inf', 'scan', '-inf', False),                 # objects within range_min: under the robot, the wall kept
    ('spoof_empty_scans', 'scan', 'spoof_driver', False),    # a second publisher: said, the real scans keep the view
    ('cloud_nan_points', 'cloud', 'not finite', True),       # every point NaN: said nothing, blind
    ('cloud_point_step_12', 'cloud', 'point_step', True),    # refused: blind
    ('cloud_point_step_8', 'cloud', 'point_step', True),
    ('odom_nan', 'scan', 'not finite', True),                # the pose refused: stop
    ('planner_nan', 'scan', 'not finite', True),             # the planner's command refused: stop
    ('planner_silent', 'scan', 'planner silent', True),      # nothing to pass: stop
]


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('fault, detections, said, stops', FAULT_CASES, ids=[c[0] for c in FAULT_CASES])
@NODES
def test_a_faulty_input_never_drives_the_robot_into_a_wall_it_has_seen(ros_context, fault, detections, said, stops,
                                                                       fleet):
    """Faulty or spoofed input while the planner drives at a wall 1.5 m ahead that good scans have shown:
    no collision; the cause in a log line of the filter and on /diagnostics; where the filter can no
    longer judge (blind, or nothing to pass) zero twists from then on, at the watchdog's rate; where it
    still can (-inf under the robot, a second publisher beside the real driver) the map it holds guides
    the robot along the wall."""
    # a namespace of its own: the /rosout lines of each test's filter under a logger name of their own (a
    # second node of one name in a process shares the first's rosout publisher)
    graph = trips.TripGraph(ros_context, 'facing_wall', fault=fault, fault_step=25, detections=detections,
                            ns=f'/{fault}{"_fleet" if fleet else ""}', fleet=fleet)
    try:
        r = graph.run(max_time=4.0)     # at 0.5 m/s the wall is reached in 2.5 s without the filter
        assert r.figures()['collisions'] == 0 and r.figures()['least_clearance'] > 0.0, r.figures()
        # /rosout and /diagnostics (1 Hz) arrive on their own: waited for, with the graph's deadline
        graph.until(lambda: any(said in line[3] for line in graph.rosout if line[0] >= 25), f'{said!r} in a log line')
        graph.until(lambda: any(said in d[3] for d in graph.diagnostics if d[0] >= 25), f'{said!r} on /diagnostics')
        if stops:
            assert np.all(r.sent[-50:] == 0.0), f'no zero twists in the last second: {r.sent[-50:].tolist()[:5]}'
        else:
            assert r.figures()['path_length'] > 1.0, 'the map guided the robot along the wall'
    finally:
        graph.close()


# -- the messages, faults included (no nodes) ----------------------------------------------------
def test_the_laser_sees_the_world_from_its_mount():
    s = uw.facing_wall()
    ranges = trips.laser_ranges(s.world, s.start)
    assert ranges.dtype == np.float32 and len(ranges) == trips.BEAMS
    ahead = int(np.argmin(np.abs(trips.beam_angles())))
    assert ranges[ahead] == pytest.approx(1.5 - 0.1, abs=1e-6), 'the laser is 0.1 m ahead of the centre'
    assert math.isinf(ranges[0]), 'nothing behind within range_max'
    turned = trips.laser_pose((1.0, 2.0, math.pi / 2))
    assert turned == pytest.approx((1.0, 2.1, math.pi / 2))


def test_scans_and_their_faults():
    ranges = np.array([1.0, np.inf, 2.0] + [np.inf] * (trips.BEAMS - 3), dtype=np.float32)
    good = trips.laser_scan(1_500_000_000, ranges)
    assert (good.header.stamp.sec, good.header.stamp.nanosec, good.header.frame_id) == (1, 500_000_000, 'laser')
    assert good.angle_increment == pytest.approx(2 * math.pi / trips.BEAMS)
    assert good.angle_min == pytest.approx(-math.pi)
    assert (good.range_min, good.range_max) == (trips.RANGE_MIN, trips.RANGE_MAX)
    assert good.ranges[0] == 1.0 and math.isinf(good.ranges[1])
    assert all(math.isnan(r) for r in trips.laser_scan(0, ranges, 'scan_nan').ranges)
    assert all(r == -math.inf for r in trips.laser_scan(0, ranges, 'scan_neg_inf').ranges)
    assert all(r < 0 for r in trips.laser_scan(0, ranges, 'scan_negative').ranges)
    bad = trips.laser_scan(0, ranges, 'scan_range_min_above_max')
    assert bad.range_min > bad.range_max and bad.ranges[0] == 1.0
    assert trips.laser_scan(0, ranges, 'scan_angle_increment_0').angle_increment == 0.0
    assert len(trips.laser_scan(0, []).ranges) == 0


def test_clouds_and_their_faults():
    ranges = np.full(trips.BEAMS, np.inf, dtype=np.float32)
    ahead = int(np.argmin(np.abs(trips.beam_angles())))
    ranges[ahead], ranges[ahead + 90] = 2.0, 3.0                  # straight ahead, and to the left
    cloud = trips.point_cloud(0, ranges)
    assert (cloud.width, cloud.height, cloud.point_step, cloud.row_step) == (2, 1, 16, 32)
    xyz = np.frombuffer(bytes(cloud.data), dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('pad', 'V4')])
    assert np.allclose(np.column_stack([xyz['x'], xyz['y']]), [[2.0, 0.0], [0.0, 3.0]], atol=1e-6)
    assert [(f.name, f.offset) for f in cloud.fields] == [('x', 0), ('y', 4), ('z', 8)]
    nan = trips.point_cloud(0, ranges, 'cloud_nan_points')
    assert np.all(np.isnan(np.frombuffer(bytes(nan.data), dtype='<f4').reshape(2, 4)[:, :3])) and not nan.is_dense
    for fault, step in (('cloud_point_step_12', 12), ('cloud_point_step_8', 8)):
        bad = trips.point_cloud(0, ranges, fault)
        assert bad.point_step == step and len(bad.data) == bad.row_step == 16 * bad.width


def test_odometry_and_commands():
    m = trips.odometry((1.0, -2.0, 0.5), (0.3, -0.2), 2_000_000_000)
    assert (m.header.frame_id, m.child_frame_id) == ('odom', 'base_link')
    assert (m.pose.pose.position.x, m.pose.pose.position.y) == (1.0, -2.0)
    assert 2 * math.atan2(m.pose.pose.orientation.z, m.pose.pose.orientation.w) == pytest.approx(0.5)
    assert (m.twist.twist.linear.x, m.twist.twist.angular.z) == (0.3, -0.2)
    nan = trips.odometry((1.0, -2.0, 0.5), (0.0, 0.0), 0, nan_position=True)
    assert math.isnan(nan.pose.pose.position.x) and math.isnan(nan.pose.pose.position.y)
    cmd = trips.twist_stamped((0.5, 0.25), 3_000_000_001)
    assert (cmd.header.stamp.sec, cmd.header.stamp.nanosec, cmd.header.frame_id) == (3, 1, 'base_link')
    assert (cmd.twist.linear.x, cmd.twist.angular.z) == (0.5, 0.25)


def test_faults_are_checked_before_any_node_is_made():
    trips.check_options(None, 'scan')
    for fault in trips.FAULTS:
        trips.check_options(fault, 'cloud' if fault in trips.CLOUD_FAULTS else 'scan')
    with pytest.raises(ValueError, match='unknown fault'):
        trips.check_options('scan_on_fire', 'scan')
    with pytest.raises(ValueError, match='does not go with'):
        trips.check_options('scan_nan', 'cloud')
    with pytest.raises(ValueError, match='does not go with'):
        trips.check_options('cloud_point_step_8', 'scan')
    with pytest.raises(ValueError, match='detections'):
        trips.check_options(None, 'sonar')


def test_the_harness_uses_this_trees_simulator():
    assert trips.own_simulator() is uw
    assert trips.checkout_root() == trips.ROOT
