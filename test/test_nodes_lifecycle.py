"""managed_safety_filter and managed_fleet_safety_filter as processes (their console scripts),
driven through the lifecycle_msgs services: every transition of the lifecycle graph, by id and
by label, from every primary state. A valid one succeeds; an invalid one is answered
success=False with a WARN on /rosout naming it, and the process lives on; GetState agrees after
each. Deactivate (and shutdown from active) sends one zero twist and then nothing; /diagnostics
says WARN "inactive" whenever the node is not active, the filter's own status while active.
The request-reading functions of nodes/managed.py are checked first, without ROS."""
import sys
from pathlib import Path

import pytest
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import Log
from std_msgs.msg import Float64MultiArray

from supersafe_ros.nodes.managed import inactive_message, refusal, request_name, requested_transition
from supersafe_ros.ros_io import rosmsg

from filter_process_support import start, stop
from graph_support import Spinner

SCRIPTS = Path(sys.executable).parent           # the venv's console scripts
# the rows rcl_lifecycle gives (id, label, start, ...): from unconfigured, and a part of its graph
FROM_UNCONFIGURED = [(1, 'configure', 1, 'unconfigured', 10, 'configuring'),
                     (5, 'shutdown', 1, 'unconfigured', 12, 'shuttingdown')]
GRAPH = [(1, 'configure'), (10, 'transition_success'), (2, 'cleanup'), (3, 'activate'), (5, 'shutdown')]

# the primary states' transitions: id -> (label, goal)
VALID = {
    'unconfigured': {1: ('configure', 'inactive'), 5: ('shutdown', 'finalized')},
    'inactive': {2: ('cleanup', 'unconfigured'), 3: ('activate', 'active'), 6: ('shutdown', 'finalized')},
    'active': {4: ('deactivate', 'inactive'), 7: ('shutdown', 'finalized')},
    'finalized': {},
}
NAMES = {1: 'configure', 2: 'cleanup', 3: 'activate', 4: 'deactivate', 5: 'shutdown', 6: 'shutdown',
         7: 'shutdown', 10: 'transition_success', 99: 'unknown'}
IDS = sorted(NAMES)             # the seven of the graph's primary states, one of a transition state, one of none
LABELS = ['configure', 'cleanup', 'activate', 'deactivate', 'shutdown', 'transition_success', 'launch']
LONG = ['pose_timeout:=60.0', 'cmd_timeout:=60.0', 'detections_timeout:=60.0', 'hold_timeout:=60.0']


def test_a_request_is_read_as_rclpy_reads_it():
    assert requested_transition(1, '', FROM_UNCONFIGURED) == 1
    assert requested_transition(3, '', FROM_UNCONFIGURED) is None, 'activate is not valid from unconfigured'
    assert requested_transition(0, 'shutdown', FROM_UNCONFIGURED) == 5, 'by label: the id of this state\'s shutdown'
    assert requested_transition(1, 'activate', FROM_UNCONFIGURED) is None, 'a label wins over the id'
    assert requested_transition(0, '', FROM_UNCONFIGURED) is None
    assert requested_transition(1, '', []) is None, 'finalized: nothing is valid'


def test_a_refusal_names_the_transition_the_state_and_what_is_valid():
    assert refusal(request_name(3, '', GRAPH), 'unconfigured', FROM_UNCONFIGURED) == (
        "lifecycle: transition 3 (activate) refused: not valid from 'unconfigured' (valid: configure, shutdown)")
    assert refusal(request_name(0, 'activate', GRAPH), 'unconfigured', FROM_UNCONFIGURED) == (
        "lifecycle: transition 'activate' refused: not valid from 'unconfigured' (valid: configure, shutdown)")
    assert request_name(42, '', GRAPH) == '42 (unknown)'
    assert refusal("'configure'", 'finalized', []).endswith("not valid from 'finalized' (valid: none)")


def test_the_inactive_message_says_the_state_and_why_configure_failed():
    assert inactive_message('unconfigured') == 'inactive (lifecycle state unconfigured): no cmd_vel'
    assert inactive_message('unconfigured', 'ValueError: no value function', ['cmd_vel_nav has a Twist']) == (
        'inactive (lifecycle state unconfigured): no cmd_vel; configure failed: ValueError: no value function; '
        'cmd_vel_nav has a Twist')


# -- the processes ------------------------------------------------------------------------------------------
def start_script(tmp_path, script, ns, *params):
    """A console script of the venv (run by this interpreter: filter_process_support.start) as a
    process in namespace ``ns``, with ``params`` (-p each); its output in ``<script>.log``."""
    argv = [str(SCRIPTS / script), '--ros-args', '-r', f'__ns:={ns}']
    for p in params:
        argv += ['-p', p]
    return start(tmp_path, script, argv)


