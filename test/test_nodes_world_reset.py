"""The world's study hooks at topic level: /world/reset starts a game afresh on a running
node, and the H2 measures follow the poses and each filter's reported action."""
import numpy as np
import pytest
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticStatus

from supersafe_ros.ros_io import rosmsg
from supersafe_ros.nodes.world_node import WorldNode

from graph_support import Rosout, Spinner, matched, params
from world_support import ROBOTS, Robots

pytestmark = pytest.mark.ros   # rclpy nodes in this process


@pytest.fixture(scope='module')
def rig(ros_context):
    world = WorldNode(context=ros_context, parameter_overrides=params(
        robots=ROBOTS, seed=5, n_obstacles=4, stats_heartbeat=0.05))
    driver = Node('reset_test_driver', context=ros_context)
    robots = Robots(driver)
    rosout = Rosout(driver)
    reset = driver.create_publisher(DiagnosticStatus, '/world/reset', rosmsg.QOS_EVENTS)
    state = {r: driver.create_publisher(DiagnosticStatus, f'/{r}/safety_filter/state', rosmsg.QOS_STREAM)
             for r in ROBOTS}
    spin = Spinner(ros_context, world, driver)
    spin.until(lambda: matched(*robots.endpoints(), reset, *state.values()), 10.0, 'world and driver')
    spin.until(lambda: len(robots.obstacles.centres) == 4 and robots.stats, 5.0, 'obstacles and stats')
    yield world, robots, rosout, reset, state, spin
    spin.shutdown()
    world.destroy_node()
    driver.destroy_node()


def latest(robots, key):
    return robots.stats[-1].get(key)


def test_reset_restarts_counts_layout_and_measures(rig):
    world, robots, rosout, reset, state, spin = rig
    ids0, xy0 = robots.obstacles.arrays()
    # a game: robot_0 drives right along y = -11 (far from every obstacle), overriding
    # for two of its segments, and crosses the goal line
    robots.send_pose('robot_0', -17.0, -11.0, t=0.0)
    for k in range(1, 60):
        action = 'override' if k in (5, 6) else 'pass'
        state['robot_0'].publish(rosmsg.make_diagnostic('f', {'action': action}))
        spin.until(lambda: world.world.filter_actions['robot_0'] == action, 5.0, 'the filter state')
        robots.send_pose('robot_0', -17.0 + 0.6 * k, -11.0, t=0.2 * k)
    spin.until(lambda: latest(robots, 'trips') == '1', 5.0, 'a trip')
    spin.until(lambda: abs(float(latest(robots, 'path_length')) - 59 * 0.6) < 1e-3, 5.0,
               'the H2 measures of every pose')
    s = robots.stats[-1]
    assert float(s['override_fraction']) == pytest.approx(2 / 59, abs=1e-4)     # written to 4 places
    assert int(s['avoidance_arcs']) == 1 and float(s['path_per_trip']) >= 33.0
    assert float(s['min_clearance']) > 0
    before = robots.marker_msgs
    reset.publish(rosmsg.make_diagnostic('reset', {'seed': 5}))
    spin.until(lambda: latest(robots, 'resets') == '1', 5.0, 'the reset')
    s = robots.stats[-1]
    assert (s['trips'], s['interventions'], s['avoidance_arcs']) == ('0', '0', '0')
    assert s['path_per_trip'] == 'nan' and s['override_fraction'] == 'nan'
    spin.until(lambda: robots.marker_msgs > before, 5.0, 'the new layout')
    ids1, xy1 = robots.obstacles.arrays()
    # the same seed gives the same layout again, numbered from 0
    assert ids1.tolist() == list(range(4)) and np.allclose(xy1, xy0)
    spin.until(lambda: rosout.has('world', 'world reset 1'), 5.0, 'the reset logged')


def test_bad_reset_and_state_are_refused_with_a_reason(rig):
    world, robots, rosout, reset, state, spin = rig
    resets = latest(robots, 'resets')
    reset.publish(rosmsg.make_diagnostic('reset', {'seed': 'many'}))
    state['robot_1'].publish(rosmsg.make_diagnostic('f', {'reason': 'no action'}))
    spin.until(lambda: rosout.has('world', '/world/reset rejected')
               and rosout.has('world', 'without an action'), 5.0, 'the rejections')
    assert latest(robots, 'resets') == resets
