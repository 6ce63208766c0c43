"""Trips of a differential-drive robot through real ROS nodes, in one process, stepped by events on
a harness-driven /clock (not a test module; test_nodes_unicycle_trips.py and bench/bench_trips.py).

The graph, in the caller's rclpy Context (conftest's ``ros_context``), every node on sim time:

* ``unicycle_robot`` (the robot, ``supersafe_ros.sim.unicycle_world``'s unicycle in a scenario's
  world): nav_msgs/Odometry on ``<ns>/odom`` (frame odom, child base_link) every step (dt 0.02 s,
  50 Hz), a sensor_msgs/LaserScan on ``<ns>/scan`` every 5th step (10 Hz; frame laser, 360 beams
  round the full circle, range_min 0.05, range_max 8, the laser at (0.1, 0, 0) in base_link as
  config/nav2_safety_filter.yaml says), or the scan's returns as a PointCloud2 on ``<ns>/cloud``
  (``detections='cloud'``); it takes geometry_msgs/TwistStamped on ``<ns>/cmd_vel`` and applies the
  newest one received over the next step (a base holds its last command);
* ``trip_planner``: the scenario's planner (``PathFollower``, 0.5 m/s) on the true pose, a
  TwistStamped on ``<ns>/cmd_vel_nav`` after each odometry (stamped with the sim time, base_link);
* ``safety_filter``: the filter under test, ``ManagedSafetyFilterNode`` of the supersafe_ros that
  is imported (the checkout under test), in-process, configured and activated with
  trigger_configure() / trigger_activate(), its parameters config/nav2_safety_filter.yaml of that
  checkout (``--params-file``) plus ``use_sim_time: true``, remapped pose:=odom and
  detections:=scan (or cloud); checked after configure to hold every value the file gives;
* ``trip_monitor``: /clock, and records of ``<ns>/safety_filter/state``, /diagnostics and the
  filter's /rosout lines.

Before step 0, a warm-up step (``TripGraph.start``: the robot stands, the answer is not applied).
A step (k, sim time t0 + k dt): /clock; wait until the filter's clock reads it; odometry, the
scan on its steps, the planner's command; then wait until the filter has answered that command: a
cmd_vel stamped with its stamp (the filter keeps the planner's header on what it judged from a
command, as Nav2's collision_monitor does, and a filter that stamps its decision time stamps it
so too, the clock being there), and the newest of the newest stamp is applied (a decision on a
scan taken before the command carries an older stamp). The filter node (its /clock, watchdog,
diagnostics) has an executor of its own, spun with the harness's except while an answer is
awaited: a watchdog due then would run before the command was taken and, in a filter that stamps
its decision time, answer it with a decision on the previous one (its inputs are taken by a thread
of their own, ``direct_take``; a filter node that takes cmd_vel_nav itself is spun throughout).
Every wait is on events, with a deadline (``deadline``, 20 s) that only catches a
dead graph (``DeadGraph``, the trip so far attached). A step with no command (the planner
silent) waits for any new cmd_vel (the filter's watchdog).

Faults (``FAULTS``; ``fault`` from ``fault_step`` on): each scan replaced by a faulty one
(``scan_nan``, ``scan_neg_inf``, ``scan_negative``: every range NaN, -inf, -1; ``scan_range_min_above_max``:
range_min 9 > range_max 8; ``scan_angle_increment_0``), with ``detections='cloud'`` each cloud
(``cloud_nan_points``: every point NaN; ``cloud_point_step_12``, ``cloud_point_step_8``: point_step
says 12 or 8 while the points are 16 bytes apart), a second publisher ``spoof_driver`` on the scan
topic at 30 Hz of sim time (``spoof_empty_scans``: no beams; ``spoof_clear_scans``: 360 beams, no
return), odometry with NaN position (``odom_nan``; the planner still drives on the true pose), a
planner sending NaN (``planner_nan``) or falling silent (``planner_silent``). A cmd_vel that is not
finite is counted and not applied (the robot stands).

Records (``TripResult``): per step the true pose, the planner's (v, w), the (v, w) applied and the
newest safety_filter/state (action, reason) received by then (the filter sends it at most
state_rate times a second while the action holds, so it can be a step or more old); every state,
/diagnostics status and /rosout line of the filter with the step it came in. ``figures()``: reached,
the time to the goal, the planner's own time, path length, least clearance, collisions, turning
in place, the largest excess of the speed sent over the planner's (this step's and the one before).

Reproducible: a trip's figures came out the same run after run, at load 1-2 and beside burners
(the trips of today's filter hang on small differences: a start 1 cm to the side can double the
open field's time, bench/bench_trips.py --start-shift).

The harness needs of the package under test only its filter node class and its config file:
the simulator is this tree's (loaded by its path when another checkout is imported), and so
are the QoS profiles, so another checkout cannot change the world, the robot or the planner.
"""
from __future__ import annotations

