"""The robots' side of world_node for its topic-level tests (not a test module).

``Robots`` publishes the poses and detections of ``ROBOTS`` and the supervisor's
interventions, and records what the world says (obstacles, stats, intervention log, events).
"""
import math

import numpy as np

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseArray, PoseStamped
from visualization_msgs.msg import MarkerArray

from supersafe_ros.nodes.markers import ObstacleMarkers
from supersafe_ros.ros_io import rosmsg

ROBOTS = ['robot_0', 'robot_1']


class Robots:
    """Plays the robots' pose and detections publishers; records what the world says."""

    def __init__(self, node):
        self.pose = {r: node.create_publisher(PoseStamped, f'/{r}/pose', rosmsg.QOS_STREAM) for r in ROBOTS}
        self.det = {r: node.create_publisher(PoseArray, f'/{r}/detections', rosmsg.QOS_STREAM)
                    for r in ROBOTS}
        self.intervene = node.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
        self.goals = {r: [] for r in ROBOTS}
        self.subs = [node.create_subscription(PoseStamped, f'/{r}/goal',
                                              lambda m, r=r: self.goals[r].append(m), rosmsg.QOS_LATCHED)
                     for r in ROBOTS]
        self.obstacles = ObstacleMarkers()
        self.marker_msgs = 0
        self.stats, self.log, self.events = [], [], []

        def on_markers(m):
            self.obstacles.update(m)
            self.marker_msgs += 1
        self.subs += [
            node.create_subscription(MarkerArray, '/obstacle_markers', on_markers, rosmsg.QOS_LATCHED),
            node.create_subscription(DiagnosticStatus, '/world/stats',
                                     lambda m: self.stats.append(rosmsg.diagnostic_values(m)),
                                     rosmsg.QOS_LATCHED),
            node.create_subscription(DiagnosticStatus, '/world/intervention_log',
                                     lambda m: self.log.append(rosmsg.diagnostic_values(m)),
                                     rosmsg.QOS_EVENTS),
            node.create_subscription(DiagnosticStatus, '/world/events',
                                     lambda m: self.events.append((m.name, rosmsg.diagnostic_values(m))),
                                     rosmsg.QOS_EVENTS)]

    def endpoints(self):
        return [*self.pose.values(), *self.det.values(), self.intervene, *self.subs]

    def send_pose(self, robot, x, y, th=0.0, t=0.0):
        msg = PoseStamped()          # by hand: the tests send NaN the converters refuse
        msg.header.frame_id = 'map'
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round(t * 1e9)), 10**9)
        msg.pose.position.x, msg.pose.position.y = float(x), float(y)
        if math.isfinite(th):
            msg.pose.orientation = rosmsg.yaw_to_quaternion(th)
        self.pose[robot].publish(msg)

    def send_detections(self, robot, xy):
        self.det[robot].publish(rosmsg.xy_to_posearray(np.asarray(xy, dtype=float).reshape(-1, 2)))

    def intervention(self, obstacle_id, rel, t=0.0, frame=None):
        msg = rosmsg.state_to_pose(rel, frame=frame or rosmsg.obstacle_frame(obstacle_id))
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(round(t * 1e9)), 10**9)
        self.intervene.publish(msg)
