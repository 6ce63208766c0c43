"""fleet_safety_filter_node (safety_filter_node for a fleet) at topic level: per-robot topics (drop-in)
and the batched interface; what it says of its robots."""
import math
import time

import numpy as np
import pytest
from rclpy.parameter import Parameter

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Pose, PoseArray, PoseStamped, Twist
from std_msgs.msg import Float64MultiArray

from supersafe_ros.nodes import filter_batched, safety_filter_node as filter_module
from supersafe_ros.nodes.fleet_safety_filter_node import FleetSafetyFilterNode
from supersafe_ros.ros_io import fleetmsg, rosmsg

from filter_support import Log
from graph_support import Rosout, Spinner, matched

ROBOTS = ['robot_0', 'robot_1', 'robot_2']
OBSTACLE = (4.0, -2.0)
FAR = (OBSTACLE[0] - 7.5, OBSTACLE[1] + 7.0, 0.0)          # clear: pass the planner's command
INTO = (OBSTACLE[0] - 3.0, OBSTACLE[1] + 0.6, 0.0)         # heading at the disc, left of it: turn left


class Driver:
    def __init__(self, ctx):
        from rclpy.node import Node
        self.node = n = Node('fleet_test_driver', context=ctx)
        self.pose = {r: n.create_publisher(PoseStamped, f'/{r}/pose', rosmsg.QOS_STREAM) for r in ROBOTS}
        self.det = {r: n.create_publisher(PoseArray, f'/{r}/detections', rosmsg.QOS_STREAM) for r in ROBOTS}
        self.cmd = {r: n.create_publisher(Twist, f'/{r}/cmd_vel_nav', rosmsg.QOS_STREAM) for r in ROBOTS}
        self.out = {r: [] for r in ROBOTS}
        self.states = {r: [] for r in ROBOTS}
        self.subs = []
        for r in ROBOTS:
            self.subs.append(n.create_subscription(Twist, f'/{r}/cmd_vel', self.out[r].append, rosmsg.QOS_STREAM))
            self.subs.append(n.create_subscription(DiagnosticStatus, f'/{r}/safety_filter/state',
                                                   self._recorder(self.states[r]), rosmsg.QOS_STREAM))
        self.fleet_poses = n.create_publisher(PoseArray, '/fleet/poses', rosmsg.QOS_STREAM)
        self.fleet_det = n.create_publisher(PoseArray, '/fleet/detections', rosmsg.QOS_STREAM)
        self.fleet_cmd = n.create_publisher(Float64MultiArray, '/fleet/cmd_vel_nav', rosmsg.QOS_STREAM)
        self.fleet_out, self.fleet_states = [], []
        self.subs.append(n.create_subscription(Float64MultiArray, '/fleet/cmd_vel', self.fleet_out.append,
                                               rosmsg.QOS_STREAM))
        self.subs.append(n.create_subscription(DiagnosticArray, '/fleet/safety_filter/state',
                                               self.fleet_states.append, rosmsg.QOS_STREAM))
        self.rosout = Rosout(n)

    @staticmethod
    def _recorder(into):
        def record(msg):   # one parameter: rclpy passes the message only
            into.append(rosmsg.diagnostic_values(msg))
        return record

    def endpoints(self):
        return (*self.pose.values(), *self.det.values(), *self.cmd.values(), *self.subs, self.fleet_poses,
                self.fleet_det, self.fleet_cmd)

    def newest(self, robot):
        return self.states[robot][-1] if self.states[robot] else {}

    def fleet_newest(self):
        """{robot: state values} of the newest batched state of each robot."""
        newest = {}
        for arr in self.fleet_states:
            for st in arr.status:
                newest[st.name] = rosmsg.diagnostic_values(st)
        return newest


@pytest.fixture(scope='module')
def setup(ros_context):
    # no test here waits for an input to go stale: timeouts long enough that a reply read a few
    # busy seconds after its tick (load 10: seen with 2 s) is still the tick's, not a fail safe
    params = [Parameter('robots', value=ROBOTS), Parameter('batched_topics', value=True),
              Parameter('standard_shape', value=[41, 41, 24]),
              Parameter('pose_timeout', value=30.0), Parameter('detections_timeout', value=30.0),
              Parameter('cmd_timeout', value=30.0), Parameter('hold_timeout', value=30.0),
              Parameter('state_rate', value=100.0), Parameter('rate', value=20.0)]
    node = FleetSafetyFilterNode(context=ros_context, parameter_overrides=params)
    driver = Driver(ros_context)
    spin = Spinner(ros_context, node, driver.node)
    spin.until(lambda: matched(*driver.endpoints()), 15.0, 'fleet topics to match')
    yield node, driver, spin
    spin.shutdown()
    node.close()
    node.destroy_node()
    driver.node.destroy_node()