from collections import Counter
import dataclasses
from dataclasses import dataclass, field
import gc
import importlib.util
import math
from pathlib import Path
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OWN_SIMULATOR = ROOT / 'supersafe_ros' / 'sim' / 'unicycle_world.py'
DT = 0.02                 # s: a step (odometry at 50 Hz)
SCAN_EVERY = 5            # steps: the scan at 10 Hz
BEAMS, RANGE_MIN, RANGE_MAX = 360, 0.05, 8.0
LASER_MOUNT = (0.1, 0.0, 0.0)        # base_link -> laser (x, y, yaw), as config/nav2_safety_filter.yaml
SPOOF_RATE = 30.0         # Hz of sim time
PLANNER_FRAME = 'base_link'   # the planner's commands' header frame
HARNESS_CALLBACKS = 8         # the harness's callbacks run per turn of the filter's executor
START_TIME = 1.0          # s: sim time at step 0 (ROS time 0 reads as "no /clock" to the filter)
TURNING_V, TURNING_W = 0.01, 0.05    # turning in place: |v| below, |w| above
SCAN_FAULTS = ('scan_nan', 'scan_neg_inf', 'scan_negative', 'scan_range_min_above_max', 'scan_angle_increment_0')
CLOUD_FAULTS = ('cloud_nan_points', 'cloud_point_step_12', 'cloud_point_step_8')
SPOOF_FAULTS = ('spoof_empty_scans', 'spoof_clear_scans')
FAULTS = SCAN_FAULTS + CLOUD_FAULTS + SPOOF_FAULTS + ('odom_nan', 'planner_nan', 'planner_silent')


def check_options(fault, detections):
    """ValueError unless ``fault`` is None or one of FAULTS that goes with ``detections`` ('scan' or 'cloud')."""
    if fault is not None and fault not in FAULTS:
        raise ValueError(f'unknown fault {fault!r}; one of {FAULTS}')
    if detections not in ('scan', 'cloud'):
        raise ValueError(f"detections must be 'scan' or 'cloud', got {detections!r}")
    if (fault in SCAN_FAULTS and detections != 'scan') or (fault in CLOUD_FAULTS and detections != 'cloud'):
        raise ValueError(f'fault {fault!r} does not go with detections {detections!r}')


def own_simulator():
    """This tree's supersafe_ros/sim/unicycle_world.py: the imported one if it is that file, else
    loaded by its path (another checkout's supersafe_ros is under test)."""
    try:
        from supersafe_ros.sim import unicycle_world
        if Path(unicycle_world.__file__).resolve() == OWN_SIMULATOR:
            return unicycle_world
    except ImportError:
        pass
    name = '_trips_unicycle_world'
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, OWN_SIMULATOR)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module          # (dataclasses look their module up while the class is made)
        spec.loader.exec_module(module)
    return sys.modules[name]


def checkout_root() -> Path:
    """The root of the checkout whose supersafe_ros is imported (the one under test)."""
    import supersafe_ros
    return Path(supersafe_ros.__file__).resolve().parents[1]


def _qos():
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

    def reliable(depth):
        return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
    # /rosout as its publishers keep it (reliable, transient local, 1000): a line logged before the monitor's
    # subscription is matched (discovery takes up to 3 s; a fault can come sooner) still arrives
    rosout = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
    return dict(stream=reliable(5), every=reliable(1000), clock=reliable(10), sensor=qos_profile_sensor_data,
                rosout=rosout)


def _params(**values):
    from rclpy.parameter import Parameter
    return [Parameter(k, value=v) for k, v in values.items()]


