"""nodes/filter_sources.py: robot-stack messages as the filter's arrays (MarkerArray discs, a pose with
a header) and a range sensor's local map (SensorMap); message objects only, no node."""
import math

import numpy as np
import pytest

from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import LaserScan
from visualization_msgs.msg import Marker, MarkerArray

from supersafe_ros.filter import FilterConfig
from supersafe_ros.nodes.filter_parameters import MAP_PARAMETERS, TYPE_PARAMETERS
from supersafe_ros.nodes.filter_sources import PoseHistory, SensorMap, marker_discs, message_type
from supersafe_ros.ros_io import rosmsg


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
    discs, ignored = marker_discs(msg, 'map')
    assert discs.tolist() == [[1, 2, 0.8], [3, 4, 1.0], [5, 6, 2.5]]
    assert ignored == 3


@pytest.mark.parametrize('bad, why', [
    (marker(Marker.CYLINDER, 1, 2, 1, 1, frame='odom'), "expected 'map'"),
    (marker(Marker.CYLINDER, math.nan, 2, 1, 1), 'non-finite'),
    (marker(Marker.CYLINDER, 1, 2, 0.0, 1), 'must be > 0')])
def test_a_bad_marker_refuses_the_whole_message(bad, why):
    with pytest.raises(rosmsg.MessageError, match=why):
        marker_discs(MarkerArray(markers=[marker(Marker.CYLINDER, 0, 0, 1, 1), bad]), 'map')


def test_amcl_pose_is_read_in_its_frame():
    m = PoseWithCovarianceStamped()
    m.header.frame_id = 'map'
    m.pose.pose = rosmsg.state_to_pose((1.0, 2.0, 0.5)).pose
    assert rosmsg.header_pose_to_state(m.header, m.pose.pose, 'map') == pytest.approx((1.0, 2.0, 0.5))
    with pytest.raises(rosmsg.MessageError, match='frame'):
        rosmsg.header_pose_to_state(m.header, m.pose.pose, 'odom')
    assert message_type('pose_with_covariance') is PoseWithCovarianceStamped


def scan(ranges):
    m = LaserScan(angle_min=-math.pi, angle_increment=2 * math.pi / len(ranges), range_min=0.05, range_max=10.0)
    m.angle_max = m.angle_min + m.angle_increment * (len(ranges) - 1)
    m.ranges = [float(r) for r in ranges]
    return m


def sensor(**over):
    p = {s.name: s.default for s in TYPE_PARAMETERS + MAP_PARAMETERS}
    p.update({'detections_type': 'laser_scan', **over})
    return SensorMap(p, PoseHistory(), FilterConfig(), 3.0, 'map')


def cell_of(m, x, y):
    """Whether the map's cell holding (x, y) is occupied (False off the window)."""
    i, j = int(math.floor((x - m.origin[0]) / m.cell)), int(math.floor((y - m.origin[1]) / m.cell))
    n = m.occupied.shape
    return 0 <= i < n[0] and 0 <= j < n[1] and bool(m.occupied[i, j])


def test_a_scan_is_placed_with_the_pose_at_its_stamp_and_its_mount():
    """The pose at the scan's stamp, interpolated between the poses that bracket it, carries the sensor
    at its mount: the return lands in the map where it was seen."""
    s = sensor(sensor_x=1.01, robot_radius=0.2)
    s.history.add(10.0, (1.02, 0.0, math.pi / 2))
    s.history.add(10.2, (1.02, 0.6, math.pi / 2))
    ranges = np.full(8, np.inf)
    ranges[4] = 2.0                          # straight ahead of the sensor
    summary, _ = s.take(scan(ranges), 10.1, FilterConfig(), 0.5)
    # at 10.1 the robot is at (1.02, 0.3) facing +y, the sensor 1.01 m ahead of it: the return at (1.02, 3.31)
    assert summary.marked == 1 and cell_of(s.map, 1.02, 3.31)
    assert not cell_of(s.map, 1.02, 3.0), 'the beam before its return is seen free'
    assert s.view.sensor == 'scan' and s.view.clearance == 0.2