@pytest.mark.ros
def test_per_robot_topics_are_a_drop_in_with_one_step_per_tick(setup, monkeypatch):
    node, d, spin = setup
    calls = []
    real = filter_module.decide_many
    monkeypatch.setattr(filter_module, 'decide_many', lambda filters, *a, **k: calls.append(len(filters))
                        or real(filters, *a, **k))
    # robot_0 clear, robot_1 heading at the disc, robot_2 silent
    for r, s, w in (('robot_0', FAR, 0.3), ('robot_1', INTO, -0.4)):
        d.det[r].publish(rosmsg.xy_to_posearray([OBSTACLE]))
        d.pose[r].publish(rosmsg.state_to_pose(s))
        d.cmd[r].publish(rosmsg.turn_rate_to_twist(w, 3.0))
    spin.until(lambda: d.newest('robot_0').get('action') == 'pass'
               and d.newest('robot_1').get('action') == 'override', 10.0, 'pass and override')
    st0, st1 = d.newest('robot_0'), d.newest('robot_1')
    assert float(st0['cmd_angular_z']) == pytest.approx(0.3) and d.out['robot_0'][-1].angular.z == pytest.approx(0.3)
    assert float(st1['cmd_angular_z']) == pytest.approx(1.0) and st1['obstacle_index'] == '0'
    spin.until(lambda: d.out['robot_1'] and d.out['robot_1'][-1].angular.z == pytest.approx(1.0), 5.0,
               'robot_1 turning away')
    spin.until(lambda: d.states['robot_2'], 5.0, 'a state of robot_2')
    st2 = d.newest('robot_2')
    assert st2['action'] == 'fail_safe' and 'no pose received yet' in st2['reason']
    assert (d.out['robot_2'][-1].linear.x, d.out['robot_2'][-1].angular.z) == (0.0, 0.0)    # stop: a zero twist
    # every tick decided the three robots in one call
    assert calls and set(calls) == {3}


@pytest.mark.ros
def test_per_robot_bad_input_is_rejected_with_the_reason(setup):
    """Per-robot topics are taken serialized and read by the single node's Sources: a bad pose
    (wrong frame, NaN) fails that robot safe with the validator's reason, a command not finite
    stops it until a valid one comes (as safety_filter_node does)."""
    node, d, spin = setup
    r = 'robot_2'
    d.det[r].publish(rosmsg.xy_to_posearray([OBSTACLE]))
    d.cmd[r].publish(rosmsg.turn_rate_to_twist(0.25, 3.0))
    d.pose[r].publish(rosmsg.state_to_pose(FAR))
    spin.until(lambda: d.newest(r).get('action') == 'pass', 10.0, f'{r} passing')
    assert float(d.newest(r)['cmd_angular_z']) == pytest.approx(0.25)
    nan_cmd = Twist()
    nan_cmd.angular.z = float('nan')
    d.cmd[r].publish(nan_cmd)
    spin.until(lambda: d.rosout.has('fleet_safety_filter', 'cmd_vel_nav rejected', 'not finite (angular.z=nan'),
               10.0, 'the bad command logged')
    d.pose[r].publish(rosmsg.state_to_pose(FAR))
    spin.until(lambda: d.newest(r).get('action') == 'fail_safe', 10.0, f'{r} stopped on the bad command')
    assert 'planner command rejected' in d.newest(r)['reason']
    spin.until(lambda: (d.out[r][-1].linear.x, d.out[r][-1].angular.z) == (0.0, 0.0), 5.0, f'{r} sent a zero twist')
    d.cmd[r].publish(rosmsg.turn_rate_to_twist(-0.5, 3.0))
    d.pose[r].publish(rosmsg.state_to_pose(FAR))
    spin.until(lambda: d.newest(r).get('action') == 'pass', 10.0, f'{r} passing again')
    assert float(d.newest(r)['cmd_angular_z']) == pytest.approx(-0.5)    # the new command
    odom = rosmsg.state_to_pose(FAR, frame='odom')
    d.pose[r].publish(odom)
    spin.until(lambda: d.newest(r).get('action') == 'fail_safe', 10.0, f'{r} failing safe')
    assert "pose frame is 'odom', expected 'map'" in d.newest(r)['reason']
    bad = rosmsg.state_to_pose(FAR)
    bad.pose.position.y = float('nan')
    d.pose[r].publish(rosmsg.state_to_pose(FAR))
    spin.until(lambda: d.newest(r).get('action') == 'pass', 10.0, f'{r} back')
    d.pose[r].publish(bad)
    spin.until(lambda: d.newest(r).get('action') == 'fail_safe', 10.0, f'{r} failing safe on NaN')
    assert 'pose position is not finite' in d.newest(r)['reason']


