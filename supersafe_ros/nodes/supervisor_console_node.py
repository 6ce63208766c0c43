"""supervisor_console_node: a web page where a person supervises the team (issue 8).

The page (supersafe_ros/console/static) draws the field, goal lines, robots (pose,
heading, a short trail), obstacles and the world's counts; clicking an obstacle is an
intervention, published exactly as supervisor_node publishes one. The robots'
detection state is not shown (as in the paper).

  sub  /<robot>/pose          geometry_msgs/PoseStamped  newest pose of each robot
  sub  /obstacle_markers      visualization_msgs/MarkerArray  latched, ids and centres
  sub  /world/stats           diagnostic_msgs/DiagnosticStatus  latched, the counts
  sub  /world/intervention_log  diagnostic_msgs/DiagnosticStatus  the world's answer to a click
  sub  /world/events          diagnostic_msgs/DiagnosticStatus  crashes, marked on the page
  pub  /interventions         geometry_msgs/PoseStamped  on a click: the nearest robot's pose
                              relative to the obstacle (obstacle at the origin, axes as map),
                              frame obstacle_<id>, stamp = that pose's stamp

The topics are wired by supersafe_ros/console/bridge.py. The web server (aiohttp) runs
in its own thread and asyncio loop; this node spins in the main thread. See
supersafe_ros/console/server.py for the hand-off and access rules.
"""
from __future__ import annotations

from rclpy.node import Node

from ..console.bridge import ConsoleBridge
from ..console.server import ConsoleServer
from ..console.state import ConsoleState, Field
from .common import declare, run_node


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
        max_connections = p('max_connections', 8, 'most pages (WebSockets) open at once; more get 503',
                            1, 1000)
        per_second = p('interventions_per_second', 3.0, 'most interventions published in any one second '
                       '(and one per obstacle until the world answers); more clicks are refused', 1.0, 100.0)
        confirm = p('confirm_timeout', 3.0, "wall seconds a click waits for the world's answer", 0.1, 60.0)
        header_timeout = p('header_timeout', 10.0, 'wall seconds a connection has to send a whole request\'s '
                           'headers (also how long an idle keep-alive connection stays open)', 0.1, 600.0)
        max_unfinished = p('max_unfinished', 64, 'most connections without a complete request at once; '
                           'when one more opens, the oldest is closed', 1, 10000)
        self.robots = [r.strip('/') for r in p('robots', ['robot_0', 'robot_1'],
                                               'robot namespaces to show')]
        field = Field(
            half_width=p('half_width', 20.0, "the world's field: x in +-half_width [m]", 1.0, 1e4),
            half_height=p('half_height', 12.0, "the world's field: y in +-half_height [m]", 1.0, 1e4),
            goal_x=p('goal_x', 16.0, "the world's goal lines at x = +-goal_x [m]", 0.1, 1e4))
        self.state = ConsoleState(self.robots, field)
        self.bridge = ConsoleBridge(self, self.state, per_second=per_second, confirm_timeout=confirm)
        self.server = ConsoleServer(self.state, self.bridge.intervene, host=host, port=port, token=token,
                                    update_rate=rate, log=self.get_logger().info,
                                    page_config={'trail_length': trail}, max_connections=max_connections,
                                    confirm_timeout=confirm, unanswered=self.bridge.unanswered,
                                    header_timeout=header_timeout, max_unfinished=max_unfinished)
        bound = self.server.start()
        # the URL (with the token when one is needed) is the one thing the operator needs
        self.get_logger().info(f'console: {self.server.url()}  (robots {self.robots}, port {bound})')

    def close(self):
        self.server.stop()


def main(args=None):
    return run_node(SupervisorConsoleNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
