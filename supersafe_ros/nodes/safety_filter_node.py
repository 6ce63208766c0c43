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
                                                            set_update_reason, time_base, cmd_clipped,
                                                            detections_dropped(_reason)
  pub  safety_filter/level_set  visualization_msgs/MarkerArray  the set in force at the robot's
                                                            heading around each detection (RViz;
                                                            level_set_markers, level_set_rate)
  pub  safety_filter/ready      std_msgs/Empty              latched; the publisher appears once the
                                                            filter has valid detections (at once with
                                                            require_detections false)
  pub  /diagnostics             diagnostic_msgs/DiagnosticArray  1 Hz, this robot's status (filter_diagnostics)

The message types above are the defaults: ``pose_type`` (Odometry, PoseWithCovarianceStamped),
``detections_type`` (MarkerArray, LaserScan, PointCloud2: sensor-data QoS) and
``cmd_vel_stamped`` (TwistStamped both ways) choose others (``filter_inputs``). A pose or scan
stamped farther than ``stamp_tolerance`` from the node's clock is refused (failing safe). As
a managed node (``ManagedSafetyFilterNode``, executable managed_safety_filter; ``managed``)
it publishes no cmd_vel unless active.

Before its first valid detections, and whenever they are stale, the filter fails safe: a
detections message means "the sensor has looked", and none (or an old one) means nothing
is known about the obstacles. A robot without an obstacle sensor opts out with
``require_detections`` false: the filter then takes "no obstacle" with every pose and does
not subscribe to ``detections``. ``safety_filter/ready`` lets a lockstep clock start only
once every filter can judge (``supersafe_ros.team``); the pose is not part of it, since a
lockstepped robot publishes its first pose at the first step, parked until the filter
answers it.

The decision is ``supersafe_ros.filter`` (law, hysteresis, fail safe, delay
compensation; see there). When it is made: on every planner command (and, with
``publish_on_pose``, on every pose), plus a watchdog on the steady clock that
publishes when nothing went out for 1/rate s, so the robot never starves, even with
the planner dead.

``lockstep`` (a simulated robot under sim_clock_node, set by ``supersafe team``): the
robot acknowledges its step on the first command that arrives after its pose, and the
clock then advances. So every command that goes out must be the answer to the newest
pose: the filter decides and publishes on each pose only. A planner command only
updates the command judged at the next pose (one step later, which the filter judges
like any other), and the watchdog speaks only after ``lockstep_silence`` steady seconds
without a pose. Otherwise the watchdog (timers run before subscriptions in rclpy's
executor) answered a step on the pose before, the clock advanced on that answer, and
under load the filter fell steps behind: decisions on poses 0.8 s old let a robot
into a disc (docs/graph_safety.md). With ``cluster_hold_timeout`` > 0 the answer to a
pose near a cluster whose union value is still being solved is held (the lockstep
clock waits, sim time stands still) until the value is in force, at most that many
steady seconds; the clock's ``ack_timeout`` must be longer.

Ages of inputs: on the filter's time base (``runtime.timebase``): sim time while
/clock advances, the steady clock with ``use_sim_time`` false or when ROS time
stands still longer than ``clock_stall_timeout``. A stale input is detected whatever
``use_sim_time`` says.

