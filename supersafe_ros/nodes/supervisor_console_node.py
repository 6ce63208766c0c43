"""supervisor_console_node: a web page where a person supervises the team (issue 8).

The page (supersafe_ros/console/static) draws the field, goal lines, robots (pose,
heading, a short trail), obstacles and the world's counts; clicking an obstacle is an
intervention, published exactly as supervisor_node publishes one. The robots'
detection state is not shown (as in the paper).

  sub  /<robot>/pose          geometry_msgs/PoseStamped  newest pose of each robot
  sub  /obstacle_markers      visualization_msgs/MarkerArray  latched, ids and centres
  sub  /world/stats           diagnostic_msgs/DiagnosticStatus  latched, the counts
  pub  /interventions         geometry_msgs/PoseStamped  on a click: the nearest robot's pose
                              relative to the obstacle (obstacle at the origin, axes as map),
                              frame obstacle_<id>, stamp = that pose's stamp

The web server (aiohttp) runs in its own thread and asyncio loop; this node spins in
the main thread. See supersafe_ros/console/server.py for the hand-off and access rules.
"""
from __future__ import annotations

from rclpy.node import Node
from rclpy.time import Time

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from visualization_msgs.msg import MarkerArray

from ..console.server import ConsoleServer
from ..console.state import ConsoleState, Field
from ..ros_io import rosmsg
from .common import declare, run_node
from .markers import ObstacleMarkers


class SupervisorConsoleNode(Node):
    def __init__(self, node_name='supervisor_console', **kwargs):
        super().__init__(node_name, **kwargs)
        p = lambda *a, **k: declare(self, *a, **k, read_only=True)  # noqa: E731
        host = p('host', '127.0.0.1', 'address the web server binds; any non-loopback address '
                 'requires the token')
        port = p('port', 8765, 'TCP port of the web server (0: any free port)', 0, 65535)
        token = p('token', '', 'access token; empty: none on loopback, generated (and printed) '
                  'for any other address')
        rate = p('update_rate', 30.0, 'most state updates per second sent to each page', 1.0, 120.0)
        trail = p('trail_length', 40, 'positions in the trail drawn behind each robot', 0, 1000)
        self.robots = [r.strip('/') for r in p('robots', ['robot_0', 'robot_1'],
                                               'robot namespaces to show')]
        field = Field(
            half_width=p('half_width', 20.0, "the world's field: x in +-half_width [m]", 1.0, 1e4),
            half_height=p('half_height', 12.0, "the world's field: y in +-half_height [m]", 1.0, 1e4),
            goal_x=p('goal_x', 16.0, "the world's goal lines at x = +-goal_x [m]", 0.1, 1e4))
        self.state = ConsoleState(self.robots, field)
        self.obstacles = ObstacleMarkers()
        self.intervention_pub = self.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
        for r in self.robots:
            self.create_subscription(PoseStamped, f'/{r}/pose', lambda m, r=r: self.on_pose(r, m),
                                     rosmsg.QOS_STREAM)
        self.create_subscription(MarkerArray, '/obstacle_markers', self.on_markers, rosmsg.QOS_LATCHED)
        self.create_subscription(DiagnosticStatus, '/world/stats', self.on_stats, rosmsg.QOS_LATCHED)
        self.server = ConsoleServer(self.state, self.intervene, host=host, port=port, token=token,
                                    update_rate=rate, log=self.get_logger().info,
                                    page_config={'trail_length': trail})
        bound = self.server.start()
        # the URL (with the token when one is needed) is the one thing the operator needs
        self.get_logger().info(f'console: {self.server.url()}  (robots {self.robots}, port {bound})')

    def on_pose(self, robot, msg: PoseStamped):
        try:
            x, y, th = rosmsg.pose_to_state(msg)
            self.state.set_pose(robot, x, y, th, Time.from_msg(msg.header.stamp).nanoseconds)
        except ValueError as exc:
            self.get_logger().error(f'pose of {robot} rejected: {exc}', throttle_duration_sec=1.0)

    def on_markers(self, msg: MarkerArray):
        try:
            self.obstacles.update(msg)
        except ValueError as exc:
            self.get_logger().error(f'/obstacle_markers rejected: {exc}')
            return
        self.state.set_obstacles({i: (*c, self.obstacles.radii[i])
                                  for i, c in self.obstacles.centres.items()})

    def on_stats(self, msg: DiagnosticStatus):
        self.state.set_stats(rosmsg.diagnostic_values(msg))

    def intervene(self, obstacle_id: int) -> dict:
        """A click on an obstacle (called from the web server's thread)."""
        try:
            req = self.state.intervention(obstacle_id)
        except KeyError:
            return {'ok': False, 'message': f'obstacle {obstacle_id} is already gone'}
        except LookupError:
            return {'ok': False, 'message': 'no robot has reported a pose yet'}
        stamp = Time(nanoseconds=req.stamp_ns).to_msg()
        self.intervention_pub.publish(
            rosmsg.state_to_pose(req.rel_state, stamp, rosmsg.obstacle_frame(obstacle_id)))
        self.get_logger().info(f'intervention from the console: obstacle {obstacle_id}, '
                               f'nearest robot {req.robot}')
        return {'ok': True, 'robot': req.robot, 'message': f'obstacle {obstacle_id} removed'}

    def close(self):
        self.server.stop()


def main(args=None):
    return run_node(SupervisorConsoleNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
