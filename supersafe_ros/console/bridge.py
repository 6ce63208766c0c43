"""The console's ROS side, on any rclpy node: topics in, ``ConsoleState`` updated,
clicks out as interventions, and the world's answer back to the page. Used by
supervisor_console_node and by the participant session (which swaps graphs under one
web server).

  sub  /<robot>/pose         geometry_msgs/PoseStamped  newest pose of each robot
  sub  /obstacle_markers     visualization_msgs/MarkerArray  latched, ids and centres
  sub  /world/stats          diagnostic_msgs/DiagnosticStatus  latched, the counts
  sub  /world/intervention_log  diagnostic_msgs/DiagnosticStatus  what the world did with
                             each intervention (the answer a click gets)
  sub  /world/events         diagnostic_msgs/DiagnosticStatus  crashes, marked on the page
  pub  /interventions        geometry_msgs/PoseStamped  the nearest robot's pose relative to the
                             obstacle, frame obstacle_<id>, stamp of that pose (as supervisor_node)

A click is published only if the ``InterventionLimiter`` lets it through (one per
obstacle at a time, at most ``per_second``); its answer is a future that the world's
/world/intervention_log record for that obstacle completes.
"""
from __future__ import annotations

from concurrent.futures import Future
import threading

from rclpy.time import Time

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from visualization_msgs.msg import MarkerArray

from ..nodes.markers import ObstacleMarkers
from ..ros_io import rosmsg
from .limits import InterventionLimiter
from .state import ConsoleState


class ConsoleBridge:
    def __init__(self, node, state: ConsoleState, on_pose=None, per_second: float = 3.0,
                 confirm_timeout: float = 3.0):
        self.node = node
        self.state = state
        self.obstacles = ObstacleMarkers()
        self.extra_on_pose = on_pose          # fn(robot, msg) after the state is updated
        self.limiter = InterventionLimiter(per_second, confirm_timeout)
        self.confirm_timeout = confirm_timeout
        self._waiting: dict[int, list] = {}  # obstacle -> futures of the clicks that sent it
        self._lock = threading.Lock()
        self.intervention_pub = node.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
        self.pose_subscriptions = [
            node.create_subscription(PoseStamped, f'/{r}/pose', lambda m, r=r: self.on_pose(r, m),
                                     rosmsg.QOS_EVERY_SAMPLE)
            for r in state.robots]
        node.create_subscription(MarkerArray, '/obstacle_markers', self.on_markers, rosmsg.QOS_LATCHED)
        node.create_subscription(DiagnosticStatus, '/world/stats', self.on_stats, rosmsg.QOS_LATCHED)
        node.create_subscription(DiagnosticStatus, '/world/intervention_log', self.on_world_log,
                                 rosmsg.QOS_LOG)
        node.create_subscription(DiagnosticStatus, '/world/events', self.on_event, rosmsg.QOS_LOG)
        self.published = []                   # (obstacle id, robot) of every intervention sent
        self.world_log = []                   # the world's records, as received

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

    def on_event(self, msg: DiagnosticStatus):
        if msg.name != 'crash':
            return
        try:
            self.state.add_crash(rosmsg.diagnostic_values(msg))
        except ValueError as exc:
            self.node.get_logger().error(f'/world/events: {exc}', throttle_duration_sec=1.0)

    def on_world_log(self, msg: DiagnosticStatus):
        """The world removed an obstacle: answer the clicks that asked for it."""
        values = rosmsg.diagnostic_values(msg)
        self.world_log.append(values)
        try:
            oid = int(values.get('obstacle', ''))
        except ValueError:
            self.node.get_logger().error(f'/world/intervention_log without an obstacle id: {values}')
            return
        self.limiter.removed(oid)
        with self._lock:
            futures = self._waiting.pop(oid, [])
        answer = {'ok': True, 'robot': values.get('robot', 'unknown'),
                  'message': 'removed', 'new_obstacle': values.get('new_obstacle', 'none')}
        for f in futures:
            if not f.done():
                f.set_result(answer)

    def intervene(self, obstacle_id: int):
        """A click on an obstacle (called from the web server's thread; publishing is
        thread-safe in rclpy). Returns a dict at once when nothing is published (the
        reason), else a Future of the world's answer."""
        if not self.state.has_obstacle(obstacle_id):
            return {'ok': False, 'message': 'That obstacle is already gone.'}
        refused = self.limiter.admit(obstacle_id)
        if refused is not None:
            return {'ok': False, 'message': refused, 'limited': True}
        try:
            req = self.state.intervention(obstacle_id)
        except KeyError:
            self.limiter.forget(obstacle_id)
            return {'ok': False, 'message': 'That obstacle is already gone.'}
        except LookupError:
            self.limiter.forget(obstacle_id)
            return {'ok': False, 'message': 'The robots have not started yet.'}
        future = Future()
        with self._lock:
            self._waiting.setdefault(obstacle_id, []).append(future)
        stamp = Time(nanoseconds=req.stamp_ns).to_msg()
        self.intervention_pub.publish(
            rosmsg.state_to_pose(req.rel_state, stamp, rosmsg.obstacle_frame(obstacle_id)))
        self.published.append((obstacle_id, req.robot))
        self.node.get_logger().info(f'intervention from the console: obstacle {obstacle_id}, '
                                    f'nearest robot {req.robot}')
        return future

    def unanswered(self, obstacle_id: int, future) -> dict:
        """The world did not answer within the timeout: the click's reply, and the obstacle
        is clickable again."""
        with self._lock:
            waiting = self._waiting.get(obstacle_id, [])
            if future in waiting:
                waiting.remove(future)
        self.limiter.forget(obstacle_id)
        return {'ok': False, 'message': 'The robots did not confirm the removal; try again.'}
