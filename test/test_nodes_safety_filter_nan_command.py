"""safety_filter_node on a planner that sends NaN turn rates (issue 29): what the WARN says
is what the filter sends. The previous command stays in force until it is cmd_timeout
old; after that the filter sends a zero twist (planner silent), and the WARN says so."""
import math

import pytest
from rclpy.parameter import Parameter

from supersafe_ros.nodes.safety_filter_node import SafetyFilterNode
from supersafe_ros.ros_io import rosmsg

from graph_support import Rosout, Spinner, matched
from safety_filter_support import NS, SHAPE, Driver, state

pytestmark = pytest.mark.ros   # rclpy nodes in this process

CMD_TIMEOUT = 0.3


def test_a_nan_turn_rate_keeps_the_previous_command_until_cmd_timeout_then_a_zero_twist(ros_context):
    params = [Parameter('standard_shape', value=SHAPE), Parameter('cmd_timeout', value=CMD_TIMEOUT),
              Parameter('state_rate', value=100.0)]
    node = SafetyFilterNode(namespace=NS, context=ros_context, parameter_overrides=params)
    driver = Driver(ros_context)
    rosout = Rosout(driver.node)
    spin = Spinner(ros_context, node, driver.node)
    try:
        spin.until(lambda: matched(*driver.endpoints(), rosout.sub), 10.0, 'filter topics to match')
        far = state(-7.5, 7.0, 0.0)
        driver.send(pose=far)
        spin.until(lambda: driver.states, 10.0, 'the first decision')
        driver.send(pose=far, detections=None, cmd=0.3)
        spin.until(lambda: driver.states and driver.last_state().get('cmd_angular_z') == '0.3', 10.0,
                   'the planner\'s 0.3 passed')
        # from now on the planner sends only NaN; poses keep coming
        outputs = []
        for k in range(400):
            n = len(driver.states)
            driver.send(pose=far, detections=None)
            bad = rosmsg.turn_rate_to_twist(0.0, 3.0)
            bad.angular.z = math.nan
            driver.cmd.publish(bad)
            spin.until(lambda: len(driver.states) > n, 10.0, 'a decision')
            st = driver.last_state()
            outputs.append((float(st['cmd_angular_z']), st['reason']))
            if 'planner silent' in st['reason']:
                break
        else:
            raise AssertionError(f'no zero twist after {len(outputs)} NaN commands: {outputs[-3:]}')
        # the WARN says what happens: the previous command, then a zero twist after cmd_timeout
        spin.until(lambda: rosout.has('safety_filter', 'cmd_vel_nav rejected', 'not finite'), 10.0, 'the WARN')
        warn = next(m for m in rosout.logs if 'cmd_vel_nav rejected' in m.msg)
        assert warn.level == 30 and 'keeping the previous command' not in warn.msg
        assert f'cmd_timeout ({CMD_TIMEOUT:g} s) old, then a zero twist goes out' in warn.msg, warn.msg
        assert outputs[-1][0] == 0.0 and 'zero command' in outputs[-1][1]
        spin.until(lambda: driver.out and driver.out[-1].angular.z == 0.0, 10.0, 'the zero twist')
        assert driver.out[-1].linear.x == 0.0                      # a zero twist, linear.x too
        assert outputs[0][0] == 0.3                               # until then, the previous command
    finally:
        spin.shutdown()
        node.destroy_node()
        driver.node.destroy_node()
