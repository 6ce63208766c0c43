"""sim_clock_node at topic level: start gate, lockstep with acknowledgements, late steps,
parameters at run time.

Timeouts are generous (a loaded 2-core machine can hold a test's callbacks for
seconds): the assertions are about order and bounds, not about exact wall times."""
import time

import numpy as np

import pytest
from rclpy.logging import LoggingSeverity
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticStatus
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Empty

from supersafe_ros.ros_io import rosmsg
from supersafe_ros.nodes.sim_clock_node import SimClockNode, parse_topic_counts

from graph_support import Rosout, Spinner, live_and_read_only, params, set_parameters


def ns_of(msg):
    return msg.clock.sec * 1_000_000_000 + msg.clock.nanosec


class FakeRobot:
    """Acknowledges each /clock step ``delay`` wall seconds late (skipping those in ``skip``);
    a step arriving while the previous one is still unacknowledged is a lockstep violation."""

    def __init__(self, node):
        self.ack = node.create_publisher(Clock, '/robot_0/step_done', rosmsg.QOS_ACK)
        self.ticks, self.coarse, self.status = [], [], []
        self.acked = -1
        self.skip = set()
        self.violations = []
        self.pending = None          # (sim ns, wall time received)
        self.delay = 0.01
        node.create_subscription(Clock, '/clock', self.on_clock, rosmsg.QOS_CLOCK)
        node.create_subscription(Clock, '/clock_coarse', lambda m: self.coarse.append(ns_of(m)),
                                 rosmsg.QOS_CLOCK)
        node.create_subscription(DiagnosticStatus, '/sim/clock_status',
                                 lambda m: self.status.append(rosmsg.diagnostic_values(m)),
                                 rosmsg.QOS_LATCHED)

    def on_clock(self, msg):
        t = ns_of(msg)
        if self.pending is not None:
            self.violations.append(t)          # came before the previous one was acknowledged
        first = not self.ticks       # the start time is set, not stepped: no acknowledgement
        self.ticks.append(t)
        self.pending = None if first or t in self.skip else (t, time.monotonic())

    def poll(self):
        """Acknowledge the pending step once its delay is over (call while spinning)."""
        if self.pending is not None and time.monotonic() - self.pending[1] >= self.delay:
            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = divmod(self.pending[0], 1_000_000_000)
            self.pending = None
            self.ack.publish(msg)
        return True


def holding_for(rosout, item: str) -> bool:
    """The clock logged that ``item`` is the only thing it still waits for."""
    return any('sim_clock' in m.name and m.msg == f'waiting for the graph: {[item]}'
               for m in rosout.logs)


def test_parse_topic_counts():
    assert parse_topic_counts(['/a=2', '/b', '']) == [('/a', 2), ('/b', 1)]


@pytest.mark.ros
def test_clock_waits_for_graph_then_steps_in_lockstep(ros_context):
    step_ns = 50_000_000
    clock = SimClockNode(context=ros_context, parameter_overrides=params(
        robots=['robot_0'], step=0.05, rate_factor=0.0, lockstep=True, ack_timeout=3.0,
        start_timeout=60.0, coarse_period=0.2, status_period=0.5,
        wait_for_publishers=['/test_gate=1']))
    clock.get_logger().set_level(LoggingSeverity.DEBUG)
    driver = Node('clock_test_driver', context=ros_context)
    robot = FakeRobot(driver)
    rosout = Rosout(driver)
    spin = Spinner(ros_context, clock, driver)
    try:
        # the clock holds: it has seen the robot, and says the gate alone is missing
        spin.until(lambda: holding_for(rosout, '/test_gate publishers 0/1'), 30.0,
                   'the clock to wait for the gate alone')
        assert robot.ticks == []
        gate = driver.create_publisher(Empty, '/test_gate', 1)
        spin.until(lambda: robot.poll() and len(robot.ticks) >= 60, 20.0, '60 steps')
        t = np.array(robot.ticks[:60])
        assert np.all(np.diff(t) == step_ns)     # fixed steps, none skipped
        assert robot.violations == []            # never ahead of the robot
        # a step the robot does not acknowledge: the clock goes on after ack_timeout
        skip_at = robot.ticks[-1] + 3 * step_ns
        robot.skip.add(skip_at)
        spin.until(lambda: robot.poll() and robot.ticks[-1] > skip_at + 5 * step_ns, 30.0,
                   'steps past the skipped one')
        spin.until(lambda: robot.poll() and robot.status and int(robot.status[-1]['late_steps']) >= 1,
                   30.0, 'a late step in the status')
        assert skip_at + step_ns in robot.ticks   # released after ack_timeout, nothing skipped
        assert robot.violations == []
        # coarse clock: every 0.2 s of sim time
        c = np.array(robot.coarse)
        assert len(c) >= 3 and np.all(np.diff(c) == 4 * step_ns)
        gate.destroy()
    finally:
        clock.close()
        spin.shutdown()
        clock.destroy_node()
        driver.destroy_node()


