"""The console's ROS side, on any rclpy node: topics in, ``ConsoleState`` updated,
clicks out as interventions. Used by supervisor_console_node and by the participant
session (which swaps graphs under one web server).

  sub  /<robot>/pose         geometry_msgs/PoseStamped  newest pose of each robot
  sub  /obstacle_markers     visualization_msgs/MarkerArray  latched, ids and centres
  sub  /world/stats          diagnostic_msgs/DiagnosticStatus  latched, the counts
  pub  /interventions        geometry_msgs/PoseStamped  the nearest robot's pose relative to the
                             obstacle, frame obstacle_<id>, stamp of that pose (as supervisor_node)
"""
from __future__ import annotations

from rclpy.time import Time

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from visualization_msgs.msg import MarkerArray

from ..nodes.markers import ObstacleMarkers
from ..ros_io import rosmsg
from .state import ConsoleState


class ConsoleBridge:
    def __init__(self, node, state: ConsoleState, on_pose=None):
        self.node = node
        self.state = state
        self.obstacles = ObstacleMarkers()
        self.extra_on_pose = on_pose          # fn(robot, msg) after the state is updated
        self.intervention_pub = node.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
        self.pose_subscriptions = [
            node.create_subscription(PoseStamped, f'/{r}/pose', lambda m, r=r: self.on_pose(r, m),
                                     rosmsg.QOS_EVERY_SAMPLE)
            for r in state.robots]
        node.create_subscription(MarkerArray, '/obstacle_markers', self.on_markers, rosmsg.QOS_LATCHED)
        node.create_subscription(DiagnosticStatus, '/world/stats', self.on_stats, rosmsg.QOS_LATCHED)
        self.published = []                   # (obstacle id, robot) of every intervention sent

    def on_pose(self, robot, msg: PoseStamped):
        try:
            x, y, th = rosmsg.pose_to_state(msg)
            self.state.set_pose(robot, x, y, th, Time.from_msg(msg.header.stamp).nanoseconds)
        except ValueError as exc:
            self.node.get_logger().error(f'pose of {robot} rejected: {exc}', throttle_duration_sec=1.0)
        if self.extra_on_pose is not None:
            self.extra_on_pose(robot, msg)

    def on_markers(self, msg: MarkerArray):
        try:
            self.obstacles.update(msg)
        except ValueError as exc:
            self.node.get_logger().error(f'/obstacle_markers rejected: {exc}')
            return
        self.state.set_obstacles({i: (*c, self.obstacles.radii[i])
                                  for i, c in self.obstacles.centres.items()})

    def on_stats(self, msg: DiagnosticStatus):
        self.state.set_stats(rosmsg.diagnostic_values(msg))

    def intervene(self, obstacle_id: int) -> dict:
        """A click on an obstacle (called from the web server's thread; publishing is
        thread-safe in rclpy)."""
        try:
            req = self.state.intervention(obstacle_id)
        except KeyError:
            return {'ok': False, 'message': f'obstacle {obstacle_id} is already gone'}
        except LookupError:
            return {'ok': False, 'message': 'no robot has reported a pose yet'}
        stamp = Time(nanoseconds=req.stamp_ns).to_msg()
        self.intervention_pub.publish(
            rosmsg.state_to_pose(req.rel_state, stamp, rosmsg.obstacle_frame(obstacle_id)))
        self.published.append((obstacle_id, req.robot))
        self.node.get_logger().info(f'intervention from the console: obstacle {obstacle_id}, '
                                    f'nearest robot {req.robot}')
        return {'ok': True, 'robot': req.robot}
