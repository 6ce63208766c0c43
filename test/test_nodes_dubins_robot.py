"""dubins_robot_node at topic level: a real node in-process, on sim time driven by the test."""
import math

import numpy as np
import pytest
from rclpy.node import Node

from geometry_msgs.msg import PoseArray, PoseStamped, Twist
from visualization_msgs.msg import MarkerArray

from supersafe_ros.ros_io import rosmsg
from supersafe_ros.nodes.dubins_robot_node import DubinsRobotNode
from supersafe_ros.nodes.markers import obstacles_to_markers
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import wrap_angle

from graph_support import ClockDriver, Rosout, Spinner, live_and_read_only, matched, params, set_parameters

pytestmark = pytest.mark.ros   # rclpy nodes in this process


class Controller:
    """Plays the safety filter: answers every pose with a cmd_vel of ``self.omega``."""

    def __init__(self, node, ns):
        self.omega = 0.0
        self.poses, self.detections = [], []
        self.cmd = node.create_publisher(Twist, f'{ns}/cmd_vel', rosmsg.QOS_STREAM)
        self.pose_sub = node.create_subscription(PoseStamped, f'{ns}/pose', self.on_pose,
                                                 rosmsg.QOS_EVERY_SAMPLE)
        self.det_sub = node.create_subscription(PoseArray, f'{ns}/detections', self.detections.append,
                                                rosmsg.QOS_EVERY_SAMPLE)
        self.answer = True

    def on_pose(self, msg):
        self.poses.append((msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9,
                           rosmsg.pose_to_state(msg)))
        if self.answer:
            t = Twist()
            t.angular.z = float(self.omega)
            self.cmd.publish(t)


@pytest.fixture(scope='module')
def rig(ros_context):
    robot = DubinsRobotNode(context=ros_context, namespace='robot_0', parameter_overrides=params(
        use_sim_time=True, initial_x=1.0, initial_y=-2.0, initial_theta=0.3, speed=3.0, w_max=1.0,
        rate=20.0, command_timeout=0.5, seed=3, detections_period=0.0))
    driver = Node('robot_test_driver', context=ros_context)
    ctl = Controller(driver, '/robot_0')
    clock = ClockDriver(driver, ['robot_0'])
    rosout = Rosout(driver)
    spin = Spinner(ros_context, robot, driver)
    spin.until(lambda: matched(ctl.cmd, ctl.pose_sub, ctl.det_sub, clock.pub, *clock.subs),
               10.0, 'robot and driver to match')
    yield robot, ctl, clock, rosout, spin
    spin.shutdown()
    robot.destroy_node()
    driver.destroy_node()


def test_robot_parameters_are_live_or_read_only(rig):
    robot, ctl, clock, rosout, spin = rig
    assert live_and_read_only(robot, robot.live.names) == []
    assert robot.live.names == {'detections_period'}
    node = Node('robot_param_client', context=robot.context)
    spin.add(node)
    try:
        result, = set_parameters(spin, node, '/robot_0/dubins_robot', w_max=3.0)
        assert not result.successful and 'read-only' in result.reason
        assert robot.robot.omega_max == 1.0
    finally:
        spin.remove(node)
        node.destroy_node()


def test_robot_integrates_commands_on_exact_arcs_and_clips_w_max(rig):
    robot, ctl, clock, rosout, spin = rig
    ctl.omega = -5.0                        # |u| > w_max: the robot turns at -1 rad/s
    for _ in range(45):
        clock.step(spin)
    spin.until(lambda: ctl.poses and ctl.poses[-1][0] >= clock.now_ns * 1e-9 - 1e-9, 5.0, 'last pose')
    times = np.array([t for t, _ in ctl.poses])
    states = np.array([s for _, s in ctl.poses])
    start = np.array([1.0, -2.0, 0.3])
    parked = np.all(np.abs(states - start) < 1e-9, axis=1)
    assert parked[0] and not parked[-1]
    k0 = np.flatnonzero(parked)[-1]         # last pose before the first command took effect
    expected = DubinsCar(3.0, 1.0).flow(np.repeat(start[None], len(times) - k0, 0), -1.0,
                                        times[k0:] - times[k0])
    assert states[k0:, :2] == pytest.approx(expected[:, :2], abs=1e-6)
    assert np.all(np.abs(wrap_angle(states[k0:, 2] - expected[:, 2])) < 1e-6)
    assert times[-1] - times[k0] > 1.5      # it really drove
    assert np.all(np.diff(times) == pytest.approx(0.05, abs=1e-9))


