"""filter.sensing.readings: a scan's beams as REP 117 readings, a cloud's strict layout, the pose at a stamp."""
import array
import math

import numpy as np
import pytest

from supersafe_ros.filter.sensing.readings import cloud_xy, interpolated_pose, scan_rays

FULL = dict(angle_min=-math.pi, angle_max=math.pi - 2 * math.pi / 360, angle_increment=2 * math.pi / 360,
            range_min=0.1, range_max=10.0)


def scan(ranges, **over):
    """scan_rays over ``ranges`` with 360-beam full-circle geometry unless ``over`` says otherwise."""
    return scan_rays(ranges, **{**FULL, **over})


# -- refusals --------------------------------------------------------------------------------------
class Unreadable:
    """A ranges sequence that says how long it is and refuses to be read."""

    def __len__(self):
        return 2_000_000

    def __iter__(self):
        raise AssertionError('the ranges were read')

    def __array__(self, *args, **kwargs):
        raise AssertionError('the ranges were read')


def test_too_many_beams_are_refused_before_the_ranges_are_read():
    with pytest.raises(ValueError, match=r'scan refused: 2000000 beams exceed max_beams=1000000'):
        scan(Unreadable())
    with pytest.raises(ValueError, match=r'11 beams exceed max_beams=10'):
        scan_rays([1.0] * 11, 0.0, 1.0, 0.1, 0.0, 5.0, max_beams=10)


@pytest.mark.parametrize('name', ['angle_min', 'angle_max', 'angle_increment', 'range_min', 'range_max'])
@pytest.mark.parametrize('value', [math.nan, math.inf, -math.inf])
def test_a_geometry_value_not_finite_is_refused_by_name(name, value):
    with pytest.raises(ValueError, match=rf'scan refused: {name} is {value} \(must be finite\)'):
        scan([1.0] * 360, **{name: value})


def test_a_zero_increment_is_refused():
    with pytest.raises(ValueError, match=r'scan refused: angle_increment is 0 \(must be finite and > 0'):
        scan([1.0] * 360, angle_increment=0.0)


def test_the_increment_must_run_the_way_of_the_angles():
    with pytest.raises(ValueError, match=r'angle_increment is -0.1 < 0 but angle_max 1 >= angle_min 0'):
        scan_rays([1.0] * 11, 0.0, 1.0, -0.1, 0.0, 5.0)
    with pytest.raises(ValueError, match=r'angle_increment is 0.1 > 0 but angle_max 0 < angle_min 1'):
        scan_rays([1.0] * 11, 1.0, 0.0, 0.1, 0.0, 5.0)


def test_a_clockwise_scan_is_read_with_descending_angles():
    rays = scan_rays([1.0, 2.0, 3.0], math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0, 5.0)
    assert np.allclose(rays.angles, [math.pi / 2, 0.0, -math.pi / 2])
    assert np.allclose(rays.mark_range, [1.0, 2.0, 3.0])


def test_range_limits_are_checked():
    with pytest.raises(ValueError, match=r'scan refused: range_min is -0.5 \(must be >= 0\)'):
        scan([1.0] * 360, range_min=-0.5)
    with pytest.raises(ValueError, match=r'scan refused: range_min 6 > range_max 5'):
        scan([1.0] * 360, range_min=6.0, range_max=5.0)


def test_a_beam_count_that_disagrees_with_the_angles_is_refused_with_both_numbers():
    with pytest.raises(ValueError, match=r'scan refused: 100 ranges but its angles give 360.0 beams'):
        scan([1.0] * 100)
    # within 1.5 of the angles' count: a driver's rounding of angle_max
    assert scan([1.0] * 361).beams == 361
    assert scan([1.0] * 359).beams == 359
    with pytest.raises(ValueError, match=r'358 ranges but its angles give 360.0'):
        scan([1.0] * 358)


def test_angles_spanning_more_than_a_turn_are_refused():
    inc = 0.01
    n = int(round(8.0 / inc)) + 1
    with pytest.raises(ValueError, match=r'scan refused: its angles span 8 rad, over 2 pi \+ one increment'):
        scan_rays([1.0] * n, -4.0, 4.0, inc, 0.0, 5.0)
    # a full turn and one increment more is still a scan
    assert scan_rays([1.0] * 362, -math.pi, math.pi + 2 * math.pi / 360, 2 * math.pi / 360, 0.0, 5.0).beams == 362


# -- REP 117 readings ------------------------------------------------------------------------------
ONE_OF_EACH = [2.0, -math.inf, math.inf, math.nan, 0.05, -1.0, 20.0, 10.0, 0.1]


