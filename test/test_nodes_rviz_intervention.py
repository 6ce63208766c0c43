"""RViz: clicks on obstacles are interventions, and the level set in force is drawn.

Core: supersafe_ros.interventions (shared with the web console) and
runtime.contours. Topic level: rviz_intervention_node in-process (the test plays the
world, the robots and RViz), and safety_filter_node's level-set markers."""
import math

import numpy as np
import pytest
from rclpy.parameter import Parameter

from geometry_msgs.msg import PointStamped, PoseArray, PoseStamped
from visualization_msgs.msg import Marker, MarkerArray

from supersafe_ros.runtime.contours import level_set_contour, level_sets_around
from supersafe_ros.interventions import (NoIntervention, intervention_at_point, intervention_on_obstacle,
                                         obstacle_under_point)
from supersafe_ros.nodes.markers import level_set_lines, level_set_markers, obstacles_to_markers
from supersafe_ros.ros_io import rosmsg

from graph_support import Rosout, Spinner, matched

OBSTACLES = {2: (0.0, 0.0), 9: (6.0, 3.0)}
RADIUS = 1.8
ROBOTS = {'robot_0': (-4.0, 0.5, 0.2), 'robot_1': (9.0, 1.0, 2.5)}
SHAPE = [41, 41, 24]


@pytest.fixture(scope='module')
def standard_vf():
    from supersafe_ros.nodes.filter_wiring import standard_value_function
    return standard_value_function([-8.0, -8.0], [8.0, 8.0], SHAPE, 3.0, 1.0, RADIUS, 3.0)


# -- the shared click -> intervention logic --------------------------------------------------------
def test_click_on_an_obstacle_names_it_and_the_nearest_robot():
    it = intervention_at_point((6.5, 4.0), OBSTACLES, RADIUS, ROBOTS, tolerance=0.0)
    assert (it.obstacle_id, it.robot) == (9, 'robot_1')
    assert it.rel_state == pytest.approx((3.0, -2.0, 2.5))
    assert it.robot_distance == pytest.approx(math.hypot(3.0, -2.0))
    it = intervention_at_point((-1.0, 0.2), OBSTACLES, {2: RADIUS, 9: RADIUS}, ROBOTS)
    assert (it.obstacle_id, it.robot, it.rel_state) == (2, 'robot_0', pytest.approx((-4.0, 0.5, 0.2)))


def test_tolerance_widens_the_rim_and_off_obstacle_points_say_why():
    just_outside = (RADIUS + 0.3, 0.0)
    with pytest.raises(NoIntervention, match='on no obstacle.*nearest, 2, is 0.30 m beyond'):
        obstacle_under_point(just_outside, OBSTACLES, RADIUS, tolerance=0.2)
    assert obstacle_under_point(just_outside, OBSTACLES, RADIUS, tolerance=0.4) == 2
    with pytest.raises(NoIntervention, match='not finite'):
        obstacle_under_point((math.nan, 0.0), OBSTACLES, RADIUS)
    with pytest.raises(NoIntervention, match='already removed'):
        intervention_on_obstacle(5, OBSTACLES, ROBOTS)
    with pytest.raises(NoIntervention, match='no robot pose'):
        intervention_on_obstacle(2, OBSTACLES, {'robot_0': None})


# -- contours and markers ---------------------------------------------------------------------------
@pytest.mark.parametrize('theta, alpha', [(0.0, 0.0), (1.234, 0.0), (-2.5, 0.6)])
def test_contour_points_lie_on_the_level_at_the_heading(standard_vf, theta, alpha):
    lines = level_set_contour(standard_vf, theta, alpha)
    assert lines, 'V crosses alpha on the grid'
    pts = np.concatenate(lines)
    v = standard_vf.value(np.column_stack([pts, np.full(len(pts), theta)]))
    assert np.abs(v - alpha).max() < 0.02        # interpolation tolerance (m of value)
    # the test can tell headings apart: at a quarter turn the same points are off the level
    off = standard_vf.value(np.column_stack([pts, np.full(len(pts), theta + math.pi / 2)]))
    assert np.median(np.abs(off - alpha)) > 0.2
    # the contour encloses the obstacle: its points are outside the disc
    assert np.hypot(pts[:, 0], pts[:, 1]).min() >= RADIUS - 0.05


def test_level_sets_around_obstacles_become_line_strip_markers(standard_vf):
    state = (10.0, -3.0, 0.7)
    centres = [(12.0, 0.0), (-5.0, 4.0)]
    contours = level_sets_around(standard_vf, state, centres, 0.0)
    assert len(contours) == 2
    msg = level_set_markers(contours, source='learned')
    assert msg.markers[0].action == Marker.DELETEALL
    strips = [m for m in msg.markers if m.type == Marker.LINE_STRIP]
    assert len(strips) == sum(len(c) for c in contours) and len({m.id for m in strips}) == len(strips)
    assert all(m.header.frame_id == 'map' and m.color.g > m.color.b for m in strips)
    lines = level_set_lines(msg)
    for (cx, cy), got in zip(centres, [lines[:len(contours[0])], lines[len(contours[0]):]]):
        pts = np.concatenate(got) - (cx, cy)
        v = standard_vf.value(np.column_stack([pts, np.full(len(pts), state[2])]))
        assert np.abs(v).max() < 0.02
    assert level_sets_around(standard_vf, state, np.zeros((0, 2)), 0.0) == []
    # a lidar's thousands of points: drawn around the nearest only, in their order
    many = np.random.default_rng(0).uniform(-500, 500, (5000, 2))
    near = level_sets_around(standard_vf, state, many, 0.0, nearest=64)
    dist = np.hypot(*(many - state[:2]).T)
    nearest = np.sort(np.argsort(dist)[:64])
    assert len(near) == 64
    assert [tuple(np.round(c[0][0] - contours[0][0][0] + centres[0], 9)) for c in near] == [
        tuple(np.round(many[i], 9)) for i in nearest]