def fleet_poses(states, frame='map'):
    msg = PoseArray()
    msg.header.frame_id = frame
    for x, y, th in states:
        p = Pose()
        p.position.x, p.position.y = float(x), float(y)
        if math.isfinite(th):
            p.orientation = rosmsg.yaw_to_quaternion(th)
        else:
            p.orientation.z = float('nan')
        msg.poses.append(p)
    return msg


def batched_tick(d, spin, states, turns, want, what, frame='map'):
    d.fleet_out.clear()
    d.fleet_det.publish(rosmsg.xy_to_posearray([OBSTACLE]))
    d.fleet_cmd.publish(fleetmsg.commands_to_msg([(3.0, w) for w in turns]))
    spin.spin_for(0.05)    # commands in before the poses tick
    d.fleet_poses.publish(fleet_poses(states, frame))
    spin.until(lambda: d.fleet_out and want(d.fleet_newest()), 10.0, what)
    # the reply read is one sent after that state: the state and the reply of one tick come on
    # two topics, and a loaded reader may hold the state before that tick's reply (seen in CI)
    seen = len(d.fleet_out)
    spin.until(lambda: len(d.fleet_out) > seen, 10.0, f'{what}: a reply after the state')
    rows = np.asarray(d.fleet_out[-1].data).reshape(-1, 2)
    assert rows.shape == (3, 2)
    assert [x.label for x in d.fleet_out[-1].layout.dim] == ['robot', 'linear_x,angular_z']
    return rows, d.fleet_newest()


def actions(*wanted):
    return lambda st: all(st.get(f'/{r}', {}).get('action') == a for r, a in zip(ROBOTS, wanted))


@pytest.mark.ros
def test_batched_poses_commands_and_states(setup):
    node, d, spin = setup
    rows, st = batched_tick(d, spin, [FAR, INTO, FAR], [0.3, -0.4, -0.2], actions('pass', 'override', 'pass'),
                            'a batched reply')
    assert rows[0] == pytest.approx([3.0, 0.3]) and rows[2] == pytest.approx([3.0, -0.2])
    assert rows[1] == pytest.approx([3.0, 1.0])
    assert st['/robot_1']['obstacle_index'] == '0'


