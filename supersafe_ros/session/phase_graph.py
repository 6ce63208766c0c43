"""One phase of a participant session on ROS: its graph of node processes, and the
session's node in the supervisor's place.

``PhaseNode``: this process's node for one phase's graph, named 'supervisor' so that
its ~/step_done is the observer topic the lockstep clock waits for. It feeds the page
(``ConsoleBridge``), answers each pose (the arrow keys in Phase I), records the driven
robot's path, and can hold the clock (``hold``: it withholds its step acknowledgement,
so the whole graph waits: the pause between calibration scenes). The clock paces its
steps on one wall-clock schedule and would run the held seconds off at full speed
after the pause; so before letting go, the node sets the clock's live ``rate_factor``
(to the value it has), which starts the schedule afresh from that moment.

``PhaseGraph``: the phase's node processes (``Team``) and a ``TeamMonitor``; ``run``
waits for the clock to reach the phase's duration. ``stop`` ends them within a bound
(SIGINT to every child at once, SIGKILL after ``grace``), so Ctrl-C ends a session in
about a second, whatever phase it is in.
"""
from __future__ import annotations

import signal
import subprocess
import time

from ..team import Team, TeamMonitor, _param_value, process_name
from ..console.state import ConsoleState

SET_GATE_TOPIC = '/session/set_in_force'


class PhaseNode:
    """Own context, own executor thread. ``hold()`` (optional) is read on every pose: while
    it is true the step acknowledgements wait (a steady timer releases them)."""

    def __init__(self, env, state: ConsoleState, robots, drive_robot: str | None = None,
                 keys=None, w_max: float = 1.0, set_msg=None, on_first_pose=None, hold=None,
                 record_path: bool = False, rate_factor: float | None = None):
        from rclpy.clock import Clock, ClockType
        from geometry_msgs.msg import Twist
        from ..nodes.common import StepAcknowledger
        from ..ros_io import rosmsg
        from ..ros_io.background_node import BackgroundNode
        from ..console.bridge import ConsoleBridge
        self.ros = BackgroundNode('supervisor', env['ROS_DOMAIN_ID'])
        self.context, self.node = self.ros.context, self.ros.node
        state.reset(robots)
        self.Twist = Twist
        self.keys = keys
        self.w_max = w_max
        self.on_first_pose = on_first_pose     # the clock has started: the phase runs
        self.hold = hold
        self.held = []                         # (robot, stamp) acknowledgements waiting for the hold
        self.path = [] if record_path else None   # [t, x, y, theta, u] of the driven robot
        self.cmd_pub = (self.node.create_publisher(Twist, f'/{drive_robot}/cmd_vel', rosmsg.QOS_STREAM)
                        if drive_robot else None)
        self.drive_robot = drive_robot
        self.acks = StepAcknowledger(self.node, robots)
        self.bridge = ConsoleBridge(self.node, state, on_pose=self._after_pose)
        self.acks.watch(*self.bridge.pose_subscriptions)
        self.set_gate = SetGate(self.node, set_msg, len(robots)) if set_msg is not None else None
        self.repace = None
        if hold is not None:
            self.node.create_timer(0.02, self._release, clock=Clock(clock_type=ClockType.STEADY_TIME))
            if rate_factor is not None:
                from rcl_interfaces.srv import SetParameters
                from rclpy.parameter import Parameter
                self.repace = (self.node.create_client(SetParameters, '/sim_clock/set_parameters'),
                               SetParameters.Request(parameters=[
                                   Parameter('rate_factor', value=float(rate_factor)).to_parameter_msg()]))
                self._repacing = None
        self.ros.start()

    def _after_pose(self, robot, msg):
        if self.on_first_pose is not None:
            callback, self.on_first_pose = self.on_first_pose, None
            callback()
        if self.cmd_pub is not None:
            # the person's arrow keys: left turns left (+u); this is also the lockstep answer
            left, right = self.keys() if self.keys else (False, False)
            u = self.w_max * (float(left) - float(right))
            self.cmd_pub.publish(self.Twist(angular=type(self.Twist().angular)(z=u)))
            if self.path is not None and robot == self.drive_robot:
                from ..ros_io import rosmsg
                try:
                    x, y, th = rosmsg.pose_to_state(msg)
                    t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
                    self.path.append([round(t, 3), round(x, 3), round(y, 3), round(th, 4), u])
                except ValueError:
                    pass            # the bridge has logged it
        if self.held or (self.hold is not None and self.hold()):
            self.held.append((robot, msg.header.stamp))
            return
        self.acks.processed(robot, msg.header.stamp)

    def _release(self):
        if not self.held or self.hold():
            return
        if self.repace is not None and self.repace[0].service_is_ready():
            # first the clock's schedule starts afresh, then the held steps go
            if self._repacing is None:
                self._repacing = self.repace[0].call_async(self.repace[1])
                return
            if not self._repacing.done():
                return
            self._repacing = None
        held, self.held = self.held, []
        for robot, stamp in held:
            self.acks.processed(robot, stamp)

    def close(self):
        self.bridge.state.reset([])     # the phase is over: its scene leaves the page
        self.ros.close(join_timeout=1.0, shutdown_timeout=0.5)   # Ctrl-C ends a session in about a second


