"""The filter's robot-stack inputs at topic level, on the wall clock: Odometry + LaserScan /
PointCloud2 / OccupancyGrid + TwistStamped, bad input (NaN ranges, a malformed or huge cloud, a wrong
frame, a pose of another clock), /diagnostics, a foreign publisher type; each on both nodes: a
safety_filter_node of the robot (decided on its inputs, taken by the default direct_take path) and a
fleet_safety_filter_node of it and a second robot (decided on ticks); and the managed nodes'
lifecycle through the lifecycle_msgs services."""
import math
import time

import numpy as np
import pytest
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Twist, TwistStamped
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from nav_msgs.msg import Odometry
from sensor_msgs.msg import LaserScan, PointCloud2

from supersafe_ros.nodes.fleet_safety_filter_node import FleetSafetyFilterNode
from supersafe_ros.nodes.safety_filter_node import ManagedSafetyFilterNode, SafetyFilterNode
from supersafe_ros.ros_io import rosmsg

from graph_support import FilterRigs, Rosout, Spinner, matched, params
from sensor_graph_support import xy_cloud

pytestmark = pytest.mark.ros   # rclpy nodes in this process


class Stack:
    """The test's side: a robot stack's odometry, scan or cloud, and planner; what the filter says."""

    def __init__(self, ctx, ns, detections=LaserScan):
        self.node = n = Node(f'stack{ns.replace("/", "_")}', context=ctx)
        self.odom = n.create_publisher(Odometry, f'{ns}/pose', rosmsg.QOS_STREAM)
        self.det = n.create_publisher(detections, f'{ns}/detections', rosmsg.QOS_STREAM)
        self.cmd = n.create_publisher(TwistStamped, f'{ns}/cmd_vel_nav', rosmsg.QOS_STREAM)
        self.out, self.states, self.diagnostics = [], [], []
        self.subs = [n.create_subscription(TwistStamped, f'{ns}/cmd_vel', self.out.append, rosmsg.QOS_EVERY_SAMPLE),
                     n.create_subscription(DiagnosticStatus, f'{ns}/safety_filter/state',
                                           lambda m: self.states.append(rosmsg.diagnostic_values(m)),
                                           rosmsg.QOS_EVERY_SAMPLE)]
        self.diag_sub = n.create_subscription(DiagnosticArray, '/diagnostics', self.diagnostics.append,
                                              rosmsg.QOS_EVERY_SAMPLE)
        self.rosout = Rosout(n)

    def stamp(self):
        return self.node.get_clock().now().to_msg()

    def send_pose(self, x=0.0, y=0.0, frame='map', stamp=None):
        m = Odometry()
        m.header.frame_id, m.header.stamp = frame, stamp or self.stamp()
        m.pose.pose = rosmsg.state_to_pose((x, y, 0.0)).pose
        self.odom.publish(m)

    def send_scan(self, ranges, frame='laser'):
        m = LaserScan()
        m.header.frame_id, m.header.stamp = frame, self.stamp()
        m.angle_min, m.angle_increment = -math.pi, 2 * math.pi / len(ranges)
        m.angle_max = m.angle_min + m.angle_increment * (len(ranges) - 1)
        m.range_min, m.range_max = 0.05, 10.0
        m.ranges = [float(r) for r in ranges]
        self.det.publish(m)

    def send_cmd(self, linear=1.0, omega=0.0):
        m = TwistStamped()
        m.header.frame_id, m.header.stamp = 'base_link', self.stamp()
        m.twist.linear.x, m.twist.angular.z = linear, omega
        self.cmd.publish(m)


def filter_node(ctx, ns, detections_type='laser_scan', managed=False, kind='single', **extra):
    """The filter of robot ``ns``: a safety_filter_node in its namespace (``single``), or a fleet node in /
    of it and a second robot (``fleet``: ticks)."""
    values = dict(pose_type='odometry', detections_type=detections_type, cmd_vel_stamped=True,
                  level_set_markers=False, rate=20.0, **extra)
    if kind == 'fleet':
        return FleetSafetyFilterNode(context=ctx, parameter_overrides=params(
            robots=[ns.strip('/'), ns.strip('/') + '_idle'], **values))
    cls = ManagedSafetyFilterNode if managed else SafetyFilterNode
    return cls(context=ctx, namespace=ns, parameter_overrides=params(**values))