@pytest.mark.parametrize('inf_is_valid', [False, True])
def test_each_reading_clears_and_marks_as_rep_117_says(inf_is_valid):
    n = len(ONE_OF_EACH)
    rays = scan_rays(ONE_OF_EACH, 0.0, (n - 1) * 0.1, 0.1, 0.1, 10.0, inf_is_valid=inf_is_valid)
    inf_clear = 10.0 if inf_is_valid else 0.0
    #                         return  -inf  +inf       nan  below  neg   beyond  =max  =min
    assert rays.clear.tolist() == [2.0, 0.1, inf_clear, 0.0, 0.0, 0.0, 0.0, 10.0, 0.1]
    assert rays.mark.tolist() == [True, True, False, False, False, False, False, True, True]
    assert rays.mark_range.tolist() == [2.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 10.0, 0.1]
    assert np.allclose(rays.angles, 0.1 * np.arange(n))
    assert rays.counts() == {'beams': 9, 'returns': 3, 'near_objects': 1, 'no_return': 1, 'erroneous': 1,
                             'below_min': 2, 'beyond_max': 1}


def test_the_arrays_are_read_only():
    rays = scan([1.0] * 360)
    for a in (rays.angles, rays.clear, rays.mark, rays.mark_range):
        with pytest.raises(ValueError):
            a[0] = 0


@pytest.mark.parametrize('ranges, words', [
    ([math.nan] * 360, '360 of 360 beams NaN (erroneous measurements, REP 117): they clear nothing'),
    ([0.05] * 360, '360 of 360 beams below range_min 0.1: they clear nothing'),
    ([-2.0] * 360, '360 of 360 beams below range_min 0.1: they clear nothing'),
    ([math.nan] * 50 + [0.05] * 50 + [1.0] * 260,
     '50 of 360 beams NaN (erroneous measurements, REP 117) and 50 of 360 beams below range_min 0.1: they clear '
     'nothing'),
    ([math.inf] * 360, 'not one usable reading in 360 beams: 360 +inf (no return within range_max; inf_is_valid is '
                       'false); they clear nothing'),
    ([20.0] * 360, 'not one usable reading in 360 beams: 360 beyond range_max 10 (did not come back); they clear '
                   'nothing'),
    ([math.inf] * 350 + [math.nan] * 10,
     'not one usable reading in 360 beams: 350 +inf (no return within range_max; inf_is_valid is false), 10 of 360 '
     'beams NaN (erroneous measurements, REP 117); they clear nothing'),
    ([-math.inf] * 360, '360 of 360 beams -inf (objects closer than range_min 0.1, REP 117): marked there'),
])
def test_a_suspicious_scan_is_described_in_plain_words(ranges, words):
    assert scan(ranges).problem() == words


@pytest.mark.parametrize('ranges, inf_is_valid', [
    ([1.0] * 360, False),
    ([math.nan] * 90 + [1.0] * 270, False),          # a quarter exactly: not more than a quarter
    ([math.inf] * 360, True),
    ([-math.inf] * 90 + [1.0] * 270, False),       # a quarter of the beams on something too close
    ([math.inf] * 359 + [3.0], False),
])
def test_a_plausible_scan_has_no_problem(ranges, inf_is_valid):
    assert scan(ranges, inf_is_valid=inf_is_valid).problem() == ''


def test_an_empty_scan_says_nothing():
    rays = scan_rays([], 0.0, 0.0, 0.1, 0.0, 5.0)
    assert rays.beams == 0 and rays.problem() == 'the scan has no beams: it says nothing'


# -- clouds ----------------------------------------------------------------------------------------
def cloud(xy, dtype='<f4', pad=4, z_first=True):
    """(data bytes, fields, point_step) of a cloud of x, y (and z) points of ``dtype`` with ``pad`` bytes more."""
    names = [('z', dtype), ('x', dtype), ('y', dtype)] if z_first else [('x', dtype), ('y', dtype), ('z', dtype)]
    points = np.zeros(len(xy), dtype=names + ([('pad', f'V{pad}')] if pad else []))
    points['x'], points['y'] = np.asarray(xy, dtype=float).reshape(-1, 2).T
    code = 7 if np.dtype(dtype).itemsize == 4 else 8
    fields = {name: (points.dtype.fields[name][1], code, 1) for name, _ in names}
    return points.tobytes(), fields, points.dtype.itemsize