def stopped(proc) -> int:
    """SIGINT to its group, as Ctrl-C (filter_process_support.stop); its exit code."""
    stop(proc)
    return proc.returncode


class Managed:
    """The test's side of one managed node process: its lifecycle services, /rosout, its
    /diagnostics statuses. Every wait has a deadline on an event."""

    def __init__(self, node, spin, proc, fqn, log_path):
        self.node, self.spin, self.proc, self.fqn, self.log_path = node, spin, proc, fqn, log_path
        self.logger = fqn.strip('/').replace('/', '.')          # /rosout names: <namespace>.<node>
        self.change = node.create_client(ChangeState, f'{fqn}/change_state')
        self.get = node.create_client(GetState, f'{fqn}/get_state')
        self.logs, self.statuses = [], []
        latched = QoSProfile(depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(Log, '/rosout', self.logs.append, latched)
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, rosmsg.QOS_EVERY_SAMPLE)

    def _on_diagnostics(self, msg):
        self.statuses.extend(s for s in msg.status if s.name.startswith(self.fqn + ':'))

    def why(self) -> str:
        return f'\n--- {self.log_path.name} (tail) ---\n' + ''.join(self.log_path.read_text().splitlines(True)[-30:])

    def alive(self):
        assert self.proc.poll() is None, f'the process ended (exit code {self.proc.returncode}){self.why()}'

    def call(self, client, request, timeout=60.0):
        self.spin.until(lambda: client.service_is_ready() or self.proc.poll() is not None, 180.0, client.srv_name)
        self.alive()
        future = client.call_async(request)
        self.spin.until(lambda: future.done() or self.proc.poll() is not None, timeout,
                        f'{client.srv_name} to answer')
        self.alive()
        return future.result()

    def state(self) -> str:
        return self.call(self.get, GetState.Request()).current_state.label

    def request(self, transition_id=0, label='', timeout=60.0) -> bool:
        request = ChangeState.Request(transition=Transition(id=transition_id, label=label))
        return self.call(self.change, request, timeout).success

    def go(self, goal, transition_id=0, label='', timeout=60.0):
        """A valid transition: it succeeds, the process lives on, GetState says ``goal``."""
        assert self.request(transition_id, label, timeout), f'{transition_id or label!r} -> {goal}{self.why()}'
        self.alive()
        assert self.state() == goal

    def refused(self, transition_id=0, label=''):
        """An invalid transition: success=False, a WARN naming it and the state, the process alive,
        the state unchanged."""
        state = self.state()
        asked = repr(label) if label else f'{transition_id} ({NAMES[transition_id]})'
        words = f"lifecycle: transition {asked} refused: not valid from '{state}' (valid: "
        seen = len(self.logs)
        assert not self.request(transition_id, label), f'{asked} from {state} answered success'
        self.spin.until(lambda: any(m.name == self.logger and m.level == Log.WARN and words in m.msg
                                    for m in self.logs[seen:]) or self.proc.poll() is not None,
                        60.0, f'the WARN "{words}..."')
        self.alive()
        assert self.state() == state

    def refuses_every_invalid_transition(self):
        """Every id and label not valid from the current state, refused (both ways)."""
        valid = VALID[self.state()]
        for transition_id in IDS:
            if transition_id not in valid:
                self.refused(transition_id=transition_id)
        for label in LABELS:
            if label not in {name for name, _ in valid.values()}:
                self.refused(label=label)

    def diagnoses(self, what, predicate, count=1):
        """Wait for ``count`` statuses of this node, received from now on, that satisfy ``predicate``."""
        seen = len(self.statuses)
        self.spin.until(lambda: sum(map(predicate, self.statuses[seen:])) >= count or self.proc.poll() is not None,
                        60.0, f'/diagnostics: {what}')
        self.alive()
        return [s for s in self.statuses[seen:] if predicate(s)]

    def says_inactive(self, state, count=1):
        words = f'inactive (lifecycle state {state}): no cmd_vel'
        return self.diagnoses(words, lambda s: s.level == DiagnosticStatus.WARN and s.message.startswith(words),
                              count)


