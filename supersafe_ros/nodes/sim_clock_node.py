"""sim_clock_node: drives /clock for the whole graph, optionally in lockstep with the robots.

Sim time advances in fixed steps of ``step`` seconds; between steps the node waits
so that sim time runs ``rate_factor`` times faster than the wall clock (0: as fast
as the graph allows).

Lockstep (default): a step is published only when every robot in ``robots`` has
acknowledged the previous one on /<robot>/step_done, and every observer (the
``observers`` topics: world and supervisor, which judge every pose) has
acknowledged the poses of ``observer_lag`` steps before, so what they decide
(crashes, interventions, removals) lags the robots by a bounded sim time at any
rate factor, while their work still overlaps the robots' next steps. A robot acknowledges after it
has integrated the step, published its pose and received the command that answers
it, so each step's command is computed from that step's pose no matter how far
the wall clock is ahead: the closed loop in sim time is the same at 1x or 30x,
only the wall time changes. A robot that does not answer within ``ack_timeout``
wall seconds is skipped for that step (logged, counted as a late step) so a dead
process cannot freeze the graph.

Publishes /clock (rosgraph_msgs/Clock) every step, /clock_coarse (the same, every
``coarse_period``: for nodes that read time only for timeouts and statistics and
take their event times from message stamps; `supersafe team` remaps their /clock
to it) and /sim/clock_status (DiagnosticStatus:
sim_time, steps, achieved real-time factor, late steps) every ``status_period``
sim seconds. This node itself always runs on the wall clock.

At ``duration`` the clock stops advancing; with ``exit_at_duration`` (the launch file sets
it when a duration is given) the node then exits with code 0, and the launch file's
OnProcessExit ends the launch: without a clock nothing moves, and the rest of the graph
would only fail safe on stale poses 20 s later.
"""
from __future__ import annotations

import threading
import time

import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter

from diagnostic_msgs.msg import DiagnosticStatus
from rosgraph_msgs.msg import Clock

from ..ros_io import rosmsg
from .common import LiveParameters, declare, run_node


def seconds_to_clock(t: float) -> Clock:
    ns = int(round(t * 1e9))
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = divmod(ns, 1_000_000_000)
    return msg


def parse_topic_counts(items) -> list[tuple[str, int]]:
    """['/a=2', '/b'] -> [('/a', 2), ('/b', 1)]; empty strings are ignored."""
    out = []
    for item in items:
        topic, _, count = str(item).strip().partition('=')
        if topic:
            out.append((topic, int(count) if count else 1))
    return out