def new_state(spin, stack, count, what, **expected):
    """Wait for a state message after the first ``count`` that has the ``expected`` values."""
    spin.until(lambda: any(all(s.get(k) == v for k, v in expected.items()) for s in stack.states[count:]),
               15.0, what)


@pytest.fixture(params=['single', 'fleet'])
def rig(ros_context, request):
    rigs = FilterRigs(ros_context)

    def make(ns, detections=LaserScan, **kw):
        f = filter_node(ros_context, f'{ns}_{request.param}', kind=request.param, **kw)
        s = Stack(ros_context, f'{ns}_{request.param}', detections)
        return f, s, rigs.add(f, s.node)
    yield make
    rigs.close()


def occupied_at(f, x, y) -> bool:
    """Whether the filter's local map holds (x, y) occupied (the cell or a neighbour: returns land on edges)."""
    return len(f.sensors[0].map.occupied_centres(x, y, 0.1)) > 0


def test_a_scan_goes_into_the_map_and_bad_scans_are_refused_until_blind(rig):
    """A scan's returns mark the local map, its NaN and beyond-range beams clear nothing; a scan with no
    return in range looked and saw nothing (fresh, the map kept); one whose geometry is not finite is
    refused with its fault named, and the filter fails safe once its last valid view is
    detections_timeout old, the cause in its reason."""
    f, s, spin = rig('/scan_robot', detections_timeout=0.3)
    spin.until(lambda: matched(s.odom, s.det, s.cmd, *s.subs), 15.0, 'the filter to match')
    assert (f.direct is not None) == (f.mode == 'input'), 'a lone robot\'s inputs taken by a thread of their own'
    ranges = np.full(360, np.inf)
    ranges[170:190] = 4.0                      # a wall 4 m ahead, NaN and beyond-range beams elsewhere
    ranges[10], ranges[20] = np.nan, 50.0
    deadline = time.monotonic() + 30.0      # (a dead graph; each round is paced by the filter's answer)
    while time.monotonic() < deadline:      # until the map's first value is in force: the command then passes
        n = len(s.out)
        s.send_pose()
        s.send_scan(ranges)
        s.send_cmd(1.0)
        spin.until(lambda: len(s.out) > n, 5.0, 'an answer')
        if f.sensors[0].worker.latest() is not None and s.out[-1].twist.linear.x == 1.0:
            break
    m = f.sensors[0].map
    assert occupied_at(f, 4.0, 0.0) and not occupied_at(f, 2.0, 0.0), 'the wall ahead, seen through before it'
    cells = m.occupied_centres(0.0, 0.0, 10.0)
    assert len(cells) == int(np.count_nonzero(m.occupied)) >= 20
    # only the wall's returns marked (each with the slack of its pose's gap to the scan's stamp): cells near the arc
    assert np.all(np.abs(np.hypot(*cells.T) - 4.0) < 0.5) and np.all(np.abs(np.arctan2(cells[:, 1], cells[:, 0])) < 0.4)
    assert s.out[-1].twist.linear.x == 1.0, 'the planner\'s speed passed'
    assert s.out[-1].header.frame_id == 'base_link'
    # looked, nothing seen (no return in range): fresh; +inf clears nothing (inf_is_valid false): the wall stays
    t = f.filters[0].detections.t
    s.send_scan(np.full(360, np.inf))
    spin.until(lambda: f.filters[0].detections.t > t, 5.0, 'an empty scan taken')
    assert occupied_at(f, 4.0, 0.0)
    # a scan whose geometry is not finite: refused, logged; blind at detections_timeout, failing safe, said
    n = len(s.states)
    bad = LaserScan()
    bad.header.frame_id, bad.header.stamp, bad.angle_min, bad.angle_increment = 'laser', s.stamp(), math.nan, 0.1
    bad.range_max, bad.ranges = 10.0, [1.0] * 10
    for _ in range(40):
        if any(st.get('action') == 'fail_safe' for st in s.states[n:]):
            break
        s.det.publish(bad)
        s.send_pose()
        s.send_cmd(1.0)
        spin.until(lambda: len(s.states) > n or s.out, 2.0, 'a decision')
        spin.spin_for(0.02)        # (the refusals come on; the filter goes blind at 0.3 s)
    new_state(spin, s, n, 'fail safe on bad scans', action='fail_safe')
    st = next(st for st in s.states[n:] if st.get('action') == 'fail_safe')
    assert st['reason'].startswith('stopped: blind for') and 'angle_min' in st['reason'], st['reason']
    spin.until(lambda: s.rosout.has('safety_filter', 'scan refused', 'angle_min'), 10.0, 'the log line')
    assert occupied_at(f, 4.0, 0.0), 'what was seen stays'


