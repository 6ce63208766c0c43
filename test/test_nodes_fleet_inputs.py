"""A fleet robot takes what a lone robot takes: Odometry (or PoseWithCovarianceStamped) poses,
MarkerArray discs, TwistStamped commands both ways, no sensor at all (require_detections false),
on the same topics of the same types as safety_filter_node; the same behaviour, run on both
nodes; and a fleet node of one robot shows on the graph (nodes, topics, parameters) exactly what a
single filter with the same parameters shows, for every pose_type and detections_type."""
import pytest

from diagnostic_msgs.msg import DiagnosticStatus
from std_msgs.msg import Empty
from geometry_msgs.msg import PoseWithCovarianceStamped, TwistStamped
from nav_msgs.msg import Odometry
from visualization_msgs.msg import MarkerArray

from supersafe_ros.nodes.fleet_safety_filter_node import FleetSafetyFilterNode
from supersafe_ros.nodes.safety_filter_node import SafetyFilterNode
from supersafe_ros.ros_io import rosmsg

from graph_support import FilterRigs, Spinner, matched, params
from sensor_graph_support import obstacle_markers

DISC = (4.0, -2.0, 1.2)                 # a marker disc of its own radius (not the node's radius 1.8)
FAR = (-3.5, 5.0, 0.0)                  # clear: the planner's command passes
INTO = (DISC[0] - 2.6, DISC[1] + 0.4, 0.0)   # heading at the disc, left of its centre: the filter turns left
# long timeouts: no test here waits for an input to go stale (a busy machine reads replies late)
QUIET = dict(pose_timeout=30.0, detections_timeout=30.0, cmd_timeout=30.0, hold_timeout=30.0, rate=20.0,
             state_rate=100.0, standard_shape=[41, 41, 24])


def make_filter(ctx, kind, ns, **types):
    """safety_filter_node in ``ns``, or a fleet node (in /) of the one robot ``ns``."""
    if kind == 'single':
        return SafetyFilterNode(context=ctx, namespace=ns, parameter_overrides=params(
            level_set_markers=False, direct_take=False, **QUIET, **types))
    return FleetSafetyFilterNode(context=ctx, node_name=f'fleet_{ns.strip("/")}', parameter_overrides=params(
        robots=[ns.strip('/')], batched_topics=False, **QUIET, **types))


class Stack:
    """A robot's stack: Odometry or PoseWithCovarianceStamped poses, MarkerArray detections,
    TwistStamped commands; it records the filter's TwistStamped cmd_vel and states."""

    def __init__(self, ctx, ns, pose_msg=Odometry, detections=True):
        from rclpy.node import Node
        self.node = n = Node(f'stack_{ns.strip("/")}', namespace=ns, context=ctx)
        self.pose_msg = pose_msg
        self.pose = n.create_publisher(pose_msg, 'pose', rosmsg.QOS_STREAM)
        self.det = n.create_publisher(MarkerArray, 'detections', rosmsg.QOS_STREAM) if detections else None
        self.cmd = n.create_publisher(TwistStamped, 'cmd_vel_nav', rosmsg.QOS_STREAM)
        self.out, self.states = [], []
        self.subs = [n.create_subscription(TwistStamped, 'cmd_vel', self.out.append, rosmsg.QOS_STREAM),
                     n.create_subscription(DiagnosticStatus, 'safety_filter/state',
                                           lambda m: self.states.append(rosmsg.diagnostic_values(m)),
                                           rosmsg.QOS_STREAM)]

    def endpoints(self):
        return [e for e in (self.pose, self.det, self.cmd, *self.subs) if e is not None]

    def send_pose(self, state, frame='map'):
        p = rosmsg.state_to_pose(state, frame=frame)
        m = self.pose_msg()
        m.header.frame_id, m.header.stamp = frame, self.node.get_clock().now().to_msg()
        target = m.pose.pose
        target.position, target.orientation = p.pose.position, p.pose.orientation
        self.pose.publish(m)

    def send_cmd(self, omega, linear=3.0, sec=7, frame='base_link'):
        m = TwistStamped()
        m.header.frame_id, m.header.stamp.sec = frame, sec
        m.twist.linear.x, m.twist.angular.z = linear, omega
        self.cmd.publish(m)

    def newest(self):
        return self.states[-1] if self.states else {}


@pytest.fixture
def rig(ros_context):
    rigs = FilterRigs(ros_context)

    def make(kind, ns, pose_msg=Odometry, detections=True, **types):
        f = make_filter(ros_context, kind, ns, cmd_vel_stamped=True, **types)
        s = Stack(ros_context, ns, pose_msg, detections)
        spin = rigs.add(f, s.node)
        spin.until(lambda: matched(*s.endpoints()), 15.0, f'{ns} topics to match')
        return f, s, spin
    yield make
    rigs.close()


