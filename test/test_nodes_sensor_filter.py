"""The filter in a real robot's stack, at topic level: a robot that publishes only Odometry and
a LaserScan and takes TwistStamped, driven by a planner that slows near its goal and stops
there, through a field of obstacles of three sizes (sensor_graph_support), filtered by a
safety_filter_node or a fleet_safety_filter_node. Lockstepped on a test-driven /clock: bounded by
steps, not wall time."""
import pytest

from supersafe_ros.team import SENSOR_MODE

from sensor_graph_support import OBSTACLES, SensorGraph

pytestmark = pytest.mark.ros   # rclpy nodes in this process

STEPS = 500       # 25 s of sim time: the trip takes about 15


@pytest.mark.parametrize('detections_type, topic, fleet', [
    ('laser_scan', 'scan', False), ('point_cloud2', 'cloud', False), ('marker_array', 'markers', False),
    ('laser_scan', 'scan', True), ('marker_array', 'markers', True)],
    ids=['scan', 'cloud', 'markers', 'fleet_node_scan', 'fleet_node_markers'])
def test_a_robot_crosses_a_field_of_three_sizes_without_a_collision(ros_context, detections_type, topic, fleet):
    """On safety_filter_node, and on a fleet_safety_filter_node whose robot it is."""
    # the returns stand for their beams 5.2 m behind them too: the largest obstacle's far side; the
    # local map and its value as the scan team sets them for its 3 m/s robots (supersafe_ros.team)
    mapped = {k: SENSOR_MODE['safety_filter'][k] for k in (
        'inf_is_valid', 'map_cell', 'map_size', 'value_cell', 'value_headings', 'value_horizon', 'value_reach')}
    g = SensorGraph(ros_context, detections_type, topic, fleet=fleet, robot_radius=0.3, obstacle_depth=5.2,
                    time_before_collision=0.5, **(mapped if detections_type != 'marker_array' else {}))
    try:
        g.start()
        reached = g.run(STEPS)
        assert g.collisions() == 0, 'the robot entered an obstacle the scan saw'
        assert reached, f'the robot did not reach its goal in {STEPS} steps (last pose {g.poses[-1]})'
        assert len({r for _, _, r in OBSTACLES}) == 3
        assert 'override' in g.actions, 'the obstacles were in the way: the filter turned the robot'
        faster = [(s, a) for s, a in g.sent if s > a + 1e-9]
        assert not faster, f'the filter sent a robot faster than its planner asked: {faster[:5]}'
        assert min(a for _, a in g.sent) < 3.0, 'the planner slowed near its goal'
    finally:
        g.close()
