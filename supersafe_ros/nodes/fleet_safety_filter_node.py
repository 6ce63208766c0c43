"""fleet_safety_filter_node: the safety filter of a whole fleet in one process.

Parameter ``robots`` lists the namespaces (e.g. ['robot_0', 'robot_1']). Two
interfaces, each switchable (read-only parameters), used together or alone:

Per-robot topics (``per_robot_topics``), those of safety_filter_node, of the same types
(``pose_type``, ``detections_type`` pose_array or marker_array, ``cmd_vel_stamped``,
``require_detections``: read by the same Sources, ``filter_sources``), so it is a drop-in for
N of them:
  sub  <ns>/pose, <ns>/detections, <ns>/cmd_vel_nav     as safety_filter_node
  pub  <ns>/cmd_vel, <ns>/safety_filter/state           as safety_filter_node
  pub  <ns>/safety_filter/ready                         as safety_filter_node (latched, once it can judge)
A range sensor's or a costmap's detections (a local map and its value per robot, solved in
the background) are safety_filter_node's alone: the fleet node refuses them at start.

Batched topics (``batched_topics``; see docs/fleet.md and ``ros_io.fleetmsg``), for a
fleet manager or simulator that holds every robot's state; robot i = robots[i]:
  sub  fleet/poses             geometry_msgs/PoseArray       N poses, frame map; each one is a tick
  sub  fleet/detections        geometry_msgs/PoseArray       obstacle centres seen by the fleet,
                                                             applied to every robot
  sub  fleet/cmd_vel_nav       std_msgs/Float64MultiArray    N x [linear.x, angular.z]
  pub  fleet/cmd_vel           std_msgs/Float64MultiArray    N x [linear.x, angular.z]
  pub  fleet/safety_filter/state  diagnostic_msgs/DiagnosticArray  one status per robot whose action
                                                             changed or whose state is due (state_rate)
(fleet/... are relative to the node's namespace.)
  pub  /diagnostics            diagnostic_msgs/DiagnosticArray  1 Hz, a status per robot (filter_diagnostics)
As a managed node (``ManagedFleetSafetyFilterNode``, executable managed_fleet_safety_filter;
``managed``) it publishes no cmd_vel unless active.

Every decision of every robot is made in ONE vectorised ``filter.step_many``
call per tick. Ticks: every ``fleet/poses`` message (the batched reply), and a
steady-clock timer at ``rate`` while they pause: each batched tick restarts the timer, so
flowing poses cost no timer wake-up, and with batched topics alone the timer decides once
no poses have come for 1.5 periods (its second wake-up, two periods after the last
poses, then one per period). Per-robot topics, fleet/detections and fleet/cmd_vel_nav
are not taken through the executor one message at a time: their subscriptions belong to a
helper node that is never spun, and each tick drains them (``ros_io.take``): every batched
message waiting, in order (decoded by rclpy; of the commands, each robot's newest good row
applied once); the newest sample of each per-robot topic (serialized, read by the Sources of
``filter_sources``). Each robot's cmd_vel
is published serialized, so the cost per robot is a few takes and one publish, not a
callback and a message object per sample.
A per-robot decision therefore waits for the next tick (at most 1/rate s).

A bad per-robot input is refused as safety_filter_node refuses it (a bad pose or detections
fail the robot safe; a command not finite or unreadable stops a robot that can stop until a
valid one comes). Bad batched input (wrong frame or size, NaN rows) is rejected with a logged
reason:
a whole bad pose message fails every robot safe (their newest pose is rejected), a
bad row only its robot; a bad command row keeps that robot's previous command.
Parameters, the safe sets, the admissibility check of learned sets and the time
base are those of safety_filter_node (``filter_wiring``).
"""
from __future__ import annotations

import itertools
from operator import eq
import time

import numpy as np
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseArray
from std_msgs.msg import Empty, Float64MultiArray

from ..filter import FAIL_SAFE, step_many, update_commands, update_detections_all, update_poses
from ..ros_io import cdr, fleetmsg, rosmsg
from ..ros_io.take import take_all, take_newest
from .common import ParameterSpec, declare_all, run_node
from .filter_diagnostics import FilterDiagnostics, array_bytes, status_copy
from .filter_inputs import MAP_SENSORS, TYPE_PARAMETERS, check_types
from .filter_sources import NO_DETECTIONS, CommandSink, CommandSource, DiscSource, PoseSource
from .filter_state import FleetThrottle, Status
from .filter_wiring import FilterWiring
from .managed import ManagedFilter

