"""ros_io.sensors and filter_inputs.SensorDiscs: robot-stack messages as the filter's arrays
(message objects only, no node)."""
import math

import numpy as np
import pytest

from geometry_msgs.msg import PoseWithCovarianceStamped
from sensor_msgs.msg import LaserScan
from visualization_msgs.msg import Marker, MarkerArray

from supersafe_ros.filter import FilterConfig
from supersafe_ros.nodes.filter_inputs import INPUT_PARAMETERS, PoseHistory, SensorDiscs, message_type
from supersafe_ros.ros_io import rosmsg, sensors


def marker(kind, x, y, sx, sy, frame='map', action=Marker.ADD):
    m = Marker(type=kind, action=action)
    m.header.frame_id = frame
    m.pose.position.x, m.pose.position.y = x, y
    m.scale.x, m.scale.y, m.scale.z = sx, sy, 1.0
    return m


def test_markers_become_discs_of_their_own_radius_and_the_rest_is_counted():
    msg = MarkerArray(markers=[
        marker(0, 0, 0, 0, 0, action=Marker.DELETEALL), marker(Marker.CYLINDER, 1, 2, 1.6, 1.0),
        marker(Marker.SPHERE, 3, 4, 2.0, 2.0), marker(Marker.CUBE, 5, 6, 3.0, 4.0), marker(Marker.ARROW, 0, 0, 1, 1),
        marker(Marker.CYLINDER, 9, 9, 1, 1, action=Marker.DELETE)])
    discs, ignored = sensors.marker_discs(msg, 'map')
    assert discs.tolist() == [[1, 2, 0.8], [3, 4, 1.0], [5, 6, 2.5]]
    assert ignored == 3


@pytest.mark.parametrize('bad, why', [
    (marker(Marker.CYLINDER, 1, 2, 1, 1, frame='odom'), "expected 'map'"),
    (marker(Marker.CYLINDER, math.nan, 2, 1, 1), 'non-finite'),
    (marker(Marker.CYLINDER, 1, 2, 0.0, 1), 'must be > 0')])
def test_a_bad_marker_refuses_the_whole_message(bad, why):
    with pytest.raises(rosmsg.MessageError, match=why):
        sensors.marker_discs(MarkerArray(markers=[marker(Marker.CYLINDER, 0, 0, 1, 1), bad]), 'map')


def test_amcl_pose_is_read_in_its_frame():
    m = PoseWithCovarianceStamped()
    m.header.frame_id = 'map'
    m.pose.pose = rosmsg.state_to_pose((1.0, 2.0, 0.5)).pose
    assert sensors.header_pose_to_state(m.header, m.pose.pose, 'map') == pytest.approx((1.0, 2.0, 0.5))
    with pytest.raises(rosmsg.MessageError, match='frame'):
        sensors.header_pose_to_state(m.header, m.pose.pose, 'odom')
    assert message_type('pose_with_covariance') is PoseWithCovarianceStamped


def scan(ranges):
    m = LaserScan(angle_min=-math.pi, angle_increment=2 * math.pi / len(ranges), range_min=0.05, range_max=10.0)
    m.ranges = [float(r) for r in ranges]
    return m


def sensor(**over):
    p = {s.name: s.default for s in INPUT_PARAMETERS}
    p.update(detections_type='laser_scan', **over)
    return SensorDiscs(p, PoseHistory())


def test_a_scan_is_placed_with_the_nearest_pose_and_its_mount():
    s = sensor(sensor_x=1.0, robot_radius=0.2, obstacle_depth=0.0)
    s.history.add(10.0, (5.0, 0.0, math.pi / 2))
    s.history.add(10.1, (5.0, 0.3, math.pi / 2))
    ranges = np.full(8, np.inf)
    ranges[4] = 2.0                          # straight ahead of the sensor
    discs = s.discs(scan(ranges), 10.1, FilterConfig(), 0.5)
    # the robot at (5, 0.3) facing +y, the sensor 1 m ahead of it: the return at (5, 3.3)
    assert discs.shape == (1, 3) and np.allclose(discs[0, :2], (5.0, 3.3)) and discs[0, 2] == pytest.approx(0.2)
    slack = s.discs(scan(ranges), 10.15, FilterConfig(speed=3.0, omega_max=1.0), 0.5)
    assert slack[0, 2] == pytest.approx(0.2 + 0.05 * 3.0 + 3.0 * 0.05, rel=1e-6), 'v dt + rho w dt'


def test_a_scan_without_a_pose_near_its_stamp_or_too_long_is_refused():
    s = sensor(max_sensor_points=100)
    with pytest.raises(rosmsg.MessageError, match='no pose'):
        s.discs(scan([1.0] * 10), 0.0, FilterConfig(), 0.5)
    s.history.add(0.0, (0.0, 0.0, 0.0))
    with pytest.raises(rosmsg.MessageError, match='no pose within'):
        s.discs(scan([1.0] * 10), 2.0, FilterConfig(), 0.5)
    with pytest.raises(rosmsg.MessageError, match='exceeds max_sensor_points'):
        s.discs(scan([1.0] * 101), 0.0, FilterConfig(), 0.5)


def test_each_return_also_covers_what_lies_behind_it_on_its_beam():
    s = sensor(obstacle_depth=2.0, robot_radius=0.1)
    s.history.add(0.0, (0.0, 0.0, 0.0))
    ranges = np.full(8, np.inf)
    ranges[4] = 3.0                          # straight ahead: the return at (3, 0)
    (disc,) = s.discs(scan(ranges), 0.0, FilterConfig(), 0.5)
    for x in (3.0, 4.0, 5.0):               # the segment to 2 m behind it
        assert math.hypot(disc[0] - x, disc[1]) + 0.1 <= disc[2] + 1e-9
    assert math.hypot(disc[0], disc[1]) > disc[2], 'the robot is not inside'
