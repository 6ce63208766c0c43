"""rviz_intervention_node: RViz "Publish Point" clicks on obstacles are interventions.

  sub  /clicked_point    geometry_msgs/PointStamped  frame map (RViz's Publish Point tool)
  sub  /obstacle_markers visualization_msgs/MarkerArray  latched: obstacle ids, centres, radii
  sub  /<robot>/pose     geometry_msgs/PoseStamped   newest pose of each robot in ``robots``
  pub  /interventions    geometry_msgs/PoseStamped   as supervisor_node: the state of the robot
                         nearest the obstacle, relative to it (obstacle at the origin, axes
                         as map), frame obstacle_<id>, stamp = that pose's stamp

A point within an obstacle's radius plus ``tolerance`` is an intervention on it (the
nearest such obstacle); any other point, or one in another frame, is logged and
nothing is sent. The logic is supersafe_ros.interventions (shared with the console).
"""
from __future__ import annotations

import math

from rclpy.node import Node
from rclpy.qos import QoSProfile

from geometry_msgs.msg import PointStamped, PoseStamped
from visualization_msgs.msg import MarkerArray

from ..interventions import NoIntervention, intervention_at_point
from ..ros_io import rosmsg
from .common import declare, run_node
from .markers import ObstacleMarkers

# RViz's Publish Point tool publishes reliable, volatile, keep last
QOS_CLICKS = QoSProfile(depth=10)


class RvizInterventionNode(Node):
    def __init__(self, node_name='rviz_intervention', **kwargs):
        super().__init__(node_name, **kwargs)
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        self.tolerance = p('tolerance', 0.5, 'a click this far outside an obstacle\'s rim still '
                           'names it [m]', 0.0, 100.0)
        self.robots = [r.strip('/') for r in p('robots', ['robot_0'], 'robot namespaces to watch')]
        self.obstacles = ObstacleMarkers()
        self.poses = {r: None for r in self.robots}      # robot -> (state, stamp)
        self.intervention_pub = self.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
        self.create_subscription(MarkerArray, '/obstacle_markers', self.on_markers, rosmsg.QOS_LATCHED)
        for r in self.robots:
            self.create_subscription(PoseStamped, f'/{r}/pose', lambda m, r=r: self.on_pose(r, m),
                                     rosmsg.QOS_STREAM)
        self.create_subscription(PointStamped, '/clicked_point', self.on_click, QOS_CLICKS)
        self.get_logger().info(f'rviz interventions: clicks on /clicked_point within '
                               f'{self.tolerance} m of an obstacle; robots {self.robots}')

    def on_markers(self, msg: MarkerArray):
        try:
            self.obstacles.update(msg)
        except ValueError as exc:
            self.get_logger().error(f'/obstacle_markers rejected: {exc}')

    def on_pose(self, robot, msg: PoseStamped):
        try:
            self.poses[robot] = (rosmsg.pose_to_state(msg), msg.header.stamp)
        except rosmsg.MessageError as exc:
            self.get_logger().error(f'pose of {robot} rejected: {exc}', throttle_duration_sec=1.0)

    def on_click(self, msg: PointStamped):
        if msg.header.frame_id != rosmsg.MAP_FRAME:
            self.get_logger().warn(f"click ignored: frame '{msg.header.frame_id}', expected "
                                   f"'{rosmsg.MAP_FRAME}' (set RViz's fixed frame to map)")
            return
        states = {r: v[0] for r, v in self.poses.items() if v is not None}
        try:
            if not (math.isfinite(msg.point.x) and math.isfinite(msg.point.y)):
                raise NoIntervention(f'clicked point ({msg.point.x}, {msg.point.y}) is not finite')
            it = intervention_at_point((msg.point.x, msg.point.y), self.obstacles.centres,
                                       self.obstacles.radii, states, self.tolerance)
        except NoIntervention as exc:
            self.get_logger().warn(f'click ignored, nothing sent: {exc}')
            return
        stamp = self.poses[it.robot][1]
        self.intervention_pub.publish(
            rosmsg.state_to_pose(it.rel_state, stamp, rosmsg.obstacle_frame(it.obstacle_id)))
        self.get_logger().info(f'intervene (RViz click): obstacle {it.obstacle_id}, {it.robot} at '
                               f'({it.rel_state[0]:.2f}, {it.rel_state[1]:.2f}) from its centre')


def main(args=None):
    return run_node(RvizInterventionNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
