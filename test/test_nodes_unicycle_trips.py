"""Trips of a differential-drive robot (a unicycle with odometry at 50 Hz, a 360-beam laser at
10 Hz, TwistStamped at 0.5 m/s) through the managed filter as config/nav2_safety_filter.yaml sets
it, at topic level (unicycle_graph_support; the worlds: sim/unicycle_world.py). Stepped by events
on a harness-driven /clock: bounded by steps, not wall time.

What is asserted here holds for today's filter and must hold for any: no collision, never faster
than the planner asked, no command that is not finite. Today's filter does not reach the goal of
the door or the open field in the time allowed (bench/bench_trips.py prints how far it gets):
that is not asserted either way here. The messages the harness sends, faults included, are
checked without nodes."""
import math

import numpy as np
import pytest

from supersafe_ros.sim import unicycle_world as uw

import unicycle_graph_support as trips

TRIP_TIME = 40.0           # sim s: over twice the planner's own time in the door and the open field


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize('name', ['door', 'open_field'])
def test_a_trip_through_the_nav2_filter_never_collides_nor_speeds_up(ros_context, name):
    r = trips.run_trip(ros_context, name, max_time=TRIP_TIME)
    f = r.figures()
    assert f['collisions'] == 0 and f['least_clearance'] > 0.0, f'the robot touched an obstacle: {f}'
    assert f['speed_excess'] <= 1e-9, f'the filter sent the robot faster than its planner asked: {f}'
    assert r.nonfinite_commands == 0
    # the harness: every step answered, the filter's state and /diagnostics recorded
    assert r.reached or r.steps == round(TRIP_TIME / trips.DT)
    assert r.outputs >= r.commands == r.steps
    assert r.states and {'pass', 'override'} & set(r.actions)
    assert any(d[2].startswith('/safety_filter') for d in r.diagnostics), r.diagnostics[:3]
    assert f['path_length'] > 0.0 and math.isfinite(f['planner_time'])


@pytest.mark.ros
def test_with_nothing_in_the_way_the_trip_is_the_planners_own(ros_context):
    # the harness adds no delay: each command is passed and applied over its own step
    empty = uw.Scenario('empty', uw.World(), (0.0, 0.0, 0.0), ((0.0, 0.0), (2.0, 0.0), (2.0, 1.5)), (2.0, 1.5),
                        math.inf)
    r = trips.run_trip(ros_context, empty, max_time=20.0, ns='/robot_0')
    assert r.reached and r.time == pytest.approx(uw.planner_time(empty), abs=1e-9)
    assert np.array_equal(r.sent, r.asked), 'every command passed unchanged'
    assert set(r.actions[1:]) == {'pass'}


@pytest.mark.ros
def test_a_pose_that_is_not_finite_stops_the_robot(ros_context):
    r = trips.run_trip(ros_context, 'facing_wall', max_time=3.0, fault='odom_nan', fault_step=25)
    assert r.figures()['collisions'] == 0
    assert np.all(r.sent[-50:] == 0.0), 'no valid pose for a second: a zero twist'
    assert any('not finite' in line[3] for line in r.rosout), r.rosout


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