# -- rviz_intervention_node at topic level ---------------------------------------------------------
@pytest.mark.ros
def test_clicks_on_obstacles_become_interventions(ros_context):
    from rclpy.node import Node
    from supersafe_ros.nodes.rviz_intervention_node import QOS_CLICKS, RvizInterventionNode
    node = RvizInterventionNode(context=ros_context, parameter_overrides=[
        Parameter('robots', value=list(ROBOTS)), Parameter('tolerance', value=0.5)])
    test = Node('rviz_test', context=ros_context)
    markers = test.create_publisher(MarkerArray, '/obstacle_markers', rosmsg.QOS_LATCHED)
    poses = {r: test.create_publisher(PoseStamped, f'/{r}/pose', rosmsg.QOS_STREAM) for r in ROBOTS}
    clicks = test.create_publisher(PointStamped, '/clicked_point', QOS_CLICKS)
    got = []
    sub = test.create_subscription(PoseStamped, '/interventions', got.append, rosmsg.QOS_EVENTS)
    rosout = Rosout(test)
    spin = Spinner(ros_context, node, test)
    try:
        spin.until(lambda: matched(markers, clicks, sub, *poses.values()), 30.0, 'topics to match')
        ids = sorted(OBSTACLES)
        markers.publish(obstacles_to_markers(ids, [OBSTACLES[i] for i in ids], RADIUS))
        spin.until(lambda: sorted(node.obstacles.centres) == ids, 10.0, 'the obstacles')
        stamps = {}
        for i, (r, s) in enumerate(ROBOTS.items()):
            stamps[r] = rosmsg.state_to_pose(s).header.stamp
            stamps[r].sec = 40 + i
            poses[r].publish(rosmsg.state_to_pose(s, stamps[r]))
        spin.until(lambda: all(node.poses[r] is not None for r in ROBOTS), 10.0, 'the robot poses')

        def click(x, y, frame='map'):
            msg = PointStamped()
            msg.header.frame_id = frame
            msg.point.x, msg.point.y = float(x), float(y)
            clicks.publish(msg)

        click(3.0, -3.0)                       # between the two obstacles: on none
        spin.until(lambda: rosout.has('rviz_intervention', 'click ignored', 'on no obstacle'), 10.0,
                   'the off-obstacle click to be logged')
        click(6.0, 3.0, frame='odom')          # on obstacle 9, but not in map
        spin.until(lambda: rosout.has('rviz_intervention', 'click ignored', "'odom'"), 10.0,
                   'the wrong-frame click to be logged')
        assert got == []
        click(6.0 + RADIUS + 0.3, 3.0)         # within the tolerance of obstacle 9
        spin.until(lambda: len(got) >= 1, 10.0, 'the intervention')
        spin.until(lambda: rosout.has('rviz_intervention', 'intervene (RViz click): obstacle 9'), 10.0,
                   'the intervention to be logged')
        assert len(got) == 1                    # the ignored clicks sent nothing before it
        msg = got[0]
        assert msg.header.frame_id == 'obstacle_9'
        assert rosmsg.pose_to_state(msg, frame=None) == pytest.approx((3.0, -2.0, 2.5))
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (41, 0)   # robot_1's pose
    finally:
        spin.shutdown()
        node.destroy_node()
        test.destroy_node()


# -- safety_filter_node's level-set markers ----------------------------------------------------------
@pytest.mark.ros
def test_filter_node_draws_the_set_in_force_at_the_robot_heading(ros_context, standard_vf):
    from rclpy.node import Node
    from supersafe_ros.nodes.safety_filter_node import SafetyFilterNode
    ns = '/robot_0'
    node = SafetyFilterNode(namespace=ns, context=ros_context, parameter_overrides=[
        Parameter('standard_shape', value=SHAPE), Parameter('level_set_rate', value=20.0)])
    test = Node('level_set_test', namespace=ns, context=ros_context)
    pose_pub = test.create_publisher(PoseStamped, 'pose', rosmsg.QOS_STREAM)
    det_pub = test.create_publisher(PoseArray, 'detections', rosmsg.QOS_STREAM)
    got = []
    sub = test.create_subscription(MarkerArray, 'safety_filter/level_set', got.append, rosmsg.QOS_STREAM)
    spin = Spinner(ros_context, node, test)
    state, centres = (1.0, 2.0, -0.8), [(4.0, 0.0), (-3.0, 6.0)]
    try:
        spin.until(lambda: matched(pose_pub, det_pub, sub), 30.0, 'topics to match')
        spin.until(lambda: len(got) >= 1, 10.0, 'markers before any pose')
        assert level_set_lines(got[-1]) == []    # nothing known yet: only the DELETEALL
        pose_pub.publish(rosmsg.state_to_pose(state))
        det_pub.publish(rosmsg.xy_to_posearray(centres))
        spin.until(lambda: got and len(level_set_lines(got[-1])) >= 2, 10.0, 'level-set markers')
        lines = level_set_lines(got[-1])
        assert got[-1].markers[1].ns == 'level_set'
        for cx, cy in centres:     # each obstacle has a contour around it, on V = alpha (0)
            near = [ln for ln in lines if np.hypot(*(ln.mean(axis=0) - (cx, cy))) < 3.0]
            assert near, f'no contour around ({cx}, {cy})'
            pts = np.concatenate(near) - (cx, cy)
            v = standard_vf.value(np.column_stack([pts, np.full(len(pts), state[2])]))
            assert np.abs(v - node.wiring.safe_set.alpha).max() < 0.02
    finally:
        spin.shutdown()
        node.destroy_node()
        test.destroy_node()
