"""safety_filter_node on a planner that sends NaN turn rates (issues 29 and 36): what the WARN says
is what the filter sends. A robot that can stop stops at once (a zero twist) until a valid command
comes; the study's constant-speed robot keeps the previous command until it is cmd_timeout old, then
drives straight on (planner silent)."""
import math

import pytest
from rclpy.parameter import Parameter

from supersafe_ros.nodes.safety_filter_node import SafetyFilterNode
from supersafe_ros.ros_io import rosmsg

from graph_support import Rosout, Spinner, matched
from safety_filter_support import NS, SHAPE, Driver, state

pytestmark = pytest.mark.ros   # rclpy nodes in this process

CMD_TIMEOUT = 0.3


def nan_command(driver):
    bad = rosmsg.turn_rate_to_twist(0.0, 3.0)
    bad.angular.z = math.nan
    driver.cmd.publish(bad)


@pytest.mark.parametrize('mode', ['stop', 'stop_turn'])
def test_a_nan_turn_rate_stops_a_robot_that_can_stop_and_is_said(ros_context, mode):
    params = [Parameter('standard_shape', value=SHAPE), Parameter('cmd_timeout', value=CMD_TIMEOUT),
              Parameter('state_rate', value=100.0), Parameter('fail_safe_command', value=mode)]
    node = SafetyFilterNode(namespace=f'{NS}_{mode}', context=ros_context, parameter_overrides=params)
    driver = Driver(ros_context, ns=f'{NS}_{mode}')
    rosout = Rosout(driver.node)
    spin = Spinner(ros_context, node, driver.node)
    try:
        spin.until(lambda: matched(*driver.endpoints(), rosout.sub), 10.0, 'filter topics to match')
        far = state(-7.5, 7.0, 0.0)
        driver.send(pose=far)
        spin.until(lambda: driver.states, 10.0, 'the first decision')
        driver.send(pose=far, cmd=0.3)
        spin.until(lambda: driver.states and driver.last_state().get('cmd_angular_z') == '0.3', 10.0,
                   'the planner\'s 0.3 passed')
        # from now on the planner sends only NaN; poses and detections keep coming
        outputs = []
        for k in range(400):
            n = len(driver.states)
            driver.send(pose=far)
            nan_command(driver)
            spin.until(lambda: len(driver.states) > n, 10.0, 'a decision')
            st = driver.last_state()
            if mode == 'stop' and not outputs and st['reason'].startswith("passing the planner's command"):
                continue    # the watchdog decided before the NaN was taken (a busy machine): the 0.3 still
            outputs.append((float(st['cmd_angular_z']), st['reason']))
            if mode == 'stop' or 'planner silent' in st['reason']:
                break
        else:
            raise AssertionError(f'no planner silent after {len(outputs)} NaN commands: {outputs[-3:]}')
        spin.until(lambda: rosout.has('safety_filter', 'cmd_vel_nav rejected', 'not finite'), 10.0, 'the WARN')
        warn = next(m for m in rosout.logs if 'cmd_vel_nav rejected' in m.msg)
        assert warn.level == 30
        if mode == 'stop':      # at once: a zero twist, and the WARN and the state say so
            assert 'the robot stops until a valid command comes' in warn.msg, warn.msg
            assert outputs[0][0] == 0.0 and outputs[0][1].startswith('stopped: planner command rejected: not finite')
            assert driver.last_state()['action'] == 'fail_safe'
            spin.until(lambda: driver.out and driver.out[-1].angular.z == 0.0, 10.0, 'the zero twist')
            assert driver.out[-1].linear.x == 0.0
            driver.send(pose=far, cmd=0.2)      # a valid command again: filtering again
            spin.until(lambda: driver.last_state().get('cmd_angular_z') == '0.2', 10.0, 'the planner\'s 0.2 passed')
        else:                   # the previous command until cmd_timeout, then straight on (it cannot stop)
            assert f'the previous command kept until it is cmd_timeout ({CMD_TIMEOUT:g} s) old' in warn.msg, warn.msg
            assert outputs[0][0] == 0.3 and outputs[-1][0] == 0.0 and outputs[-1][1].startswith('driving straight on')
    finally:
        spin.shutdown()
        node.destroy_node()
        driver.node.destroy_node()