@pytest.mark.ros
def test_clock_keeps_observers_within_their_lag(ros_context):
    step_ns, lag = 50_000_000, 2
    clock = SimClockNode(context=ros_context, parameter_overrides=params(
        robots=['robot_0'], observers=['/observer/step_done'], observer_lag=lag, step=0.05,
        rate_factor=0.0, ack_timeout=30.0, start_timeout=60.0))
    clock.get_logger().set_level(LoggingSeverity.DEBUG)
    driver = Node('observer_test_driver', context=ros_context)
    robot = FakeRobot(driver)
    rosout = Rosout(driver)
    robot.delay = 0.0
    obs_pub = driver.create_publisher(Clock, '/observer/step_done', rosmsg.QOS_ACK)
    state = {'acked': -1, 'violations': [], 'last_ack_wall': time.monotonic()}

    def check(msg):                          # every step must respect the observer's lag
        t = ns_of(msg)
        if t > step_ns and state['acked'] < t - (lag + 1) * step_ns:
            state['violations'].append(t)
    driver.create_subscription(Clock, '/clock', check, rosmsg.QOS_CLOCK)

    def observer_poll():                     # a slow observer: catches up every 30 ms
        if robot.ticks and time.monotonic() - state['last_ack_wall'] > 0.03:
            state['acked'] = robot.ticks[-1]
            state['last_ack_wall'] = time.monotonic()
            m = Clock()
            m.clock.sec, m.clock.nanosec = divmod(robot.ticks[-1], 1_000_000_000)
            obs_pub.publish(m)
        return robot.poll()
    spin = Spinner(ros_context, clock, driver)
    try:
        spin.until(lambda: holding_for(rosout, '/observer/step_done (not ready)'), 30.0,
                   'the clock to wait for the observer alone')
        assert robot.ticks == []                 # the observer has not said it is ready
        obs_pub.publish(Clock())                 # ready: acknowledges t = 0
        state['acked'] = 0
        spin.until(lambda: observer_poll() and len(robot.ticks) >= 40, 60.0, '40 steps')
        assert state['violations'] == [] and robot.violations == []
        t = np.array(robot.ticks)
        assert np.all(np.diff(t) == step_ns)
        assert clock.late_steps == 0         # the observer's acknowledgements released every step
    finally:
        clock.close()
        spin.shutdown()
        clock.destroy_node()
        driver.destroy_node()


