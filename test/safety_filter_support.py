"""A test node that drives one safety_filter_node (not a test module).

``Driver`` plays robot, sensor, planner and learner on the filter's topics in ``NS`` and
records what the filter publishes (``on_cmd_vel``/``on_state``: what is kept of each message;
filter_process_support's driver keeps arrival times); ``state`` places a pose relative to
``OBSTACLE``.
"""
import math

import numpy as np

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Pose, PoseArray, PoseStamped, Twist
from std_msgs.msg import Float32MultiArray

from supersafe_ros.nodes.safety_filter_node import VALUE_FUNCTION_TOPIC
from supersafe_ros.ros_io import rosmsg

NS = '/robot_0'
OBSTACLE = (4.0, -2.0)
SHAPE = [41, 41, 24]


def state(rel_x, rel_y, theta):
    return (OBSTACLE[0] + rel_x, OBSTACLE[1] + rel_y, theta)


class Driver:
    """Plays robot, sensor, planner and learner for one filter; records its outputs."""

    def __init__(self, ctx, ns=NS, name='filter_test_driver'):
        from rclpy.node import Node
        self.node = Node(name, namespace=ns, context=ctx)
        n = self.node
        self.pose = n.create_publisher(PoseStamped, 'pose', rosmsg.QOS_STREAM)
        self.det = n.create_publisher(PoseArray, 'detections', rosmsg.QOS_STREAM)
        self.cmd = n.create_publisher(Twist, 'cmd_vel_nav', rosmsg.QOS_STREAM)
        self.vf = n.create_publisher(Float32MultiArray, VALUE_FUNCTION_TOPIC, rosmsg.QOS_LATCHED)
        self.out, self.states = [], []
        self.out_sub = n.create_subscription(Twist, 'cmd_vel', self.on_cmd_vel, rosmsg.QOS_STREAM)
        self.state_sub = n.create_subscription(DiagnosticStatus, 'safety_filter/state', self.on_state,
                                               rosmsg.QOS_STREAM)

    def on_cmd_vel(self, msg):
        self.out.append(msg)

    def on_state(self, msg):
        self.states.append(msg)

    def endpoints(self):
        return (self.pose, self.det, self.cmd, self.vf, self.out_sub, self.state_sub)

    def send(self, pose=None, detections=(OBSTACLE,), cmd=None, frame='map'):
        if detections is not None:
            msg = PoseArray()   # built by hand: the test sends NaNs the converters refuse
            msg.header.frame_id = frame
            for x, y in np.asarray(detections, dtype=float).reshape(-1, 2):
                p = Pose()
                p.position.x, p.position.y, p.orientation.w = float(x), float(y), 1.0
                msg.poses.append(p)
            self.det.publish(msg)
        if pose is not None:
            msg = PoseStamped()
            msg.header.frame_id = frame
            msg.pose.position.x, msg.pose.position.y = float(pose[0]), float(pose[1])
            if math.isfinite(pose[2]):
                msg.pose.orientation = rosmsg.yaw_to_quaternion(pose[2])
            else:
                msg.pose.orientation.z = float('nan')
            self.pose.publish(msg)
        if cmd is not None:
            self.cmd.publish(rosmsg.turn_rate_to_twist(cmd, 3.0))

    def last_state(self):
        return rosmsg.diagnostic_values(self.states[-1]) if self.states else {}