@pytest.mark.parametrize('dtype, bigendian', [('<f4', False), ('>f4', True), ('<f8', False), ('>f8', True)])
def test_a_cloud_is_read_in_either_byte_order_and_its_nan_points_dropped(dtype, bigendian):
    xy = [[1.0, 2.0], [3.0, -4.0], [math.nan, 1.0], [5.0, math.inf], [-0.5, 0.25]]
    data, fields, step = cloud(xy, dtype)
    out = cloud_xy(data, fields, step, step * 5, 5, 1, bigendian, 100)
    assert np.array_equal(out.xy, [[1.0, 2.0], [3.0, -4.0], [-0.5, 0.25]])
    assert out.dropped == 2
    xy_only, dropped = out                         # also a (xy, dropped) pair
    assert dropped == 2 and xy_only.shape == (3, 2)


def test_a_cloud_of_rows_is_read_row_after_row():
    xy = np.arange(12, dtype=float).reshape(6, 2)
    data, fields, step = cloud(xy, pad=0)
    out = cloud_xy(data, fields, step, step * 3, 3, 2, False, 100)
    assert np.array_equal(out.xy, xy) and out.dropped == 0


@pytest.mark.parametrize('wrap', [bytes, bytearray, memoryview, lambda b: array.array('B', b),
                                  lambda b: np.frombuffer(b, dtype=np.uint8), list])
def test_a_cloud_is_read_from_any_byte_container(wrap):
    data, fields, step = cloud([[1.0, 2.0], [3.0, 4.0]])
    assert np.array_equal(cloud_xy(wrap(data), fields, step, 2 * step, 2, 1, False, 10).xy, [[1, 2], [3, 4]])


def test_an_empty_cloud_has_no_points():
    _, fields, step = cloud([])
    out = cloud_xy(b'', fields, step, 0, 0, 1, False, 10)
    assert out.xy.shape == (0, 2) and out.dropped == 0


def test_a_cloud_of_too_many_points_is_refused_before_its_data_is_read():
    _, fields, step = cloud([[0.0, 0.0]])
    with pytest.raises(ValueError, match=r'cloud refused: 1000 x 1001 = 1001000 points exceed max_points=1000000'):
        cloud_xy(None, fields, step, step * 1000, 1000, 1001, False, 1_000_000)


def test_a_cloud_whose_point_step_is_not_its_stride_is_refused_both_ways():
    n = 100
    xy = np.ones((n, 2))
    data, fields, step = cloud(xy, '<f4', pad=4, z_first=False)      # 16-byte points
    assert step == 16
    # declared point_step 12 and row_step 12 n, but 16 n bytes sent
    with pytest.raises(ValueError, match=r'data is 1600 bytes, not row_step 1200 x height 1 \(1200\): its real '
                                         r'stride is 16 bytes a point, point_step says 12'):
        cloud_xy(data, fields, 12, 12 * n, n, 1, False, 1000)
    # row_step 16 n agrees with the data, point_step 12 does not
    with pytest.raises(ValueError, match=r"row_step 1600 != point_step 12 x width 100 \(1200\): its rows' stride "
                                         r'is 16 bytes a point, point_step says 12'):
        cloud_xy(data, fields, 12, 16 * n, n, 1, False, 1000)
    assert len(cloud_xy(data, fields, 16, 16 * n, n, 1, False, 1000).xy) == n


def test_a_cloud_with_padded_rows_or_short_data_is_refused():
    data, fields, step = cloud(np.ones((4, 2)), pad=0)
    with pytest.raises(ValueError, match=r'row_step 28 != point_step 12 x width 2 \(24\)'):
        cloud_xy(data + b'\0' * 8, fields, step, 28, 2, 2, False, 100)
    with pytest.raises(ValueError, match=r'data is 44 bytes, not row_step 24 x height 2 \(48\)'):
        cloud_xy(data[:-4], fields, step, 24, 2, 2, False, 100)


@pytest.mark.parametrize('change, words', [
    (lambda f: f.pop('x'), r"no field 'x' \(fields: \['y', 'z'\]\)"),
    (lambda f: f.pop('y'), r"no field 'y'"),
    (lambda f: f.update(x=(4, 6, 1)), r"field 'x' has datatype 6 \(FLOAT32 \(7\) or FLOAT64 \(8\) expected\)"),
    (lambda f: f.update(y=(8, 2, 1)), r"field 'y' has datatype 2"),
    (lambda f: f.update(y=(14, 7, 1)), r"field 'y' at offset 14 with 4 bytes does not fit point_step 16"),
    (lambda f: f.update(x=(-4, 7, 1)), r"field 'x' at offset -4 with 4 bytes does not fit point_step 16"),
    (lambda f: f.update(z=(0, 7, 5)), r"field 'z' at offset 0 with 20 bytes does not fit point_step 16"),
    (lambda f: f.update(rgb=(12, 0, 1)), r"field 'rgb' has datatype 0 \(not a PointField type 1..8\)"),
    (lambda f: f.update(rgb=(12, 7, -1)), r"field 'rgb' has count -1"),
    (lambda f: f.update(y=(6, 7, 1)), r'fields x \(bytes 4..8\) and y \(bytes 6..10\) overlap'),
])
def test_a_cloud_layout_fault_is_refused_by_name(change, words):
    data, fields, step = cloud(np.ones((3, 2)), pad=4)            # z at 0, x at 4, y at 8, pad to 16
    change(fields)
    with pytest.raises(ValueError, match='cloud refused: ' + words):
        cloud_xy(data, fields, step, 3 * step, 3, 1, False, 100)