def test_robot_rejects_nan_command_keeps_previous_then_loiters(rig):
    robot, ctl, clock, rosout, spin = rig
    ctl.omega = -1.0
    for _ in range(3):
        clock.step(spin)
    ctl.omega = float('nan')
    n0 = len(ctl.poses)
    for _ in range(30):
        clock.step(spin)                    # still stepping: the node answers and keeps going
    spin.until(lambda: rosout.has('dubins_robot', 'cmd_vel rejected', 'not finite'), 5.0,
               'the rejection to be logged')
    spin.until(lambda: len(ctl.poses) >= n0 + 30, 5.0, 'poses of every step')
    th = np.array([s[2] for _, s in ctl.poses[n0 - 1:]])
    rates = wrap_angle(np.diff(th)) / 0.05
    # the last valid command (-1) stays in force until command_timeout (0.5 s), then the
    # fail-safe loiter turns at +w_max
    assert rates[0] == pytest.approx(-1.0, abs=1e-6)
    assert rates[-1] == pytest.approx(1.0, abs=1e-6)
    switch = np.flatnonzero(rates > 0)[0]
    assert np.all(rates[:switch] == pytest.approx(-1.0, abs=1e-6))
    assert np.all(rates[switch:] == pytest.approx(1.0, abs=1e-6))
    assert 0.45 <= switch * 0.05 <= 0.65


def test_robot_detections_within_range_missed_20_percent_per_trip(ros_context):
    robot = DubinsRobotNode(context=ros_context, namespace='robot_1', parameter_overrides=params(
        use_sim_time=True, initial_x=0.0, initial_y=0.0, initial_theta=0.0, sensor_range=6.0,
        miss_probability=0.2, seed=11, detections_period=0.0))
    driver = Node('sensor_test_driver', context=ros_context)
    ctl = Controller(driver, '/robot_1')
    ctl.answer = False                      # no commands: the robot stays parked
    markers = driver.create_publisher(MarkerArray, '/obstacle_markers', rosmsg.QOS_LATCHED)
    goal = driver.create_publisher(PoseStamped, '/robot_1/goal', rosmsg.QOS_LATCHED)
    clock = ClockDriver(driver, ['robot_1'])
    spin = Spinner(ros_context, robot, driver)
    try:
        spin.until(lambda: matched(markers, goal, ctl.det_sub, clock.pub, *clock.subs), 10.0, 'matching')
        centres = np.array([[3.0, 0.0], [0.0, 4.0], [-5.0, 0.5], [2.0, -2.0], [4.0, 4.0], [9.0, 0.0]])
        markers.publish(obstacles_to_markers(range(10, 16), centres, 1.8))
        in_range = 5                        # (9, 0) is beyond 6 m
        spin.until(lambda: (clock.step(spin) or True) and ctl.detections
                   and len(ctl.detections[-1].poses) > 0, 10.0, 'obstacles to be sensed')
        seen_fraction, patterns = [], set()
        for trip in range(250):
            goal.publish(rosmsg.state_to_pose((16.0 * (-1) ** trip, 0.0, 0.0)))
            clock.step(spin)
            clock.step(spin)
            spin.until(lambda: ctl.detections and ctl.detections[-1].header.stamp.nanosec
                       + ctl.detections[-1].header.stamp.sec * 10**9 == clock.now_ns, 5.0, 'detections')
            a, b = ctl.detections[-2], ctl.detections[-1]
            xy = rosmsg.posearray_to_xy(b)
            assert np.array_equal(rosmsg.posearray_to_xy(a), xy)   # one draw per trip
            d = np.hypot(*(xy[:, None] - centres[None]).transpose(2, 0, 1))
            assert np.all(np.min(d, axis=1) < 1e-9)                  # real centres only
            assert not np.any(np.min(d, axis=0)[5:] < 1e-9)          # nothing out of range
            seen_fraction.append(len(xy) / in_range)
            patterns.add(tuple(np.round(xy.ravel(), 3)))
        missed = 1.0 - np.mean(seen_fraction)
        # 1250 draws: sd of the fraction ~ 0.011
        assert missed == pytest.approx(0.2, abs=0.05)
        assert len(patterns) >= 8           # drawn again per trip
    finally:
        spin.shutdown()
        robot.destroy_node()
        driver.destroy_node()


def sensor_rig(ros_context, ns, **extra):
    """A parked robot at the origin (sensor range 6 m, no misses) and a driver in ``ns``."""
    robot = DubinsRobotNode(context=ros_context, namespace=ns, parameter_overrides=params(
        use_sim_time=True, initial_x=0.0, initial_y=0.0, initial_theta=0.0, sensor_range=6.0,
        miss_probability=0.0, seed=5, detections_period=0.25, **extra))
    driver = Node(f'{ns}_world_driver', context=ros_context)
    ctl = Controller(driver, f'/{ns}')
    ctl.answer = False                      # no commands: the robot stays parked
    clock = ClockDriver(driver, [ns])
    spin = Spinner(ros_context, robot, driver)
    spin.until(lambda: matched(ctl.det_sub, ctl.pose_sub, clock.pub, *clock.subs), 10.0, 'matching')
    return robot, driver, ctl, clock, spin