def test_a_costmap_is_one_more_detections_type(rig):
    """nav_msgs/OccupancyGrid (Nav2's local costmap) on detections: its lethal cells go into the local
    map, its inscribed (99) and free ones do not, its unknown (-1) leave the map as it was; a robot 0.5 m
    before a lethal row, its planner driving at it, is turned away by the map's value, the reason naming it."""
    from nav_msgs.msg import OccupancyGrid
    f, s, spin = rig('/costmap_robot', OccupancyGrid, detections_type='occupancy_grid', speed=0.5, robot_radius=0.2,
                     time_before_collision=0.5, frame_id='map')
    spin.until(lambda: matched(s.odom, s.det, s.cmd, *s.subs), 15.0, 'the filter to match')
    g = OccupancyGrid()
    g.header.frame_id = 'map'
    g.info.resolution, g.info.width, g.info.height = 0.1, 40, 40
    g.info.origin.position.x, g.info.origin.position.y, g.info.origin.orientation.w = -2.0, -2.0, 1.0
    data = np.zeros((40, 40), dtype=np.int8)          # rows are y, columns x
    data[:, 27] = 100                                  # a lethal row at x = 0.7 .. 0.8
    data[:, 26] = 99                                   # inscribed: not an obstacle here
    data[:5, :5] = -1
    g.data = data.reshape(-1).tolist()
    deadline = time.monotonic() + 30.0
    out = None
    while time.monotonic() < deadline:
        n = len(s.out)
        g.header.stamp = s.stamp()
        s.send_pose()
        s.det.publish(g)
        s.send_cmd(0.5)
        spin.until(lambda: len(s.out) > n, 5.0, 'an answer')
        out = s.out[-1]
        if f.sensors[0].worker.latest() is not None and s.states and s.states[-1]['action'] != 'fail_safe':
            break
    cells = f.sensors[0].map.occupied_centres
    assert len(cells(0.725, 0.025, 0.03)) and not len(cells(0.625, 0.025, 0.03)), 'lethal cells only'
    st = s.states[-1]
    # the robot's rim 0.5 m from the lethal cells, its planner driving straight at them: the map's value turns it
    # away (or the cut slows it), naming the obstacle
    assert st['action'] == 'override' or st['reason'].startswith(('slowing to', 'stopped, turning')), st['reason']
    assert out.twist.angular.z != 0.0 or out.twist.linear.x < 0.5
    assert 'an obstacle 0.4' in st['reason'] and st.get('view', '').startswith('grid') and st['source'] == 'map'


def test_a_pose_of_another_clock_fails_safe_with_an_error(rig):
    f, s, spin = rig('/clock_robot')
    spin.until(lambda: matched(s.odom, s.det, s.cmd, *s.subs), 15.0, 'the filter to match')
    from builtin_interfaces.msg import Time
    n = len(s.states)
    s.send_pose(stamp=Time(sec=100))
    s.send_scan(np.full(360, np.inf))
    s.send_cmd(1.0)
    new_state(spin, s, n, 'fail safe', action='fail_safe')
    spin.until(lambda: s.rosout.has('safety_filter', 'pose rejected', 'another clock'), 10.0, 'the ERROR')
    # a pose in another frame: refused too
    s.send_pose(frame='odom')
    spin.until(lambda: "expected 'map'" in f.filters[0].pose.rejected, 10.0, 'the wrong frame refused')


