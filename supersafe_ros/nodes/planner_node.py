"""planner_node: the nominal goal-seeking planner of one robot (supersafe_ros.sim.planner).

Topics (relative; run it in the robot's namespace):
  sub  pose         geometry_msgs/PoseStamped  frame map
  sub  goal         geometry_msgs/PoseStamped  latched, from the world
  pub  cmd_vel_nav  geometry_msgs/Twist        angular.z = clip(gain * heading error, +-w_max),
                                               linear.x = speed (informative); one per pose
No goal yet, or an invalid pose: nothing is published (the filter and robot fail safe).

Near its goal it slows and stops there for a moment (``sim.planner.approach_speed``):
linear.x falls from ``speed`` within ``slow_radius`` of the goal and is 0 within
``goal_tolerance``, where it waits ``goal_wait`` seconds (turn rate 0); then it heads for
the newest goal, or creeps on at a fifth of ``speed`` while no new one has come (the team's
world hands out the next goal once the robot crosses the goal line). ``pose_type`` odometry
reads nav_msgs/Odometry on pose; ``cmd_vel_stamped`` publishes geometry_msgs/TwistStamped.
The defaults (no slowing, no stop) are the study's constant-speed planner.
"""
from __future__ import annotations

from rclpy.node import Node

import math

from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry

from ..ros_io import rosmsg
from ..sim.planner import approach_speed, goal_seeking_turn_rate
from .common import LiveParameters, declare, run_node


class PlannerNode(Node):
    def __init__(self, node_name='planner', **kwargs):
        super().__init__(node_name, **kwargs)
        self.gain = declare(self, 'gain', 2.0, 'turn rate per radian of heading error [1/s]; live',
                            0.0, 100.0)
        self.w_max = declare(self, 'w_max', 1.0, 'largest turn rate the planner asks for [rad/s]; live',
                             0.0, 20.0)
        self.speed = declare(self, 'speed', 3.0, 'linear.x written into cmd_vel_nav (informative); live',
                             0.0, 100.0)
        self.slow_radius = declare(self, 'slow_radius', 0.0, 'linear.x falls from speed within this distance '
                                   'of the goal [m]; 0 = never slows; live', 0.0, 1000.0)
        self.goal_tolerance = declare(self, 'goal_tolerance', 0.0, 'linear.x 0 within this distance of the '
                                      'goal [m]; live', 0.0, 1000.0)
        self.goal_wait = declare(self, 'goal_wait', 0.0, 'stopped this long on reaching the goal [s]; live',
                                 0.0, 3600.0)
        pose_type = declare(self, 'pose_type', 'pose_stamped', 'pose_stamped or odometry (read-only)',
                            read_only=True)
        self.stamped = declare(self, 'cmd_vel_stamped', False, 'publish TwistStamped (read-only)', read_only=True)
        # every parameter takes effect at the next pose
        self.live = LiveParameters(self)
        for name in ('gain', 'w_max', 'speed', 'slow_radius', 'goal_tolerance', 'goal_wait'):
            self.live.add(name, lambda v, name=name: setattr(self, name, v))
        self.goal = None
        self.arrived = None        # when it reached the current goal (its clock's seconds)
        self.pub = self.create_publisher(TwistStamped if self.stamped else Twist, 'cmd_vel_nav', rosmsg.QOS_STREAM)
        self.create_subscription(Odometry if pose_type == 'odometry' else PoseStamped, 'pose', self.on_pose,
                                 rosmsg.QOS_STREAM)
        self.create_subscription(PoseStamped, 'goal', self.on_goal, rosmsg.QOS_LATCHED)

    def on_goal(self, msg: PoseStamped):
        try:
            x, y, _ = rosmsg.pose_to_state(msg)
        except rosmsg.MessageError as exc:
            self.get_logger().error(f'goal rejected: {exc}')
            return
        self.goal = (x, y)
        now = self.get_clock().now().nanoseconds * 1e-9
        if self.arrived is not None and now - self.arrived >= self.goal_wait:
            self.arrived = None          # (while it waits at the old goal, the wait goes on)
        self.get_logger().debug(f'new goal ({x:.2f}, {y:.2f})')   # the world logs trips

    def on_pose(self, msg):
        if self.goal is None:
            self.get_logger().warn('no goal yet; not commanding', throttle_duration_sec=5.0)
            return
        try:
            state = (rosmsg.header_pose_to_state(msg.header, msg.pose.pose, rosmsg.MAP_FRAME)
                     if isinstance(msg, Odometry) else rosmsg.pose_to_state(msg))
        except rosmsg.MessageError as exc:
            self.get_logger().error(f'pose rejected: {exc}', throttle_duration_sec=1.0)
            return
        omega = goal_seeking_turn_rate(state, self.goal, self.gain, self.w_max)
        distance = math.hypot(self.goal[0] - state[0], self.goal[1] - state[1])
        speed = approach_speed(distance, self.speed, self.slow_radius, self.goal_tolerance)
        now = self.get_clock().now().nanoseconds * 1e-9
        if speed == 0.0 and self.arrived is None:
            self.arrived = now
        if self.arrived is not None:
            if now - self.arrived < self.goal_wait:
                speed = omega = 0.0          # a moment at the goal
            elif speed == 0.0:
                # waited and no new goal yet: creep on at the least speed (the team's world
                # gives the next goal when the robot crosses the goal line)
                speed = 0.2 * self.speed
        twist = rosmsg.turn_rate_to_twist(omega if speed > 0.0 else 0.0, speed)
        if self.stamped:
            out = TwistStamped()
            out.header.stamp, out.header.frame_id = msg.header.stamp, 'base_link'
            out.twist = twist
            twist = out
        self.pub.publish(twist)


def main(args=None):
    return run_node(PlannerNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