CENTRES = np.array([[3.0, 0.0], [0.0, 4.0], [9.0, 0.0]])     # (9, 0) is out of range


def test_robot_publishes_no_detections_until_it_knows_the_world(ros_context):
    """An empty detections message says "nothing near": before the obstacle set has arrived the
    robot has not looked, so it publishes none, while it steps and after (issue 22: a filter
    passed the planner into an obstacle on the empty detections of a robot that had not yet
    received /obstacle_markers)."""
    robot, driver, ctl, clock, spin = sensor_rig(ros_context, 'robot_3')
    markers = None
    try:
        for _ in range(12):                 # 0.6 s sim, more than two detections periods
            clock.step(spin)
        spin.until(lambda: len(ctl.poses) >= 12, 5.0, 'the poses of every step')
        assert ctl.detections == []
        markers = driver.create_publisher(MarkerArray, '/obstacle_markers', rosmsg.QOS_LATCHED)
        markers.publish(obstacles_to_markers(range(20, 23), CENTRES, 1.8))
        spin.until(lambda: robot.world_known, 10.0, 'the obstacle set to arrive')
        clock.step(spin)
        spin.until(lambda: ctl.detections, 5.0, 'detections at the next step')
        xy = rosmsg.posearray_to_xy(ctl.detections[0])
        assert sorted(map(tuple, xy.tolist())) == [(0.0, 4.0), (3.0, 0.0)]
        stamp = ctl.detections[0].header.stamp
        assert stamp.sec * 10**9 + stamp.nanosec == clock.now_ns        # with that step's pose
    finally:
        if markers is not None:
            driver.destroy_publisher(markers)
        spin.shutdown()
        robot.destroy_node()
        driver.destroy_node()


def test_a_scan_robot_still_says_what_it_saw_for_the_worlds_false_positive_rule(ros_context):
    """sensors scan: odom and scan for its filter, and detections (the centres in range) for the
    world, which classifies an intervention by what the near robots saw."""
    robot, driver, ctl, clock, spin = sensor_rig(ros_context, 'robot_5', sensors='scan')
    markers = driver.create_publisher(MarkerArray, '/obstacle_markers', rosmsg.QOS_LATCHED)
    try:
        markers.publish(obstacles_to_markers(range(20, 23), CENTRES, 1.8))
        spin.until(lambda: robot.world_known, 10.0, 'the obstacle set to arrive')
        clock.step(spin)
        spin.until(lambda: ctl.detections, 5.0, 'detections')
        xy = rosmsg.posearray_to_xy(ctl.detections[-1])
        assert sorted(map(tuple, xy.tolist())) == [(0.0, 4.0), (3.0, 0.0)]
    finally:
        driver.destroy_publisher(markers)
        spin.shutdown()
        robot.destroy_node()
        driver.destroy_node()


def test_robot_reports_what_it_sees_before_the_clock_starts(ros_context):
    """Once it knows the world, a robot that has not stepped yet (no /clock) repeats its
    detections from the initial pose on the steady clock, so its filter can be ready before
    sim time starts; its first step then sends them with its pose."""
    robot, driver, ctl, clock, spin = sensor_rig(ros_context, 'robot_4')
    markers = driver.create_publisher(MarkerArray, '/obstacle_markers', rosmsg.QOS_LATCHED)
    try:
        markers.publish(obstacles_to_markers(range(20, 23), CENTRES, 1.8))
        spin.until(lambda: len(ctl.detections) >= 3, 10.0, 'three detections before any /clock')
        assert ctl.poses == [] and robot.steps == 0
        for msg in ctl.detections:
            assert sorted(map(tuple, rosmsg.posearray_to_xy(msg).tolist())) == [(0.0, 4.0), (3.0, 0.0)]
        before = len(ctl.detections)
        clock.step(spin)
        spin.until(lambda: ctl.poses and len(ctl.detections) > before, 5.0, 'the first step')
        stamp = ctl.detections[-1].header.stamp
        assert stamp.sec * 10**9 + stamp.nanosec == clock.now_ns
        n = len(ctl.detections)
        spin.spin_for(0.6)                  # no steps: the steady repeats have stopped
        assert len(ctl.detections) == n
    finally:
        driver.destroy_publisher(markers)
        spin.shutdown()
        robot.destroy_node()
        driver.destroy_node()


