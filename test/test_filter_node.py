"""safety_filter_node at topic level: a real node in-process, driven by a test node."""
import math

import numpy as np
import pytest
from rclpy.parameter import Parameter

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Pose, PoseArray, PoseStamped, Twist
from std_msgs.msg import Float32MultiArray

from supersafe_ros.ros_io import rosmsg
from supersafe_ros.nodes.safety_filter_node import VALUE_FUNCTION_TOPIC, SafetyFilterNode
from supersafe_ros.ros_io.vfmsg import value_function_to_msg

from filter_learner_support import Spinner, matched, ros_context  # noqa: F401  (fixture)

NS = '/robot_0'
OBSTACLE = (4.0, -2.0)
SHAPE = [41, 41, 24]


def state(rel_x, rel_y, theta):
    return (OBSTACLE[0] + rel_x, OBSTACLE[1] + rel_y, theta)


class Driver:
    """Plays robot, sensor, planner and learner for one filter; records its outputs."""

    def __init__(self, ctx):
        from rclpy.node import Node
        self.node = Node('filter_test_driver', namespace=NS, context=ctx)
        n = self.node
        self.pose = n.create_publisher(PoseStamped, 'pose', rosmsg.QOS_STREAM)
        self.det = n.create_publisher(PoseArray, 'detections', rosmsg.QOS_STREAM)
        self.cmd = n.create_publisher(Twist, 'cmd_vel_nav', rosmsg.QOS_STREAM)
        self.vf = n.create_publisher(Float32MultiArray, VALUE_FUNCTION_TOPIC, rosmsg.QOS_LATCHED)
        self.out, self.states = [], []
        self.out_sub = n.create_subscription(Twist, 'cmd_vel', self.out.append, rosmsg.QOS_STREAM)
        self.state_sub = n.create_subscription(DiagnosticStatus, 'safety_filter/state', self.states.append,
                                               rosmsg.QOS_STREAM)

    def endpoints(self):
        return (self.pose, self.det, self.cmd, self.vf, self.out_sub, self.state_sub)

    def send(self, pose=None, detections=(OBSTACLE,), cmd=None, frame='map'):
        if detections is not None:
            msg = PoseArray()   # built by hand: the test sends NaNs the converters refuse
            msg.header.frame_id = frame
            for x, y in np.asarray(detections, dtype=float).reshape(-1, 2):
                p = Pose()
                p.position.x, p.position.y, p.orientation.w = float(x), float(y), 1.0
                msg.poses.append(p)
            self.det.publish(msg)
        if pose is not None:
            msg = PoseStamped()
            msg.header.frame_id = frame
            msg.pose.position.x, msg.pose.position.y = float(pose[0]), float(pose[1])
            if math.isfinite(pose[2]):
                msg.pose.orientation = rosmsg.yaw_to_quaternion(pose[2])
            else:
                msg.pose.orientation.z = float('nan')
            self.pose.publish(msg)
        if cmd is not None:
            self.cmd.publish(rosmsg.turn_rate_to_twist(cmd, 3.0))

    def last_state(self):
        return rosmsg.diagnostic_values(self.states[-1]) if self.states else {}


@pytest.fixture(scope='module')
def setup(ros_context):
    params = [Parameter('standard_shape', value=SHAPE), Parameter('pose_timeout', value=0.3),
              Parameter('detections_timeout', value=0.3), Parameter('hold_timeout', value=0.6),
              Parameter('state_rate', value=100.0), Parameter('rate', value=20.0)]
    node = SafetyFilterNode(namespace=NS, context=ros_context, parameter_overrides=params)
    driver = Driver(ros_context)
    spin = Spinner(ros_context, node, driver.node)
    spin.until(lambda: matched(*driver.endpoints()), 10.0, 'filter topics to match')
    yield node, driver, spin
    spin.shutdown()
    node.destroy_node()
    driver.node.destroy_node()


def exchange(driver, spin, pose, cmd, detections=(OBSTACLE,), frame='map', want=None, timeout=3.0):
    """Send inputs, then wait for a filtered command whose state satisfies ``want``."""
    driver.out.clear()
    driver.states.clear()
    driver.send(pose=pose, detections=detections, frame=frame)
    spin.spin_for(0.05)   # inputs in before the planner's command triggers the decision
    driver.send(pose=None, detections=None, cmd=cmd)
    want = want or (lambda s: True)
    spin.until(lambda: driver.states and want(driver.last_state()), timeout, 'a filtered command')
    msg = driver.states[-1]
    st = rosmsg.diagnostic_values(msg)
    # the Twist published together with that state (same decision)
    w = float(st['cmd_angular_z'])
    spin.until(lambda: any(abs(o.angular.z - w) < 1e-5 for o in driver.out), 2.0, 'the matching Twist')
    out = [o for o in driver.out if abs(o.angular.z - w) < 1e-5][-1]
    return out, st, msg


def passing(cmd):
    """A pass of the planner's command ``cmd`` (not the watchdog's zero)."""
    return lambda s: s['action'] == 'pass' and abs(float(s['cmd_angular_z']) - cmd) < 1e-5