class SetGate:
    """Publishes one value-function message, latched, on /safe_set/value_function, and opens
    a gate (a publisher on ``SET_GATE_TOPIC``, which the game's sim clock waits for) once
    ``n_filters`` safety filters have said on /rosout that a set from it is in force: a
    game's first step then runs on the condition's set, not on the one a filter starts with."""

    def __init__(self, node, msg, n_filters: int):
        from rcl_interfaces.msg import Log
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Empty, Float32MultiArray
        from ..ros_io import rosmsg
        self.node, self.n_filters, self.Empty = node, int(n_filters), Empty
        self.in_force = set()
        self.gate = None
        rosout = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(Log, '/rosout', self.on_log, rosout)
        self.pub = node.create_publisher(Float32MultiArray, '/safe_set/value_function', rosmsg.QOS_LATCHED)
        self.pub.publish(msg)

    def on_log(self, log):
        # "learned set in force: ..." or "... the local standard set is in force ..."
        if log.name.endswith('safety_filter') and (' set in force' in log.msg or ' set is in force' in log.msg):
            self.in_force.add(log.name)
            if len(self.in_force) >= self.n_filters and self.gate is None:
                from ..ros_io import rosmsg
                self.gate = self.node.create_publisher(self.Empty, SET_GATE_TOPIC, rosmsg.QOS_LATCHED)


def add_clock_gate(argvs, topic):
    """The sim clock also waits for one publisher on ``topic`` before its first step."""
    for a in argvs:
        if process_name(a) == 'sim_clock':
            for i, item in enumerate(a):
                if item.startswith('wait_for_publishers:='):
                    entries = [t for t in item.split(':=', 1)[1].strip('[]').split(',') if t]
                    a[i] = f'wait_for_publishers:={_param_value(entries + [f"{topic}=1"])}'
    return argvs


def without(argvs, *names):
    return [a for a in argvs if process_name(a) not in names]


def set_clock_param(argvs, key, value):
    """Set one -p parameter of the sim clock's argv (replaced, or added after the others)."""
    for a in argvs:
        if process_name(a) == 'sim_clock':
            for i, item in enumerate(a):
                if item.startswith(f'{key}:='):
                    a[i] = f'{key}:={_param_value(value)}'
                    break
            else:
                a += ['-p', f'{key}:={_param_value(value)}']
    return argvs


class PhaseGraph:
    """A phase's node processes and a monitor of the world's counts and the clock."""

    def __init__(self, argvs, env, log_dir):
        self.team = Team(argvs, env, log_dir)
        self.env = env
        self.monitor = None
        self.stopped = None
        self.signalled_at = None

    def start(self):
        self.team.start()
        self.monitor = TeamMonitor(self.env)
        return self

    def run(self, duration: float, timeout: float, poll: float = 0.1) -> dict:
        """Until the clock reaches ``duration`` sim seconds (and the world has counted it), a
        process exits, or ``timeout`` wall seconds; the world's last counts and the reason."""
        wall0 = time.monotonic()
        reason = 'wall-clock timeout'
        while time.monotonic() - wall0 < timeout:
            dead = self.team.dead()
            if dead:
                reason = f'processes exited: {dead}'
                break
            stats, clock = self.monitor.snapshot()
            if float(clock.get('sim_time', 0.0)) >= duration - 1e-6:
                reason = 'duration reached'
                # the world's final counts: stats whose sim_time is the last step
                deadline = time.monotonic() + 10.0
                while (float(self.monitor.snapshot()[0].get('sim_time', 0.0)) < duration - 1e-6
                       and time.monotonic() < deadline):
                    time.sleep(0.05)
                break
            time.sleep(poll)
        stats, clock = self.monitor.snapshot()
        return {'stats': stats, 'clock': clock, 'interventions': list(self.monitor.interventions),
                'events': list(self.monitor.events), 'reason': reason}

    def signal_stop(self):
        """SIGINT to every child that still runs (returns at once); ``stop``'s grace counts
        from the first call."""
        if self.signalled_at is None:
            self.signalled_at = time.monotonic()
        for p in self.team.procs:
            if p.poll() is None:
                try:
                    p.send_signal(signal.SIGINT)
                except ProcessLookupError:
                    pass

    def stop(self, grace: float = 3.0) -> dict:
        """SIGINT every child, SIGKILL those still running after ``grace`` s; exit codes."""
        if self.stopped is not None:
            return self.stopped
        self.signal_stop()
        if self.monitor is not None:
            self.monitor.close()
        deadline = self.signalled_at + grace
        for p in self.team.procs:
            try:
                p.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for log in self.team.logs:
            log.close()
        self.stopped = {process_name(a): p.returncode for a, p in zip(self.team.argvs, self.team.procs)}
        return self.stopped
