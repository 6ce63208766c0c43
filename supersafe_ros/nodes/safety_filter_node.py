"""safety_filter_node: the minimally invasive safety filter of one robot.

Topics (relative; run it in the robot's namespace such as /robot_0):
  sub  pose                     geometry_msgs/PoseStamped   frame map
  sub  detections               geometry_msgs/PoseArray     frame map, obstacle centres
  sub  cmd_vel_nav              geometry_msgs/Twist         the planner's command (angular.z)
  sub  /safe_set/value_function std_msgs/Float32MultiArray  latched, from the learner (supersafe_ros.ros_io.vfmsg)
  pub  cmd_vel                  geometry_msgs/Twist         the filtered command
  pub  safety_filter/state      diagnostic_msgs/DiagnosticStatus  OK pass / WARN override /
                                                            ERROR fail_safe; values: action, reason,
                                                            obstacle_index/x/y, value, alpha,
                                                            omega_max, source, cmd_*, set_update,
                                                            set_update_reason, time_base
  pub  safety_filter/level_set  visualization_msgs/MarkerArray  the set in force at the robot's
                                                            heading around each detection (RViz;
                                                            level_set_markers, level_set_rate)

The decision is ``supersafe_ros.filter.core`` (law, hysteresis, fail safe, delay
compensation; see there). When it is made: on every planner command (and, with
``publish_on_pose``, on every pose), plus a watchdog on the steady clock that
publishes when nothing went out for 1/rate s, so the robot never starves, even with
the planner dead or /clock halted waiting in lockstep.

Ages of inputs: on the filter's time base (``filter.timebase``): sim time while
/clock advances, the steady clock with ``use_sim_time`` false or when ROS time
stands still longer than ``clock_stall_timeout``. A stale input is detected whatever
``use_sim_time`` says.

Safe set, parameters at run time, value-function decoding and the admissibility
check of learned sets (on a worker thread, off the control path): ``filter_wiring``.
"""
from __future__ import annotations

import time

from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseArray, PoseStamped, Twist

from ..filter.core import FAIL_SAFE
from ..ros_io import rosmsg
from .common import declare, run_node
from .filter_wiring import VALUE_FUNCTION_TOPIC, FilterWiring, StateThrottle, learned_alpha  # noqa: F401
from .markers import LevelSetMarkerPublisher


class SafetyFilterNode(Node):
    def __init__(self, node_name='safety_filter', **kwargs):
        super().__init__(node_name, **kwargs)
        self.wiring = w = FilterWiring(self, [self.get_namespace()], on_rate=self._set_rate)
        self.filter = w.filters[0]
        self.publish_on_pose = declare(self, 'publish_on_pose', False,
                                       'also decide and publish on every pose (not in a lockstep graph)')
        w.live.add('publish_on_pose', lambda v: setattr(self, 'publish_on_pose', bool(v)))
        self.name = self.get_fully_qualified_name()
        self._last_publish = -1e18     # steady seconds
        self._throttle = StateThrottle()
        self._failing = None           # the fail-safe story: None (start), True, False
        self.decisions = 0

        self.cmd_pub = self.create_publisher(Twist, 'cmd_vel', rosmsg.QOS_STREAM)
        self.state_pub = self.create_publisher(DiagnosticStatus, 'safety_filter/state', rosmsg.QOS_STREAM)
        self.create_subscription(PoseStamped, 'pose', self.on_pose, rosmsg.QOS_STREAM)
        self.create_subscription(PoseArray, 'detections', self.on_detections, rosmsg.QOS_STREAM)
        self.create_subscription(Twist, 'cmd_vel_nav', self.on_command, rosmsg.QOS_STREAM)
        self.timer = None
        self._set_rate(w.rate)
        # RViz: the level set in force around each detected obstacle (computed only while watched)
        level_set_rate = declare(self, 'level_set_rate', 2.0,
                                 'rate of safety_filter/level_set markers [Hz, steady clock]', 0.1, 50.0,
                                 read_only=True)
        if declare(self, 'level_set_markers', True, 'publish the level set in force at the robot\'s '
                   'heading around each detected obstacle on safety_filter/level_set (LINE_STRIPs, '
                   'for RViz)', read_only=True):
            self.level_set = LevelSetMarkerPublisher(
                self, lambda: (w.safe_set, self.filter.pose.value, self.filter.detections.value),
                level_set_rate)
        self.get_logger().info('filtering cmd_vel_nav -> cmd_vel; waiting for the first pose and detections '
                               '(failing safe until then)')

    # compatibility: the set in force and the standard set (tests, tools)
    @property
    def safe_set(self):
        return self.wiring.safe_set

    @property
    def standard(self):
        return self.wiring.standard

    def _set_rate(self, rate):
        self.period = 1.0 / rate
        if self.timer is not None:
            self.destroy_timer(self.timer)
        self.timer = self.create_timer(self.period, self.on_watchdog, clock=self.wiring.steady)

    # -- inputs -----------------------------------------------------------------------------
    def on_pose(self, msg: PoseStamped):
        w = self.wiring
        t = w.now()
        try:
            self.filter.update_pose(rosmsg.pose_to_state(msg, w.frame), t, stamp=w.stamp(msg.header.stamp, t))
        except ValueError as exc:   # MessageError is a ValueError
            self.filter.reject_pose(str(exc), t)
            w.complain('pose', f'pose rejected: {exc}; failing safe', level='error')
        if self.publish_on_pose:
            self.decide(t)

    def on_detections(self, msg: PoseArray):
        w = self.wiring
        t = w.now()
        try:
            self.filter.update_detections(rosmsg.posearray_to_xy(msg, w.frame), t)
        except ValueError as exc:
            self.filter.reject_detections(str(exc), t)
            w.complain('detections', f'detections rejected: {exc}; failing safe', level='error')

    def on_command(self, msg: Twist):
        w = self.wiring
        t = w.now()
        try:
            self.filter.update_command(rosmsg.twist_turn_rate(msg), t)
        except ValueError as exc:
            w.complain('cmd', f'cmd_vel_nav rejected: {exc}; keeping the previous command')
        self.decide(t)

    def on_watchdog(self):
        if time.monotonic() - self._last_publish >= self.period * 0.999:
            self.decide()

    # -- output --------------------------------------------------------------------------------
    def decide(self, t=None):
        w = self.wiring
        out = self.filter.step(w.safe_set, w.now() if t is None else t)
        twist = Twist()
        twist.linear.x = float(out.linear)
        twist.angular.z = float(out.omega)
        self.cmd_pub.publish(twist)
        now = time.monotonic()
        self._last_publish = now
        self.decisions += 1
        self._tell_story(out)
        if self._throttle.due(now, out.action, w.set_update, w.state_period):
            self.state_pub.publish(w.state_message(self.name, out))
        return out

    def _tell_story(self, out):
        """One log line per change of the fail-safe state (not one per decision): nothing while
        starting up (said once in __init__), ERROR when valid input is lost, INFO when it is back."""
        failing = out.action == FAIL_SAFE
        if self._failing is None:          # starting: wait quietly for the first valid inputs
            if not failing:
                self._failing = False
                self.get_logger().info(f'inputs valid: filtering ({out.action}: {out.reason})')
        elif failing and not self._failing:
            self._failing = True
            self.get_logger().error(f'failing safe: {out.reason}')
        elif not failing and self._failing:
            self._failing = False
            self.get_logger().info(f'inputs valid again: filtering ({out.action}: {out.reason})')

    def close(self):
        self.wiring.close()


def main(args=None):
    return run_node(SafetyFilterNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
