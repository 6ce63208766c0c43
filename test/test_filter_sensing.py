"""filter.sensing: returns of scans and clouds, into map, and their covering discs (ROS-free)."""
import math

import numpy as np
import pytest

from supersafe_ros.filter import sensing


def covered(points, inflation, discs) -> bool:
    """Every inflated return lies inside some disc: |p - c| + inflation <= r."""
    p = np.asarray(points)
    infl = np.broadcast_to(inflation, (len(p),))
    reach = np.hypot(p[:, None, 0] - discs[None, :, 0], p[:, None, 1] - discs[None, :, 1]) + infl[:, None]
    return bool(np.all((reach <= discs[None, :, 2] + 1e-9).any(axis=1)))


def test_scan_returns_skip_nan_inf_and_out_of_range_beams():
    r = np.array([1.0, np.nan, np.inf, 0.01, 20.0, 2.0])
    p = sensing.scan_points(r, 0.0, math.pi / 2, 0.05, 10.0)
    assert p.shape == (2, 2)
    assert np.allclose(p[0], [1.0, 0.0])
    assert np.allclose(p[1], [2.0 * math.cos(5 * math.pi / 2), 2.0 * math.sin(5 * math.pi / 2)])
    with pytest.raises(ValueError, match='angle_increment'):
        sensing.scan_points(r, 0.0, math.nan, 0.05, 10.0)


def test_an_empty_scan_is_no_disc():
    assert sensing.covering_discs(sensing.scan_points([np.inf] * 8, 0, 0.1, 0.1, 5), 0.3, 0.5, 2.5).shape == (0, 3)


@pytest.mark.parametrize('seed', range(5))
def test_every_inflated_return_is_inside_a_disc(seed):
    rng = np.random.default_rng(seed)
    # clumps (objects), a wall, scattered points
    clumps = np.concatenate([rng.normal(c, 0.3, (50, 2)) for c in rng.uniform(-8, 8, (6, 2))])
    wall = np.column_stack([np.linspace(-9, 9, 300), np.full(300, 7.0)])
    points = np.concatenate([clumps, wall, rng.uniform(-10, 10, (40, 2))])
    infl = rng.uniform(0.1, 0.6, len(points))
    discs = sensing.covering_discs(points, infl, 0.5, 2.5)
    assert covered(points, infl, discs)
    assert len(discs) < len(points) / 2, 'close returns share a disc'
    # no disc wider than the limit (the pieces of a wide group: the limit plus their inflation)
    assert np.all(discs[:, 2] <= 2.5 + infl.max() + 1e-9)


def test_a_wall_is_covered_in_pieces_not_by_one_disc_over_the_robot():
    wall = np.column_stack([np.linspace(-10, 10, 400), np.full(400, 2.0)])
    discs = sensing.covering_discs(wall, 0.3, 0.5, 2.5)
    assert covered(wall, 0.3, discs)
    # the robot at the origin, 2 m from the wall, is outside every disc
    assert np.all(np.hypot(discs[:, 0], discs[:, 1]) > discs[:, 2])


def test_to_map_applies_the_pose_and_the_mount():
    p = sensing.to_map([[1.0, 0.0]], (2.0, 3.0, math.pi / 2), (0.5, 0.0, math.pi / 2))
    # sensor at (2, 3.5) facing -x: its (1, 0) is map (1, 3.5)
    assert np.allclose(p, [[1.0, 3.5]])


def test_stamp_slack_covers_the_motion_between_the_stamps():
    pts = np.array([[0.0, 0.0], [10.0, 0.0]])
    slack = sensing.stamp_slack(pts, (0.0, 0.0, 0.0), 0.1, 3.0, 1.0)
    assert np.allclose(slack, [0.3, 0.3 + 10 * 0.1])
    assert np.all(sensing.stamp_slack(pts, (0.0, 0.0, 0.0), 0.0, 3.0, 1.0) == 0)


@pytest.mark.parametrize('dtype, bigendian', [('<f4', False), ('>f4', True), ('<f8', False), ('>f8', True)])
def test_cloud_xy_reads_any_float_layout(dtype, bigendian):
    xy = np.array([[1.0, 2.0], [3.0, -4.0], [np.nan, 1.0]])
    points = np.zeros(3, dtype=[('z', dtype), ('x', dtype), ('y', dtype), ('pad', 'V3')])
    points['x'], points['y'] = xy[:, 0], xy[:, 1]
    size = np.dtype(dtype).itemsize
    code = 7 if size == 4 else 8
    out = sensing.cloud_xy(points.tobytes(), {'x': (size, code, 1), 'y': (2 * size, code, 1)},
                           points.dtype.itemsize, points.dtype.itemsize * 3, 3, 1, bigendian)
    assert np.allclose(out, xy[:2])