@pytest.mark.ros
def test_in_process_triggers_from_the_wrong_state_return_failure(ros_context):
    """trigger_*() from a state it is not valid from, called in a timer's callback: FAILURE, the
    state unchanged, nothing raised out of the executor's spin."""
    from rclpy.lifecycle import TransitionCallbackReturn
    from supersafe_ros.nodes.safety_filter_node import ManagedSafetyFilterNode
    f = ManagedSafetyFilterNode(context=ros_context, namespace='/lc_in_process')
    spin = Spinner(ros_context, f)
    answers = []

    def trigger_from_unconfigured():
        answers.append((f.trigger_activate(), f.trigger_deactivate(), f.trigger_cleanup()))
    timer = f.create_timer(0.01, trigger_from_unconfigured)
    try:
        spin.until(lambda: answers, 30.0, 'the timer to trigger')    # a callback that raised raises here
        f.destroy_timer(timer)
        assert set(answers) == {(TransitionCallbackReturn.FAILURE,) * 3}
        assert f._state_machine.current_state[1] == 'unconfigured'
        assert f.trigger_shutdown() == TransitionCallbackReturn.SUCCESS
        assert f._state_machine.current_state[1] == 'finalized'
        assert f.trigger_shutdown() == TransitionCallbackReturn.FAILURE, 'rclpy raises RCLError here'
        assert f.trigger_configure() == TransitionCallbackReturn.FAILURE
        assert f._state_machine.current_state[1] == 'finalized'
    finally:
        spin.shutdown()
        f.close()
        f.destroy_node()


@pytest.fixture
def ros_node(ros_context):
    node = Node('lifecycle_driver', context=ros_context)
    spin = Spinner(ros_context, node)
    yield node, spin
    spin.shutdown()
    node.destroy_node()