def test_a_scan_beyond_the_poses_is_placed_with_a_slack():
    """A stamp no pose brackets (later than the newest): the newest pose, each return's cell grown by
    v dt + rho w dt (the robot moved at most that since)."""
    s = sensor()
    s.history.add(0.0, (0.0, 0.0, 0.0))
    ranges = np.full(8, np.inf)
    ranges[4] = 3.0                          # straight ahead: (3, 0)
    s.take(scan(ranges), 0.2, FilterConfig(speed=3.0, omega_max=1.0), 0.5)
    slack = 0.2 * 3.0 + 3.0 * 1.0 * 0.2      # 1.2 m
    assert cell_of(s.map, 3.02, 1.1) and cell_of(s.map, 3.02, -1.1) and not cell_of(s.map, 3.02, 1.4), slack


def test_a_scan_without_a_pose_near_its_stamp_too_long_or_of_bad_geometry_is_refused():
    s = sensor(max_sensor_points=100)
    with pytest.raises(rosmsg.MessageError, match='no pose'):
        s.take(scan([1.0] * 10), 0.0, FilterConfig(), 0.5)
    s.history.add(0.0, (0.0, 0.0, 0.0))
    with pytest.raises(rosmsg.MessageError, match='no pose within'):
        s.take(scan([1.0] * 10), 2.0, FilterConfig(), 0.5)
    with pytest.raises(rosmsg.MessageError, match='100'):
        s.take(scan([1.0] * 101), 0.0, FilterConfig(), 0.5)
    bad = scan([1.0] * 10)
    bad.angle_increment = 0.0
    with pytest.raises(rosmsg.MessageError, match='angle_increment'):
        s.take(bad, 0.0, FilterConfig(), 0.5)
    assert s.map.version == 0, 'nothing refused went into the map'


def test_each_return_also_marks_what_lies_behind_it_on_its_beam():
    s = sensor(obstacle_depth=2.0, robot_radius=0.1)
    s.history.add(0.0, (0.0, 0.0, 0.0))
    ranges = np.full(8, np.inf)
    ranges[4] = 3.0                          # straight ahead: the return at (3, 0)
    s.take(scan(ranges), 0.0, FilterConfig(), 0.5)
    for x in (3.02, 4.02, 4.9):             # its beam to 2 m behind it (within the map's 5 m)
        assert cell_of(s.map, x, 0.02)
    assert not cell_of(s.map, 2.9, 0.02) and not cell_of(s.map, 1.0, 0.02)


def test_a_costmap_is_read_in_its_frame_with_its_threshold():
    s = sensor(detections_type='occupancy_grid', occupied_threshold=100)
    s.history.add(0.0, (0.0, 0.0, 0.0))
    g = OccupancyGrid()
    g.header.frame_id = 'map'
    g.info.resolution, g.info.width, g.info.height = 0.5, 4, 4
    g.info.origin.position.x, g.info.origin.position.y, g.info.origin.orientation.w = 1.0, -1.0, 1.0
    data = np.zeros((4, 4), dtype=np.int8)
    data[1, 2] = 100        # row y = -0.5..0, column x = 2..2.5: lethal
    data[2, 2] = 99         # inscribed: below the threshold
    data[3, 3] = -1
    g.data = data.reshape(-1).tolist()
    s.take(g, 0.0, FilterConfig(), 0.5)
    assert cell_of(s.map, 2.25, -0.25) and not cell_of(s.map, 2.25, 0.25)
    g.header.frame_id = 'odom'
    with pytest.raises(rosmsg.MessageError, match="frame is 'odom'"):
        s.take(g, 0.0, FilterConfig(), 0.5)


def test_the_maps_value_is_asked_for_at_most_every_value_period():
    s = sensor(value_period=0.2)
    s.history.add(0.0, (0.0, 0.0, 0.0))
    s.take(scan([3.0] * 36), 0.0, FilterConfig(), 0.5)
    try:
        assert s.solve(1.0, 10.0, 0.0, 0.0)
        assert not s.solve(1.0, 10.1, 0.0, 0.0) and s.solve(1.0, 10.25, 0.0, 0.0)
        assert s.worker.submitted == 2
    finally:
        s.close()
