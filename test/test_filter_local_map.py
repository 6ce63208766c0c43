"""filter.sensing.local_map: what the range sensors saw, kept in a rolling window of cells (ROS-free)."""
import math

import numpy as np
import pytest

from supersafe_ros.filter.sensing.local_map import LocalMap, MapSettings
from supersafe_ros.filter.sensing.readings import scan_rays

CELL = 0.1


def new_map(size=10.0, depth=0.0, at=(0.0, 0.0)) -> LocalMap:
    m = LocalMap(MapSettings(cell=CELL, size=size, depth=depth))
    m.follow(*at)
    return m


def fan(ranges, lo=-0.5, hi=0.5, range_min=0.1, range_max=8.0, inf_is_valid=False):
    """Rays of a scan of len(ranges) beams from ``lo`` to ``hi``."""
    n = len(ranges)
    return scan_rays(ranges, lo, hi, (hi - lo) / (n - 1), range_min, range_max, inf_is_valid=inf_is_valid)


def wall_ranges(n=101, x=3.0, lo=-0.5, hi=0.5):
    """Ranges from the origin to the wall x = ``x``, beams from ``lo`` to ``hi``."""
    return x / np.cos(np.linspace(lo, hi, n))


def is_occupied(m: LocalMap, x, y) -> bool:
    i, j = int(math.floor(x / CELL)) - round(m.origin[0] / CELL), int(math.floor(y / CELL)) - round(m.origin[1] / CELL)
    return bool(m.occupied[i, j])


def is_seen(m: LocalMap, x, y) -> bool:
    i, j = int(math.floor(x / CELL)) - round(m.origin[0] / CELL), int(math.floor(y / CELL)) - round(m.origin[1] / CELL)
    return bool(m.seen[i, j])


def centres_are(got, expected) -> bool:
    """The centres ``got`` are ``expected`` (same count, same places)."""
    expected = np.asarray(expected, dtype=float).reshape(-1, 2)
    return got.shape == expected.shape and np.allclose(got, expected)


def all_occupied(m: LocalMap):
    """Every cell of the window occupied (an occupancy grid of 100s over it)."""
    n = m.shape[0]
    m.integrate_grid((m.origin[0], m.origin[1], 0.0), CELL, n, n, [100] * (n * n), 50)
    assert m.occupied.all()


# -- the headline: a wall stays where it was seen ------------------------------------------------------
@pytest.mark.parametrize('reading, inf_is_valid', [
    (math.nan, False), (-2.0, False), (0.05, False), (math.inf, False), (20.0, False)])
def test_a_seen_wall_stays_after_scans_that_say_nothing(reading, inf_is_valid):
    m = new_map()
    m.integrate_rays((0.0, 0.0, 0.0), fan(wall_ranges()))
    wall = m.occupied_centres(3.0, 0.0, 2.0)
    assert len(wall) > 30 and np.all(np.abs(wall[:, 0] - 3.05) < 1e-9)
    before, version = m.occupied.copy(), m.version
    for _ in range(3):
        view = m.integrate_rays((0.0, 0.0, 0.0), fan([reading] * 101, inf_is_valid=inf_is_valid))
        assert view.marked == 0 and view.cleared == 0
    assert np.array_equal(m.occupied, before)
    assert m.version == version, 'nothing changed'
    assert m.last_view.problem, 'a scan that says nothing is described'


def test_a_scan_of_minus_inf_marks_a_ring_at_range_min():
    m = new_map()
    n = 720
    inc = 2 * math.pi / n
    m.integrate_rays((0.0, 0.0, 0.0), scan_rays([-math.inf] * n, -math.pi, math.pi - inc, inc, 1.0, 8.0))
    ring = m.occupied_centres(0.0, 0.0, 3.0)
    r = np.hypot(ring[:, 0], ring[:, 1])
    assert len(ring) > 40 and np.all(np.abs(r - 1.0) <= m.cell_radius)
    assert m.last_view.counts['near_objects'] == n
    assert is_seen(m, 0.45, 0.05) and not is_occupied(m, 0.45, 0.05)       # inside the ring: cleared