@pytest.mark.ros
def test_clock_rate_factor_changes_at_run_time_and_read_only_sets_are_refused(ros_context):
    """`ros2 param set /sim_clock rate_factor 1.0`: sim time then runs no faster than the
    wall clock; `step` (the robots' rate depends on it) is refused and stays."""
    step = 0.2
    clock = SimClockNode(context=ros_context, parameter_overrides=params(
        robots=['robot_0'], step=step, rate_factor=0.0, ack_timeout=30.0, start_timeout=60.0,
        status_period=step))
    driver = Node('clock_param_driver', context=ros_context)
    robot = FakeRobot(driver)
    robot.delay = 0.0
    rosout = Rosout(driver)
    spin = Spinner(ros_context, clock, driver)
    try:
        assert live_and_read_only(clock, clock.live.names) == []
        spin.until(lambda: robot.poll() and len(robot.ticks) >= 30, 60.0, '30 steps at full speed')
        fast = [s for s in robot.status if float(s['rate_factor_achieved']) > 0]
        assert float(fast[-1]['rate_factor_achieved']) > 1.5    # well above 1x before the change
        result, = set_parameters(spin, driver, '/sim_clock', rate_factor=1.0)
        assert result.successful
        spin.until(lambda: robot.poll() and robot.status
                   and float(robot.status[-1]['rate_factor_target']) == 1.0, 30.0, 'the new target')
        # from now on: sim time advances at most as fast as wall time (plus one step)
        first_tick, wall0 = robot.ticks[-1], time.monotonic()
        spin.until(lambda: robot.poll() and robot.ticks[-1] >= first_tick + 8 * int(step * 1e9), 60.0,
                   '8 more steps')
        wall = time.monotonic() - wall0
        assert (robot.ticks[-1] - first_tick) * 1e-9 <= wall + step
        # read-only and out-of-range values are refused with a reason, and change nothing
        result, = set_parameters(spin, driver, '/sim_clock', step=0.05)
        assert not result.successful and 'read-only' in result.reason
        result, = set_parameters(spin, driver, '/sim_clock', rate_factor=-1.0)
        assert not result.successful
        assert clock.get_parameter('step').value == step and clock.step_ns == int(step * 1e9)
        assert clock.get_parameter('rate_factor').value == 1.0 and clock.rate_factor == 1.0
        spin.until(lambda: robot.poll() and rosout.has('sim_clock', 'rate_factor', 'in force'), 10.0,
                   'the change logged')
    finally:
        clock.close()
        spin.shutdown()
        clock.destroy_node()
        driver.destroy_node()


@pytest.mark.ros
def test_the_clock_process_exits_at_its_duration_with_exit_at_duration(tmp_path):
    """exit_at_duration: the clock (a process, as the launch file starts it) exits with code 0 and
    nothing on stderr once its duration is reached; without it, it runs on (the team runner and
    the study's games stop it themselves)."""
    import os
    import signal
    import subprocess
    from supersafe_ros import team
    env = dict(os.environ, RCUTILS_LOGGING_USE_STDOUT='1', RCUTILS_COLORIZED_OUTPUT='0')
    # no robots to wait for: start_timeout 0 starts it at once (it says what it did not wait for)
    common = {'lockstep': False, 'rate_factor': 0.0, 'step': 0.05, 'duration': 0.5, 'start_timeout': 0.0}
    procs = {exits: subprocess.Popen(team.node_argv('sim_clock', None, dict(common, exit_at_duration=exits)),
                                     env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     start_new_session=True)
             for exits in (True, False)}
    try:
        out, err = procs[True].communicate(timeout=120)
        assert procs[True].returncode == 0 and err == '', err
        assert 'duration reached at sim time 0.500; exiting' in out, out
        assert procs[False].poll() is None             # the same clock without it runs on
    finally:
        for p in procs.values():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


@pytest.mark.ros
def test_a_node_that_ends_before_the_spin_loop_begins_still_exits():
    """The race a quiet CI run hit: a 0.5 s clock at rate 0 reached its duration while its node
    was still being constructed, found no stop hook yet and ran on for ever. A node that raises
    ``stop_requested`` in its constructor stands for it: run_node must still stop it, exit 0."""
    import os
    import subprocess
    import sys
    code = '\n'.join([
        'import sys',
        'from rclpy.node import Node',
        'from supersafe_ros.nodes.common import run_node',
        'class EndsAtOnce(Node):',
        '    def __init__(self):',
        '        super().__init__("ends_at_once")',
        '        self.stop_requested = True',
        'sys.exit(run_node(EndsAtOnce))',
    ])
    p = subprocess.run([sys.executable, '-c', code], env=dict(os.environ), capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0 and p.stderr == '', p.stderr