def test_passes_commands_far_from_obstacles(setup):
    node, driver, spin = setup
    out, st, msg = exchange(driver, spin, state(-7.5, 7.0, 0.0), 0.3, want=passing(0.3))
    assert out.angular.z == pytest.approx(0.3)
    assert msg.level == bytes([0]) and st['source'] == 'standard' and float(st['alpha']) == 0.0


@pytest.mark.parametrize('side', [1.0, -1.0])
def test_overrides_near_obstacles_turning_away(setup, side):
    node, driver, spin = setup
    out, st, msg = exchange(driver, spin, state(-3.0, 0.6 * side, 0.0), -0.4 * side,
                            want=lambda s: s['action'] == 'override')
    assert out.angular.z == pytest.approx(side * 1.0)
    assert msg.level == bytes([1]) and st['obstacle_index'] == '0'
    assert float(st['obstacle_x']) == OBSTACLE[0] and float(st['value']) <= 0.0
    # move clear again so later tests start from pass
    exchange(driver, spin, state(-7.5, 7.0, 0.0), 0.0, want=passing(0.0))


def test_stale_pose_fails_safe_on_the_watchdog(setup):
    node, driver, spin = setup
    exchange(driver, spin, state(-7.5, 7.0, 0.0), 0.3, want=passing(0.3))
    driver.out.clear()
    driver.states.clear()
    # no more poses or planner commands: the watchdog keeps publishing, first the avoid
    # control of the last state, then stop-turn
    spin.until(lambda: driver.states and 'stop-turn' in driver.last_state()['reason'], 3.0, 'stop-turn')
    assert driver.states[-1].level == bytes([2])
    assert driver.out[-1].linear.x == 0.0 and driver.out[-1].angular.z == pytest.approx(1.0)
    actions = {rosmsg.diagnostic_values(s)['action'] for s in driver.states}
    assert 'pass' in actions and 'fail_safe' in actions


@pytest.mark.parametrize('bad', ['nan_pose', 'inf_pose', 'nan_heading', 'wrong_frame', 'nan_detection'])
def test_invalid_inputs_fail_safe_and_the_node_keeps_running(setup, bad):
    node, driver, spin = setup
    exchange(driver, spin, state(-7.5, 7.0, 0.0), 0.3, want=passing(0.3))
    pose, dets, frame = state(-7.5, 7.0, 0.0), (OBSTACLE,), 'map'
    if bad == 'nan_pose':
        pose = (math.nan, 0.0, 0.0)
    elif bad == 'inf_pose':
        pose = (0.0, math.inf, 0.0)
    elif bad == 'nan_heading':
        pose = (0.0, 0.0, math.nan)
    elif bad == 'wrong_frame':
        frame = 'odom'
    elif bad == 'nan_detection':
        dets = ((math.nan, 0.0),)
    if bad == 'nan_detection' or bad == 'wrong_frame':
        out, st, msg = exchange(driver, spin, pose, 0.3, detections=dets, frame=frame,
                                want=lambda s: s['action'] == 'fail_safe')
    else:
        driver.send(detections=dets)
        out, st, msg = exchange(driver, spin, pose, 0.3, detections=None,
                                want=lambda s: s['action'] == 'fail_safe')
    assert 'rejected' in st['reason'] and out.angular.z != pytest.approx(0.3)
    # valid input again: back to passing the planner's command
    out, st, msg = exchange(driver, spin, state(-7.5, 7.0, 0.0), 0.3, want=passing(0.3))
    assert out.angular.z == pytest.approx(0.3)


def test_learned_set_replaces_the_standard_and_malformed_sets_are_ignored(setup):
    node, driver, spin = setup
    far = state(-7.5, 7.0, 0.0)
    v_far = float(exchange(driver, spin, far, 0.3, want=passing(0.3))[1]['value'])
    # a "learned" set: the standard V with mu above V at this state -> override here
    learned = value_function_to_msg(node.standard.vf, source='learned', mu=v_far + 0.5, sigma=0.2,
                                    alpha=v_far + 0.5, estimator='paper', interventions=9)
    driver.vf.publish(learned)
    spin.until(lambda: node.safe_set.source == 'learned', 5.0, 'the learned set to arrive')
    out, st, msg = exchange(driver, spin, far, 0.3, want=lambda s: s['action'] == 'override')
    assert st['source'] == 'learned' and float(st['alpha']) == pytest.approx(v_far + 0.5)
    # malformed: NaN inside, wrong sizes -> rejected, the learned set stays
    bad = value_function_to_msg(node.standard.vf, source='learned', mu=-5.0, sigma=0.0)
    bad.data[7] = float('nan')
    driver.vf.publish(bad)
    short = value_function_to_msg(node.standard.vf, source='learned', mu=-5.0, sigma=0.0)
    short.data = short.data[:100]
    driver.vf.publish(short)
    spin.spin_for(0.3)
    assert node.safe_set.source == 'learned' and node.safe_set.alpha == pytest.approx(v_far + 0.5)
    # the standard set back (as the learner publishes after a reset)
    driver.vf.publish(value_function_to_msg(node.standard.vf, source='standard', alpha=0.0))
    spin.until(lambda: node.safe_set.source == 'standard', 5.0, 'the standard set')
    out, st, msg = exchange(driver, spin, far, 0.3, want=passing(0.3))
    assert st['source'] == 'standard'