@pytest.mark.ros
def test_batched_bad_input_is_rejected_with_a_reason_and_fails_the_robots_safe(setup):
    node, d, spin = setup
    batched_tick(d, spin, [FAR, FAR, FAR], [0.3, 0.3, 0.3], actions('pass', 'pass', 'pass'), 'all passing')
    # a NaN row: only that robot fails safe
    rows, st = batched_tick(d, spin, [FAR, (math.nan, 0.0, 0.0), FAR], [0.3, 0.3, 0.3],
                            actions('pass', 'fail_safe', 'pass'), 'robot_1 failing safe')
    assert 'not finite' in st['/robot_1']['reason'] and rows[1][1] != pytest.approx(0.3)
    spin.until(lambda: d.rosout.has('fleet_safety_filter', 'fleet/poses row rejected', 'not finite'), 5.0,
               'the rejection logged')
    # wrong size (2 poses for 3 robots): the whole message is rejected, every robot fails safe
    # (robot_1 was failing safe already: its state for this tick is the one with the new reason,
    # which may come a state period later, as its action did not change)
    said = lambda st: all('2 poses for 3 robots' in st.get(f'/{r}', {}).get('reason', '')  # noqa: E731
                          for r in ROBOTS)
    everyone = actions('fail_safe', 'fail_safe', 'fail_safe')
    rows, st = batched_tick(d, spin, [FAR, FAR], [0.3, 0.3, 0.3], lambda st: everyone(st) and said(st),
                            'everyone failing safe, saying why')
    assert said(st)
    spin.until(lambda: d.rosout.has('fleet_safety_filter', 'fleet/poses rejected', '2 poses for 3 robots'), 5.0,
               'the rejection logged')
    # wrong frame, likewise
    batched_tick(d, spin, [FAR, FAR, FAR], [0.3, 0.3, 0.3], actions('fail_safe', 'fail_safe', 'fail_safe'),
                 'wrong frame rejected', frame='odom')
    # good input again: all pass; then a command message of the wrong size keeps the previous commands
    batched_tick(d, spin, [FAR, FAR, FAR], [0.3, 0.3, 0.3], actions('pass', 'pass', 'pass'), 'all passing again')
    bad = Float64MultiArray()
    bad.data = [3.0, 0.9, 3.0, 0.9]
    d.fleet_cmd.publish(bad)
    spin.until(lambda: d.rosout.has('fleet_safety_filter', 'fleet/cmd_vel_nav rejected', '4 values for 3 robots'),
               5.0, 'the command rejection logged')
    d.fleet_out.clear()
    d.fleet_poses.publish(fleet_poses([FAR, FAR, FAR]))
    spin.until(lambda: d.fleet_out, 5.0, 'a reply')
    assert np.asarray(d.fleet_out[-1].data).reshape(-1, 2)[:, 1] == pytest.approx([0.3, 0.3, 0.3])


@pytest.mark.ros
def test_poses_that_wait_are_superseded_by_the_newest(setup, ros_context, monkeypatch):
    """Five fleet/poses messages waiting at once (the filter busy): it decides on the newest,
    once or a few times but fewer than five, counts the rest as superseded and says so; every
    message is either decided on or superseded."""
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    node, d, spin = setup
    batched_tick(d, spin, [FAR, FAR, FAR], [0.3, 0.3, 0.3], actions('pass', 'pass', 'pass'), 'all passing')
    decided = []
    real = filter_batched.update_poses
    monkeypatch.setattr(filter_batched, 'update_poses', lambda filters, states, *a, **k: decided.append(
        np.array(states)) or real(filters, states, *a, **k))
    # an observer of its own (not spun with the filter) tells when the burst has been delivered
    observer = Node('fleet_test_observer', context=ros_context)
    seen = []
    observer.create_subscription(PoseArray, '/fleet/poses', seen.append, rosmsg.QOS_STREAM)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(observer)
    try:
        deadline = time.monotonic() + 10.0
        while d.fleet_poses.get_subscription_count() < 2 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        before = node.fleet.superseded
        burst = [[(FAR[0] + k, FAR[1], 0.0)] * 3 for k in range(5)]
        for states in burst:
            d.fleet_poses.publish(fleet_poses(states))
        while len(seen) < 5 and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.01)
        assert len(seen) == 5, 'the burst was not delivered'
    finally:
        ex.shutdown()
        observer.destroy_node()
    spin.until(lambda: decided and decided[-1][0, 0] == pytest.approx(burst[-1][0][0]), 10.0,
               'a decision on the newest poses')
    superseded = node.fleet.superseded - before
    assert len(decided) < 5 and len(decided) + superseded == 5, (len(decided), superseded)
    assert node.wiring.filters[0].pose.value[0] == pytest.approx(burst[-1][0][0])
    spin.until(lambda: d.rosout.has('fleet_safety_filter', 'fleet/poses', 'superseded'), 5.0, 'the warning')


@pytest.mark.ros
def test_robots_parameter_is_read_only_and_must_name_distinct_robots(setup, ros_context):
    node, d, spin = setup
    result = node.set_parameters([Parameter('robots', value=['robot_9'])])[0]
    assert not result.successful
    with pytest.raises(ValueError, match='twice'):
        FleetSafetyFilterNode(node_name='fleet_dup', context=ros_context,
                              parameter_overrides=[Parameter('robots', value=['a', '/a/'])])
    with pytest.raises(ValueError, match='decide_on input'):
        FleetSafetyFilterNode(node_name='fleet_input_batched', context=ros_context, parameter_overrides=[
            Parameter('robots', value=['a']), Parameter('batched_topics', value=True),
            Parameter('decide_on', value='input')])