# this node's own parameters (the filter's are in filter_parameters), in the order declared
PARAMETERS = (
    ParameterSpec('robots', ['robot_0'], 'namespaces of the robots (order = rows of the batched topics)'),
    ParameterSpec('per_robot_topics', True, 'serve <ns>/pose, <ns>/detections, <ns>/cmd_vel_nav -> '
                  '<ns>/cmd_vel, <ns>/safety_filter/state'),
    ParameterSpec('batched_topics', True, 'serve fleet/poses, fleet/detections, fleet/cmd_vel_nav -> '
                  'fleet/cmd_vel, fleet/safety_filter/state'),
    *TYPE_PARAMETERS,       # the per-robot topics' types, as safety_filter_node's
)


def robot_namespace(name: str) -> str:
    """'/robot_0' for 'robot_0' or '/robot_0/'; refuses empty names."""
    ns = '/' + str(name).strip().strip('/')
    if ns == '/':
        raise ValueError(f'robot namespace {name!r} is empty')
    return ns


class _RobotTopics:
    """A robot's per-robot endpoints (on the never-spun io node), of its Sources' types (no
    detections subscription without ``require_detections``), and its cmd_vel's sink; ``ready``:
    its latched ``safety_filter/ready``, made once its filter can judge (``say_ready``)."""

    __slots__ = ('ns', 'pose', 'detections', 'command', 'sink', 'cmd_pub', 'state_pub', 'ready')

    def __init__(self, io, ns, sources, stamped):
        self.ns, self.ready = ns, None
        noop = lambda msg: None  # noqa: E731  (taken by the tick, never by an executor)
        self.pose, self.detections, self.command = (
            None if source is None else io.create_subscription(source.msg_type, f'{ns}/{source.topic}', noop,
                                                               source.qos, raw=True)
            for source in sources)
        self.sink = CommandSink(stamped)
        self.cmd_pub = io.create_publisher(self.sink.msg_type, f'{ns}/cmd_vel', rosmsg.QOS_STREAM)
        self.state_pub = io.create_publisher(DiagnosticStatus, f'{ns}/safety_filter/state', rosmsg.QOS_STREAM)

    def say_ready(self, io):
        """The latched ``safety_filter/ready``, as safety_filter_node's: made and sent once."""
        if self.ready is None:
            self.ready = io.create_publisher(Empty, f'{self.ns}/safety_filter/ready', rosmsg.QOS_LATCHED)
            self.ready.publish(Empty())


