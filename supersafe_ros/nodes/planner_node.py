"""planner_node: the nominal goal-seeking planner of one robot (supersafe_ros.sim.planner).

Topics (relative; run it in the robot's namespace):
  sub  pose         geometry_msgs/PoseStamped  frame map
  sub  goal         geometry_msgs/PoseStamped  latched, from the world
  pub  cmd_vel_nav  geometry_msgs/Twist        angular.z = clip(gain * heading error, +-w_max),
                                               linear.x = speed (informative); one per pose
No goal yet, or an invalid pose: nothing is published (the filter and robot fail safe).
"""
from __future__ import annotations

from rclpy.node import Node

from geometry_msgs.msg import PoseStamped, Twist

from ..ros_io import rosmsg
from ..sim.planner import goal_seeking_turn_rate
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
        # every parameter takes effect at the next pose
        self.live = LiveParameters(self)
        for name in ('gain', 'w_max', 'speed'):
            self.live.add(name, lambda v, name=name: setattr(self, name, v))
        self.goal = None
        self.pub = self.create_publisher(Twist, 'cmd_vel_nav', rosmsg.QOS_STREAM)
        self.create_subscription(PoseStamped, 'pose', self.on_pose, rosmsg.QOS_STREAM)
        self.create_subscription(PoseStamped, 'goal', self.on_goal, rosmsg.QOS_LATCHED)

    def on_goal(self, msg: PoseStamped):
        try:
            x, y, _ = rosmsg.pose_to_state(msg)
        except rosmsg.MessageError as exc:
            self.get_logger().error(f'goal rejected: {exc}')
            return
        self.goal = (x, y)
        self.get_logger().debug(f'new goal ({x:.2f}, {y:.2f})')   # the world logs trips

    def on_pose(self, msg: PoseStamped):
        if self.goal is None:
            self.get_logger().warn('no goal yet; not commanding', throttle_duration_sec=5.0)
            return
        try:
            state = rosmsg.pose_to_state(msg)
        except rosmsg.MessageError as exc:
            self.get_logger().error(f'pose rejected: {exc}', throttle_duration_sec=1.0)
            return
        omega = goal_seeking_turn_rate(state, self.goal, self.gain, self.w_max)
        self.pub.publish(rosmsg.turn_rate_to_twist(omega, self.speed))


def main(args=None):
    return run_node(PlannerNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