def test_held_steps_are_debug_lines_and_an_info_summary_at_most_every_period():
    """A team run logged one INFO line per held lockstep step (377 in 3.5 min): each is DEBUG
    now, with one INFO summary per period that had any (times given: no clock involved)."""
    from supersafe_ros.nodes.filter_state import HoldSummary
    log = Log()
    holds = HoldSummary(log, period=30.0, now=0.0)
    for t, held in ((1.0, 0.31), (2.0, 0.62), (29.0, 0.1)):
        holds.held(held, now=t)
    assert [lv for lv, _ in log.lines] == ['debug'] * 3
    holds.held(0.2, now=31.0)                     # the period is over: one summary of the four
    assert log.lines[-1] == ('info', '4 steps held in the last 31 s until a cluster value was in force '
                                     '(1.23 s in all, longest 0.62 s)')
    holds.flush(now=40.0)                         # nothing since: nothing said
    holds.held(0.5, now=45.0)
    holds.flush(now=50.0)                         # the node stops: what is left is said
    assert [lv for lv, _ in log.lines].count('info') == 2 and '1 step held in the last 10 s' in log.lines[-1][1]


def test_a_robots_state_is_due_on_its_phase_on_a_change_and_alike_decided_alone_or_with_the_fleet():
    """StateThrottle: with nothing changing, robot i of n is due once a period on its phase i / n; a
    change of its action or of the set makes it due at once; after a pause of two periods its phase
    restarts. Deciding the robots one at a time (decide_on input) gives each the same dues as
    deciding them all at once (a tick)."""
    from supersafe_ros.nodes.filter_state import StateThrottle
    n, period, start = 4, 1.0, 100.0
    th = StateThrottle(n, start, period)
    dues = {i: [] for i in range(n)}
    for k in range(1, 41):            # steady, 0.1 s ticks: each robot due once a period, on its phase
        now = start + 0.1 * k
        for i in th.due(now, range(n), ['pass'] * n, 'set', period):
            dues[i].append(round(now - start, 6))
    # (the first tick: every robot, its action new)
    assert dues[0] == [0.1, 1.0, 2.0, 3.0, 4.0] and dues[2] == [0.1, 0.5, 1.5, 2.5, 3.5]
    rng = np.random.default_rng(3)
    n, period = 37, 0.5
    fleet, alone = StateThrottle(n, start, period), StateThrottle(n, start, period)
    updates = [object(), object()]
    now, kinds = start, set()
    for tick in range(500):
        if tick < 100:      # first steady: only the phases make robots due
            now += 0.01
            actions, update = ['pass'] * n, updates[0]
        else:               # then ticks, and pauses longer than 2 periods, changes of action and set
            now += rng.choice([0.02, 0.02, 0.02, 0.3, 1.2])
            actions = [str(a) for a in rng.choice(['pass', 'override', 'fail_safe'], n, p=[0.9, 0.07, 0.03])]
            update = updates[int(rng.random() < 0.02)]
        got = fleet.due(now, range(n), actions, update, period)
        want = [i for i in range(n) if alone.due(now, (i,), (actions[i],), update, period) == [0]]
        odd = list(range(1, n, 2))          # a subset, just told: none due
        assert fleet.due(now, odd, [actions[i] for i in odd], update, period) == []
        assert got == want, f'tick {tick}'
        kinds.add(0 < len(got) < n)
    assert kinds == {True, False}       # some ticks with a few robots due, some with all or none
    # a subset's due robots are told by their positions in it
    robots = [3, 8, 21]
    later = now + 10 * period
    assert fleet.due(later, robots, ['pass', 'pass', 'pass'], update, period) == [0, 1, 2]
    assert fleet.due(later, robots, ['pass', 'override', 'pass'], update, period) == [1]


class _Decisions(list):
    """What Story reads of a decision: the actions, and each robot's output (action, reason)."""

    def __init__(self, actions):
        super().__init__(type('Out', (), {'action': a, 'reason': f'why {i}'})() for i, a in enumerate(actions))
        self.action = actions


def _filters(n):
    from supersafe_ros.filter import FilterConfig, RobotFilter
    filters = [RobotFilter(FilterConfig(), f'/r{i}') for i in range(n)]
    for f in filters:
        f.update_pose((0.0, 0.0, 0.0), 0.0)
    return filters