def test_plus_inf_clears_its_beam_to_range_max_only_when_the_driver_says_so():
    m = new_map()
    m.integrate_rays((0.0, 0.0, 0.0), fan([2.05] * 11, -0.01, 0.01))
    assert is_occupied(m, 2.05, 0.0)
    m.integrate_rays((0.0, 0.0, 0.0), fan([math.inf] * 11, -0.01, 0.01, range_max=4.0))
    assert is_occupied(m, 2.05, 0.0)
    m.integrate_rays((0.0, 0.0, 0.0), fan([math.inf] * 11, -0.01, 0.01, range_max=4.0, inf_is_valid=True))
    assert not is_occupied(m, 2.05, 0.0)
    assert not is_occupied(m, 3.95, 0.0) and is_seen(m, 3.95, 0.0) and not is_seen(m, 4.15, 0.0)


def test_beams_of_any_finite_length_clear_across_the_window():
    m = new_map()
    all_occupied(m)
    with np.errstate(all='raise'):
        m.integrate_rays((0.0, 0.05, 0.0), scan_rays([math.inf, 1e300], 0.0, math.pi, math.pi, 0.0, 1e300,
                                                     inf_is_valid=True))
    assert not m.occupied[:, 50].any(), 'both beams along y = 0.05 clear the whole row'
    assert m.occupied.sum() == 100 * 99


def test_a_return_beyond_a_marked_cell_clears_it_and_a_return_at_it_keeps_it():
    m = new_map()
    beam = dict(lo=-0.001, hi=0.001)
    m.integrate_rays((0.0, 0.0, 0.0), fan([2.05] * 3, **beam))
    version = m.version
    m.integrate_rays((0.0, 0.0, 0.0), fan([2.07] * 3, **beam))          # the same cell again
    assert is_occupied(m, 2.05, 0.0) and m.version == version
    m.integrate_rays((0.0, 0.0, 0.0), fan([4.5] * 3, **beam))           # seen through
    assert not is_occupied(m, 2.05, 0.0) and is_occupied(m, 4.5, 0.0) and m.version > version


def test_marks_win_over_clears_in_the_same_message():
    m = new_map()
    # beam 0 returns in cell (20, 0); beam 1, 0.001 rad above, passes through that cell to 4.5 m
    rays = scan_rays([2.05, 4.5], 0.0, 0.001, 0.001, 0.1, 8.0)
    view = m.integrate_rays((0.0, 0.0, 0.0), rays)
    assert is_occupied(m, 2.05, 0.0) and is_occupied(m, 4.5 * math.cos(0.001), 4.5 * math.sin(0.001))
    assert view.marked == 2
    # the same beam alone, later: seen through
    m.integrate_rays((0.0, 0.0, 0.0), scan_rays([4.5], 0.001, 0.001, 0.001, 0.1, 8.0))
    assert not is_occupied(m, 2.05, 0.0)


def test_depth_marks_the_beam_behind_a_return_but_not_what_the_same_message_cleared():
    alone = new_map(depth=1.0)
    alone.integrate_rays((0.0, 0.0, 0.0), scan_rays([2.05], 0.0, 0.0, 0.1, 0.1, 8.0))
    behind = [(x + 0.05, 0.05) for x in np.arange(2.0, 3.0, CELL)]
    assert all(is_occupied(alone, *p) for p in behind)
    assert not is_occupied(alone, 3.15, 0.05) and not is_occupied(alone, 1.95, 0.05)
    # a second beam of the same scan passes through those cells (0.03 rad: y < 0.1 up to x = 3.3)
    both = new_map(depth=1.0)
    both.integrate_rays((0.0, 0.0, 0.0), scan_rays([2.05, 4.0], 0.0, 0.03, 0.03, 0.1, 8.0))
    assert is_occupied(both, 2.05, 0.05)
    assert not any(is_occupied(both, *p) for p in behind[1:])
    # depth marks do cover what an earlier message cleared
    earlier = new_map(depth=1.0)
    earlier.integrate_rays((0.0, 0.0, 0.0), scan_rays([4.0], 0.03, 0.03, 0.1, 0.1, 8.0))
    earlier.integrate_rays((0.0, 0.0, 0.0), scan_rays([2.05], 0.0, 0.0, 0.1, 0.1, 8.0))
    assert all(is_occupied(earlier, *p) for p in behind)