def test_cloud_xy_refuses_malformed_and_huge_clouds():
    fields = {'x': (0, 7, 1), 'y': (4, 7, 1)}
    with pytest.raises(ValueError, match='shorter'):
        sensing.cloud_xy(bytes(20), fields, 8, 80, 10, 1, False)
    with pytest.raises(ValueError, match='max_sensor_points'):
        sensing.cloud_xy(bytes(8), fields, 8, 8, 10_000_000, 1, False, max_points=1_000_000)
    with pytest.raises(ValueError, match="no field 'y'"):
        sensing.cloud_xy(bytes(8), {'x': (0, 7, 1)}, 8, 8, 1, 1, False)
    with pytest.raises(ValueError, match='does not fit'):
        sensing.cloud_xy(bytes(80), {'x': (0, 7, 1), 'y': (6, 7, 1)}, 8, 80, 10, 1, False)
    with pytest.raises(ValueError, match='datatype'):
        sensing.cloud_xy(bytes(80), {'x': (0, 2, 1), 'y': (4, 7, 1)}, 8, 80, 10, 1, False)


def test_organised_clouds_with_row_padding():
    w, h, step = 4, 3, 8
    row_step = w * step + 8          # 8 bytes of padding per row
    buf = np.zeros(row_step * h, dtype=np.uint8)
    for row in range(h):
        vals = np.zeros(w, dtype=[('x', '<f4'), ('y', '<f4')])
        vals['x'], vals['y'] = np.arange(w) + 10 * row, -row
        buf[row * row_step: row * row_step + w * step] = np.frombuffer(vals.tobytes(), np.uint8)
    out = sensing.cloud_xy(buf.tobytes(), {'x': (0, 7, 1), 'y': (4, 7, 1)}, step, row_step, w, h, False)
    assert out.shape == (12, 2) and out[5].tolist() == [11.0, -1.0]


def test_the_work_is_bounded_for_a_100k_point_cloud():
    """The discs number at most the occupied cells, whatever the cloud (its time: bench_sensors.py)."""
    rng = np.random.default_rng(1)
    points = rng.uniform(-20, 20, (100_000, 2))
    discs = sensing.covering_discs(points, 0.3, 0.5, 2.5)
    assert covered(points[::97], 0.3, discs)
    assert len(discs) <= (40 / 0.5 + 1) ** 2


def test_a_large_disc_seen_from_one_side_is_covered_whole_with_its_depth():
    """The visible arc of a disc of radius 2.6 and its shadows 5.2 deep: the discs hold the
    whole obstacle, its unseen back and flanks included."""
    from supersafe_ros.sim.laser import beam_angles, ray_cast
    angles = beam_angles(360)
    r = ray_cast((0.0, 0.0, 0.0), angles, [(6.0, 0.5)], [2.6], 10.0)
    pts = sensing.scan_points(r, float(angles[0]), float(angles[1] - angles[0]), 0.05, 10.0)
    a = np.linspace(-np.pi, np.pi, 200)
    rim = np.column_stack([6.0 + 2.6 * np.cos(a), 0.5 + 2.6 * np.sin(a)])
    surface_only = sensing.covering_discs(pts, 0.1, 0.5, 2.5)
    assert not covered(rim, 0.0, surface_only), 'the surface alone leaves its back out'
    for budget in (50_000, 500):               # sampled as they are, or merged per cell first
        samples, inflation = sensing.shadows(pts, 0.1, (0.0, 0.0), 5.2, 0.5, budget)
        discs = sensing.covering_discs(samples, inflation, 0.5, 2.5)
        assert covered(rim, 0.0, discs), 'every point of the obstacle is inside a disc'
        assert np.all(np.hypot(discs[:, 0], discs[:, 1]) > discs[:, 2]), 'the robot (the sensor) is outside'
    samples, inflation = sensing.shadows(pts, 0.1, (0.0, 0.0), 5.2, 0.5)
    assert len(samples) <= 50_000 and np.all(inflation >= 0.1)
