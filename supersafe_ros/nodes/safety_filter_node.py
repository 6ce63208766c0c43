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
                                                            omega_max, source, cmd_*
  pub  safety_filter/level_set  visualization_msgs/MarkerArray  the set in force at the robot's
                                                            heading around each detection (RViz;
                                                            level_set_markers, level_set_rate)

The decision is ``supersafe_ros.filter.core`` (law, hysteresis, fail safe; see there).
When it is made: on every planner command (and, with ``publish_on_pose``, on every
pose), plus a watchdog on the steady clock that publishes when nothing went out for
1/rate s — so the robot never starves, even with the planner dead or /clock halted
waiting in lockstep. Ages of inputs are measured on the node clock (sim time when
``use_sim_time``), at arrival.

Safe set: the standard set (true dynamics, true radius, alpha = ``standard_alpha``)
is computed or loaded from the cache at start. A learned set from the learner
replaces it (if ``use_learned``) with alpha = mu + alpha_offset * sigma from the
message's metadata. Invalid value-function messages are rejected with the reason
and the set in force is kept.
"""
from __future__ import annotations

import math
import time

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseArray, PoseStamped, Twist
from std_msgs.msg import Float32MultiArray

from ..ros_io import rosmsg
from ..filter.core import FilterConfig, RobotFilter, SafeSet
from ..ros_io.vfmsg import ValueFunctionMessageError, msg_to_value_function
from .common import declare, run_node
from .markers import LevelSetMarkerPublisher

VALUE_FUNCTION_TOPIC = '/safe_set/value_function'
LOG_THROTTLE_S = 2.0   # the same kind of complaint at most this often


def standard_value_function(lo, hi, shape, speed, omega_max, radius, horizon, cache_dir=None):
    """The standard set's V: true dynamics and radius, from the cache or solved now.

    horizon <= 0 means "to convergence".
    """
    from ..reach.grid import Grid
    from ..reach.library import load_or_solve
    return load_or_solve(Grid(tuple(lo), tuple(hi), tuple(int(n) for n in shape)), speed, omega_max,
                         radius, horizon if horizon > 0 else None, cache_dir=cache_dir or None)


def learned_alpha(meta: dict, k: float) -> float:
    """alpha = mu + k sigma from the fit's metadata, else its alpha, else 0."""
    mu, sigma = meta.get('mu'), meta.get('sigma')
    if mu is not None and sigma is not None:
        return float(mu) + k * float(sigma)
    return float(meta.get('alpha') or 0.0)