class DeadGraph(AssertionError):
    """A wait ran past its deadline: the graph stopped answering. ``result``: the trip so far."""

    def __init__(self, message, result=None):
        super().__init__(message)
        self.result = result


@dataclass
class TripResult:
    """A trip's records (per step: arrays over steps) and its figures (see ``figures``)."""

    scenario: str
    start: tuple
    checkout: str
    fault: str | None
    planner_time: float
    robot_radius: float
    goal_tolerance: float
    poses: np.ndarray                 # (K, 3) true pose at each step
    asked: np.ndarray                 # (K, 2) planner's (v, w); NaN where it sent nothing
    sent: np.ndarray                  # (K, 2) the filter's (v, w) applied over the step (0 if not finite)
    actions: list                     # per step: the newest safety_filter/state action, reason
    reasons: list
    clearance: np.ndarray             # (K,) clearance of the robot's centre from the obstacles
    contact: object                   # unicycle_world.Contact of the poses: entries, poses inside, depth
    reached: bool = False
    time: float = math.inf            # sim s from the start to within goal_tolerance
    outputs: int = 0                  # cmd_vel received from the first step on
    commands: int = 0                 # planner commands published
    nonfinite_commands: int = 0
    diagnostics: list = field(default_factory=list)   # (step, level, name, message)
    rosout: list = field(default_factory=list)        # (step, level, logger, message) of the filter
    states: list = field(default_factory=list)        # (step, action, reason) of every state message

    @property
    def steps(self) -> int:
        return len(self.sent)

    def figures(self) -> dict:
        """reached, time, planner_time, ratio, path_length, turning (time, share), least_clearance,
        collisions (entries, depth), speed_excess, the actions' counts, outputs beyond commands."""
        p = self.poses[:, :2]
        v, w = self.sent[:, 0], self.sent[:, 1]
        turning = (np.abs(v) < TURNING_V) & (np.abs(w) > TURNING_W)
        asked = self.asked[:, 0]
        asked_recent = np.fmax(asked, np.concatenate([[np.nan], asked[:-1]]))     # this step's and the one before
        finite = np.isfinite(asked_recent)
        excess = float(np.max(v[finite] - asked_recent[finite])) if finite.any() else math.nan
        return dict(
            scenario=self.scenario, start=list(self.start), checkout=self.checkout, fault=self.fault,
            reached=bool(self.reached),
            time=float(self.time), planner_time=float(self.planner_time),
            ratio=float(self.time / self.planner_time) if self.reached else math.inf,
            sim_time=self.steps * DT, steps=self.steps,
            path_length=float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0,
            turning_time=float(turning.sum() * DT), turning_share=float(turning.mean()) if len(v) else 0.0,
            least_clearance=float(self.clearance.min() - self.robot_radius) if len(p) else math.nan,
            collisions=self.contact.entries, collision_depth=self.contact.depth, speed_excess=excess,
            actions=dict(Counter(self.actions)), extra_outputs=self.outputs - self.commands,
            nonfinite_commands=self.nonfinite_commands)


def _state_values(msg) -> dict:
    return {kv.key: kv.value for kv in msg.values}