@pytest.mark.ros
@pytest.mark.parametrize('kind', ['single', 'fleet'])
def test_odometry_markers_and_stamped_commands_are_judged_alike_on_both_nodes(rig, kind):
    ns = f'/in_{kind}'
    f, s, spin = rig(kind, ns, pose_type='odometry', detections_type='marker_array')
    s.det.publish(obstacle_markers([DISC]))
    s.send_cmd(0.25)
    s.send_pose(FAR)
    spin.until(lambda: s.newest().get('action') == 'pass', 15.0, f'{ns} passing')
    assert float(s.newest()['cmd_angular_z']) == pytest.approx(0.25)
    spin.until(lambda: s.out and s.out[-1].twist.angular.z == pytest.approx(0.25), 10.0, 'the pass on cmd_vel')
    # its filter can judge: safety_filter/ready, latched (a subscriber that comes now still gets it)
    ready = []
    s.subs.append(s.node.create_subscription(Empty, 'safety_filter/ready', ready.append, rosmsg.QOS_LATCHED))
    spin.until(lambda: ready, 15.0, f'{ns} ready')
    judged = s.out[-1]
    assert (judged.header.frame_id, judged.header.stamp.sec) == ('base_link', 7)     # the planner's header
    # heading at the disc of its own radius: the avoid turn, left (the disc is to the right)
    s.send_cmd(-0.5, sec=8)
    s.send_pose(INTO)
    spin.until(lambda: s.newest().get('action') == 'override', 15.0, f'{ns} overriding')
    assert s.newest()['obstacle_index'] == '0'
    spin.until(lambda: s.out[-1].twist.angular.z == pytest.approx(1.0), 10.0, 'the avoid turn on cmd_vel')
    # a marker in another frame: refused, failing safe, a zero twist stamped by the node's clock
    s.det.publish(obstacle_markers([DISC], frame='odom'))
    s.send_pose(FAR)
    spin.until(lambda: s.newest().get('action') == 'fail_safe', 15.0, f'{ns} failing safe')
    assert 'frame' in s.newest()['reason']
    spin.until(lambda: (s.out[-1].twist.linear.x, s.out[-1].twist.angular.z) == (0.0, 0.0)
               and s.out[-1].header.stamp.sec != 8, 10.0, 'a zero twist of the node\'s own stamp')


@pytest.mark.ros
@pytest.mark.parametrize('kind', ['single', 'fleet'])
def test_a_robot_without_a_sensor_is_judged_with_no_obstacle_on_both_nodes(rig, kind):
    ns = f'/blind_{kind}'
    f, s, spin = rig(kind, ns, PoseWithCovarianceStamped, detections=False, pose_type='pose_with_covariance',
                     require_detections=False)
    s.send_cmd(-0.3)
    s.send_pose(INTO)       # no disc known: what would be an override passes
    spin.until(lambda: s.newest().get('action') == 'pass', 15.0, f'{ns} passing without detections')
    assert float(s.newest()['cmd_angular_z']) == pytest.approx(-0.3)
    names = {name for name, _ in s.node.get_topic_names_and_types()}
    assert f'{ns}/cmd_vel' in names
    assert not s.node.get_subscriptions_info_by_topic(f'{ns}/detections')     # nobody listens there


def endpoint_types(node, ns):
    """{(topic, 'sub' or 'pub'): sorted (type, node) pairs} of the topics under ``ns`` on the graph."""
    out = {}
    for topic, _ in node.get_topic_names_and_types():
        if not topic.startswith(ns + '/'):
            continue
        for side, infos in (('sub', node.get_subscriptions_info_by_topic(topic)),
                            ('pub', node.get_publishers_info_by_topic(topic))):
            theirs = [i for i in infos if not i.node_name.startswith('probe')]
            if theirs:
                out[(topic, side)] = sorted({(i.topic_type, f'{i.node_namespace}/{i.node_name}') for i in theirs})
    return out


TYPES = [
    dict(pose_type='pose_stamped', detections_type='pose_array', cmd_vel_stamped=False),
    dict(pose_type='odometry', detections_type='marker_array', cmd_vel_stamped=True),
    dict(pose_type='pose_with_covariance', detections_type='pose_array', cmd_vel_stamped=True),
    dict(pose_type='odometry', detections_type='pose_array', cmd_vel_stamped=False, require_detections=False),
    dict(pose_type='odometry', detections_type='laser_scan', cmd_vel_stamped=True, time_before_collision=0.5),
    dict(pose_type='pose_with_covariance', detections_type='point_cloud2', cmd_vel_stamped=True,
         time_before_collision=0.5),
    dict(pose_type='pose_stamped', detections_type='occupancy_grid', cmd_vel_stamped=False,
         time_before_collision=0.5),
]