def test_clouds_malformed_or_huge_are_refused_with_bounded_work(rig):
    f, s, spin = rig('/cloud_robot', PointCloud2, detections_type='point_cloud2', max_sensor_points=200_000)
    spin.until(lambda: matched(s.odom, s.det, s.cmd, *s.subs), 15.0, 'the filter to match')
    rng = np.random.default_rng(0)
    xy = rng.uniform(-4, 4, (100_000, 2))
    for dtype in ('<f4', '>f8'):               # float32 little-endian, float64 big-endian
        before = f.filters[0].detections.t
        s.send_pose()
        s.det.publish(xy_cloud(_header(s), xy, dtype))
        spin.until(lambda: f.filters[0].detections.t > before and not f.filters[0].detections.refused, 15.0,
                   f'a {dtype} cloud of 100k points')
        assert int(np.count_nonzero(f.sensors[0].map.occupied)) > 100
    bad = xy_cloud(_header(s), xy[:10])
    bad.data = bytes(bad.data)[:50]            # shorter than its points
    s.det.publish(bad)
    spin.until(lambda: 'data' in f.filters[0].detections.refused, 10.0, 'a malformed cloud refused')
    spin.until(lambda: s.rosout.has('safety_filter', 'cloud refused', 'data'), 10.0, 'and logged')
    huge = xy_cloud(_header(s), np.zeros((1, 2)))
    huge.width = 10_000_000                    # claims more points than max_sensor_points: refused unread
    s.det.publish(huge)
    spin.until(lambda: 'max_points' in f.filters[0].detections.refused, 10.0, 'a huge cloud refused')
    spin.until(lambda: s.rosout.has('safety_filter', 'cloud refused', '10000000'), 10.0, 'said with its size')


def _header(s):
    from std_msgs.msg import Header
    return Header(frame_id='lidar', stamp=s.stamp())


def test_diagnostics_and_a_foreign_type_on_an_input(rig):
    f, s, spin = rig('/diag_robot')
    ns = f.namespaces[0]
    import rclpy
    ctx = rclpy.Context()                   # a participant of its own: one takes one type per topic
    rclpy.init(context=ctx)
    other = Node('twist_planner', context=ctx)
    wrong = other.create_publisher(Twist, f'{ns}/cmd_vel_nav', rosmsg.QOS_STREAM)
    spin.until(lambda: any(st.name.endswith(ns) for a in s.diagnostics for st in a.status), 15.0,
               '/diagnostics')
    spin.until(lambda: s.rosout.has('safety_filter', 'geometry_msgs/msg/Twist', 'geometry_msgs/msg/TwistStamped'),
               15.0, 'the WARN naming both types')
    ours = [st for a in s.diagnostics for st in a.status if st.name.endswith(ns)]
    assert ours[-1].level[0] >= DiagnosticStatus.WARN[0]
    other.destroy_publisher(wrong)
    other.destroy_node()
    ctx.try_shutdown()


def test_the_managed_filter_publishes_only_while_active(ros_context):
    ns = '/managed_robot'
    f = filter_node(ros_context, ns, managed=True)
    s = Stack(ros_context, ns)
    spin = Spinner(ros_context, f, s.node)
    change = s.node.create_client(ChangeState, f'{ns}/safety_filter/change_state')
    get = s.node.create_client(GetState, f'{ns}/safety_filter/get_state')

    def call(client, request):
        spin.until(client.service_is_ready, 15.0, client.srv_name)
        future = client.call_async(request)
        spin.until(future.done, 30.0, f'{client.srv_name} to answer')
        return future.result()

    def transition(tid):
        assert call(change, ChangeState.Request(transition=Transition(id=tid))).success

    def label():
        return call(get, GetState.Request()).current_state.label
    try:
        assert label() == 'unconfigured'
        transition(Transition.TRANSITION_CONFIGURE)
        assert label() == 'inactive'
        spin.until(lambda: matched(s.odom, s.det, s.cmd), 15.0, 'the configured filter to subscribe')
        for _ in range(5):
            s.send_pose()
            s.send_scan(np.full(360, np.inf))
            s.send_cmd(1.0)
            spin.until(lambda: f.filters[0].pose.value is not None, 5.0, 'inputs taken while inactive')
        assert f.decisions == 0 and not s.out, 'inactive: no cmd_vel'
        transition(Transition.TRANSITION_ACTIVATE)
        assert label() == 'active'
        spin.until(lambda: len(s.out) >= 3, 10.0, 'cmd_vel once active')
        transition(Transition.TRANSITION_DEACTIVATE)
        n = f.decisions
        s.send_cmd(1.0)
        spin.until(lambda: f.filters[0].command.t > 0, 5.0, 'a command taken while inactive')
        assert f.decisions == n
        transition(Transition.TRANSITION_CLEANUP)
        assert label() == 'unconfigured'
        spin.until(lambda: s.cmd.get_subscription_count() == 0, 10.0, 'subscriptions gone on cleanup')
        transition(Transition.TRANSITION_CONFIGURE)       # configured again: the parameters read again
        assert label() == 'inactive'
    finally:
        spin.shutdown()
        f.close()
        f.destroy_node()
        s.node.destroy_node()