class TripGraph:
    """The graph of the module for one trip of ``scenario`` (a name or an own_simulator().Scenario)."""

    def __init__(self, ctx, scenario, *, fault=None, fault_step=0, detections='scan', ns='',
                 filter_overrides=None, params_file=None, deadline=20.0, planner_config=None, start=None,
                 fleet=False):
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
        from geometry_msgs.msg import TwistStamped
        from nav_msgs.msg import Odometry
        from rcl_interfaces.msg import Log
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import LaserScan, PointCloud2
        check_options(fault, detections)
        own = own_simulator()
        self.sim = own
        self.scenario = own.scenario(scenario) if isinstance(scenario, str) else scenario
        if start is not None:       # the same trip from another start (its path and figures stay the scenario's)
            self.scenario = dataclasses.replace(self.scenario, start=tuple(float(v) for v in start))
        self.planner = own.PathFollower(self.scenario.waypoints, planner_config or own.PlannerConfig())
        self.fault, self.fault_step, self.detections, self.deadline = fault, int(fault_step), detections, deadline
        self.ns = ns.rstrip('/')
        qos = _qos()
        self.ctx = ctx
        self.fleet = fleet
        self.filter = self._make_filter(ctx, detections, filter_overrides or {}, params_file)
        sim = _params(use_sim_time=True)
        self.robot = Node('unicycle_robot', namespace=self.ns or '/', context=ctx, parameter_overrides=sim)
        self.planner_node = Node('trip_planner', namespace=self.ns or '/', context=ctx, parameter_overrides=sim)
        self.monitor = Node('trip_monitor', context=ctx, parameter_overrides=sim)
        topic = f'{self.ns}/'
        self.odom_pub = self.robot.create_publisher(Odometry, topic + 'odom', qos['stream'])
        if detections == 'scan':
            self.sensor_pub = self.robot.create_publisher(LaserScan, topic + 'scan', qos['sensor'])
        else:
            self.sensor_pub = self.robot.create_publisher(PointCloud2, topic + 'cloud', qos['sensor'])
        self.received = []                     # (v, w) of every cmd_vel
        self.received_stamps = []              # and its header stamp (ns)
        self.received_frames = []              # and its header frame
        self.cmd_sub = self.robot.create_subscription(TwistStamped, topic + 'cmd_vel', self._on_cmd, qos['every'])
        self.cmd_pub = self.planner_node.create_publisher(TwistStamped, topic + 'cmd_vel_nav', qos['stream'])
        self.clock_pub = self.monitor.create_publisher(Clock, '/clock', qos['clock'])
        self.state = ('', '')
        self.step_index = 0
        self.states, self.diagnostics, self.rosout = [], [], []
        m = self.monitor
        self.subs = [self.cmd_sub,
                     m.create_subscription(DiagnosticStatus, topic + 'safety_filter/state', self._on_state,
                                           qos['every']),
                     m.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, qos['every']),
                     m.create_subscription(Log, '/rosout', self._on_rosout, qos['rosout'])]
        self.spoof = None
        if fault in SPOOF_FAULTS:
            self.spoof = Node('spoof_driver', namespace=self.ns or '/', context=ctx, parameter_overrides=sim)
            self.spoof_pub = self.spoof.create_publisher(LaserScan, topic + 'scan', qos['sensor'])
            self._spoof_ticks = None
        self.executor = SingleThreadedExecutor(context=ctx)            # the harness's nodes
        for n in (self.robot, self.planner_node, self.monitor, self.spoof):
            if n is not None:
                self.executor.add_node(n)
        # the filter node's own: its /clock, watchdog, diagnostics, parameters. While a command's
        # answer is awaited it is not spun (unless the node takes cmd_vel_nav itself, direct_take
        # false): its watchdog, due after a slow step, ran there before the command was taken and
        # answered it with a decision on the previous command (seen after a garbage collection)
        self.filter_executor = SingleThreadedExecutor(context=ctx)
        self.filter_executor.add_node(self.filter)
        # a filter that takes cmd_vel_nav itself, or decides on a tick of its executor's (decide_on tick)
        takes_commands = any(sub.topic_name.endswith('/cmd_vel_nav') for sub in self.filter.subscriptions)
        self.answers_on_executor = takes_commands or getattr(self.filter, 'mode', None) == 'tick'
        self.state_xy = np.asarray(self.scenario.start, dtype=float)
        self.t0_ns = int(round(START_TIME * 1e9))
        self.records = dict(poses=[], asked=[], sent=[], actions=[], reasons=[])
        self.commands = 0
        self.outputs_before = 0
        self.nonfinite = 0

    # -- the filter ------------------------------------------------------------------------------
    def _make_filter(self, ctx, detections, overrides, params_file):
        import yaml
        from rclpy.lifecycle import TransitionCallbackReturn
        from supersafe_ros.nodes.safety_filter_node import ManagedSafetyFilterNode
        path = Path(params_file) if params_file else checkout_root() / 'config' / 'nav2_safety_filter.yaml'
        document = yaml.safe_load(path.read_text())
        bodies = [body for key, body in document.items() if key.rstrip('/').split('/')[-1] == 'safety_filter']
        if len(bodies) != 1:
            raise ValueError(f'{path}: expected the parameters of one safety_filter node, found {list(document)}')
        body = bodies[0]
        self.file_parameters = dict(body['ros__parameters'])
        self.params_file = path
        cls, name = ManagedSafetyFilterNode, 'safety_filter'
        values = dict(use_sim_time=True, **({'detections_type': 'point_cloud2'} if detections == 'cloud' else {}))
        if self.fleet:
            # a fleet node of this robot and an idle second one, deciding both on ticks (at 100 Hz: a
            # step waits for the next tick)
            from supersafe_ros.nodes.fleet_safety_filter_node import ManagedFleetSafetyFilterNode
            cls, name = ManagedFleetSafetyFilterNode, 'fleet_safety_filter'
            values.update(robots=['', 'idle'], rate=100.0)
        if self.ns or self.fleet:        # the file names safety_filter in the root namespace: the same for ours
            self._tmp = tempfile.NamedTemporaryFile('w', suffix='.yaml', prefix='trip_params_')
            yaml.safe_dump({f'{self.ns}/{name}': body}, self._tmp)
            self._tmp.flush()
            path = Path(self._tmp.name)
        topic = 'cloud' if detections == 'cloud' else 'scan'
        values.update(overrides)
        node = cls(
            context=ctx, namespace=self.ns or '/',
            cli_args=['--ros-args', '--params-file', str(path), '-r', 'pose:=odom', '-r', f'detections:={topic}'],
            parameter_overrides=_params(**values))
        if node.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            node.destroy_node()
            raise RuntimeError(f'the filter did not configure (its log says why); params {path}')
        wrong = {k: (v, node.get_parameter(k).value) for k, v in self.file_parameters.items()
                 if k not in values and not _same(node.get_parameter(k).value, v)}
        if wrong:
            node.close()
            node.destroy_node()
            raise RuntimeError(f'{path}: the filter does not hold the file\'s parameters (file, node): {wrong}')
        if node.trigger_activate() != TransitionCallbackReturn.SUCCESS:
            raise RuntimeError('the filter did not activate')
        return node

    # -- callbacks -------------------------------------------------------------------------------
    def _on_cmd(self, msg):
        self.received.append((msg.twist.linear.x, msg.twist.angular.z))
        self.received_stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        self.received_frames.append(msg.header.frame_id)

    def _on_state(self, msg):
        values = _state_values(msg)
        self.state = (values.get('action', ''), values.get('reason', ''))
        self.states.append((self.step_index, *self.state))

    def _on_diagnostics(self, msg):
        for s in msg.status:
            self.diagnostics.append((self.step_index, int(s.level[0]) if isinstance(s.level, bytes) else int(s.level),
                                     s.name, s.message))

    def _on_rosout(self, msg):
        if 'safety_filter' in msg.name:
            self.rosout.append((self.step_index, int(msg.level), msg.name, msg.msg))

    # -- waiting ---------------------------------------------------------------------------------
    def until(self, condition, what, timeout=None, filter_too=True):
        """Spin until ``condition()`` (the filter node too unless ``filter_too`` is false); DeadGraph
        past the deadline."""
        end = time.monotonic() + (self.deadline if timeout is None else timeout)
        while not condition():
            if time.monotonic() > end:
                raise DeadGraph(f'timed out after {self.deadline} s waiting for {what} (step {self.step_index})',
                                self.result())
            if filter_too:
                self.filter_executor.spin_once(timeout_sec=0.005)
                # what came meanwhile, a few callbacks of it (a filter deciding on ticks sends a cmd_vel each
                # tick: one callback a turn fell behind them, answers 150 ms late)
                for _ in range(HARNESS_CALLBACKS):
                    self.executor.spin_once(timeout_sec=0.0)
                    if condition():
                        return
            else:
                self.executor.spin_once(timeout_sec=0.01)

    def _answer(self, before, what, t_ns, command=True):
        """Wait for a cmd_vel after the ``before``-th and, with a command out, one stamped with it (at ``t_ns``)."""
        if command:
            self.until(lambda: any(s >= t_ns for s in self.received_stamps[before:]), what,
                       filter_too=self.answers_on_executor)
        else:
            self.until(lambda: len(self.received) > before, what)

    def _drain(self):
        """Take what has already arrived (the state that went out with the answer), without waiting."""
        for _ in range(3):          # the state message goes out right after the cmd_vel
            self.executor.spin_once(timeout_sec=0.0)

    def start(self):
        """Match every endpoint, then the warm-up: one step before step 0 (at t0 - dt) in which the
        robot stands at its start while the filter takes its first odometry, scan and command, and
        its answer is not applied. Without it the watchdog's start-up fail safe (no command yet) could
        go out after step 0's command was published and before it was taken, and the robot would
        start a step late (seen: 1 trip in 3; the trips' outcomes then differ).

        The warm-up ends on an answer judged from its command: in the planner's frame (a filter
        stamps what it did not judge from a command with its clock, in the last frame it heard: none
        before the first) and at a speed when the planner asked for one. The watchdog runs on the
        filter's input thread, which the harness does not stop: its "stopped: planner silent" zero
        twist, stamped t0 - dt by the filter's clock before the command was taken, once ended the
        warm-up, and at step 0 the command was still not taken: the robot started a step late (CI,
        2026-12-04: the empty trip in 7.46 s against the planner's 7.44 s)."""
        pubs = [self.odom_pub, self.sensor_pub, self.cmd_pub, self.clock_pub] + (
            [self.spoof_pub] if self.spoof is not None else [])
        self.until(lambda: all(p.get_subscription_count() > 0 for p in pubs)
                   and all(s.get_publisher_count() > 0 for s in self.subs), 'the graph to match')
        t_ns = self.t0_ns - int(round(DT * 1e9))
        self._clock(t_ns)
        start = self.state_xy
        self.odom_pub.publish(odometry(start, (0.0, 0.0), t_ns))
        ranges = laser_ranges(self.scenario.world, start)
        self.sensor_pub.publish(point_cloud(t_ns, ranges) if self.detections == 'cloud' else laser_scan(t_ns, ranges))
        before = len(self.received)
        asked = self.planner.command(start)
        self.cmd_pub.publish(twist_stamped(asked, t_ns))

        def judged():
            return any(self.received_stamps[i] >= t_ns and self.received_frames[i] == PLANNER_FRAME
                       and (self.received[i][0] > 0.0 or asked[0] <= 0.0) for i in range(before, len(self.received)))
        self.until(judged, 'the answer judged from the warm-up command', filter_too=self.answers_on_executor)
        self._drain()

    def _clock(self, t_ns):
        from rosgraph_msgs.msg import Clock
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
        self.clock_pub.publish(msg)
        self.until(lambda: self.filter.get_clock().now().nanoseconds >= t_ns, f'the filter\'s clock at {t_ns} ns')

    # -- a step ----------------------------------------------------------------------------------
    def step(self):
        """One step (the module); returns the (v, w) applied."""
        k = self.step_index
        t_ns = self.t0_ns + int(round(k * DT * 1e9))
        self._clock(t_ns)
        faulty = self.fault is not None and k >= self.fault_step
        state = self.state_xy
        moving = self.records['sent'][-1] if self.records['sent'] else (0.0, 0.0)
        self.odom_pub.publish(odometry(state, moving, t_ns, nan_position=faulty and self.fault == 'odom_nan'))
        if k % SCAN_EVERY == 0:
            ranges = laser_ranges(self.scenario.world, state)
            fault = self.fault if faulty else None
            self.sensor_pub.publish(point_cloud(t_ns, ranges, fault) if self.detections == 'cloud'
                                    else laser_scan(t_ns, ranges, fault))
        if faulty and self.spoof is not None:
            self._spoof(t_ns)
        before = len(self.received)
        if faulty and self.fault == 'planner_silent':
            asked = (math.nan, math.nan)
        else:
            asked = self.planner.command(state)
            if faulty and self.fault == 'planner_nan':
                asked = (math.nan, math.nan)
            before = len(self.received)
            self.cmd_pub.publish(twist_stamped(asked, t_ns))
            self.commands += 1
            if not math.isfinite(asked[0]):
                asked = (math.nan, math.nan)
        self._answer(before, f'cmd_vel at step {k}', t_ns, command=not (faulty and self.fault == 'planner_silent'))
        self._drain()
        latest = max(range(before, len(self.received)), key=lambda i: (self.received_stamps[i], i))
        v, w = self.received[latest]
        if not (math.isfinite(v) and math.isfinite(w)):
            self.nonfinite += 1
            v = w = 0.0
        r = self.records
        r['poses'].append(state)
        r['asked'].append(asked)
        r['sent'].append((v, w))
        r['actions'].append(self.state[0])
        r['reasons'].append(self.state[1])
        self.state_xy = self.sim.unicycle_step(state, v, w, DT)
        self.step_index += 1
        return v, w

    def _spoof(self, t_ns):
        ticks = math.floor((t_ns - self.t0_ns) * 1e-9 * SPOOF_RATE + 1e-9)
        if self._spoof_ticks is not None and ticks <= self._spoof_ticks:
            return
        self._spoof_ticks = ticks
        ranges = [] if self.fault == 'spoof_empty_scans' else np.full(BEAMS, np.inf)
        self.spoof_pub.publish(laser_scan(t_ns, ranges))

    # -- the trip --------------------------------------------------------------------------------
    def run(self, max_time=90.0) -> TripResult:
        """Step until the robot is within the goal's tolerance or ``max_time`` sim seconds."""
        self.start()
        self.outputs_before = len(self.received)
        goal = np.asarray(self.scenario.goal, dtype=float)
        tolerance = self.planner.config.goal_tolerance
        for _ in range(int(round(max_time / DT))):
            if math.hypot(*(self.state_xy[:2] - goal)) <= tolerance:
                return self.result(reached_at=self.step_index * DT)
            self.step()
        return self.result()

    def result(self, reached_at=None) -> TripResult:
        r = self.records
        poses = np.asarray(r['poses'], dtype=float).reshape(-1, 3)
        return TripResult(
            scenario=self.scenario.name, start=self.scenario.start, checkout=str(checkout_root()), fault=self.fault,
            planner_time=self.sim.planner_time(self.scenario, DT, self.planner.config),
            robot_radius=self.scenario.robot_radius, goal_tolerance=self.planner.config.goal_tolerance,
            poses=poses, asked=np.asarray(r['asked'], dtype=float).reshape(-1, 2),
            sent=np.asarray(r['sent'], dtype=float).reshape(-1, 2), actions=list(r['actions']),
            reasons=list(r['reasons']), clearance=self.scenario.world.clearance(poses[:, :2]),
            contact=self.sim.collides(self.scenario.world, poses[:, :2], self.scenario.robot_radius),
            reached=reached_at is not None, time=math.inf if reached_at is None else reached_at,
            outputs=len(self.received) - self.outputs_before, commands=self.commands,
            nonfinite_commands=self.nonfinite, diagnostics=list(self.diagnostics), rosout=list(self.rosout),
            states=list(self.states))

    def close(self):
        self.executor.shutdown()
        self.filter_executor.shutdown()
        self.filter.close()
        for n in (self.filter, self.robot, self.planner_node, self.monitor, self.spoof):
            if n is not None:
                n.destroy_node()
        if getattr(self, '_tmp', None) is not None:
            self._tmp.close()
        # the nodes' handles sit in reference cycles (callbacks bound to this graph, the filter's
        # wiring): collected now, in this process, not in a child that forks later (flake8's
        # workers in the same pytest run died in the garbage collector: SIGSEGV)
        self.filter = self.robot = self.planner_node = self.monitor = self.spoof = None
        self.executor = self.filter_executor = None
        self.subs = []
        gc.collect()


