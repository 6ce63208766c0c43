"""safety_filter_node in a lockstep graph (issue 9: every decision on the pose it is for).

A lockstepped robot acknowledges its step on the first command after its pose, and
the clock then advances. So the filter must answer each pose once, on that pose:
not on the planner's command (which may answer the pose before), not on its
watchdog; and while a cluster's union value is being solved it holds the answer.
"""
import time

import numpy as np
import pytest
from rclpy.parameter import Parameter

from supersafe_ros.filter import default_cluster_store
from supersafe_ros.filter.clusters.geometry import canonical
from supersafe_ros.nodes.safety_filter_node import SafetyFilterNode

from graph_support import Spinner, matched
from safety_filter_support import NS, SHAPE, Driver

pytestmark = pytest.mark.ros   # rclpy nodes in this process

# two discs 4.5 m apart: one cluster (rims closer than a turning diameter)
PAIR = ((4.0, -2.0), (8.5, -2.0))


@pytest.fixture(scope='module')
def setup(ros_context):
    params = [Parameter('standard_shape', value=SHAPE), Parameter('rate', value=50.0),
              Parameter('state_rate', value=100.0), Parameter('lockstep', value=True),
              Parameter('lockstep_silence', value=60.0), Parameter('cluster_hold_timeout', value=60.0),
              # a busy machine may hold the test between command and pose: nothing goes stale here
              Parameter('cmd_timeout', value=60.0), Parameter('pose_timeout', value=60.0),
              Parameter('detections_timeout', value=60.0)]
    node = SafetyFilterNode(namespace=NS, context=ros_context, parameter_overrides=params)
    # the cluster solver of this process: requests are recorded, solved only when the test says
    store = default_cluster_store(node.filters[0].config)
    asked = {}

    def request(key, centres):
        if key not in store.values and key not in store.requested:
            store.requested[key] = time.monotonic()
            asked[key] = centres
    store.request = request
    driver = Driver(ros_context)
    spin = Spinner(ros_context, node, driver.node)
    spin.until(lambda: matched(*driver.endpoints()), 10.0, 'filter topics to match')
    yield node, driver, spin, store, asked
    del store.request
    spin.shutdown()
    node.destroy_node()
    driver.node.destroy_node()


def answers_to(driver, spin, pose, detections, cmd=None, settle=0.2):
    """Send a planner command first (if any), then the pose; the commands the filter sent."""
    driver.out.clear()
    driver.states.clear()
    if cmd is not None:
        driver.send(pose=None, detections=detections, cmd=cmd)
        spin.spin_for(settle)
        assert driver.out == [], 'a planner command alone must not answer (it would ack a step)'
    driver.send(pose=pose, detections=detections)
    return driver.out


def state_of(driver, twist):
    """The state message of the decision that sent ``twist`` (the topic also repeats states)."""
    from supersafe_ros.ros_io import rosmsg
    same = [rosmsg.diagnostic_values(m) for m in driver.states]
    same = [v for v in same if abs(float(v['cmd_angular_z']) - twist.angular.z) < 1e-6]
    return same[-1] if same else {}


def test_in_lockstep_the_executor_takes_pose_and_command_whatever_direct_take_says(setup):
    """The executor reads /clock before a pose waiting with it (it calls subscriptions in the
    order made), so _clock_passed knows a pose the clock has passed; a thread of its own
    could answer such a pose and ack the newer step with it."""
    node, driver, spin, _, _ = setup
    assert node.get_parameter('direct_take').value is True and node.direct is None
    for topic in ('pose', 'detections', 'cmd_vel_nav'):
        takers = {i.node_name for i in driver.node.get_subscriptions_info_by_topic(f'{NS}/{topic}')}
        assert takers == {node.get_name()}, (topic, takers)


def test_each_pose_is_answered_once_on_that_pose(setup):
    node, driver, spin, _, _ = setup
    far = ((40.0, 40.0),)
    for k in range(3):
        out = answers_to(driver, spin, (-10.0, 0.0, 0.0), far, cmd=0.3)
        spin.until(lambda: len(out) >= 1, 5.0, 'the answer to the pose')
        spin.spin_for(0.4)          # the watchdog (50 Hz) must stay silent while poses flow
        assert len(out) == 1, f'{len(out)} commands for one pose'
        assert abs(out[0].angular.z - 0.3) < 1e-6      # the planner's command, judged on that pose
    # heading straight at a disc 1 m off its rim: the answer to that pose overrides
    out = answers_to(driver, spin, (4.0 - 2.8, -2.0, 0.0), ((4.0, -2.0),), cmd=0.0)
    spin.until(lambda: len(out) >= 1 and state_of(driver, out[0]), 5.0, 'the answer to the pose')
    st = state_of(driver, out[0])
    assert st['action'] == 'override', st
    assert abs(abs(out[0].angular.z) - 1.0) < 1e-6
    assert float(st['pose_age']) < 0.05, st