class SafetyFilterNode(Node):
    def __init__(self, node_name='safety_filter', **kwargs):
        super().__init__(node_name, **kwargs)
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        speed = p('speed', 3.0, 'robot speed, true dynamics [m/s] (standard set; linear.x)', 0.01, 100.0)
        omega_max = p('omega_max', 1.0, 'robot turn-rate bound, true dynamics [rad/s]; |u*|', 0.01, 20.0)
        radius = p('radius', 1.8, 'true obstacle radius [m] (standard set)', 0.01, 100.0)
        self.standard_alpha = p('standard_alpha', 0.0, 'alpha of the standard set [value units, m]',
                                -10.0, 10.0)
        self.alpha_offset = p('alpha_offset', 0.0,
                              'k in alpha = mu + k sigma for a learned set (paper: 0)', -5.0, 10.0)
        self.use_learned = p('use_learned', True, 'replace the standard set by the learner\'s sets')
        cfg = FilterConfig(
            speed=speed, omega_max=omega_max,
            pose_timeout=p('pose_timeout', 0.5, 'a pose older than this is stale [s]', 0.001, 60.0),
            detections_timeout=p('detections_timeout', 1.0, 'detections older than this are stale [s]',
                                 0.001, 60.0),
            hold_timeout=p('hold_timeout', 1.0, 'fail safe with the avoid control of the last valid '
                           'state while it is younger than this, then stop-turn [s]', 0.0, 60.0),
            cmd_timeout=p('cmd_timeout', 0.5, 'planner silent longer than this: zero command [s]',
                          0.001, 60.0),
            clear_margin=p('clear_margin', 0.2, 'hysteresis: keep overriding until V > alpha + margin',
                           0.0, 10.0),
            lookahead=p('lookahead', 0.1, 'also override when the planner\'s command, held this long, '
                        'would reach V <= alpha; set it to the robot\'s control period [s]', 0.0, 10.0),
        )
        rate = p('rate', 50.0, 'watchdog rate [Hz, steady clock]: publish if nothing went out for 1/rate',
                 0.1, 1000.0)
        self.state_period = 1.0 / p('state_rate', 10.0, 'most state messages per second while the '
                                    'action does not change [Hz]', 0.1, 1000.0)
        self.publish_on_pose = p('publish_on_pose', False, 'also decide and publish on every pose')
        self.frame = p('frame_id', rosmsg.MAP_FRAME, 'frame of pose and detections')
        cache_dir = p('cache_dir', '',
                      'value-function cache ("" = $SUPERSAFE_CACHE or ~/.cache/supersafe_ros)')
        lo = p('standard_lo', [-8.0, -8.0], 'standard set grid: (xmin, ymin) relative to the obstacle [m]')
        hi = p('standard_hi', [8.0, 8.0], 'standard set grid: (xmax, ymax) [m]')
        shape = p('standard_shape', [65, 65, 42], 'standard set grid: nodes (nx, ny, ntheta)')
        horizon = p('standard_horizon', 3.0, 'standard set horizon [s] (as the library; 0 = to convergence)',
                    0.0, 1000.0)

        self.filter = RobotFilter(cfg, self.get_namespace())
        t0 = time.perf_counter()
        vf = standard_value_function(lo, hi, shape, speed, omega_max, radius, horizon, cache_dir)
        self.standard = SafeSet(vf, self.standard_alpha, 'standard')
        self.safe_set = self.standard
        self.get_logger().info(
            f'standard set ready in {time.perf_counter() - t0:.2f} s: grid {tuple(shape)}, speed {speed}, '
            f'w_max {omega_max}, radius {radius}, horizon {horizon}, alpha {self.standard_alpha}')

        self._last_log = {}
        self._last_publish = -math.inf      # steady seconds
        self._last_state = (-math.inf, None)
        self.decisions = 0

        self.cmd_pub = self.create_publisher(Twist, 'cmd_vel', rosmsg.QOS_STREAM)
        self.state_pub = self.create_publisher(DiagnosticStatus, 'safety_filter/state', rosmsg.QOS_STREAM)
        self.create_subscription(PoseStamped, 'pose', self.on_pose, rosmsg.QOS_STREAM)
        self.create_subscription(PoseArray, 'detections', self.on_detections, rosmsg.QOS_STREAM)
        self.create_subscription(Twist, 'cmd_vel_nav', self.on_command, rosmsg.QOS_STREAM)
        self.create_subscription(Float32MultiArray, VALUE_FUNCTION_TOPIC, self.on_value_function,
                                 rosmsg.QOS_LATCHED)
        self.period = 1.0 / rate
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.timer = self.create_timer(self.period, self.on_watchdog, clock=self.steady)
        # RViz: the level set in force around each detected obstacle (computed only while watched)
        level_set_rate = p('level_set_rate', 2.0,
                           'rate of safety_filter/level_set markers [Hz, steady clock]', 0.1, 50.0)
        if p('level_set_markers', True, 'publish the level set in force at the robot\'s heading around '
             'each detected obstacle on safety_filter/level_set (LINE_STRIPs, for RViz)'):
            self.level_set = LevelSetMarkerPublisher(
                self, lambda: (self.safe_set, self.filter.pose.value, self.filter.detections.value),
                level_set_rate)

    # -- helpers -------------------------------------------------------------------------
    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def complain(self, kind: str, text: str, level='warn'):
        """Log ``text`` at most every LOG_THROTTLE_S per ``kind``."""
        now = time.monotonic()
        if now - self._last_log.get(kind, -math.inf) >= LOG_THROTTLE_S:
            self._last_log[kind] = now
            # rclpy ties a severity to each call site: one call per level
            if level == 'error':
                self.get_logger().error(text)
            else:
                self.get_logger().warn(text)

    # -- inputs -----------------------------------------------------------------------------
    def on_pose(self, msg: PoseStamped):
        t = self.now_s()
        try:
            self.filter.update_pose(rosmsg.pose_to_state(msg, self.frame), t)
        except ValueError as exc:   # MessageError is a ValueError
            self.filter.reject_pose(str(exc), t)
            self.complain('pose', f'pose rejected: {exc}; failing safe')
        if self.publish_on_pose:
            self.decide()

    def on_detections(self, msg: PoseArray):
        t = self.now_s()
        try:
            self.filter.update_detections(rosmsg.posearray_to_xy(msg, self.frame), t)
        except ValueError as exc:
            self.filter.reject_detections(str(exc), t)
            self.complain('detections', f'detections rejected: {exc}; failing safe')

    def on_command(self, msg: Twist):
        try:
            self.filter.update_command(rosmsg.twist_turn_rate(msg), self.now_s())
        except ValueError as exc:
            self.complain('cmd', f'cmd_vel_nav rejected: {exc}; keeping the previous command')
        self.decide()

    def on_value_function(self, msg: Float32MultiArray):
        try:
            vf = msg_to_value_function(msg)
            source = str(vf.meta.get('source', 'learned'))
            if source == 'standard':
                alpha = self.standard_alpha
            else:
                source = 'learned'
                alpha = learned_alpha(vf.meta, self.alpha_offset)
            new = SafeSet(vf, alpha, source)
        except (ValueFunctionMessageError, ValueError) as exc:
            self.get_logger().error(f'value function rejected: {exc}; keeping the {self.safe_set.source} set')
            return
        if source == 'learned' and not self.use_learned:
            self.get_logger().info('learned set received but use_learned is false: keeping the standard set')
            return
        self.safe_set = new
        self.get_logger().info(
            f'{source} set in force: omega_max {vf.meta.get("omega_max")}, alpha {alpha:.4g} '
            f'(mu {vf.meta.get("mu")}, sigma {vf.meta.get("sigma")}), grid {vf.grid.shape}, '
            f'{vf.meta.get("interventions", "?")} interventions')

    def on_watchdog(self):
        if time.monotonic() - self._last_publish >= self.period * 0.999:
            self.decide()

    # -- output --------------------------------------------------------------------------------
    def decide(self):
        out = self.filter.step(self.safe_set, self.now_s())
        twist = Twist()
        twist.linear.x = float(out.linear)
        twist.angular.z = float(out.omega)
        self.cmd_pub.publish(twist)
        self._last_publish = time.monotonic()
        self.decisions += 1
        if out.action == 'fail_safe':
            # nothing received yet is the normal start-up state (warn); losing data is an error
            starting = self.filter.pose.value is None or self.filter.detections.value is None
            self.complain('fail_safe', f'fail safe: {out.reason}', level='warn' if starting else 'error')
        now = time.monotonic()
        last_t, last_action = self._last_state
        if out.action != last_action or now - last_t >= self.state_period:
            self._last_state = (now, out.action)
            msg = rosmsg.make_diagnostic(f'{self.get_fully_qualified_name()}', out.record(),
                                         f'{out.action}: {out.reason}', out.level)
            self.state_pub.publish(msg)
        return out


def main(args=None):
    return run_node(SafetyFilterNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
