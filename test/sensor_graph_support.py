"""A robot that publishes what a real one does, its planner and its filter, in one process, in
lockstep with a test-driven /clock (not a test module; see test_nodes_sensor_filter.py).

The graph: dubins_robot_node (``sensors: scan``: odom, scan, TwistStamped cmd_vel, follows its
commanded speed) <- safety_filter_node (odometry on pose, the detections as the test says,
TwistStamped) <- planner_node (odometry, slows near its goal, stops there). The test's own node
publishes the obstacles (/obstacle_markers: discs of three sizes) and the goal, steps the clock,
and records the robot's true poses, the planner's commands and the filter's.
"""
from __future__ import annotations

import math

import numpy as np
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped, TwistStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import LaserScan, PointCloud2, PointField
from visualization_msgs.msg import Marker, MarkerArray

from supersafe_ros.nodes.dubins_robot_node import DubinsRobotNode
from supersafe_ros.nodes.planner_node import PlannerNode
from supersafe_ros.nodes.fleet_safety_filter_node import FleetSafetyFilterNode
from supersafe_ros.nodes.safety_filter_node import SafetyFilterNode
from supersafe_ros.ros_io import rosmsg

from graph_support import ClockDriver, Spinner, matched, params

NS = '/robot_0'
# a field of discs of three sizes between the start (-16, 0) and the goal (16, 0)
OBSTACLES = ((-8.0, 0.6, 1.8), (-1.0, -0.5, 0.8), (6.0, 0.4, 2.6), (11.0, -3.5, 0.8), (2.0, 4.5, 1.8))
START, GOAL = (-16.0, 0.0, 0.0), (16.0, 0.0)


def obstacle_markers(obstacles, frame='map') -> MarkerArray:
    out = MarkerArray()
    for i, (x, y, r) in enumerate(obstacles):
        m = Marker()
        m.header.frame_id = frame
        m.ns, m.id, m.type, m.action = 'obstacles', i, Marker.CYLINDER, Marker.ADD
        m.pose.position.x, m.pose.position.y, m.pose.orientation.w = float(x), float(y), 1.0
        m.scale.x = m.scale.y = 2.0 * float(r)
        m.scale.z = 0.5
        out.markers.append(m)
    return out


def xy_cloud(header, xy, dtype='<f4', pad=4) -> PointCloud2:
    """A PointCloud2 of points (x, y, z=0) of ``dtype``, each followed by ``pad`` bytes."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    size = np.dtype(dtype).itemsize
    fields = [('x', dtype), ('y', dtype), ('z', dtype)] + ([('pad', f'V{pad}')] if pad else [])
    points = np.zeros(len(xy), dtype=fields)
    points['x'], points['y'] = xy[:, 0], xy[:, 1]
    msg = PointCloud2()
    msg.header = header
    datatype = PointField.FLOAT32 if size == 4 else PointField.FLOAT64
    msg.fields = [PointField(name=n, offset=i * size, datatype=datatype, count=1) for i, n in enumerate('xyz')]
    msg.is_bigendian = dtype.startswith('>')
    msg.height, msg.width = 1, len(xy)
    msg.point_step = points.dtype.itemsize
    msg.row_step = msg.point_step * len(xy)
    msg.data = points.tobytes()
    msg.is_dense = True
    return msg


def scan_cloud(scan) -> PointCloud2:
    """A scan's returns as a cloud in its frame (the beams with a finite range)."""
    r = np.asarray(scan.ranges, dtype=float)
    a = scan.angle_min + scan.angle_increment * np.arange(len(r))
    ok = np.isfinite(r)
    return xy_cloud(scan.header, np.column_stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])]))