def test_planner_steers_to_its_goal_and_rejects_bad_poses(ros_context):
    from supersafe_ros.nodes.planner_node import PlannerNode
    planner = PlannerNode(context=ros_context, namespace='robot_7',
                          parameter_overrides=params(gain=2.0, w_max=0.8))
    driver = Node('planner_test_driver', context=ros_context)
    pose = driver.create_publisher(PoseStamped, '/robot_7/pose', rosmsg.QOS_STREAM)
    goal = driver.create_publisher(PoseStamped, '/robot_7/goal', rosmsg.QOS_LATCHED)
    out = []
    sub = driver.create_subscription(Twist, '/robot_7/cmd_vel_nav', out.append, rosmsg.QOS_STREAM)
    rosout = Rosout(driver)
    spin = Spinner(ros_context, planner, driver)
    try:
        spin.until(lambda: matched(pose, goal, sub), 10.0, 'matching')
        pose.publish(rosmsg.state_to_pose((0.0, 0.0, 0.0)))
        spin.until(lambda: rosout.has('planner', 'no goal yet'), 5.0, 'the no-goal warning')
        assert out == []                                   # no goal: no command
        goal.publish(rosmsg.state_to_pose((0.0, 10.0, 0.0)))
        spin.until(lambda: planner.goal is not None, 5.0, 'the goal')
        pose.publish(rosmsg.state_to_pose((0.0, 0.0, 0.0)))
        spin.until(lambda: out, 5.0, 'a command')
        assert out[-1].angular.z == pytest.approx(0.8)     # pi/2 to the left, saturated
        bad = rosmsg.state_to_pose((0.0, 0.0, 0.0))
        bad.pose.orientation.w = float('nan')
        pose.publish(bad)
        spin.until(lambda: rosout.has('planner', 'pose rejected'), 5.0, 'the rejection log')
        n = len(out)
        pose.publish(rosmsg.state_to_pose((0.0, 0.0, math.pi / 2 - 0.1)))
        spin.until(lambda: len(out) == n + 1, 5.0, 'a command after the bad pose')
        assert out[-1].angular.z == pytest.approx(0.2)     # gain 2 x 0.1 rad
        # `ros2 param set /robot_7/planner gain 5.0`: the next command uses it
        assert live_and_read_only(planner, planner.live.names) == []
        result, = set_parameters(spin, driver, '/robot_7/planner', gain=5.0)
        assert result.successful
        result, = set_parameters(spin, driver, '/robot_7/planner', gain=-1.0)   # out of range
        assert not result.successful
        pose.publish(rosmsg.state_to_pose((0.0, 0.0, math.pi / 2 - 0.1)))
        spin.until(lambda: len(out) == n + 2, 5.0, 'a command after the change')
        assert out[-1].angular.z == pytest.approx(0.5)     # gain 5 x 0.1 rad
    finally:
        spin.shutdown()
        planner.destroy_node()
        driver.destroy_node()


def test_robot_teleports_on_initialpose_and_rejects_nan(rig):
    from geometry_msgs.msg import PoseWithCovarianceStamped
    robot, ctl, clock, rosout, spin = rig
    driver_pub = ctl.cmd  # any node of the rig's driver can publish; reuse its node
    node = [n for n in spin.executor.get_nodes() if n.get_name() == 'robot_test_driver'][0]
    pub = node.create_publisher(PoseWithCovarianceStamped, '/robot_0/initialpose', rosmsg.QOS_EVENTS)
    spin.until(lambda: pub.get_subscription_count() > 0, 10.0, 'initialpose to match')
    # other tests drove /clock with their own drivers: resume past all of them
    clock.now_ns = 100 * 10**9
    ctl.omega = 0.0
    clock.step(spin)
    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = 'map'
    msg.pose.pose = rosmsg.state_to_pose((-8.0, 1.25, 0.0)).pose
    ctl.omega = 0.0
    pub.publish(msg)
    spin.until(lambda: rosout.has('dubins_robot', 'teleported'), 5.0, 'the teleport')
    n0 = len(ctl.poses)
    clock.step(spin)
    clock.step(spin)
    spin.until(lambda: len(ctl.poses) >= n0 + 2, 5.0, 'poses after the teleport')
    x, y, th = ctl.poses[-1][1]
    assert y == pytest.approx(1.25, abs=1e-6) and th == pytest.approx(0.0, abs=1e-6)
    assert -8.0 <= x <= -8.0 + 3.0 * 0.1 + 1e-6      # straight on from the new pose
    bad = PoseWithCovarianceStamped()
    bad.header.frame_id = 'map'
    bad.pose.pose.position.x = float('nan')
    bad.pose.pose.orientation.w = 1.0
    pub.publish(bad)
    spin.until(lambda: rosout.has('dubins_robot', 'initialpose rejected'), 5.0, 'the rejection')
    clock.step(spin)
    spin.until(lambda: len(ctl.poses) >= n0 + 3, 5.0, 'the next pose')
    assert np.all(np.isfinite(ctl.poses[-1][1])) and ctl.poses[-1][1][0] > x
    del driver_pub