class SimClockNode(Node):
    def __init__(self, node_name='sim_clock', **kwargs):
        super().__init__(node_name, **kwargs)
        if self.get_parameter('use_sim_time').value:
            self.get_logger().warn('use_sim_time is true for the clock source; forcing it off')
            self.set_parameters([Parameter('use_sim_time', Parameter.Type.BOOL, False)])
        ro = lambda *a, **k: declare(self, *a, read_only=True, **k)  # noqa: E731
        p = lambda *a, **k: declare(self, *a, **k)  # noqa: E731
        # fixed for the node's life: the robots' rate and the graph's shape depend on them
        self.step_ns = int(round(ro('step', 0.05, 'sim seconds per /clock step (read-only: the '
                                    "robots' rate is 1/step)", 1e-4, 10.0) * 1e9))
        self.lockstep = ro('lockstep', True, 'wait for every robot to acknowledge each step')
        self.robots = list(ro('robots', ['robot_0'], 'robot namespaces to wait for in lockstep'))
        self.observers = [t for t in ro(
            'observers', [''],
            'acknowledgement topics of nodes that judge the robots\' poses (world, supervisor); '
            'the clock keeps them at most observer_lag steps behind') if t]
        self.start_timeout = ro('start_timeout', 60.0,
                                'wall seconds to wait for every robot to appear before starting',
                                0.0, 3600.0)
        self.start_ns = int(round(ro('start_time', 0.0, 'sim time of the first step [s]', 0.0, 1e9) * 1e9))
        self.exit_at_duration = ro('exit_at_duration', False, 'exit (code 0) once duration is reached: '
                                   'the launch file then shuts the launch down')
        self.wait_publishers = parse_topic_counts(ro(
            'wait_for_publishers', [''],
            "before the first step, wait until each 'topic=count' has that many publishers "
            "(e.g. '/interventions=1': the supervisor is up)"))
        self.wait_subscriptions = parse_topic_counts(ro(
            'wait_for_subscriptions', [''],
            "before the first step, wait until each 'topic=count' has that many subscriptions"))
        # live: `ros2 param set /sim_clock rate_factor 2.0` takes effect at the next step
        self.rate_factor = p('rate_factor', 10.0,
                             'sim seconds per wall second (0: as fast as the graph allows); live',
                             0.0, 1e4)
        self.observer_lag = p('observer_lag', 2, 'steps an observer may lag behind the robots; live',
                              0, 1000)
        self.ack_timeout = p('ack_timeout', 0.5, 'wall seconds to wait for a robot per step; live',
                             0.001, 60.0)
        self.status_period = p('status_period', 1.0, 'sim seconds between status messages; live',
                               0.01, 1e4)
        self.duration = p('duration', 0.0, 'stop advancing after this many sim seconds from the '
                          'start (0: never); live', 0.0, 1e9)
        self.coarse_ns = int(round(p(
            'coarse_period', 0.5,
            'sim seconds between /clock_coarse messages (0: none); nodes that only need coarse '
            'time remap /clock to it and skip a callback per step; live', 0.0, 1e4) * 1e9))
        self.changed = threading.Event()      # wakes a pacing sleep when the rate changes
        self.pace = None                      # (wall, sim ns) the pacing and achieved rate count from
        self.live = live = LiveParameters(self)
        live.add('rate_factor', self.set_rate_factor)
        live.add('observer_lag', lambda v: self._set_and_wake('observer_lag', v))
        live.add('ack_timeout', lambda v: self._set_and_wake('ack_timeout', v))
        live.add('status_period', lambda v: setattr(self, 'status_period', v))
        live.add('duration', lambda v: self._set_and_wake('duration', v))
        live.add('coarse_period', lambda v: setattr(self, 'coarse_ns', int(round(v * 1e9))))
        self.clock_pub = self.create_publisher(Clock, '/clock', rosmsg.QOS_CLOCK)
        self.coarse_pub = self.create_publisher(Clock, '/clock_coarse', rosmsg.QOS_CLOCK)
        self.next_coarse = self.start_ns
        self.status_pub = self.create_publisher(DiagnosticStatus, '/sim/clock_status', rosmsg.QOS_LATCHED)
        self.cond = threading.Condition()
        self.acked = {r: -1 for r in self.robots + self.observers}
        self.ack_subs = []
        if self.lockstep:
            for r in self.robots:
                topic = f'/{r.strip("/")}/step_done'
                self.ack_subs.append(self.create_subscription(
                    Clock, topic, lambda msg, r=r: self.on_ack(r, msg), rosmsg.QOS_ACK))
            for o in self.observers:
                self.ack_subs.append(self.create_subscription(
                    Clock, o, lambda msg, o=o: self.on_ack(o, msg), rosmsg.QOS_ACK))
        self.now_ns = self.start_ns
        self.late_steps = 0
        self.steps = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.loop, name='sim_clock', daemon=True)
        self.thread.start()
        self.get_logger().info(
            f'/clock: steps of {self.step_ns * 1e-9:g} s at {self.rate_factor:g}x, '
            f'lockstep {"on, robots " + str(self.robots) if self.lockstep else "off"}')

    def set_rate_factor(self, value):
        with self.cond:
            self.rate_factor = value
            if self.pace is not None:            # pace (and measure) from here on
                self.pace = (time.monotonic(), self.now_ns)
        self.changed.set()

    def _set_and_wake(self, name, value):
        with self.cond:
            setattr(self, name, value)
            self.cond.notify_all()
        self.changed.set()

    def on_ack(self, robot, msg: Clock):
        t = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        with self.cond:
            if t > self.acked[robot]:
                self.acked[robot] = t
            self.cond.notify_all()

    def wait_for_graph(self):
        """Before the first step: wait for the robots (matched step_done publishers and
        /clock subscriptions) and for every topic count in wait_for_publishers/_subscriptions."""
        deadline = time.monotonic() + self.start_timeout
        reported = None
        while not self.stop.is_set():
            missing = [r for r, s in zip(self.robots + self.observers, self.ack_subs)
                       if s.get_publisher_count() == 0]
            if self.clock_pub.get_subscription_count() < len(self.robots):
                missing.append('(robot /clock subscriptions)')
            with self.cond:
                missing += [f'{o} (not ready)' for o in self.observers if self.acked[o] < 0]
            missing += [f'{t} publishers {self.count_publishers(t)}/{n}'
                        for t, n in self.wait_publishers if self.count_publishers(t) < n]
            missing += [f'{t} subscriptions {self.count_subscribers(t)}/{n}'
                        for t, n in self.wait_subscriptions if self.count_subscribers(t) < n]
            if not missing:
                return
            if reported is None:
                self.get_logger().info(f'waiting for the graph: {missing}')
            elif missing != reported:      # detail: what is still missing, as it changes
                self.get_logger().debug(f'waiting for the graph: {missing}')
            reported = missing
            if time.monotonic() > deadline:
                self.get_logger().error(f'still missing after {self.start_timeout} s: {missing}; '
                                        'starting anyway')
                return
            self.stop.wait(0.05)

    def publish_clock(self):
        msg = seconds_to_clock(self.now_ns * 1e-9)
        self.clock_pub.publish(msg)
        if self.coarse_ns > 0 and self.now_ns >= self.next_coarse:
            self.coarse_pub.publish(msg)
            self.next_coarse = self.now_ns + self.coarse_ns

    def publish_status(self):
        wall0, sim0 = self.pace
        wall = time.monotonic() - wall0
        sim = (self.now_ns - sim0) * 1e-9
        factor = sim / wall if wall > 0 else 0.0
        self.status_pub.publish(rosmsg.make_diagnostic('sim_clock', {
            'sim_time': f'{self.now_ns * 1e-9:.3f}', 'steps': self.steps,
            'rate_factor_target': self.rate_factor, 'rate_factor_achieved': f'{factor:.3f}',
            'late_steps': self.late_steps}))

    def loop(self):
        try:
            self.run_steps()
        except Exception:
            # a context shut down under the thread (an embedding process that did not
            # call close() first) ends it quietly; anything else is a real failure
            if self.stop.is_set() or not self.context.ok():
                return
            raise

    def run_steps(self):
        self.wait_for_graph()
        self.get_logger().info('graph ready; starting sim time')
        with self.cond:
            self.pace = (time.monotonic(), self.now_ns)
        first_ns = self.now_ns
        next_status = first_ns + int(self.status_period * 1e9)
        # the first message only sets the time (robots' timers count from it): no wait
        self.publish_clock()
        self.now_ns += self.step_ns
        while not self.stop.is_set() and rclpy.ok(context=self.context):
            self.publish_clock()
            self.steps += 1
            if self.lockstep:
                self.wait_for_acks()
            if self.now_ns >= next_status:
                self.publish_status()
                next_status = self.now_ns + int(self.status_period * 1e9)
            if self.duration > 0 and self.now_ns >= first_ns + int(round(self.duration * 1e9)):
                self.publish_status()
                self.get_logger().info(f'duration reached at sim time {self.now_ns * 1e-9:.3f}'
                                       + ('; exiting' if self.exit_at_duration else ''))
                if self.exit_at_duration:
                    # the flag first, then the hook: run_node sets the hook, then reads the
                    # flag, so a duration reached before the spin loop began (a short one on
                    # a quiet machine) still ends the process
                    self.stop_requested = True
                    stop_process = getattr(self, 'stop_process', None)
                    if stop_process is not None:
                        stop_process()
                return
            self.now_ns += self.step_ns
            self.pace_step()

    def wait_for_acks(self):
        started = time.monotonic()
        with self.cond:
            while not self.stop.is_set():
                waiting = [r for r in self.robots if self.acked[r] < self.now_ns]
                lagging = self.now_ns - self.observer_lag * self.step_ns
                waiting += [o for o in self.observers if self.acked[o] < lagging]
                left = started + self.ack_timeout - time.monotonic()
                if not waiting or left <= 0:
                    break
                self.cond.wait(left)
        if waiting and not self.stop.is_set():
            self.late_steps += 1
            self.get_logger().warn(
                f'step {self.now_ns * 1e-9:.3f}: no acknowledgement from {waiting} within '
                f'{self.ack_timeout} s; advancing without them', throttle_duration_sec=5.0)

    def pace_step(self):
        """Sleep until the wall time of the next step at the rate factor in force."""
        while not self.stop.is_set():
            self.changed.clear()
            with self.cond:
                factor, (wall0, sim0) = self.rate_factor, self.pace
            if factor <= 0:
                return
            delay = wall0 + (self.now_ns - sim0) * 1e-9 / factor - time.monotonic()
            if delay <= 0 or not self.changed.wait(delay):
                return

    def close(self):
        self.stop.set()
        self.changed.set()
        with self.cond:
            self.cond.notify_all()
        self.thread.join(timeout=2.0)


def main(args=None):
    return run_node(SimClockNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