def test_slack_marks_every_cell_whose_centre_is_within_it_of_the_return():
    m = new_map()
    slack = 0.27
    m.integrate_rays((0.0, 0.0, 0.0), scan_rays([2.013], 0.3, 0.3, 0.1, 0.1, 8.0), slack=slack)
    hit = 2.013 * np.array([math.cos(0.3), math.sin(0.3)])
    centres = m.occupied_centres(*hit, 1.0)
    expected = {(i, j) for i in range(10, 30) for j in range(0, 16)
                if math.hypot((i + 0.5) * CELL - hit[0], (j + 0.5) * CELL - hit[1]) <= slack}
    got = {(int(round(x / CELL - 0.5)), int(round(y / CELL - 0.5))) for x, y in centres}
    assert got == expected | {(int(hit[0] // CELL), int(hit[1] // CELL))}
    with pytest.raises(ValueError, match='slack must be a number or one per item'):
        m.integrate_rays((0.0, 0.0, 0.0), scan_rays([2.0, 2.0], 0.0, 0.1, 0.1, 0.1, 8.0), slack=[0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match='slack must be finite and >= 0'):
        m.integrate_rays((0.0, 0.0, 0.0), scan_rays([2.0], 0.0, 0.0, 0.1, 0.1, 8.0), slack=-0.1)


@pytest.mark.parametrize('quadrant', range(4))
@pytest.mark.parametrize('rise, run', [(1, 1), (1, 2), (2, 1)])
def test_a_cell_touched_only_at_a_corner_is_not_cleared(quadrant, rise, run):
    m = new_map()
    all_occupied(m)
    # from the corner (0, 0) at slope rise / run: through the lattice corners (k run, k rise) CELL
    sx, sy = [(1, 1), (-1, 1), (-1, -1), (1, -1)][quadrant]
    angle = math.atan2(sy * rise, sx * run)
    length = 4 * math.hypot(rise, run) * CELL
    m.integrate_rays((0.0, 0.0, 0.0), scan_rays([length], angle, angle, 0.1, 0.0, 8.0))
    free = {(i, j) for i, j in np.argwhere(~m.occupied) + np.round(np.array(m.origin) / CELL).astype(int)}
    # the cells the segment crosses (sampled densely, away from the corners) and no other
    t = np.linspace(0.0, 4.0, 4001)[:-1]
    t = t[np.abs(t * rise - np.round(t * rise)) + np.abs(t * run - np.round(t * run)) > 1e-6]
    crossed = {(int(math.floor(sx * run * v)), int(math.floor(sy * rise * v))) for v in t}
    own = tuple(int(v) for v in np.floor(length * np.array([math.cos(angle), math.sin(angle)]) / CELL))
    assert free == crossed - {own}, 'its return marks its own cell'
    assert len(crossed) == 4 * (rise + run - 1), "a corner passed is one cell, not three"


def chord(start, direction, length, lo, hi):
    """(S, C) the length of each segment inside each box [lo, hi) (negative: apart)."""
    t0 = np.zeros((len(direction), len(lo)))
    t1 = np.broadcast_to(np.asarray(length, dtype=float)[:, None], t0.shape).copy()
    for ax in (0, 1):
        p, u = start[ax], direction[:, ax][:, None]
        with np.errstate(divide='ignore', invalid='ignore'):
            a, b = (lo[None, :, ax] - p) / u, (hi[None, :, ax] - p) / u
        inside = (lo[None, :, ax] <= p) & (p <= hi[None, :, ax])
        still = u == 0
        t0 = np.maximum(t0, np.where(still, np.where(inside, -np.inf, np.inf), np.minimum(a, b)))
        t1 = np.minimum(t1, np.where(still, np.where(inside, np.inf, -np.inf), np.maximum(a, b)))
    return t1 - t0


@pytest.mark.parametrize('seed', range(12))
def test_a_scan_clears_exactly_the_cells_its_beams_pass_through(seed):
    rng = np.random.default_rng(seed)
    m = new_map(size=4.0)
    all_occupied(m)
    n = m.shape[0]
    if seed % 3 == 0:                       # on the lattice: corners and cell centres, special angles
        sensor = (rng.integers(-10, 10) * CELL + rng.choice([0.0, 0.05]), rng.integers(-10, 10) * CELL, 0.0)
        angles = np.sort(rng.choice(np.arange(-16, 16) * math.pi / 16, 24, replace=False))
    else:
        sensor = (*rng.uniform(-1.5, 1.5, 2), rng.uniform(-math.pi, math.pi))
        angles = np.sort(rng.uniform(-math.pi, math.pi, 60))
    ranges = rng.uniform(0.0, 4.0, len(angles))
    ranges[::5] = 9.0                       # beams that leave the window
    ij = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing='ij'), -1).reshape(-1, 2)
    corner = np.array(m.origin) / CELL + ij
    edge = np.array(m.origin) / CELL
    inner_lo, inner_hi = np.maximum(corner, edge + 1e-5) + 1e-7, np.minimum(corner + 1, edge + n - 1e-5) - 1e-7
    total = 0
    for a, r in zip(angles, ranges):
        m.integrate_rays(sensor, scan_rays([r], a, a, 0.1, 0.0, 10.0))
        cleared = ~m.occupied.reshape(-1)
        all_occupied(m)
        # every cleared cell is within 1e-7 cell of the beam's segment (before its return); every cell the
        # beam crosses over more than 1e-5 cell (1e-7 inside the cell's edges, 1e-5 inside the window's),
        # but its return's, is cleared
        u = np.array([[math.cos(a + sensor[2]), math.sin(a + sensor[2])]])
        start, length = np.array(sensor[:2]) / CELL, np.array([r / CELL])
        near = chord(start, u, length, corner - 1e-7, corner + 1 + 1e-7)[0] >= 0
        through = chord(start, u, length, inner_lo, inner_hi)[0] > 1e-5
        own = (ij == np.floor((np.array(sensor[:2]) + r * u[0]) / CELL) - np.round(edge)).all(axis=1)
        assert not (cleared & ~near).any(), f'beam {a:.4f} ({r:.3f} m) cleared a cell it does not come near'
        assert not (through & ~cleared & ~own).any(), f'beam {a:.4f} ({r:.3f} m) left a cell it crossed'
        total += cleared.sum()
    assert total > 200


def test_one_scan_of_many_beams_clears_what_its_beams_do_one_by_one_except_its_returns():
    rng = np.random.default_rng(3)
    n = 400
    ranges = rng.uniform(0.0, 7.0, n)
    ranges[::7] = math.nan
    rays = scan_rays(ranges, -math.pi, math.pi - 2 * math.pi / n, 2 * math.pi / n, 0.0, 6.0)
    pose = (0.33, -0.21, 0.4)
    together = new_map()
    all_occupied(together)
    together.integrate_rays(pose, rays)
    marks = new_map()
    marks.integrate_rays(pose, rays)
    one_by_one = new_map()
    cleared = np.zeros(one_by_one.shape, dtype=bool)
    for i in range(n):
        all_occupied(one_by_one)
        one_by_one.integrate_rays(pose, scan_rays([ranges[i]], rays.angles[i], rays.angles[i], 0.1, 0.0, 6.0))
        cleared |= ~one_by_one.occupied
    assert np.array_equal(~together.occupied, cleared & ~marks.occupied)
    assert (~together.occupied).sum() > 1000 and marks.occupied.sum() > 100


# -- the window -------------------------------------------------------------------------------------
def test_the_window_moves_by_whole_cells_and_marks_stay_in_the_world():
    m = new_map()
    assert m.origin == (-5.0, -5.0) and m.shape == (100, 100)
    m.integrate_rays((0.0, 0.0, 0.0), scan_rays([1.05], 0.0, 0.0, 0.1, 0.1, 8.0))
    version = m.version
    assert not m.follow(2.0, 1.0), 'within recentre (2.5): the window stays'
    assert m.version == version and m.origin == (-5.0, -5.0)
    assert m.follow(2.53, 1.47)
    assert m.version == version + 1
    x0, y0 = m.origin
    assert abs(x0 / CELL - round(x0 / CELL)) < 1e-9 and abs(y0 / CELL - round(y0 / CELL)) < 1e-9
    assert (x0, y0) == pytest.approx((2.5 - 5.0, 1.5 - 5.0))
    assert centres_are(m.occupied_centres(1.0, 0.0, 0.5), [[1.05, 0.05]])
    assert m.occupied.sum() == 1


def test_cells_that_leave_the_window_are_forgotten():
    m = new_map()
    m.integrate_rays((0.0, 0.0, 0.0), scan_rays([4.55], math.pi, math.pi, 0.1, 0.1, 8.0))
    assert is_occupied(m, -4.55, 0.0) and is_seen(m, -2.0, 0.0)
    m.follow(3.0, 0.0)                                  # the window's left edge to -2
    m.follow(0.0, 0.0)                                  # and back
    assert not is_occupied(m, -4.55, 0.0) and not is_seen(m, -4.55, 0.0) and not is_seen(m, -2.95, 0.0)
    assert is_seen(m, -1.95, 0.0), 'what stayed in the window is kept'


def test_a_message_before_any_follow_places_the_window_on_its_sensor():
    m = LocalMap(MapSettings(cell=CELL, size=4.0))
    m.integrate_rays((10.0, 20.0, 0.0), scan_rays([1.05], 0.0, 0.0, 0.1, 0.1, 8.0))
    assert m.placed and m.origin == pytest.approx((8.0, 18.0))
    assert centres_are(m.occupied_centres(11.0, 20.0, 0.2), [[11.05, 20.05]])


def test_marks_outside_the_window_are_ignored_and_seeing_free_cells_is_a_change():
    m = new_map(size=4.0)
    version = m.version
    view = m.integrate_rays((0.0, 0.0, 0.0), scan_rays([7.0], 0.0, 0.0, 0.1, 0.1, 8.0), slack=0.3)
    assert view.marked == 0 and view.cleared == 20
    assert not m.occupied.any() and m.seen.sum() == 20
    assert m.version == version + 1, 'cells newly seen free'
    m.integrate_rays((0.0, 0.0, 0.0), scan_rays([7.0], 0.0, 0.0, 0.1, 0.1, 8.0))
    assert m.version == version + 1, 'seen free again: no change'


@pytest.mark.parametrize('copies', [1, 30000])
def test_the_slack_of_a_return_outside_the_window_marks_the_cells_inside_it_reaches(copies):
    m = new_map()
    hit = (5.01, 0.09)                              # the window ends at x = 5; off its cell's centre
    m.integrate_points((4.0, hit[1], 0.0), np.repeat([[hit[0] - 4.0, 0.0]], copies, axis=0), slack=0.25)
    got = {tuple(np.round(c / CELL - 0.5).astype(int)) for c in m.occupied_centres(*hit, 1.0)}
    exact = {(i, j) for i in range(40, 50) for j in range(-5, 6)
             if math.hypot((i + 0.5) * CELL - hit[0], (j + 0.5) * CELL - hit[1]) <= 0.25}
    assert exact and exact <= got
    if copies == 1:
        assert got == exact
    else:                                           # merged per cell: at most the cell's half diagonal more
        assert all(math.hypot((i + 0.5) * CELL - hit[0], (j + 0.5) * CELL - hit[1]) <= 0.25 + 2 * m.cell_radius
                   for i, j in got)


@pytest.mark.parametrize('widest', [0.2, 0.6, 1.5])
def test_merged_slack_discs_are_the_discs_about_their_cells_centres(widest):
    rng = np.random.default_rng(5)
    points = rng.uniform(-4.0, 4.0, (40, 2))
    slack = rng.uniform(0.0, widest, 40)
    m = new_map()
    m.integrate_points((0.0, 0.0, 0.0), np.repeat(points, 2000, axis=0), slack=np.repeat(slack, 2000))
    got = {tuple(np.round(c / CELL - 0.5).astype(int)) for c in m.occupied_centres(0.0, 0.0, 10.0)}
    own = np.floor(points / CELL)                       # each point's cell holds its slack + half a diagonal
    expected = {(i, j) for i in range(-50, 50) for j in range(-50, 50)
                if (np.hypot(own[:, 0] - i, own[:, 1] - j) <= slack / CELL + math.sqrt(0.5)).any()}
    assert got == expected


def test_a_slack_over_the_window_side_is_refused():
    m = new_map()
    with pytest.raises(ValueError, match=r"slack 12 m is over the window's side \(10 m\)"):
        m.integrate_points((0.0, 0.0, 0.0), [[1.0, 0.0]], slack=12.0)


# -- clouds -----------------------------------------------------------------------------------------
def test_every_point_of_a_cloud_marks_its_cell_and_nan_points_say_nothing():
    m = new_map()
    points = [[1.05, 0.05], [2.05, -1.05], [math.nan, 1.0], [0.55, math.inf]]
    view = m.integrate_points((0.0, 0.0, 0.0), points)
    assert is_occupied(m, 1.05, 0.05) and is_occupied(m, 2.05, -1.05)
    assert view.marked == 2 and view.counts['dropped'] == 2 and view.counts['points'] == 4
    assert view.problem == '2 of 4 points not finite: they say nothing'


def test_a_cloud_clears_to_the_nearest_point_of_each_bearing_bin_only():
    m = new_map()
    m.integrate_points((0.0, 0.0, 0.0), [[1.55, 0.05], [4.55, 0.05], [1.55, 2.05]])
    assert all(is_occupied(m, *p) for p in ((1.55, 0.05), (4.55, 0.05), (1.55, 2.05)))
    # a near and a far point on the same bearing: the ray to the near one clears, the far one's not
    m.integrate_points((0.05, 0.05, 0.0), [[3.0, 0.0], [4.9, 0.0]])
    assert not is_occupied(m, 1.55, 0.05), 'between the sensor and the nearest point: seen through'
    assert is_occupied(m, 4.55, 0.05), 'between the nearest point and a farther one of its bin: kept'
    assert is_occupied(m, 3.05, 0.05) and is_occupied(m, 4.95, 0.05)
    assert is_occupied(m, 1.55, 2.05), 'no ray near it'
    assert m.last_view.counts['clearing_rays'] == 1


def test_a_cloud_point_at_the_sensor_marks_its_cell_and_clears_nothing():
    m = new_map()
    with np.errstate(all='raise'):
        view = m.integrate_points((0.55, 0.55, 0.3), [[0.0, 0.0]])
    assert view.counts['clearing_rays'] == 0 and view.marked == 1 and view.cleared == 0
    assert is_occupied(m, 0.55, 0.55)


def test_a_sensor_outside_the_window_clears_from_the_window_edge_and_a_beam_away_clears_nothing():
    m = new_map()
    view = m.integrate_rays((6.0, 0.05, 0.0), scan_rays([4.0, 3.0], math.pi, 2 * math.pi, math.pi, 0.0, 8.0))
    assert view.marked == 1 and is_occupied(m, 2.05, 0.05)
    assert view.cleared == 29 and not m.occupied[71:, 50].any() and m.seen[70:, 50].all()
    assert m.seen.sum() == 30


def test_a_cloud_point_marks_its_ray_depth_behind_it():
    m = new_map(depth=0.5)
    m.integrate_points((0.05, 0.05, 0.0), [[2.0, 0.0], [0.0, -1.0]])
    assert all(is_occupied(m, x, 0.05) for x in (2.05, 2.25, 2.45)) and not is_occupied(m, 2.65, 0.05)
    assert all(is_occupied(m, 0.05, y) for y in (-0.95, -1.15, -1.35)) and not is_occupied(m, 0.05, -1.55)


def test_a_cloud_in_the_sensor_frame_is_turned_by_the_sensor_yaw():
    m = new_map()
    m.integrate_points((1.0, 1.0, math.pi / 2), [[2.05, 0.0]])
    assert is_occupied(m, 1.0, 3.05) and not is_occupied(m, 1.0, 2.0) and is_seen(m, 1.0, 2.0)


def test_a_cloud_with_slack_marks_the_cells_within_it_merged_or_not():
    rng = np.random.default_rng(0)
    points = rng.uniform(-3.0, 3.0, (200, 2))
    few = new_map()
    few.integrate_points((0.0, 0.0, 0.0), points, slack=0.17)
    exact = {tuple(np.round(c / CELL - 0.5).astype(int)) for c in few.occupied_centres(0.0, 0.0, 10.0)}
    brute = {(i, j) for i in range(-50, 50) for j in range(-50, 50)
             if np.hypot((i + 0.5) * CELL - points[:, 0], (j + 0.5) * CELL - points[:, 1]).min() <= 0.17}
    own = {tuple(np.floor(p / CELL).astype(int)) for p in points}
    assert exact == brute | own
    # past the budget the points are merged per cell: a superset, at most half a cell's diagonal more
    many = new_map()
    many.integrate_points((0.0, 0.0, 0.0), np.repeat(points, 400, axis=0), slack=0.17)
    merged = {tuple(np.round(c / CELL - 0.5).astype(int)) for c in many.occupied_centres(0.0, 0.0, 10.0)}
    wider = {(i, j) for i in range(-50, 50) for j in range(-50, 50)
             if np.hypot((i + 0.5) * CELL - points[:, 0], (j + 0.5) * CELL - points[:, 1]).min()
             <= 0.17 + 2 * few.cell_radius}
    assert exact <= merged <= wider


# -- occupancy grids --------------------------------------------------------------------------------
def test_a_grid_marks_at_its_threshold_frees_below_and_keeps_unknown():
    m = new_map()
    m.integrate_points((0.0, 0.0, 0.0), [[0.25, 0.05], [0.35, 0.05]])   # marked before the grid
    # a 6 x 1 grid of 0.1 m cells from (0, 0): 0, 49, 50, 100, -1 (over a marked cell), 0 (over one)
    view = m.integrate_grid((0.0, 0.0, 0.0), 0.1, 6, 1, [0, 49, 50, 100, -1, 0], 50)
    assert [is_occupied(m, 0.05 + 0.1 * k, 0.05) for k in range(6)] == [False, False, True, True, False, False]
    m2 = new_map()
    m2.integrate_points((0.0, 0.0, 0.0), [[0.45, 0.05], [0.55, 0.05]])
    m2.integrate_grid((0.0, 0.0, 0.0), 0.1, 6, 1, [0, 49, 50, 100, -1, 0], 50)
    assert is_occupied(m2, 0.45, 0.05), 'unknown leaves the cell as it was'
    assert not is_occupied(m2, 0.55, 0.05), 'free clears a marked cell'
    assert view.kind == 'grid' and view.marked == 2 and view.cleared == 3


def test_a_rotated_grid_lands_where_its_origin_says():
    m = new_map()
    # a grid turned by 90 degrees at (1, 1): its x axis along the map's y; cell (gi, gj) of 0.2 m at
    # map (1 - 0.2 gj - 0.1, 1 + 0.2 gi + 0.1)
    data = np.zeros(3 * 2, dtype=np.int8)
    data[1 * 3 + 2] = 100                                  # row gj = 1, column gi = 2
    m.integrate_grid((1.0, 1.0, math.pi / 2), 0.2, 3, 2, data.tobytes(), 65)
    centres = m.occupied_centres(0.7, 1.5, 0.5)
    assert len(centres) == 4                               # a 0.2 m grid cell holds four 0.1 m centres
    assert np.allclose(centres.mean(axis=0), [1.0 - 0.3, 1.0 + 0.5])
    assert is_seen(m, 0.95, 1.05) and not is_occupied(m, 0.95, 1.05)


@pytest.mark.parametrize('args, words', [
    (((0, 0, 0), 0.0, 2, 2, [0] * 4, 50), r'resolution is 0.0 \(must be finite and > 0\)'),
    (((0, 0, 0), math.nan, 2, 2, [0] * 4, 50), r'resolution is nan'),
    (((0, 0, 0), 0.1, 2, 2, [0] * 5, 50), r'5 values for 2 x 2 = 4 cells'),
    (((0, 0, 0), 0.1, -2, 2, [0] * 4, 50), r'-2 x 2 cells'),
    (((0, 0, 0), 0.1, 5000, 5000, [0] * 4, 50), r'5000 x 5000 cells \(each >= 0, at most 16777216 in all\)'),
    (((math.nan, 0, 0), 0.1, 2, 2, [0] * 4, 50), r'grid origin must be finite'),
    (((0, 0, 0), 0.1, 2, 2, [0, 0, 101, 0], 50), r'value 101 at cell \(0, 1\) is outside -1..100'),
    (((0, 0, 0), 0.1, 2, 2, [0, -2, 0, 0], 50), r'value -2 at cell \(1, 0\)'),
    (((0, 0, 0), 0.1, 2, 2, [0] * 4, 0), r'occupied_threshold is 0'),
])
def test_a_malformed_grid_is_refused_by_name(args, words):
    with pytest.raises(ValueError, match=words):
        new_map().integrate_grid(*args)


# -- reading the map --------------------------------------------------------------------------------
def test_occupied_centres_reads_the_cells_within_the_radius():
    m = new_map()
    m.integrate_points((0.0, 0.0, 0.0), [[1.05, 0.05], [1.35, 0.05], [-3.05, 2.05]])
    assert centres_are(m.occupied_centres(1.0, 0.0, 0.2), [[1.05, 0.05]])
    assert len(m.occupied_centres(1.0, 0.0, 0.5)) == 2
    assert len(m.occupied_centres(0.0, 0.0, 20.0)) == 3
    assert m.occupied_centres(30.0, 0.0, 1.0).shape == (0, 2)
    m.integrate_points((0.0, 0.0, 0.0), [[1.35, 0.35]])
    assert centres_are(m.occupied_centres(1.05, 0.05, 0.4), [[1.05, 0.05], [1.35, 0.05]]), '(1.35, 0.35): 0.42 away'
    centre = m.occupied_centres(1.05, 0.05, 0.01)[0]
    at_radius = math.hypot(centre[0] - 0.75, centre[1] - 0.05)
    assert centres_are(m.occupied_centres(0.75, 0.05, at_radius), [centre]), 'a centre at the radius is within it'
    assert m.cell_radius == pytest.approx(CELL * math.sqrt(2) / 2)


def test_a_snapshot_is_a_read_only_copy_with_the_version():
    m = new_map()
    m.integrate_points((0.0, 0.0, 0.0), [[1.05, 0.05]])
    snap = m.snapshot()
    assert snap.version == m.version and snap.origin == m.origin and snap.cell == CELL
    with pytest.raises(ValueError):
        snap.occupied[0, 0] = True
    with pytest.raises(ValueError):
        m.occupied[0, 0] = True
    m.integrate_points((0.0, 0.0, 0.0), [[0.05, 2.05]])
    assert snap.occupied.sum() == 1 and m.occupied.sum() == 2 and m.version > snap.version


def test_the_view_summary_carries_the_scan_counts_and_problem():
    m = new_map()
    view = m.integrate_rays((0.0, 0.0, 0.0), fan([math.nan] * 50 + [2.0] + [math.nan] * 50))
    assert m.last_view is view
    assert view.as_dict() == {'kind': 'scan', 'marked': 1, 'cleared': view.cleared, 'beams': 101, 'returns': 1,
                              'near_objects': 0, 'no_return': 0, 'erroneous': 100, 'below_min': 0,
                              'beyond_max': 0,
                              'problem': '100 of 101 beams NaN (erroneous measurements, REP 117): they clear nothing'}
    assert view.cleared == 20, 'the beam along x from the origin: cells 0..19, its return in cell 20'


@pytest.mark.parametrize('kwargs, words', [
    (dict(cell=0.0), 'cell must be finite and > 0'),
    (dict(cell=math.nan), 'cell must be finite and > 0'),
    (dict(size=-1.0), 'size must be finite and > 0'),
    (dict(cell=0.001, size=10.0), r'10000 cells a side, over 4096'),
    (dict(recentre=6.0), r'recentre must be finite, > 0 and <= size / 2 \(5\)'),
    (dict(recentre=0.0), 'recentre must be'),
    (dict(depth=-0.1), 'depth must be finite and >= 0'),
])
def test_map_settings_are_checked(kwargs, words):
    with pytest.raises(ValueError, match=words):
        MapSettings(**kwargs)


def test_map_settings_defaults():
    s = MapSettings()
    assert (s.cell, s.size, s.recentre, s.depth, s.cells) == (0.05, 10.0, 2.5, 0.0, 200)


def test_a_pose_not_finite_is_refused():
    m = new_map()
    with pytest.raises(ValueError, match='sensor_pose must be finite'):
        m.integrate_rays((math.nan, 0.0, 0.0), fan([1.0] * 3))
    with pytest.raises(ValueError, match='follow: position must be finite'):
        m.follow(math.inf, 0.0)


def test_the_robots_own_disc_is_cleared_and_nothing_beyond_it():
    """clear_footprint: the cells wholly within the robot's radius are cleared (a return there is the robot
    itself: a part of it seen, or a -inf reading marked at range_min), the cells its rim only crosses and
    those beyond stay; the version moves only when a cell changed."""
    m = new_map()
    m.integrate_rays((0.05, 0.05, 0.0), fan(wall_ranges(x=0.6)))       # a wall at x = 0.6
    ranges = np.full(36, -np.inf)             # every beam: an object closer than range_min (0.1)
    m.integrate_rays((0.05, 0.05, 0.0), scan_rays(ranges, -math.pi, math.pi - math.pi / 18, math.pi / 18, 0.1, 8.0))
    assert is_occupied(m, 0.14, 0.05) and is_occupied(m, 0.65, 0.05)
    before = m.version
    freed = m.clear_footprint(0.05, 0.05, 0.35)
    assert freed > 0 and m.version == before + 1
    assert not is_occupied(m, 0.14, 0.05) and not is_occupied(m, -0.05, 0.05), 'the ring inside the robot'
    assert is_occupied(m, 0.65, 0.05), 'the wall beyond the robot stays'
    assert m.clear_footprint(0.05, 0.05, 0.35) == 0 and m.version == before + 1
    assert m.clear_footprint(0.05, 0.05, 0.05) == 0, 'a radius under a cell\'s half diagonal holds no whole cell'