class FleetSafetyFilter:
    """The filter of a fleet on a node (``self``: a Node or a LifecycleNode); ``build()`` makes
    it (the plain node in its constructor, the managed one on configure). It decides only
    while ``active``."""

    active = True

    def build(self):
        node_name = self.get_name()
        p = declare_all(self, PARAMETERS)
        check_types(p)
        if p['detections_type'] in MAP_SENSORS:
            raise ValueError(f"detections_type {p['detections_type']!r}: a local map per robot is safety_filter_node's "
                             f"alone; the fleet node takes pose_array or marker_array (run a safety_filter_node "
                             f"per robot for a range sensor or a costmap)")
        self.per_robot, self.batched = p['per_robot_topics'], p['batched_topics']
        self.require_detections = p['require_detections']
        self.namespaces = [robot_namespace(r) for r in p['robots']]
        if len(set(self.namespaces)) != len(self.namespaces):
            raise ValueError(f'robots lists a namespace twice: {self.namespaces}')
        self.wiring = w = FilterWiring(self, self.namespaces, on_rate=self._set_rate)
        # the per-robot inputs' Sources (as safety_filter_node's): pose, detections (None: no sensor), command
        self.sources = (PoseSource(p['pose_type'], w.frame),
                        DiscSource(p['detections_type'], w.frame) if self.require_detections else None,
                        CommandSource(p['cmd_vel_stamped']))
        self.stamped = p['cmd_vel_stamped']
        self.n = len(self.namespaces)
        start = time.monotonic()
        self._throttle = FleetThrottle(self.n, start, w.state_period)
        self._failing = np.full(self.n, -1, dtype=np.int8)    # per robot: -1 starting, 0 filtering, 1 failing safe
        self.ticks = 0
        self.failing_safe = 0
        self.decisions = np.zeros(self.n, dtype=np.int64)
        self._last_batched = -1e18
        self.poses_sub = None
        self.superseded_poses = 0

        # its entities are drained by the tick: never add this node to an executor
        self.io = Node(f'{node_name}_io', namespace=self.get_namespace(), context=self.context,
                       start_parameter_services=False)
        self.topics = []
        if self.per_robot:
            self.topics = [_RobotTopics(self.io, ns, self.sources, self.stamped) for ns in self.namespaces]
            if not self.require_detections:     # no obstacle sensor: every robot can judge from its first pose
                for topics in self.topics:
                    topics.say_ready(self.io)
        self.fleet_detections_sub = self.fleet_commands_sub = None
        if self.batched:
            # detections and commands are drained by the tick, before the poses (no executor wake-up
            # of their own: the poses tick, and the timer while they pause)
            noop = lambda msg: None  # noqa: E731
            if self.require_detections:
                self.fleet_detections_sub = self.io.create_subscription(PoseArray, 'fleet/detections', noop,
                                                                        rosmsg.QOS_STREAM, raw=True)
            self.fleet_commands_sub = self.io.create_subscription(Float64MultiArray, 'fleet/cmd_vel_nav', noop,
                                                                  rosmsg.QOS_STREAM)
            # raw: the poses are read straight from the CDR buffer (fleetmsg.posearray_cdr_to_states)
            self.poses_sub = self.create_subscription(PoseArray, 'fleet/poses', self.on_fleet_poses,
                                                      rosmsg.QOS_STREAM, raw=True)
            self.fleet_cmd_pub = self.create_publisher(Float64MultiArray, 'fleet/cmd_vel', rosmsg.QOS_STREAM)
            self.fleet_state_pub = self.create_publisher(DiagnosticArray, 'fleet/safety_filter/state',
                                                         rosmsg.QOS_STREAM)
        self.timer = None
        self._set_rate(w.rate)
        self._last_outs = None
        self._last_states = [None] * self.n     # each robot's last state message published
        inputs = [(f'{ns}/{source.topic}', source.msg_type) for ns in self.namespaces if self.per_robot
                  for source in self.sources if source is not None]
        if self.batched:
            inputs += [('fleet/poses', PoseArray), ('fleet/cmd_vel_nav', Float64MultiArray)]
            if self.require_detections:
                inputs.append(('fleet/detections', PoseArray))
        self.diagnostics = FilterDiagnostics(self, self._statuses, inputs, w.complain)
        self.get_logger().info(
            f'filtering {self.n} robots ({", ".join(self.namespaces[:5])}{", ..." if self.n > 5 else ""}) '
            f'in one step per tick at {w.rate:g} Hz; per-robot topics {"on" if self.per_robot else "off"}, '
            f'batched topics {"on" if self.batched else "off"}; failing safe until each robot\'s first '
            f'pose and detections')

    def _set_rate(self, rate):
        self.period = 1.0 / rate
        if self.timer is not None:
            self.destroy_timer(self.timer)
        self.timer = self.create_timer(self.period, self.on_tick, clock=self.wiring.steady)

    # -- per-robot topics: drained once per tick --------------------------------------------------
    def _drain(self, t):
        w = self.wiring
        poses, discs, commands = self.sources
        clipped, dropped = [], []        # robots whose new command was beyond limits, whose detections were cut
        for f, topics in zip(w.filters, self.topics):
            data = take_newest(topics.pose)[0]
            if data is not None:
                try:
                    state, stamp = poses.read(data)
                    f.update_pose(state, t, stamp=w.stamp(stamp, t))
                    if discs is None:       # no obstacle sensor: every pose comes with "no obstacle"
                        f.update_detections(NO_DETECTIONS, t)
                except ValueError as exc:
                    f.reject_pose(str(exc), t)
                    w.complain(f'pose {f.name}', f'{f.name}: pose rejected: {exc}; failing safe', level='error')
            data = None if discs is None else take_newest(topics.detections)[0]
            if data is not None:
                try:
                    f.update_detections(discs.read(data), t, w.safe_set)
                except ValueError as exc:
                    f.reject_detections(str(exc), t)
                    w.complain(f'det {f.name}', f'{f.name}: detections rejected: {exc}; failing safe',
                               level='error')
                else:
                    topics.say_ready(self.io)      # (once: its filter can judge)
                    if f.detections.dropped:
                        dropped.append(f)
            data = take_newest(topics.command)[0]
            if data is not None:
                if not commands.take(f, data, t, topics.sink):
                    w.complain(f'cmd {f.name}', f'{f.name}: cmd_vel_nav rejected: {f.command.note}')
                elif f.command.note:
                    clipped.append(f)
        self._tell_excess(clipped, dropped, 'cmd_vel_nav', 'detections')

    def _tell_excess(self, clipped, dropped, commands, detections):
        """One throttled line for the robots whose new commands were beyond their limits (clipped:
        the first one's raw values), one for those whose detections were cut to max_detections."""
        complain = self.wiring.complain
        if clipped:         # (a kind per topic: one does not silence the other)
            complain(f'{commands} clipped', f'{commands} beyond the robot\'s limits for {len(clipped)} robot(s); '
                     f'{clipped[0].name}: {clipped[0].command.note}')
        if dropped:
            shown = next((f for f in dropped if not f.detections.dropped_safely), dropped[0])    # an unsafe one first
            complain(f'{detections} dropped', f'{detections} of {len(dropped)} robot(s) cut; {shown.name}: '
                     f'{shown.detections.note}', level='error' if not shown.detections.dropped_safely else 'warn')

    # -- batched topics ---------------------------------------------------------------------------------
    def _drain_batched(self):
        """Every fleet/detections and fleet/cmd_vel_nav message waiting, oldest first, each
        checked (or rejected, and logged) as its own callback would: a bad row falls back to
        the previous message's. They count as arrived now, at most a period after they came."""
        if not self.batched:
            return
        for msg in take_all(self.fleet_detections_sub) if self.require_detections else ():
            self.on_fleet_detections(msg)
        commands = take_all(self.fleet_commands_sub)
        if commands:
            self.on_fleet_commands(*commands)

    def on_fleet_detections(self, msg):
        """A serialized PoseArray (the raw subscription's; a PoseArray is taken too), read as one
        array; at most ``max_detections`` kept, the nearest to the robots."""
        w = self.wiring
        t = w.now()
        try:
            xy = (rosmsg.posearray_to_xy(msg, w.frame) if isinstance(msg, PoseArray) else
                  rosmsg.checked_xy(*cdr.pose_array_xy(msg, 'fleet detections'), w.frame))
        except ValueError as exc:
            for f in w.filters:
                f.reject_detections(str(exc), t)
            w.complain('fleet detections', f'fleet/detections rejected: {exc}; failing safe', level='error')
            return
        update_detections_all(w.filters, xy, t, w.safe_set)     # one array shared by every robot
        for topics in self.topics:      # (each robot's safety_filter/ready, once)
            topics.say_ready(self.io)
        d = w.filters[0].detections if w.filters else None
        if d is not None and d.dropped:
            w.complain('fleet/detections dropped', f'fleet/detections: {d.note}',
                       level='warn' if d.dropped_safely else 'error')

    def on_fleet_commands(self, *msgs: Float64MultiArray):
        """One or more fleet/cmd_vel_nav messages, oldest first, as if each were taken in turn: a
        message or row refused is said and keeps the previous command; of the rest, each robot's
        newest row is its command (the older rows, arrived at the same time, would be replaced by
        it at once: each robot's command is updated once, however many messages waited)."""
        w = self.wiring
        t = w.now()
        newest = None                           # (N, 2): each robot's newest good row
        taken = np.zeros(self.n, bool)          # robots with a good row in some message
        newest_bad = ()                         # why each row of the newest readable message was refused
        for msg in msgs:
            try:
                commands, bad = fleetmsg.msg_to_commands(msg, self.n)
            except ValueError as exc:
                w.complain('fleet cmd', f'fleet/cmd_vel_nav rejected: {exc}; keeping the previous commands',
                           level='error')
                continue
            good = np.fromiter((not why for why in bad), dtype=bool, count=self.n)
            for i in np.flatnonzero(~good).tolist():
                f = w.filters[i]
                w.complain(f'cmd {f.name}', f'{f.name}: fleet/cmd_vel_nav row rejected: {bad[i]}; keeping the '
                           f'previous command', level='error')
            if newest is None:
                newest = np.array(commands, dtype=float)
            else:
                newest[good] = commands[good]
            taken |= good
            newest_bad = bad
        if newest is None:
            return
        # the good rows, validated at once; those beyond their robot's limits said
        beyond = update_commands(w.filters, newest[:, 1], t, skip=~taken, linears=newest[:, 0])
        for f, why in zip(w.filters, newest_bad):
            if why:     # (after the update: the newest message's word stays, as in turn)
                f.command.note = f'{why}: rejected, the previous command kept'
        self._tell_excess([w.filters[i] for i in beyond], [], 'fleet/cmd_vel_nav', '')

    def on_fleet_poses(self, data: bytes):
        """A serialized PoseArray (raw subscription); a PoseArray object is taken too.

        Poses that arrived while the filter was deciding are superseded by the newest one: it
        decides once, on the newest (deciding on each in turn would answer ever older poses)."""
        w = self.wiring
        if self.poses_sub is not None:
            newer, superseded = take_newest(self.poses_sub)
            if newer is not None:
                data = newer
                self.superseded_poses += superseded
                w.complain('fleet poses behind', f'fleet/poses: {self.superseded_poses} message(s) superseded so '
                           f'far by newer ones that came while the filter decided (it is slower than the '
                           f'poses); deciding on the newest')
        self._drain_batched()       # the detections and commands sent before these poses
        t = w.now()
        try:
            if isinstance(data, PoseArray):
                states, bad = fleetmsg.posearray_to_states(data, self.n, w.frame)
                header_stamp = data.header.stamp
            else:
                states, bad, header_stamp = fleetmsg.posearray_cdr_to_states(data, self.n, w.frame)
            stamp = w.stamp(header_stamp, t)
        except ValueError as exc:
            for f in w.filters:
                f.reject_pose(str(exc), t)
            w.complain('fleet poses', f'fleet/poses rejected: {exc}; failing safe (every robot)', level='error')
        else:
            for f, why in zip(w.filters, bad):
                if why:
                    f.reject_pose(why, t)
                    w.complain(f'pose {f.name}', f'{f.name}: fleet/poses row rejected: {why}; failing safe',
                               level='error')
            update_poses(w.filters, states, t, stamp=stamp, skip=bad)   # the good rows, validated at once
            if not self.require_detections:     # no obstacle sensor: every pose comes with "no obstacle"
                update_detections_all(w.filters, NO_DETECTIONS, t, w.safe_set)
        self.decide(t)
        self._last_batched = time.monotonic()
        self.timer.reset()      # the timer decides only when the poses pause (on_tick)

    # -- ticks ----------------------------------------------------------------------------------------
    def on_tick(self):
        if not self.per_robot and time.monotonic() - self._last_batched < self.period * 1.5:
            return   # the batched poses are ticking (a late one is not a missing one)
        self.decide()

    def _statuses(self) -> list:
        """Each robot's status on /diagnostics: its last state message (see filter_diagnostics; at
        most 1/state_rate old, and every change of action at once: not built again for
        /diagnostics, which a fleet of thousands would pay for each second)."""
        outs, w, node = self._last_outs, self.wiring, self.get_fully_qualified_name()
        if outs is None:
            return [Status(DiagnosticStatus.ERROR[0], f'{node}: {ns}',
                           'no decision yet' if self.active else 'inactive: no cmd_vel', ns) for ns in self.namespaces]
        shared = None
        out = []
        for i, (ns, state) in enumerate(zip(self.namespaces, self._last_states)):
            if state is None:       # (none published yet)
                shared = shared or w.shared_state_values()
                state = w.state_message(ns, outs[i], shared=shared)
            out.append(status_copy(state, f'{node}: {ns}', ns, None if self.active else
                                   f'inactive (lifecycle): no cmd_vel; last: {state.message}'))
        return out

    def decide(self, t=None):
        if not self.active:
            return None            # a managed node, inactive: no cmd_vel (managed.py)
        w = self.wiring
        if t is None:       # a tick of the timer's: the batched inputs that wait are taken first
            self._drain_batched()
            t = w.now()
        if self.per_robot:
            self._drain(t)
        outs = step_many(w.filters, w.safe_set, t)     # commands as lists; outputs built when read
        self.ticks += 1
        self.decisions += 1
        self.failing_safe = outs.action.count(FAIL_SAFE)
        # the commands first (serialized: no message built), then the states due, each built once for
        # both interfaces and published serialized (ros_io.cdr)
        if self.per_robot:
            for f, topics, action, v, omega in zip(w.filters, self.topics, outs.action, outs.linear, outs.omega):
                topics.cmd_pub.publish(topics.sink.cmd_vel(f, t, action, v, omega, self._clock_ns))
        if self.batched:
            self.fleet_cmd_pub.publish(fleetmsg.commands_to_msg(np.column_stack([outs.linear, outs.omega])))
        due = self._throttle.due(time.monotonic(), outs.action, w.set_update, w.state_period)
        shared = w.shared_state_values() if due else None
        states = [w.state_message(self.namespaces[i], outs[i], shared=shared) for i in due]
        kept = self._last_states
        for i, state in zip(due, states):
            kept[i] = state
        if self.per_robot:
            for i, state in zip(due, states):
                self.topics[i].state_pub.publish(cdr.diagnostic_status_bytes(state))
        if self.batched and states:
            self.fleet_state_pub.publish(array_bytes(self, states))
        self._tell_story(outs)
        self._last_outs = outs
        return outs

    def _clock_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _tell_story(self, outs):
        """At most one line per kind of change of the robots' fail-safe states per tick (quiet while
        starting): robots whose inputs became valid, robots failing safe, robots back."""
        failing = np.fromiter(map(eq, outs.action, itertools.repeat(FAIL_SAFE)), dtype=bool, count=self.n)
        before = self._failing
        started, lost, back = (np.flatnonzero(c).tolist() for c in
                               ((before < 0) & ~failing, failing & (before == 0), ~failing & (before == 1)))
        before[started] = before[back] = 0      # a robot failing safe from the start stays starting
        before[lost] = 1

        def names(rows):
            shown = ', '.join(self.namespaces[i] for i in rows[:5])
            return f'{len(rows)} robot(s) ({shown}{", ..." if len(rows) > 5 else ""})'
        if started:
            self.get_logger().info(f'inputs valid, filtering: {names(started)}')
        if lost:
            self.get_logger().error(f'failing safe: {names(lost)}; first: {outs[lost[0]].reason}')
        if back:
            self.get_logger().info(f'inputs valid again, filtering: {names(back)}')

    def send_zero_twist(self) -> list:
        """One zero twist on every robot's cmd_vel (per-robot and batched topics): a managed node
        going quiet (managed.py), the bases must not keep the last commands; the publishers."""
        sent = [topics.cmd_pub for topics in self.topics]
        for topics in self.topics:
            topics.cmd_pub.publish(topics.sink.bytes(0.0, 0.0, False, self._clock_ns))
        if self.batched:
            self.fleet_cmd_pub.publish(fleetmsg.commands_to_msg(np.zeros((self.n, 2))))
            sent.append(self.fleet_cmd_pub)
        return sent

    def close(self):
        self.wiring.close()
        self.wiring.live.close()
        self.io.destroy_node()


class FleetSafetyFilterNode(FleetSafetyFilter, Node):
    """The FleetSafetyFilter as a plain node: built and deciding from construction."""

    def __init__(self, node_name='fleet_safety_filter', **kwargs):
        Node.__init__(self, node_name, **kwargs)
        self.build()


class ManagedFleetSafetyFilterNode(ManagedFilter, FleetSafetyFilter, LifecycleNode):
    """The FleetSafetyFilter as a managed (lifecycle) node: built on configure, deciding while active
    (nodes/managed.py)."""

    def __init__(self, node_name='fleet_safety_filter', **kwargs):
        LifecycleNode.__init__(self, node_name, **kwargs)
        self.start_lifecycle()


def main(args=None):
    return run_node(FleetSafetyFilterNode, args)


def main_managed(args=None):
    return run_node(ManagedFleetSafetyFilterNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