class SensorGraph:
    """The graph of the module, built in ``ctx``; ``filter_params`` are the filter's own."""

    def __init__(self, ctx, detections_type='laser_scan', detections_topic='scan', fleet=False, **filter_params):
        """``fleet``: the filter is a fleet_safety_filter_node in / whose one robot is robot_0 (else a
        safety_filter_node in robot_0's namespace)."""
        sim = dict(use_sim_time=True)
        self.robot = DubinsRobotNode(context=ctx, namespace=NS, parameter_overrides=params(
            **sim, initial_x=START[0], initial_y=START[1], initial_theta=START[2], speed=3.0, w_max=1.0,
            rate=20.0, command_timeout=0.5, timeout_behavior='stop', miss_probability=0.0, seed=1,
            sensors='scan', cmd_vel_stamped=True, follow_speed=True, lockstep=True, sensor_range=10.0))
        values = params(**sim, lockstep=True, pose_type='odometry', cmd_vel_stamped=True,
                        detections_type=detections_type, level_set_markers=False, **filter_params)
        if fleet:
            self.filter = FleetSafetyFilterNode(context=ctx, cli_args=[
                '--ros-args', '-r', f'{NS}/pose:={NS}/odom', '-r', f'{NS}/detections:={NS}/{detections_topic}'],
                parameter_overrides=values + params(robots=[NS.strip('/')]))
        else:
            self.filter = SafetyFilterNode(context=ctx, namespace=NS, cli_args=[
                '--ros-args', '-r', 'pose:=odom', '-r', f'detections:={detections_topic}'],
                parameter_overrides=values)
        self.planner = PlannerNode(context=ctx, namespace=NS, cli_args=['--ros-args', '-r', 'pose:=odom'],
                                   parameter_overrides=params(**sim, pose_type='odometry', cmd_vel_stamped=True,
                                                              speed=3.0, slow_radius=8.0, goal_tolerance=1.0,
                                                              goal_wait=1.0))
        self.test = Node('sensor_graph_test', context=ctx)
        t = self.test
        self.markers = t.create_publisher(MarkerArray, '/obstacle_markers', rosmsg.QOS_LATCHED)
        self.goal = t.create_publisher(PoseStamped, f'{NS}/goal', rosmsg.QOS_LATCHED)
        self.poses, self.asked, self.sent = [], [], []
        self.subs = [
            t.create_subscription(PoseStamped, f'{NS}/pose', lambda m: self.poses.append(rosmsg.pose_to_state(m)),
                                  rosmsg.QOS_EVERY_SAMPLE),
            t.create_subscription(TwistStamped, f'{NS}/cmd_vel_nav', lambda m: self.asked.append(m.twist.linear.x),
                                  rosmsg.QOS_EVERY_SAMPLE),
            t.create_subscription(TwistStamped, f'{NS}/cmd_vel', self._on_sent, rosmsg.QOS_EVERY_SAMPLE),
        ]
        self.actions = []
        self.subs.append(t.create_subscription(
            DiagnosticStatus, f'{NS}/safety_filter/state',
            lambda m: self.actions.append(rosmsg.diagnostic_values(m)['action']), rosmsg.QOS_EVERY_SAMPLE))
        self.odom_sub = t.create_subscription(Odometry, f'{NS}/odom', lambda m: None, rosmsg.QOS_STREAM)
        self.detector = None
        if detections_topic == 'markers':   # a detector that sends the full set of discs every step
            self.detector = t.create_publisher(MarkerArray, f'{NS}/markers', rosmsg.QOS_STREAM)
            self.subs.append(self.detector)
        if detections_topic == 'cloud':     # the scan's returns as a PointCloud2 of the sensor's frame
            self.cloud = t.create_publisher(PointCloud2, f'{NS}/cloud', rosmsg.QOS_STREAM)
            self.subs += [t.create_subscription(LaserScan, f'{NS}/scan', self._scan_to_cloud, rosmsg.QOS_STREAM),
                          self.cloud]
        self.clock = ClockDriver(t, ['robot_0'])
        self.spin = Spinner(ctx, self.robot, self.filter, self.planner, t)

    def _scan_to_cloud(self, scan):
        self.cloud.publish(scan_cloud(scan))

    def _on_sent(self, msg):
        # the largest linear.x the planner had asked for by now (its latest, and the one before:
        # the filter may judge the previous command at the next pose in lockstep)
        recent = self.asked[-2:] if self.asked else [0.0]
        self.sent.append((msg.twist.linear.x, max(recent)))

    def start(self, obstacles=OBSTACLES):
        self.markers.publish(obstacle_markers(obstacles))
        goal = rosmsg.state_to_pose((GOAL[0], GOAL[1], 0.0))
        self.goal.publish(goal)
        self.spin.until(lambda: matched(self.markers, self.goal, *self.subs, self.clock.pub, *self.clock.subs),
                        20.0, 'the graph to match')
        self.spin.until(lambda: self.robot.world_known, 10.0, 'the robot to know the world')
        self.spin.until(lambda: self.planner.goal is not None, 10.0, 'the planner\'s goal')

    def run(self, steps: int, dt: float = 0.05):
        """Step the clock until the robot has stood at the goal or ``steps`` steps; True if it got there."""
        for _ in range(steps):
            if self.detector is not None:
                self.detector.publish(obstacle_markers(OBSTACLES))
            self.clock.step(self.spin, dt, timeout=20.0)
            if self.poses and math.hypot(self.poses[-1][0] - GOAL[0], self.poses[-1][1] - GOAL[1]) < 1.5:
                return True
        return False

    def collisions(self, obstacles=OBSTACLES) -> int:
        """Poses inside an obstacle (its centre nearer than its radius)."""
        if not self.poses:
            return 0
        p = np.asarray(self.poses)[:, :2]
        o = np.asarray(obstacles, dtype=float)
        d = np.hypot(p[:, None, 0] - o[None, :, 0], p[:, None, 1] - o[None, :, 1]) - o[None, :, 2]
        return int((d < 0.0).any(axis=1).sum())

    def close(self):
        self.spin.shutdown()
        for n in (self.robot, self.filter, self.planner, self.test):
            close = getattr(n, 'close', None)
            if close is not None:
                close()
            n.destroy_node()