# -- the messages (pure: a test can look at a fault without nodes) --------------------------------
def beam_angles() -> np.ndarray:
    """The scan's beam angles in the laser's frame: 360 round the full circle from -pi."""
    return -math.pi + (2.0 * math.pi / BEAMS) * np.arange(BEAMS)


def laser_pose(state) -> tuple:
    """The laser's pose (x, y, yaw) in odom with the robot at ``state`` (LASER_MOUNT in base_link)."""
    x, y, theta = (float(s) for s in state)
    mx, my, myaw = LASER_MOUNT
    return (x + mx * math.cos(theta) - my * math.sin(theta), y + mx * math.sin(theta) + my * math.cos(theta),
            theta + myaw)


def laser_ranges(world, state) -> np.ndarray:
    """The true scan (float32, +inf: no return) of ``world`` with the robot at ``state``."""
    return world.ray_cast(laser_pose(state), beam_angles(), RANGE_MAX)


def _stamp(header, t_ns):
    header.stamp.sec, header.stamp.nanosec = divmod(int(t_ns), 1_000_000_000)


def laser_scan(t_ns, ranges, fault=None):
    """A sensor_msgs/LaserScan (frame laser) of ``ranges``, or the SCAN_FAULTS' ``fault`` of it."""
    from sensor_msgs.msg import LaserScan
    bad = {'scan_nan': math.nan, 'scan_neg_inf': -math.inf, 'scan_negative': -1.0}
    m = LaserScan()
    _stamp(m.header, t_ns)
    m.header.frame_id = 'laser'
    increment = 2.0 * math.pi / BEAMS
    m.angle_min, m.angle_max = -math.pi, -math.pi + increment * (BEAMS - 1)
    m.angle_increment = 0.0 if fault == 'scan_angle_increment_0' else increment
    m.scan_time, m.range_min, m.range_max = DT * SCAN_EVERY, RANGE_MIN, RANGE_MAX
    if fault == 'scan_range_min_above_max':
        m.range_min = RANGE_MAX + 1.0
    ranges = np.full(len(ranges), bad[fault]) if fault in bad else ranges
    m.ranges = np.asarray(ranges, dtype=np.float32).tolist()
    return m


