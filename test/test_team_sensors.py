"""supersafe team --sensors scan: the layout (ROS-free; the graph itself: test_nodes_sensor_filter.py)."""
import pytest

from supersafe_ros.team import SENSOR_MODE, team_layout


def by_kind(layout, kind):
    return [n for n in layout if n.kind == kind]


def test_scan_robots_planners_and_filters_are_wired_to_odometry_and_the_scan():
    layout = team_layout(2, sensors='scan')
    for robot in by_kind(layout, 'dubins_robot'):
        assert robot.params['sensors'] == 'scan' and robot.params['follow_speed'] is True
    for f in by_kind(layout, 'safety_filter'):
        assert f.remaps == {'pose': 'odom', 'detections': 'scan'}
        assert f.params['detections_type'] == 'laser_scan' and f.params['cmd_vel_stamped'] is True
        assert f.params['lockstep'] is True, 'still lockstepped'
        assert f.params['fail_safe_command'] == 'stop', 'a robot that follows its speed can stop'
    for p in by_kind(layout, 'planner'):
        assert p.remaps['pose'] == 'odom' and p.params['slow_radius'] > 0
    (clock,) = by_kind(layout, 'sim_clock')
    waits = clock.params['wait_for_subscriptions']
    assert '/robot_0/odom=2' in waits and '/robot_0/pose=2' in waits, 'planner and filter on odom; world, supervisor'
    assert by_kind(layout, 'learner') and by_kind(layout, 'supervisor') and by_kind(layout, 'world')


def test_the_default_team_is_unchanged():
    layout = team_layout(2)
    for node in layout:
        for key in SENSOR_MODE.get(node.kind, {}):
            assert key not in node.params or key == 'fail_safe_command'
    assert all('detections' not in f.remaps and f.params['fail_safe_command'] == 'stop_turn'
               for f in by_kind(layout, 'safety_filter'))
    with pytest.raises(ValueError, match='sensors'):
        team_layout(2, sensors='lidar')