def test_a_fleets_story_tells_each_kind_of_change_once_per_decision():
    """Story: quiet while robots start failing safe, one line for the robots whose inputs became
    valid, one for those that failed safe (with the first one's reason), one for those back;
    nothing when nothing changed; robots decided alone are told alone."""
    from supersafe_ros.nodes.filter_state import Story
    log, filters = Log(), _filters(4)
    story = Story(log, ['/a', '/b', '/c', '/d'])

    def tell(*actions, rows=range(4)):
        log.lines.clear()
        story.tell(list(rows), _Decisions(list(actions)), [filters[i] for i in rows], 0.0)
        return [line for line in log.lines if 'until the inputs are valid' not in line[1]]
    assert tell('fail_safe', 'fail_safe', 'fail_safe', 'fail_safe') == []          # starting: quiet
    assert tell('pass', 'override', 'fail_safe', 'fail_safe') == [
        ('info', 'inputs valid for 2 robot(s) (/a, /b): the first: filtering (pass: why 0)')]
    assert tell('pass', 'override', 'fail_safe', 'fail_safe') == []                # no change
    assert tell('fail_safe', 'pass', 'pass', 'fail_safe') == [
        ('info', 'inputs valid for 1 robot(s) (/c): the first: filtering (pass: why 2)'),
        ('error', 'failing safe for 1 robot(s) (/a): the first: why 0')]
    assert tell('pass', 'fail_safe', 'pass', 'pass') == [
        ('info', 'inputs valid for 1 robot(s) (/d): the first: filtering (pass: why 3)'),
        ('error', 'failing safe for 1 robot(s) (/b): the first: why 1'),
        ('info', 'inputs valid again for 1 robot(s) (/a): the first: filtering (pass: why 0)')]
    assert tell('pass', rows=[1]) == [('info', 'inputs valid again for 1 robot(s) (/b): the first: filtering '
                                               '(pass: why 0)')]


def test_a_lone_robots_story_says_its_reason_and_its_planners_silence_once():
    from supersafe_ros.nodes.filter_state import Story
    log, (f,) = Log(), _filters(1)
    story = Story(log, ['/robot_0'])
    story.tell([0], _Decisions(['fail_safe']), [f], 0.0)
    assert log.lines == [('info', 'failing safe until the inputs are valid: why 0')]     # once, while starting
    story.tell([0], _Decisions(['fail_safe']), [f], 0.0)
    story.tell([0], _Decisions(['pass']), [f], 0.0)
    story.tell([0], _Decisions(['fail_safe']), [f], 0.0)
    assert log.lines[1:] == [('info', 'inputs valid: filtering (pass: why 0)'), ('error', 'failing safe: why 0')]
    log.lines.clear()
    f.update_command(0.1, 1.0)
    story.tell([0], _Decisions(['pass']), [f], 1.0)           # fresh: nothing to say of the planner
    story.tell([0], _Decisions(['pass']), [f], 1.0 + f.config.cmd_timeout + 0.1)
    story.tell([0], _Decisions(['pass']), [f], 1.0 + f.config.cmd_timeout + 0.2)     # said once per silence
    f.update_command(0.1, 3.0)
    story.tell([0], _Decisions(['pass']), [f], 3.0)
    assert log.lines == [('info', 'inputs valid again: filtering (pass: why 0)'),
                         ('info', 'planner silent for more than cmd_timeout (0.5 s): sending zero twists until '
                                  'it speaks'),
                         ('info', 'planner speaking again')]