def point_cloud(t_ns, ranges, fault=None):
    """The scan's returns as a sensor_msgs/PointCloud2 (frame laser; x, y, z float32 and 4 bytes of
    padding: 16 bytes a point), or the CLOUD_FAULTS' ``fault`` of it."""
    from sensor_msgs.msg import PointCloud2, PointField
    ranges = np.asarray(ranges, dtype=float)
    a = beam_angles()[:len(ranges)]
    ok = np.isfinite(ranges)
    points = np.zeros(int(ok.sum()), dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('pad', 'V4')])
    points['x'], points['y'] = ranges[ok] * np.cos(a[ok]), ranges[ok] * np.sin(a[ok])
    if fault == 'cloud_nan_points':
        points['x'] = points['y'] = points['z'] = np.nan
    m = PointCloud2()
    _stamp(m.header, t_ns)
    m.header.frame_id = 'laser'
    m.fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate('xyz')]
    m.is_bigendian, m.height, m.width = False, 1, len(points)
    m.point_step = {'cloud_point_step_12': 12, 'cloud_point_step_8': 8}.get(fault, points.dtype.itemsize)
    m.row_step = points.dtype.itemsize * len(points)          # the data's own: 16 bytes a point
    m.data = points.tobytes()
    m.is_dense = fault != 'cloud_nan_points'
    return m