def test_the_managed_fleet_filter_says_each_robot_on_diagnostics_once_configured(ros_context):
    from supersafe_ros.nodes.fleet_safety_filter_node import ManagedFleetSafetyFilterNode
    f = ManagedFleetSafetyFilterNode(context=ros_context, namespace='/fleet_m', parameter_overrides=params(
        robots=['fm_0', 'fm_1'], batched_topics=False, rate=20.0))
    watcher = Node('fleet_watcher', context=ros_context)
    arrays, out = [], []
    watcher.create_subscription(DiagnosticArray, '/diagnostics', arrays.append, rosmsg.QOS_EVERY_SAMPLE)
    # (robots resolved as topic names are: in the node's namespace)
    cmd = watcher.create_subscription(Twist, '/fleet_m/fm_0/cmd_vel', out.append, rosmsg.QOS_EVERY_SAMPLE)
    spin = Spinner(ros_context, f, watcher)
    change = watcher.create_client(ChangeState, '/fleet_m/fleet_safety_filter/change_state')

    def transition(tid):
        spin.until(change.service_is_ready, 15.0, 'change_state')
        future = change.call_async(ChangeState.Request(transition=Transition(id=tid)))
        spin.until(future.done, 60.0, 'the transition')
        assert future.result().success

    def ours(since=0):
        return [st for a in arrays[since:] for st in a.status if st.name.startswith('/fleet_m/fleet_safety_filter')]
    try:
        # unconfigured: the node's own WARN (robots are known once configured)
        spin.until(lambda: any(st.message.startswith('inactive (lifecycle state unconfigured)') for st in ours()),
                   15.0, 'the unconfigured node\'s WARN')
        assert {(st.level, st.hardware_id) for st in ours()} == {(DiagnosticStatus.WARN, '/fleet_m')}
        transition(Transition.TRANSITION_CONFIGURE)
        configured = len(arrays)
        spin.until(lambda: cmd.get_publisher_count() > 0, 15.0, 'the configured fleet to make its topics')

        def inactive():        # (an array sent before the configure may still come after it)
            return [st for st in ours(configured) if st.message.startswith('inactive (lifecycle state inactive)')]
        spin.until(lambda: {st.hardware_id for st in inactive()} == {'/fleet_m/fm_0', '/fleet_m/fm_1'}, 15.0,
                   'a status per robot')
        assert not out, 'inactive: no cmd_vel'
        assert all(st.level == DiagnosticStatus.WARN for st in inactive())
        transition(Transition.TRANSITION_ACTIVATE)
        spin.until(lambda: len(out) >= 3, 15.0, 'cmd_vel once active')
        assert out[-1].linear.x == 0.0 or out[-1].angular.z != 0.0, 'failing safe: no input yet'
        n = len(arrays)
        spin.until(lambda: any(st.level[0] == DiagnosticStatus.ERROR[0] and 'no pose' in st.message
                               for a in arrays[n:] for st in a.status), 15.0, 'ERROR: no input yet')
    finally:
        spin.shutdown()
        f.close()
        f.destroy_node()
        watcher.destroy_node()


def test_a_scan_filter_without_time_before_collision_warns(ros_context):
    """A scan's discs change every message: without the speed cut nothing stops the robot before
    what the scan saw, and the node says so at start-up (the Nav2 example config sets it)."""
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    watcher = Node('rosout_watcher', context=ros_context)
    logs = []
    latched = QoSProfile(depth=1000, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         reliability=ReliabilityPolicy.RELIABLE)      # /rosout keeps its history for late joiners
    watcher.create_subscription(Log, '/rosout', logs.append, latched)
    made = [filter_node(ros_context, '/no_cut_robot'),
            filter_node(ros_context, '/cut_robot', time_before_collision=0.5)]
    spin = Spinner(ros_context, watcher, *made)
    try:
        def said(robot, words=''):       # logger names: <namespace>.<node>
            return any(m.name.startswith(robot + '.') and words in m.msg for m in logs)
        spin.until(lambda: said('no_cut_robot', 'time_before_collision is 0'), 15.0,
                   'the WARN of the filter without the speed cut')
        spin.until(lambda: said('cut_robot'), 15.0, 'a log line of the filter with the speed cut')
        assert not said('cut_robot', 'time_before_collision is 0'), 'the filter with time_before_collision warned'
    finally:
        spin.shutdown()
        for f in made:
            f.close()
            f.destroy_node()
        watcher.destroy_node()