@pytest.mark.ros
def test_flowing_poses_keep_the_timer_quiet_and_a_pause_wakes_it(setup, monkeypatch):
    """While fleet/poses come faster than the rate, the decisions are theirs and the timer does
    not even wake (each batched tick restarts it); when they pause, the timer decides at the
    rate, taking the commands that wait."""
    node, d, spin = setup
    batched_tick(d, spin, [FAR, FAR, FAR], [0.3, 0.3, 0.3], actions('pass', 'pass', 'pass'), 'all passing')
    calls = []
    real = node.timer.callback
    monkeypatch.setattr(node.timer, 'callback', lambda: calls.append(time.monotonic()) or real())
    period = node.period
    # 50 poses, one every 0.4 periods: a count, not a wall-clock slice (on a loaded machine the
    # loop itself may stall; each stall of a period or more lets the timer wake once more)
    last, allowed = time.monotonic(), 2
    for k in range(50):
        if k % 10 == 0:     # a detector's heartbeat: the loop may outlast detections_timeout under load
            d.fleet_det.publish(rosmsg.xy_to_posearray([OBSTACLE]))
        d.fleet_poses.publish(fleet_poses([FAR, FAR, FAR]))
        now = time.monotonic()
        allowed += int((now - last) // period)
        last = now
        while time.monotonic() < now + 0.4 * period:
            spin.executor.spin_once(timeout_sec=0.002)
    assert len(calls) <= allowed + int((time.monotonic() - last) // period), (allowed, calls)
    # a pause: the timer decides, and takes the new commands with it
    ticks = node.ticks
    d.fleet_det.publish(rosmsg.xy_to_posearray([OBSTACLE]))
    d.fleet_cmd.publish(fleetmsg.commands_to_msg([(3.0, -0.25)] * 3))
    spin.until(lambda: node.ticks >= ticks + 4 and d.fleet_out
               and np.asarray(d.fleet_out[-1].data).reshape(-1, 2)[:, 1] == pytest.approx([-0.25] * 3),
               10.0, 'the timer deciding on the new commands')
    assert len(calls) >= 4


@pytest.mark.ros
def test_batched_commands_waiting_for_a_tick_are_each_applied_in_order(setup):
    """Commands that wait for the tick are taken in order, each as its own callback would: a
    bad row of the newest falls back to that robot's row of the message before (not to an
    older command), and a bad message among them is rejected and logged."""
    node, d, spin = setup
    batched_tick(d, spin, [FAR, FAR, FAR], [0.1, 0.1, 0.1], actions('pass', 'pass', 'pass'), 'all passing')
    bad = Float64MultiArray()
    bad.data = [3.0, 0.9, 3.0, 0.9]
    d.fleet_cmd.publish(fleetmsg.commands_to_msg([(3.0, 0.3)] * 3))
    d.fleet_cmd.publish(bad)                                                  # wrong size: rejected
    d.fleet_cmd.publish(fleetmsg.commands_to_msg([(3.0, 0.2), (3.0, math.nan), (3.0, 0.2)]))
    spin.spin_for(0.05)
    d.fleet_out.clear()
    d.fleet_poses.publish(fleet_poses([FAR, FAR, FAR]))
    spin.until(lambda: d.fleet_out, 5.0, 'a reply')
    assert np.asarray(d.fleet_out[-1].data).reshape(-1, 2)[:, 1] == pytest.approx([0.2, 0.3, 0.2])
    spin.until(lambda: d.rosout.has('fleet_safety_filter', 'fleet/cmd_vel_nav rejected', '4 values for 3 robots'),
               5.0, 'the rejection of the waiting message logged')


def big_detections(close_at, entries=100_000):
    """Serialized detections of ``entries`` centres 100 m to 3 km from OBSTACLE, and OBSTACLE
    itself at index ``close_at``."""
    from supersafe_ros.ros_io import cdr
    rng = np.random.default_rng(close_at)
    phi, r = rng.uniform(-math.pi, math.pi, entries - 1), rng.uniform(100.0, 3000.0, entries - 1)
    far = np.column_stack([OBSTACLE[0] + r * np.cos(phi), OBSTACLE[1] + r * np.sin(phi)])
    return cdr.pose_array_bytes(np.concatenate([far[:close_at], [OBSTACLE], far[close_at:]]))


@pytest.mark.ros
def test_100000_detections_on_both_interfaces_keep_every_tick_answered(setup):
    """Three fleet/detections messages of 100,000 (one array for every robot; the shipped
    max_detections keeps the 10,000 nearest to any robot), then three of robot_1's own: each
    message is seen judged when robot_1 overrides toward safety at its one close obstacle,
    named by its index in that message, every poses message is answered, and the state says
    what was dropped and that it was safe."""
    node, d, spin = setup
    # the robots' poses first: a message beyond max_detections keeps the nearest to them
    batched_tick(d, spin, [FAR, INTO, FAR], [0.3, -0.4, -0.2], actions('pass', 'override', 'pass'), 'poses known')

    def avoiding(st, close):
        return st.get('obstacle_index') == str(close) and st.get('action') == 'override'
    for k in range(3):
        close = 50_000 + 1000 * k
        d.fleet_det.publish(big_detections(close))
        d.fleet_cmd.publish(fleetmsg.commands_to_msg([(3.0, 0.3), (3.0, -0.4), (3.0, -0.2)]))
        replies, ticks = len(d.fleet_out), 0
        while not avoiding(d.fleet_newest().get('/robot_1', {}), close):
            assert ticks < 500, f'fleet/detections {k} not judged after {ticks} poses'
            d.fleet_poses.publish(fleet_poses([FAR, INTO, FAR]))
            ticks += 1
            spin.until(lambda: len(d.fleet_out) >= replies + ticks, 30.0, f'the reply to poses {ticks}')
        st = d.fleet_newest()['/robot_1']
        assert float(st['cmd_angular_z']) == 1.0, st
        assert st['detections_dropped'] == '90000' and 'safe to drop' in st['detections_dropped_reason'], st
        assert np.asarray(d.fleet_out[-1].data).reshape(-1, 2)[1] == pytest.approx([3.0, 1.0])
    spin.until(lambda: d.rosout.has('fleet_safety_filter', 'fleet/detections: 90000 of 100000 detections dropped',
                                    'safe to drop'), 10.0, 'the WARN naming what was dropped')
    r = 'robot_1'
    for k in range(3):
        close = 20_000 + 1000 * k
        d.det[r].publish(big_detections(close))
        answers = 0
        while not avoiding(d.newest(r), close):
            assert answers < 500, f'{r}/detections {k} not judged after {answers} commands'
            before = len(d.out[r])
            d.pose[r].publish(rosmsg.state_to_pose(INTO))
            d.cmd[r].publish(rosmsg.turn_rate_to_twist(-0.4, 3.0))
            answers += 1
            spin.until(lambda: len(d.out[r]) > before, 30.0, f'a cmd_vel after command {answers}')
        st = d.newest(r)
        assert float(st['cmd_angular_z']) == 1.0, st
        assert st['detections_dropped'] == '90000' and 'safe to drop' in st['detections_dropped_reason'], st
    d.det[r].publish(rosmsg.xy_to_posearray([OBSTACLE]))
    d.fleet_det.publish(rosmsg.xy_to_posearray([OBSTACLE]))


@pytest.mark.ros
def test_commands_beyond_the_robots_limits_are_clipped_and_said_on_both_interfaces(setup):
    node, d, spin = setup
    rows, st = batched_tick(d, spin, [FAR, FAR, FAR], [0.1, 0.1, 0.1], actions('pass', 'pass', 'pass'), 'passing')
    d.fleet_cmd.publish(fleetmsg.commands_to_msg([(3.0, 1e30), (4.5, 0.2), (0.5, -0.1)]))
    spin.spin_for(0.05)
    d.fleet_out.clear()
    d.fleet_poses.publish(fleet_poses([FAR, FAR, FAR]))
    said = lambda st: 'angular.z=1e+30' in st.get('/robot_0', {}).get('cmd_clipped', '')  # noqa: E731
    spin.until(lambda: d.fleet_out and said(d.fleet_newest()), 10.0, 'the batched clip said')
    # the planner's speed passed (robot_2: 0.5 m/s), beyond the robot's largest clipped (robot_1)
    assert np.asarray(d.fleet_out[-1].data) == pytest.approx([3.0, 1.0, 3.0, 0.2, 0.5, -0.1])
    st = d.fleet_newest()
    assert st['/robot_0']['cmd_clipped'] == 'angular.z=1e+30 beyond w_max=1: clipped to 1'
    assert st['/robot_1']['cmd_clipped'] == 'linear.x=4.5 beyond speed=3: clipped to 3'
    assert st['/robot_2']['cmd_clipped'] == ''
    spin.until(lambda: d.rosout.has('fleet_safety_filter', "fleet/cmd_vel_nav beyond the robot's limits for 2 "
                                    'robot(s)', 'angular.z=1e+30'), 10.0, 'the batched WARN')
    # per-robot topics
    r = 'robot_2'
    d.pose[r].publish(rosmsg.state_to_pose(FAR))
    d.cmd[r].publish(rosmsg.turn_rate_to_twist(-1e30, 3.0))
    spin.until(lambda: 'angular.z=-1e+30' in d.newest(r).get('cmd_clipped', ''), 10.0, f'{r}: the clip said')
    assert d.newest(r)['cmd_angular_z'] == '-1'
    spin.until(lambda: d.rosout.has('fleet_safety_filter', "cmd_vel_nav beyond the robot's limits for 1 robot(s)",
                                    '/robot_2: angular.z=-1e+30'), 10.0, 'the per-robot WARN')