class Robot:
    """One robot's stack for the single filter: a pose and the planner's (0, 1 rad/s) at 20 Hz
    (a steady timer of the test's node, spun by every wait); what comes out on cmd_vel."""

    def __init__(self, node, ns, stamped=False, frame='base_link'):
        self.node, self.stamped, self.frame = node, stamped, frame
        kind = TwistStamped if stamped else Twist
        self.pose = node.create_publisher(PoseStamped, f'{ns}/pose', rosmsg.QOS_STREAM)
        self.cmd = node.create_publisher(kind, f'{ns}/cmd_vel_nav', rosmsg.QOS_STREAM)
        self.out = []
        node.create_subscription(kind, f'{ns}/cmd_vel', self.out.append, rosmsg.QOS_EVERY_SAMPLE)
        self.timer = node.create_timer(0.05, self.feed, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def feed(self):
        now = self.node.get_clock().now().to_msg()
        self.pose.publish(rosmsg.state_to_pose((0.0, 0.0, 0.0), stamp=now))
        twist = Twist()
        twist.angular.z = 1.0
        if self.stamped:
            msg = TwistStamped(twist=twist)
            msg.header.stamp, msg.header.frame_id = now, self.frame
            self.cmd.publish(msg)
        else:
            self.cmd.publish(twist)

    def twists(self, start=0):
        return [twist_of(m) for m in self.out[start:]]


def twist_of(msg):
    t = getattr(msg, 'twist', msg)
    return (t.linear.x, t.angular.z)


def quiet_after_one_zero(lc, topics, go, what, then='inactive'):
    """Do ``go`` (a transition from active to ``then``) and check: on every one of ``topics`` (name
    -> (the messages received, how to read one as a tuple of numbers)) exactly one all-zero message
    comes after the last command, and nothing after it while the node publishes two /diagnostics
    saying it is inactive (over a second: an active filter would have sent dozens meanwhile)."""
    before = {name: len(received) for name, (received, _) in topics.items()}
    go()
    for name, (received, read) in topics.items():
        lc.spin.until(lambda: any(not any(read(m)) for m in received[before[name]:]) or lc.proc.poll() is not None,
                      60.0, f'{what}: a zero twist on {name}')
    lc.says_inactive(then, count=2)
    for name, (received, read) in topics.items():
        after = [read(m) for m in received[before[name]:]]
        zeros = [i for i, v in enumerate(after) if not any(v)]
        assert len(zeros) == 1 and zeros[0] == len(after) - 1, (
            f'{what}: on {name}, after the transition: {after} (one zero twist, last, expected)')


@pytest.mark.ros
def test_the_managed_filter_refuses_every_invalid_transition_and_stops_the_base_on_deactivate(ros_node, tmp_path):
    node, spin = ros_node
    ns = '/lc_robot'
    robot = Robot(node, ns)
    proc = start_script(tmp_path, 'managed_safety_filter', ns, 'require_detections:=false',
                        'level_set_markers:=false', *LONG)
    lc = Managed(node, spin, proc, f'{ns}/safety_filter', tmp_path / 'managed_safety_filter.log')
    try:
        assert lc.state() == 'unconfigured'
        lc.says_inactive('unconfigured')
        lc.refuses_every_invalid_transition()
        assert not robot.out, 'unconfigured: no cmd_vel'
        # configure and cleanup, both ways
        lc.go('inactive', transition_id=1, timeout=180.0)
        lc.says_inactive('inactive')
        lc.refuses_every_invalid_transition()
        lc.go('unconfigured', transition_id=2)
        lc.says_inactive('unconfigured')
        lc.go('inactive', label='configure', timeout=180.0)
        lc.go('unconfigured', label='cleanup')
        lc.go('inactive', transition_id=1, timeout=180.0)
        spin.until(lambda: robot.pose.get_subscription_count() and robot.cmd.get_subscription_count(), 60.0,
                   'the configured filter to subscribe')
        assert not robot.out, 'inactive: no cmd_vel'
        # activate and deactivate, both ways
        for by_id in (True, False):
            sent = len(robot.out)
            lc.go('active', **({'transition_id': 3} if by_id else {'label': 'activate'}))
            if by_id:
                lc.refuses_every_invalid_transition()
            spin.until(lambda: (0.0, 1.0) in robot.twists(sent), 60.0, 'the planner\'s (0, 1 rad/s) passed')
            passed = lc.diagnoses('the filter\'s own status, OK pass',
                                  lambda s: s.level == DiagnosticStatus.OK and s.message.startswith('pass'))
            assert passed[0].hardware_id == ns
            deactivate = (lambda: lc.go('inactive', transition_id=4)) if by_id else \
                (lambda: lc.go('inactive', label='deactivate'))
            quiet_after_one_zero(lc, {'cmd_vel': (robot.out, twist_of)}, deactivate,
                                 f'deactivate by {"id" if by_id else "label"}')
            assert robot.twists()[-2] == (0.0, 1.0), 'the command before the zero twist: the planner\'s'
        lc.refuses_every_invalid_transition()
        # shutdown from active: the zero twist too; finalized refuses everything
        lc.go('active', transition_id=3)
        spin.until(lambda: robot.twists()[-1:] == [(0.0, 1.0)], 60.0, 'cmd_vel again')
        quiet_after_one_zero(lc, {'cmd_vel': (robot.out, twist_of)}, lambda: lc.go('finalized', transition_id=7),
                             'shutdown from active', then='finalized')
        lc.refuses_every_invalid_transition()
        lc.alive()
    finally:
        code = stopped(proc)
    assert code == 0, lc.why()
    log = lc.log_path.read_text()
    assert 'Traceback' not in log and 'RCLError' not in log, log
    assert log.count('deactivated: sent a zero twist; no cmd_vel until activated') == 2, log


@pytest.mark.ros
@pytest.mark.parametrize('state, by', [('unconfigured', 'id'), ('unconfigured', 'label'), ('inactive', 'id'),
                                       ('inactive', 'label'), ('active', 'label')])
def test_shutdown_from_each_primary_state(ros_node, tmp_path, state, by):
    """Shutdown (id 5, 6 or 7, or its label) from each primary state (id from active: the test
    above); from active a stamped cmd_vel: the zero twist in the planner's frame."""
    node, spin = ros_node
    ns = f'/lc_{state}_{by}'
    robot = Robot(node, ns, stamped=True, frame='planner_frame')
    proc = start_script(tmp_path, 'managed_safety_filter', ns, 'require_detections:=false',
                        'level_set_markers:=false', 'cmd_vel_stamped:=true', *LONG)
    lc = Managed(node, spin, proc, f'{ns}/safety_filter', tmp_path / 'managed_safety_filter.log')
    shutdown = {'unconfigured': 5, 'inactive': 6, 'active': 7}[state]
    try:
        assert lc.state() == 'unconfigured'
        if state != 'unconfigured':
            lc.go('inactive', transition_id=1, timeout=180.0)
        if state == 'active':
            lc.go('active', transition_id=3)
            spin.until(lambda: robot.twists()[-1:] == [(0.0, 1.0)], 60.0, 'the planner\'s (0, 1 rad/s) passed')
        request = (lambda: lc.go('finalized', transition_id=shutdown)) if by == 'id' else \
            (lambda: lc.go('finalized', label='shutdown'))
        if state == 'active':
            start_at = node.get_clock().now()
            quiet_after_one_zero(lc, {'cmd_vel': (robot.out, twist_of)}, request, 'shutdown from active',
                                 then='finalized')
            zero = robot.out[-1]
            assert zero.header.frame_id == 'planner_frame'
            assert zero.header.stamp.sec * 10**9 + zero.header.stamp.nanosec >= start_at.nanoseconds - 10**9
        else:
            request()
            assert not robot.out, f'{state}: no cmd_vel, before or after the shutdown'
            lc.says_inactive('finalized')
        lc.refused(label='shutdown')
        lc.refused(transition_id=shutdown)
    finally:
        code = stopped(proc)
    assert code == 0, lc.why()


@pytest.mark.ros
def test_the_managed_fleet_filter_refuses_invalid_transitions_and_stops_every_robot(ros_node, tmp_path):
    node, spin = ros_node
    robots = ['/lf/lf_0', '/lf/lf_1']      # (resolved as topic names are: in the node's namespace)
    out = {f'{r}/cmd_vel': [] for r in robots}
    for topic, received in out.items():
        node.create_subscription(Twist, topic, received.append, rosmsg.QOS_EVERY_SAMPLE)
    batched = []
    node.create_subscription(Float64MultiArray, '/lf/fleet/cmd_vel', batched.append, rosmsg.QOS_EVERY_SAMPLE)
    # no input ever: every robot fails safe, stop_turn = (0, +omega_max), not the zero twist
    proc = start_script(tmp_path, 'managed_fleet_safety_filter', '/lf', 'robots:=[lf_0, lf_1]', 'batched_topics:=true',
                        'rate:=20.0', 'fail_safe_command:=stop_turn')
    lc = Managed(node, spin, proc, '/lf/fleet_safety_filter', tmp_path / 'managed_fleet_safety_filter.log')
    topics = {**{t: (received, twist_of) for t, received in out.items()},
              'fleet/cmd_vel': (batched, lambda m: tuple(m.data))}
    try:
        assert lc.state() == 'unconfigured'
        lc.says_inactive('unconfigured')
        for transition_id in (2, 3, 4, 6, 7):
            lc.refused(transition_id=transition_id)
        lc.refused(label='activate')
        lc.go('inactive', label='configure', timeout=180.0)
        inactive = lc.says_inactive('inactive', count=2)
        assert {s.hardware_id for s in inactive} == set(robots), 'a status per robot once configured'
        lc.refused(transition_id=1)
        lc.refused(label='deactivate')
        lc.go('active', transition_id=3)
        lc.refused(transition_id=3)
        lc.refused(label='cleanup')
        for name, (received, read) in topics.items():
            spin.until(lambda: received and any(read(received[-1])), 60.0, f'{name}: the fail safe, not zero')
        seen = len(lc.statuses)
        spin.until(lambda: {s.hardware_id for s in lc.statuses[seen:] if s.level == DiagnosticStatus.ERROR
                            and s.message.startswith('fail_safe')} == set(robots), 60.0,
                   'each robot\'s own status: ERROR fail safe')
        quiet_after_one_zero(lc, topics, lambda: lc.go('inactive', transition_id=4), 'deactivate by id')
        lc.go('active', label='activate')
        for name, (received, read) in topics.items():
            spin.until(lambda: any(read(received[-1])), 60.0, f'{name}: cmd_vel again')
        quiet_after_one_zero(lc, topics, lambda: lc.go('finalized', label='shutdown'), 'shutdown from active',
                             then='finalized')
        lc.refused(transition_id=1)
        lc.refused(label='shutdown')
    finally:
        code = stopped(proc)
    assert code == 0, lc.why()
    assert 'Traceback' not in lc.log_path.read_text(), lc.why()


@pytest.mark.ros
def test_a_failed_configure_leaves_the_node_unconfigured_and_says_why(ros_node, tmp_path):
    node, spin = ros_node
    ns = '/lc_bad_config'
    proc = start_script(tmp_path, 'managed_safety_filter', ns, 'pose_type:=nope')
    lc = Managed(node, spin, proc, f'{ns}/safety_filter', tmp_path / 'managed_safety_filter.log')
    try:
        for _ in range(2):          # and again: the same refusal of the parameter, the process alive
            assert not lc.request(transition_id=1, timeout=180.0), 'configure with pose_type nope succeeded'
            lc.alive()
            assert lc.state() == 'unconfigured'
            said = lc.says_inactive('unconfigured')
            assert "configure failed: ValueError: pose_type 'nope'" in said[0].message
        lc.refused(label='activate')
        lc.go('finalized', label='shutdown')
    finally:
        code = stopped(proc)
    assert code == 0, lc.why()