def test_the_answer_waits_for_a_clusters_value(setup):
    node, driver, spin, store, asked = setup
    # the process's store may hold this pair's value from an earlier test (a pair 4.5 m apart is
    # common): forgotten, so that the answer has a value to wait for
    key = canonical(np.array(PAIR), store.settings.key_resolution)[0]
    with store._lock:
        store.values.pop(key, None)
        store.requested.pop(key, None)
    # near the pair, heading along it: the union's value decides
    out = answers_to(driver, spin, (0.0, 1.0, 0.0), PAIR, cmd=0.0)
    spin.until(lambda: asked, 5.0, 'the cluster solve to be requested')
    spin.spin_for(0.5)
    assert out == [], 'answered while the cluster value was being solved'
    assert node.answers[0].holds >= 1
    key, centres = next(iter(asked.items()))
    store._solve(key, centres)          # the value lands
    spin.until(lambda: len(out) >= 1 and state_of(driver, out[0]), 20.0, 'the held answer')
    assert len(out) == 1
    st = state_of(driver, out[0])
    assert st['clusters_solving'] == '0', st
    assert st['source'] == 'cluster' or st['action'] == 'pass', st


def test_a_pose_the_clock_has_passed_is_not_answered(ros_context):
    """Sim time: the clock passes a step only once the robot has acknowledged it. A pose
    the clock has passed was acknowledged without this filter (a parked robot acknowledges
    by itself): answering it would acknowledge the robot's newer step with a decision on
    the older pose. Start-up in the team graph left filters 1-5 steps behind that way."""
    from geometry_msgs.msg import PoseStamped, PoseArray, Twist
    from rclpy.node import Node
    from rosgraph_msgs.msg import Clock
    from supersafe_ros.ros_io import rosmsg
    ns = '/robot_sim'
    params = [Parameter('standard_shape', value=SHAPE), Parameter('use_sim_time', value=True),
              Parameter('lockstep', value=True), Parameter('lockstep_silence', value=60.0),
              Parameter('pose_timeout', value=5.0), Parameter('detections_timeout', value=5.0)]
    node = SafetyFilterNode(namespace=ns, context=ros_context, parameter_overrides=params)
    drv = Node('lockstep_clock_driver', namespace=ns, context=ros_context)
    clock = drv.create_publisher(Clock, '/clock', rosmsg.QOS_CLOCK)
    pose = drv.create_publisher(PoseStamped, 'pose', rosmsg.QOS_STREAM)
    det = drv.create_publisher(PoseArray, 'detections', rosmsg.QOS_STREAM)
    out = []
    sub = drv.create_subscription(Twist, 'cmd_vel', out.append, rosmsg.QOS_STREAM)
    spin = Spinner(ros_context, node, drv)
    try:
        spin.until(lambda: matched(clock, pose, det, sub), 10.0, 'topics to match')

        def tick(sec):
            m = Clock()
            m.clock.sec = sec
            clock.publish(m)
            spin.until(lambda: node.get_clock().now().nanoseconds == sec * 1_000_000_000, 5.0,
                       f'the filter at sim time {sec}')

        def send_pose(sec):
            stamp = Clock().clock
            stamp.sec = sec
            det.publish(rosmsg.xy_to_posearray([(40.0, 40.0)], stamp, 'map'))
            pose.publish(rosmsg.state_to_pose((0.0, 0.0, 0.0), stamp, 'map'))

        tick(10)
        send_pose(10)
        spin.until(lambda: len(out) == 1, 5.0, 'the answer to the current pose')
        tick(12)                      # the clock went on without an answer to the pose of 11
        send_pose(11)
        spin.until(lambda: node.answers[0].poses_skipped == 1, 5.0, 'the passed pose to be skipped')
        assert len(out) == 1, 'a pose the clock had passed was answered'
        send_pose(12)
        spin.until(lambda: len(out) == 2, 5.0, 'the answer to the current pose')
        assert node.answers[0].poses_skipped == 1
    finally:
        spin.shutdown()
        node.destroy_node()
        drv.destroy_node()