def test_a_cloud_point_step_must_be_positive_and_sizes_not_negative():
    data, fields, step = cloud(np.ones((3, 2)))
    with pytest.raises(ValueError, match=r'point_step is 0 \(must be > 0\)'):
        cloud_xy(data, fields, 0, 0, 3, 1, False, 100)
    with pytest.raises(ValueError, match=r'width -3 and height 1 must be >= 0'):
        cloud_xy(data, fields, step, step, -3, 1, False, 100)


# -- the pose at a stamp ---------------------------------------------------------------------------
def test_no_pose_is_none_and_an_infinite_gap():
    pose, gap = interpolated_pose([], np.zeros((0, 3)), 1.0, 0.1)
    assert pose is None and gap == math.inf


def test_a_pose_between_two_is_exact_on_a_straight_line():
    stamps = [0.0, 0.1, 0.2]
    states = [(3.0 * t, 1.0 - 2.0 * t, 0.5) for t in stamps]
    pose, gap = interpolated_pose(stamps, states, 0.137, 0.1)
    assert gap == 0.0
    assert np.allclose(pose, (0.411, 1.0 - 0.274, 0.5), atol=1e-12)


def test_a_pose_between_two_on_an_arc_is_within_the_documented_bound():
    v, omega, dt = 3.0, 1.0, 0.1
    radius = v / omega

    def on_arc(t):
        return (radius * math.sin(omega * t), radius * (1.0 - math.cos(omega * t)), omega * t)

    stamps = [0.0, dt]
    worst = 0.0
    for w in np.linspace(0.0, 1.0, 21):
        pose, gap = interpolated_pose(stamps, [on_arc(0.0), on_arc(dt)], w * dt, dt)
        truth = on_arc(w * dt)
        assert gap == 0.0
        assert abs(pose[2] - truth[2]) < 1e-12                         # the heading is linear on an arc
        worst = max(worst, math.hypot(pose[0] - truth[0], pose[1] - truth[1]))
    bound = v * omega * dt ** 2 / 8.0                                   # the module: a (t1 - t0)^2 / 8
    assert worst <= bound
    assert worst > 0.9 * bound, 'the bound is close to the error at the middle of the arc'


def test_the_heading_is_interpolated_the_short_way_round():
    pose, _ = interpolated_pose([0.0, 1.0], [(0, 0, math.pi - 0.1), (0, 0, -math.pi + 0.1)], 0.5, 1.0)
    assert abs(abs(pose[2]) - math.pi) < 1e-12


def test_a_stamp_after_the_newest_pose_takes_the_newest_and_its_gap():
    stamps, states = [0.0, 0.1], [(0.0, 0.0, 0.0), (0.3, 0.0, 0.1)]
    pose, gap = interpolated_pose(stamps, states, 0.14, 0.05)
    assert np.array_equal(pose, states[1]) and gap == pytest.approx(0.04)
    pose, gap = interpolated_pose(stamps, states, 0.5, 0.05)             # beyond max_gap: still the nearest
    assert np.array_equal(pose, states[1]) and gap == pytest.approx(0.4)


def test_a_bracket_wider_than_max_gap_gives_the_nearest_pose_and_its_gap():
    stamps, states = [0.0, 1.0], [(0.0, 0.0, 0.0), (3.0, 0.0, 0.0)]
    pose, gap = interpolated_pose(stamps, states, 0.3, 0.5)              # 0.7 from the later pose
    assert np.array_equal(pose, states[0]) and gap == pytest.approx(0.3)
    pose, gap = interpolated_pose(stamps, states, -0.2, 0.5)             # before the oldest
    assert np.array_equal(pose, states[0]) and gap == pytest.approx(0.2)


def test_a_stamp_on_a_pose_is_that_pose_and_repeated_stamps_do_not_divide_by_zero():
    stamps, states = [0.0, 0.1, 0.1], [(0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (2.0, 0.0, 0.0)]
    pose, gap = interpolated_pose(stamps, states, 0.0, 0.05)
    assert np.array_equal(pose, states[0]) and gap == 0.0
    pose, gap = interpolated_pose(stamps, states, 0.1, 0.05)
    assert pose[0] in (1.0, 2.0) and gap == 0.0