When a lockstepped pose is answered (skipped, held, given up): ``runtime.lockstep``.
Safe set, parameters at run time, value-function decoding and the admissibility
check of learned sets (on a worker thread, off the control path): ``filter_wiring``.
"""
from __future__ import annotations

import re
import threading
import time

from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticStatus
from std_msgs.msg import Empty

from ..filter import FAIL_SAFE
from ..filter.commands import command_fresh
from ..filter.decide import decide_many
from ..filter.sent import record_decisions
from ..runtime.lockstep import GIVE_UP, LockstepAnswers
from ..ros_io import cdr, rosmsg
from ..ros_io.direct_take import DirectTake
from .common import ParameterSpec, declare_all, run_node
from .filter_diagnostics import FilterDiagnostics, status_copy
from .filter_inputs import INPUT_PARAMETERS, MAP_SENSORS, PoseHistory, SensorMap, check_types
from .filter_sources import NO_DETECTIONS, CommandSink, CommandSource, DiscSource, PoseSource
from .filter_state import HoldSummary, StateThrottle, Status
from .managed import ManagedFilter
from .filter_wiring import VALUE_FUNCTION_TOPIC, FilterWiring  # noqa: F401  (the topic, re-exported for tests)
from .markers import LevelSetMarkerPublisher

# this node's own parameters (the filter's are in filter_parameters), in the order declared
PARAMETERS = (
    ParameterSpec('publish_on_pose', False, 'also decide and publish on every pose (not in a lockstep graph)',
                  live=True),
    ParameterSpec('lockstep', False, 'the robot is lockstepped (sim_clock_node): answer each pose once, on '
                  'that pose; planner commands and the watchdog do not publish'),
    ParameterSpec('lockstep_silence', 2.0, 'lockstep: the watchdog publishes only after this long without '
                  'a pose [steady s]', 0.01, 3600.0),
    ParameterSpec('cluster_hold_timeout', 0.0, 'lockstep: hold the answer to a pose while a cluster\'s union '
                  'value is being solved, at most this long [steady s]; 0 = never hold (the fallback acts)',
                  0.0, 600.0),
    ParameterSpec('direct_take', True, 'pose, detections and cmd_vel_nav are taken by a thread of their own '
                  'that waits on them alone (helper node <name>_io), off the executor\'s wake-up over every '
                  'entity: about 0.3 ms less from pose to cmd_vel; false = the executor takes them. Not with '
                  'lockstep (there a pose must be read after the /clock before it)'),
    ParameterSpec('level_set_rate', 2.0, 'rate of safety_filter/level_set markers [Hz, steady clock]', 0.1, 50.0),
    ParameterSpec('level_set_markers', True, 'publish the level set in force at the robot\'s heading around '
                  'each detected obstacle on safety_filter/level_set (LINE_STRIPs, for RViz)'),
    *INPUT_PARAMETERS,
)


class SafetyFilter:
    """The filter of one robot on a node (``self``: a Node or a LifecycleNode); ``build()``
    makes it (the plain node in its constructor, the managed one on configure). It decides
    only while ``active``."""

    active = True

    def build(self):
        # every callback that reads or changes the filter holds this lock (the inputs may be
        # taken by a thread of their own, below; parameters change under it too)
        self.lock = threading.RLock()
        self.wiring = w = FilterWiring(self, [self.get_namespace()], on_rate=self._set_rate, lock=self.lock)
        self.filter = w.filters[0]
        p = declare_all(self, PARAMETERS)
        check_types(p)
        self.poses = PoseHistory()
        c = w.params.config
        self.sensor = None
        if p['detections_type'] in MAP_SENSORS:
            self.sensor = SensorMap(p, self.poses, c, w.params.standard_horizon, w.frame, inline=p['lockstep'])
            s = self.sensor.value_settings
            self.get_logger().info(
                f"{self.sensor.view.sensor}: a local map of {p['map_size']:g} m at {p['map_cell']:g} m cells, judged "
                f"by "
                f'its avoid value (speed {c.speed:g}, w_max {c.omega_max:g}, clearance {p["robot_radius"]:g} m, '
                f'horizon {s.horizon:g} s, {s.cell:g} m x {s.headings} headings), solved again in the background at '
                f'most every {p["value_period"]:g} s while the map changes')
        if self.sensor is not None and c.time_before_collision <= 0.0 and not c.constant_speed:
            # the map's value is that of the map at its solve time; what the map learns between
            # solves is judged only by the speed cut, for a robot that can stop
            self.get_logger().warning(
                f"detections_type {p['detections_type']}: time_before_collision is 0, so nothing stops this "
                'robot before an obstacle the map learned since its value was last solved; set it > 0 '
                '(config/nav2_safety_filter.yaml: 0.5; docs/filter_node.md, "Stop before collision")')
        self._first_value = None        # the map's first value, told once
        self.sink = CommandSink(p['cmd_vel_stamped'])     # cmd_vel (with the planner's last header)
        self.publish_on_pose = p['publish_on_pose']
        w.live.add('publish_on_pose', lambda v: setattr(self, 'publish_on_pose', bool(v)))
        self.lockstep = p['lockstep']
        self.answers = LockstepAnswers(p['cluster_hold_timeout'], p['lockstep_silence'], time.monotonic())
        self._last_out = None              # the last decision published
        self.name = self.get_fully_qualified_name()
        self._last_publish = -1e18     # steady seconds
        self._throttle = StateThrottle()
        self._holds = HoldSummary(self.get_logger())
        self._failing = None           # the fail-safe story: None (start), True, False
        self._silence_told = False     # the planner's silence said (once per silence)
        self._decided_at = 0.0
        self._waiting_told = False     # said once why it fails safe while starting
        self.decisions = 0
        self.require_detections = p['require_detections']
        self.ready_pub = None          # safety_filter/ready: made once the filter can judge
        self._inputs_ready = not self.require_detections

        self.cmd_pub = self.create_publisher(self.sink.msg_type, 'cmd_vel', rosmsg.QOS_STREAM)
        self.state_pub = self.create_publisher(DiagnosticStatus, 'safety_filter/state', rosmsg.QOS_STREAM)
        self.timer = None
        self.direct = None
        # RViz: the level set in force around each detected obstacle (computed only while watched)
        if p['level_set_markers']:
            self.level_set = LevelSetMarkerPublisher(
                self, lambda: (w.safe_set, self.filter.pose.value, self.filter.detections.value),
                p['level_set_rate'])
        inputs = self._inputs(p)
        if p['direct_take'] and not self.lockstep:
            # the inputs and the watchdog on a thread of their own (the executor keeps parameters, lifecycle
            # and /diagnostics)
            self.direct = DirectTake(self, self.lock, path=w.params.take_path)
            try:
                for msg_type, topic, callback, raw, qos in inputs:
                    self.direct.add(msg_type, topic, callback, qos, raw=raw)
                self._set_rate(w.rate)
            except BaseException:
                self.direct.close()
                raise
            self.direct.start()
        else:
            self._set_rate(w.rate)
            # lockstep: the executor reads /clock before a pose that waits with it, so a pose the
            # clock has passed is known as such (_clock_passed); a thread of its own would not be
            for msg_type, topic, callback, raw, qos in inputs:
                self.create_subscription(msg_type, topic, self._locked(callback), qos, raw=raw)
        self.diagnostics = FilterDiagnostics(self, self._statuses, [(i[1], i[0]) for i in inputs], w.complain)
        if self.require_detections:
            self.get_logger().info('filtering cmd_vel_nav -> cmd_vel; waiting for the first pose and detections '
                                   '(failing safe until then)')
        else:
            self._say_ready()
            self.get_logger().info('filtering cmd_vel_nav -> cmd_vel; require_detections false: no obstacle '
                                   'sensor, every pose is judged with no obstacle; waiting for the first pose')

    def _inputs(self, p) -> tuple:
        """(type, topic, callback, raw, qos) of each input, as ``p`` (the parameters) say, read by
        its Source (``filter_sources``). Poses, commands and PoseArrays are read raw, straight from
        their CDR bytes (ros_io.cdr), no message objects built (on the path from pose to cmd_vel;
        for detections of any size); the others are decoded by rclpy. Ready together, they are
        taken in this order (the executor's: the order made), so a command is judged on the
        detections that came with it."""
        self.pose_source = PoseSource(p['pose_type'], self.wiring.frame)
        self.command_source = CommandSource(p['cmd_vel_stamped'])
        sources = [(self.pose_source, self.on_pose)]
        if self.require_detections:
            kind = p['detections_type']
            if kind in MAP_SENSORS:
                sources.append((self.sensor, self.on_range_sensor))
            else:
                self.disc_source = DiscSource(kind, self.wiring.frame)
                sources.append((self.disc_source, self.on_detections))
        sources.append((self.command_source, self.on_command))
        return tuple((s.msg_type, s.topic, callback, s.raw, s.qos) for s, callback in sources)

    def _statuses(self) -> list:
        """This robot's status on /diagnostics: its last state (see filter_diagnostics)."""
        ns = self.get_namespace()
        name = f'{self.name}: {ns}'
        with self.lock:     # (the state message is refilled by decide, on the inputs' thread too)
            out = self._last_out
            if out is not None:
                state = self.wiring.state_message(self.name, out)
                status = status_copy(state, name, ns, None if self.active else
                                     f'inactive (lifecycle): no cmd_vel; last: {state.message}')
                note = self.sensor.problem(self.filter.detections) if self.sensor is not None else ''
                if note:        # what the sensor's last message says of itself (every beam NaN, ...)
                    status.level = max(status.level, DiagnosticStatus.WARN[0])
                    status.message = f'{status.message}; {note}'
                return [status]
        return [Status(DiagnosticStatus.ERROR[0], name, 'no decision yet' if self.active else 'inactive: no cmd_vel',
                       ns)]

    def _say_ready(self):
        """Make the latched safety_filter/ready publisher (once; from the watchdog's thread)."""
        if self.ready_pub is None:
            self.ready_pub = self.create_publisher(Empty, 'safety_filter/ready', rosmsg.QOS_LATCHED)
            self.ready_pub.publish(Empty())

    def _locked(self, callback):
        def locked(*args):
            with self.lock:
                return callback(*args)
        return locked

    def _set_rate(self, rate):
        self.period = 1.0 / rate
        if self.direct is not None:          # the inputs' thread serves the watchdog (under the lock)
            self.direct.tick(self.period, self.on_watchdog)
            return
        if self.timer is not None:
            self.destroy_timer(self.timer)
        self.timer = self.create_timer(self.period, self._locked(self.on_watchdog), clock=self.wiring.steady)

    # -- inputs -----------------------------------------------------------------------------
    def on_pose(self, data):
        """A serialized PoseStamped, Odometry or PoseWithCovarianceStamped (``pose_type``; raw: its pose
        read from the CDR bytes, with the frame and checks of a message's: ``PoseSource``)."""
        w = self.wiring
        t = w.now()
        stamp = None
        try:
            state, stamp = self.pose_source.read(data)
            self._take_pose(state, t, w.stamp(stamp, t))
            if not self.require_detections:
                self.filter.update_detections(NO_DETECTIONS, t)
        except ValueError as exc:   # MessageError is a ValueError
            self.filter.reject_pose(str(exc), t)
            w.complain('pose', f'pose rejected: {exc}; failing safe', level='error')
        self._answer_pose(t, stamp)

    def _answer_pose(self, t, stamp):
        """After a pose (``stamp``: its header's, None if unreadable): lockstep answers it,
        else with ``publish_on_pose`` decide."""
        if self.lockstep:
            self.answers.new_pose(time.monotonic())
            if stamp is not None and self._clock_passed(stamp):
                return
            self.decide(t, answers_pose=True)
        elif self.publish_on_pose:
            self.decide(t)

    def _take_pose(self, state, t, stamp):
        self.filter.update_pose(state, t, stamp=stamp)
        if self.sensor is not None:     # (the poses a local map places its returns with)
            self.poses.add(t if stamp is None else stamp, state)

    def _clock_passed(self, stamp) -> bool:
        """Lockstep with sim time: True (and said) if /clock is already past this pose, which
        the robot has acknowledged without this answer (``LockstepAnswers.clock_passed``).
        Answering it would acknowledge the newer step with a decision on the older pose, and
        the filter would stay a step behind from then on (seen at start-up: up to 5 steps,
        1 s, for seconds). Skipping it lets the next, current pose be answered."""
        clock_ns = self.get_clock().now().nanoseconds if self.wiring.time.sim else None
        if not self.answers.clock_passed(stamp.sec * 1_000_000_000 + stamp.nanosec, clock_ns):
            return False
        self.wiring.complain('lockstep', f'skipped a pose the clock has already passed ({self.answers.poses_skipped} '
                             'so far): its step went on without this answer; answering the current pose',
                             level='info')
        return True

    def on_detections(self, data):
        """A serialized PoseArray (raw subscription: its positions read as one array) or a MarkerArray
        (the full current set of discs, each of its own radius): ``DiscSource``. At most
        ``max_detections`` of them kept (the nearest; the state and a log line say which were dropped)."""
        t = self.wiring.now()
        try:
            rows = self.disc_source.read(data)
        except ValueError as exc:
            self._refuse_detections(exc, t)
            return
        self._take_detections(rows, t)

    def on_range_sensor(self, msg):
        """A LaserScan, PointCloud2 or OccupancyGrid (detections_type): checked, placed with the robot's pose
        at its stamp and put into the local map (filter_inputs.SensorMap); the map's value asked for again;
        then a decision (every sensor message triggers one, but in lockstep). A message refused leaves the
        map as it was: the filter fails safe once its last valid view is ``detections_timeout`` old."""
        w = self.wiring
        t = w.now()
        sensor = self.sensor.view.sensor
        if not self.poses.stamps and self.sensor.kind != 'occupancy_grid':
            # starting: the scan came before the first pose (said once, not an error)
            w.complain('detections before pose', f'a {sensor} before the first pose: waiting for a pose to place its '
                       'returns with (failing safe until then)', level='info')
            return
        try:
            stamp = w.stamp(msg.header.stamp, t)
            summary, learned = self.sensor.take(msg, t if stamp is None else stamp, w.config, w.config.pose_timeout)
        except ValueError as exc:     # MessageError: the fault named; the view stays as it was
            why = str(exc) if str(exc).startswith(f'{sensor} refused') else f'{sensor} refused: {exc}'
            self.filter.refuse_view(why, t)
            # each kind of fault logged (throttled per kind: its words with the numbers masked)
            w.complain(re.sub(r'[-+0-9.eE]+', '#', why), f'{why}; the map stays as it was (failing safe once its last '
                       f'valid view is detections_timeout {w.config.detections_timeout:g} s old)', level='error')
        else:
            if learned:
                self.filter.update_view(self.sensor.view, t)
                self._inputs_ready = True      # the watchdog (executor thread) says so
                if summary.problem:
                    w.complain(f'{sensor} note', f'{sensor}: {summary.problem}', level='warn')
            else:           # it did not look: blind, not "looked, nothing seen" (the map keeps what was seen)
                self.filter.refuse_view(f'{sensor} did not look: {self.sensor.note}', t)    # (blind)
                w.complain(f'{sensor} note', f'{sensor}: {self.sensor.note}; the map keeps what was seen (failing '
                           f'safe once its last view is detections_timeout {w.config.detections_timeout:g} s old)',
                           level='warn')
            self._ask_value()
        if not self.lockstep:
            self.decide(t)

    def _ask_value(self):
        """The map's value solved again around the robot (at most every value_period), for the set in force:
        the learned w_max where a learned set is, the robot's own otherwise."""
        newest = self.poses.newest
        if newest is None or not self.active:     # (inactive: no decision reads it; solved again once active)
            return
        safe = self.wiring.safe_set
        learned = safe.source == 'learned' and safe.omega_max is not None
        omega = safe.omega_max if learned else self.wiring.config.omega_max
        self.sensor.solve(float(omega), self.wiring.now(), float(newest[0]), float(newest[1]))
        value = self.sensor.worker.latest()
        if value is not None and self._first_value is None:
            self._first_value = value
            g = value.vf.grid
            self.get_logger().info(f'{self.sensor.view.sensor} map: its first value solved in {value.solve_s:.3g} s '
                                   f'(a window of {g.hi[0] - g.lo[0]:.3g} m, grid {g.shape})')

    def _refuse_detections(self, exc, t):
        self.filter.reject_detections(str(exc), t)
        self.wiring.complain('detections', f'detections rejected: {exc}; failing safe', level='error')

    def _take_detections(self, rows, t, solve_clusters=True):
        w = self.wiring
        try:
            self.filter.update_detections(rows, t, w.safe_set, solve_clusters=solve_clusters)
        except ValueError as exc:
            self._refuse_detections(exc, t)
            return
        self._inputs_ready = True      # the watchdog (executor thread) says so
        d = self.filter.detections
        if d.dropped:
            w.complain('detections dropped', d.note, level='warn' if d.dropped_safely else 'error')

    def on_command(self, data):
        """A serialized Twist or TwistStamped (``cmd_vel_stamped``; raw subscription), or a Twist:
        ``CommandSource``. A TwistStamped's header is that of the cmd_vel judged from it."""
        w = self.wiring
        t = w.now()
        if not self.command_source.take(self.filter, data, t, self.sink):
            w.complain('cmd', f'cmd_vel_nav rejected: {self.filter.command.note}')
        elif self.filter.command.note:
            w.complain('cmd clipped', f'cmd_vel_nav beyond the robot\'s limits: {self.filter.command.note}')
        if not self.lockstep:       # in lockstep the next pose's answer judges it
            self.decide(t)

    def on_watchdog(self):
        if self._inputs_ready and self.ready_pub is None:
            self._say_ready()
        now = time.monotonic()
        held = self.answers.held_pose_time
        if held is not None:
            self.decide(held)       # a held answer: out once the cluster value is in force, or timed out
        elif self.lockstep and self.answers.quiet(now):
            # the pose's answer is the robot's command (and its step's ack); the state topic
            # still reports the set in force (a new learned set) while no pose comes
            out = self._last_out
            if out is not None and self._throttle.due(now, out.action, self.wiring.set_update,
                                                      self.wiring.state_period):
                self.state_pub.publish(cdr.diagnostic_status_bytes(self.wiring.state_message(self.name, out)))
        elif now - self._last_publish >= self.period * 0.5:
            # half a period, not a whole one: the last output went out a little after the
            # previous tick, so a whole period would skip every other tick (rate / 2)
            self.decide()

    # -- output --------------------------------------------------------------------------------
    def decide(self, t=None, answers_pose=False):
        """Decide at ``t`` and publish, unless the lockstep rules hold the answer (a cluster
        near the robot is being solved): then the watchdog decides again, and None is
        returned. ``answers_pose``: this is the answer to a lockstepped pose."""
        if not self.active:
            return None            # a managed node, inactive: no cmd_vel (managed.py)
        w = self.wiring
        t = w.now() if t is None else t
        decisions = decide_many([self.filter], w.safe_set, t)
        self._decided_at = t
        verdict = self.answers.judge(t, time.monotonic(), decisions.clusters_solving(0), answers_pose)
        if not verdict.publish:
            return None         # held: not sent, so not recorded as sent
        # the command first (the robot waits for it; its explanation is built after)
        self._publish_command(decisions.action[0], decisions.linear[0], decisions.omega[0], t)
        record_decisions([self.filter], decisions)
        out = decisions[0]
        if verdict.action == GIVE_UP:
            w.complain('cluster_hold', f'{verdict.why}: answering with the fallback until it lands', level='warn')
        elif verdict.held_for is not None:
            self._holds.held(verdict.held_for)
        now = time.monotonic()
        self._last_publish = now
        self.decisions += 1
        self._last_out = out
        self._tell_story(out)
        if self._throttle.due(now, out.action, w.set_update, w.state_period):
            extra = None if self.sensor is None else self.sensor.state_values(self.filter.detections)
            self.state_pub.publish(cdr.diagnostic_status_bytes(w.state_message(self.name, out, extra)))
        return out

    def _clock_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _publish_command(self, action, linear, omega, t):
        self.cmd_pub.publish(self.sink.cmd_vel(self.filter, t, action, linear, omega, self._clock_ns))

    def _tell_story(self, out):
        """One log line per change of the fail-safe state (not one per decision): nothing while
        starting up (said once in __init__), ERROR when valid input is lost, INFO when it is back."""
        failing = out.action == FAIL_SAFE
        if self._failing is None:          # starting: wait quietly for the first valid inputs
            if not failing:
                self._failing = False
                self.get_logger().info(f'inputs valid: filtering ({out.action}: {out.reason})')
            elif not self._waiting_told and self.filter.pose.value is not None:
                # a pose to answer, but not yet what it takes: say why once (the state says it always)
                self._waiting_told = True
                self.get_logger().info(f'failing safe until the inputs are valid: {out.reason}')
        elif failing and not self._failing:
            self._failing = True
            self.get_logger().error(f'failing safe: {out.reason}')
        elif not failing and self._failing:
            self._failing = False
            self.get_logger().info(f'inputs valid again: filtering ({out.action}: {out.reason})')
        # a planner gone silent (a robot that can stop is sent zero twists), once per silence
        command = self.filter.command
        silent = (command.value is not None and not command.rejected and not self.filter.config.constant_speed
                  and not command_fresh(self.filter, self._decided_at))
        if silent and not self._silence_told:
            self._silence_told = True
            self.get_logger().info(f'planner silent for more than cmd_timeout '
                                   f'({self.filter.config.cmd_timeout:g} s): sending zero twists until it speaks')
        elif not silent and self._silence_told and command_fresh(self.filter, self._decided_at):
            self._silence_told = False
            self.get_logger().info('planner speaking again')

    def send_zero_twist(self) -> list:
        """One zero twist on cmd_vel (a managed node going quiet, managed.py: the base must not
        keep the last command), stamped as the decisions are; the publisher it went out on. Under
        the lock: after a decision under way on the inputs' thread, never before it."""
        with self.lock:
            self.cmd_pub.publish(self.sink.bytes(0.0, 0.0, False, self._clock_ns))
        return [self.cmd_pub]

    def close(self):
        """Close what build() made, also when it failed half way (a managed node's failed configure)."""
        for part in ('direct', 'sensor'):
            made = getattr(self, part, None)
            if made is not None:
                made.close()
        holds = getattr(self, '_holds', None)
        if holds is not None:
            holds.flush()
        wiring = getattr(self, 'wiring', None)
        if wiring is not None:
            wiring.close()
            wiring.live.close()

    def destroy_node(self):
        if getattr(self, 'direct', None) is not None:
            self.direct.close()          # its thread stops before the handles it waits on go
        if getattr(self, 'wiring', None) is not None:
            self.wiring.sets.close()
        return super().destroy_node()


class SafetyFilterNode(SafetyFilter, Node):
    """The SafetyFilter as a plain node: built and deciding from construction."""

    def __init__(self, node_name='safety_filter', **kwargs):
        Node.__init__(self, node_name, **kwargs)
        self.build()


class ManagedSafetyFilterNode(ManagedFilter, SafetyFilter, LifecycleNode):
    """The SafetyFilter as a managed (lifecycle) node: built on configure, deciding while active
    (nodes/managed.py)."""

    def __init__(self, node_name='safety_filter', **kwargs):
        LifecycleNode.__init__(self, node_name, **kwargs)
        self.start_lifecycle()


def main(args=None):
    return run_node(SafetyFilterNode, args)


def main_managed(args=None):
    return run_node(ManagedSafetyFilterNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