@pytest.mark.ros
@pytest.mark.parametrize('types', TYPES, ids=['defaults', 'nav2', 'amcl', 'no_sensor', 'scan', 'cloud', 'costmap'])
def test_a_fleet_of_one_shows_the_graph_of_a_single_filter(ros_context, types):
    """`ros2 node list`, `ros2 topic info -v` and `ros2 param list`/`get`: the same for
    fleet_safety_filter_node of one robot as for safety_filter_node with the same parameters (the
    fleet node given the single one's name; and, in its own name, the same topics and types for the
    robot it names); for every pose_type and detections_type, range sensors and costmaps included."""
    from rclpy.node import Node
    probe = Node('probe_graph', context=ros_context)
    seen = {}
    quiet = dict(level_set_markers=False, **QUIET, **types)
    made = {'single': lambda ns: SafetyFilterNode(context=ros_context, namespace=ns,
                                                  parameter_overrides=params(**quiet)),
            'fleet': lambda ns: FleetSafetyFilterNode(context=ros_context, node_name='safety_filter', namespace=ns,
                                                      parameter_overrides=params(**quiet)),
            'fleet_named': lambda ns: FleetSafetyFilterNode(context=ros_context, node_name='fleet_graph',
                                                            parameter_overrides=params(robots=[ns], **quiet))}
    for kind, make in made.items():
        ns = f'/graph_{types["detections_type"]}'
        f = make(ns)
        spin = Spinner(ros_context, f, probe)
        try:
            want = {f'{ns}/{t}' for t in ('pose', 'cmd_vel_nav', 'cmd_vel', 'safety_filter/state')}
            want |= {f'{ns}/detections'} if types.get('require_detections', True) else {f'{ns}/safety_filter/ready'}
            spin.until(lambda: want <= {t for t, _ in endpoint_types(probe, ns)}, 15.0, f'{kind} topics on the graph')
            nodes = sorted(f'{n_ns.rstrip("/")}/{n}' for n, n_ns in probe.get_node_names_and_namespaces()
                           if not n.startswith('probe'))
            seen[kind] = dict(topics=endpoint_types(probe, '/'), nodes=nodes,
                              params={name: f.get_parameter(name).value for name in f._parameters})
        finally:
            spin.shutdown()
            f.close()
            f.destroy_node()
    probe.destroy_node()
    single, fleet, named = seen['single'], seen['fleet'], seen['fleet_named']
    assert fleet == single
    assert f'/graph_{types["detections_type"]}/safety_filter' in single['nodes']
    # in its own name: the robot's topics of the same types (served by the fleet node's helper)
    strip = lambda topics: {k: sorted({t for t, _ in v}) for k, v in topics.items()  # noqa: E731
                            if k[0].startswith('/graph_') and '/safety_filter/level_set' not in k[0]}
    assert strip(named['topics']) == strip(single['topics'])
    assert set(named['params']) == set(single['params'])
    assert {k for k, v in named['params'].items() if v != single['params'][k]} == {'robots'}


@pytest.mark.ros
def test_a_fleet_decided_on_each_input_answers_each_robots_command_at_once(ros_context):
    """decide_on input for a fleet: each command of a robot is answered at once, for that robot alone
    (its answer carries the command's stamp), on the thread of its own (direct_take); a robot whose
    planner is silent still gets the watchdog's commands."""
    rigs, b = FilterRigs(ros_context), None
    try:
        f = FleetSafetyFilterNode(context=ros_context, node_name='fleet_on_input', parameter_overrides=params(
            robots=['on_input_a', 'on_input_b'], decide_on='input', cmd_vel_stamped=True, pose_type='odometry',
            detections_type='marker_array', level_set_markers=False, **QUIET))
        a, b = Stack(ros_context, '/on_input_a'), Stack(ros_context, '/on_input_b')
        spin = rigs.add(f, a.node)
        spin.add(b.node)
        spin.until(lambda: matched(*a.endpoints(), *b.endpoints()), 15.0, 'both robots\' topics to match')
        assert f.mode == 'input' and f.direct is not None
        a.det.publish(obstacle_markers([DISC]))
        a.send_pose(FAR)
        for sec in range(20, 26):
            n = len(a.out)
            a.send_cmd(0.25, sec=sec)
            spin.until(lambda: any(m.header.stamp.sec == sec for m in a.out[n:]), 10.0, f'the answer to command {sec}')
        answered = [m for m in a.out if 20 <= m.header.stamp.sec <= 25]     # (the watchdog's: the clock's stamp)
        assert {m.header.stamp.sec for m in answered} == set(range(20, 26))
        assert all(m.twist.angular.z == pytest.approx(0.25) for m in answered)
        spin.until(lambda: len(b.out) >= 3, 10.0, 'the silent robot\'s watchdog')
        assert all((m.twist.linear.x, m.twist.angular.z) == (0.0, 0.0) for m in b.out)   # no input: it stops
    finally:
        rigs.close()
        if b is not None:
            b.node.destroy_node()