def odometry(state, moving, t_ns, nan_position=False):
    """nav_msgs/Odometry (odom -> base_link) of ``state`` driving ``moving`` (v, w)."""
    from nav_msgs.msg import Odometry
    m = Odometry()
    _stamp(m.header, t_ns)
    m.header.frame_id, m.child_frame_id = 'odom', 'base_link'
    x, y, theta = (float(s) for s in state)
    m.pose.pose.position.x, m.pose.pose.position.y = (math.nan, math.nan) if nan_position else (x, y)
    m.pose.pose.orientation.z, m.pose.pose.orientation.w = math.sin(theta / 2), math.cos(theta / 2)
    m.twist.twist.linear.x, m.twist.twist.angular.z = (float(v) for v in moving)
    return m


def twist_stamped(vw, t_ns):
    """geometry_msgs/TwistStamped (frame base_link) of (v, w)."""
    from geometry_msgs.msg import TwistStamped
    m = TwistStamped()
    _stamp(m.header, t_ns)
    m.header.frame_id = PLANNER_FRAME
    m.twist.linear.x, m.twist.angular.z = float(vw[0]), float(vw[1])
    return m


def _same(a, b) -> bool:
    if isinstance(b, float) or isinstance(a, float):
        return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=1e-12)
    if isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


def run_trip(ctx, scenario, max_time=90.0, **options) -> TripResult:
    """One trip of ``scenario`` through the graph of the module (``options``: TripGraph's)."""
    graph = TripGraph(ctx, scenario, **options)
    try:
        return graph.run(max_time)
    finally:
        graph.close()
