"""ROS-free tests of the differential-drive robot's world (sim/unicycle_world.py): clearance and the
laser against their definitions, the unicycle's exact arc, collisions, the planner, the trips'
geometry as the issue describes it."""
import math

import numpy as np
import pytest

from supersafe_ros.sim import unicycle_world as uw

WORLD = uw.World(walls=((0.0, 3.0, 4.0, 3.0, 0.2), (5.0, -2.0, 5.0, 2.0, 0.1)),
                 polygons=(uw.box(2.0, -1.5, 1.0, 0.6, math.pi / 4), ((7.0, 0.0), (8.0, 1.0), (8.0, -1.0))),
                 discs=((-2.0, 0.0, 0.5), (2.0, 1.0, 0.1)))


def sphere_traced(world, origin, angle, range_max, tolerance=1e-9, steps=20000):
    """The first surface along a beam by marching it by the clearance (which never crosses a
    surface when the clearance is the exact distance): an independent reference for ray_cast."""
    u = np.array([math.cos(angle), math.sin(angle)])
    t = 0.0
    for _ in range(steps):
        d = float(world.clearance(np.asarray(origin) + t * u)[0])
        if d < tolerance:
            return t
        t += d
        if t > range_max:
            return math.inf
    return math.nan


def test_clearance_of_each_shape_is_its_signed_distance():
    # the wall (capsule, thickness 0.2): 0.1 from its centre line, round beyond its ends
    assert WORLD.clearance([[2.0, 3.5]])[0] == pytest.approx(0.4)
    assert WORLD.clearance([[2.0, 3.0]])[0] == pytest.approx(-0.1)
    assert WORLD.clearance([[-0.3, 3.4]])[0] == pytest.approx(0.5 - 0.1)
    # the box turned 45 degrees: on its corners, and inside it minus the distance to its nearest side
    corner = np.array(uw.box(2.0, -1.5, 1.0, 0.6, math.pi / 4))
    assert WORLD.clearance(corner) == pytest.approx(np.zeros(4), abs=1e-12)
    assert WORLD.clearance([[2.0, -1.5]])[0] == pytest.approx(-0.3)
    # the triangle, either orientation of its vertices: the point left of its tip
    assert WORLD.clearance([[6.5, 0.0]])[0] == pytest.approx(0.5)
    assert WORLD.clearance([[7.9, 0.0]])[0] < 0.0
    # discs
    assert WORLD.clearance([[-2.0, 2.0]])[0] == pytest.approx(1.5)
    assert WORLD.clearance([[-2.0, 0.0]])[0] == pytest.approx(-0.5)
    assert uw.World().clearance([[0.0, 0.0]])[0] == math.inf


def test_clearance_is_the_least_distance_to_sampled_surfaces():
    # brute force: points on every obstacle's boundary, the distance to the nearest one
    rng = np.random.default_rng(1)
    surface = []
    for x0, y0, x1, y1, t in WORLD.walls:
        s = np.linspace(0, 1, 4000)[:, None]
        a, b = np.array([x0, y0]), np.array([x1, y1])
        n = np.array([-(y1 - y0), x1 - x0]) / math.hypot(x1 - x0, y1 - y0)
        surface += [a + s * (b - a) + t / 2 * n, a + s * (b - a) - t / 2 * n]
        phi = np.linspace(0, 2 * math.pi, 2000)[:, None]
        surface += [c + t / 2 * np.hstack([np.cos(phi), np.sin(phi)]) for c in (a, b)]
    for poly in WORLD.polygons:
        v = np.asarray(poly)
        for a, b in zip(v, np.roll(v, -1, 0)):
            surface.append(a + np.linspace(0, 1, 3000)[:, None] * (b - a))
    for x, y, r in WORLD.discs:
        phi = np.linspace(0, 2 * math.pi, 4000)[:, None]
        surface.append(np.array([x, y]) + r * np.hstack([np.cos(phi), np.sin(phi)]))
    surface = np.concatenate(surface)
    points = rng.uniform([-3, -3], [9, 4], (300, 2))
    d = WORLD.clearance(points)
    brute = np.min(np.linalg.norm(points[:, None] - surface[None], axis=-1), axis=1)
    assert np.allclose(np.abs(d), brute, atol=2e-3)


def test_ray_cast_is_the_first_surface_along_each_beam():
    rng = np.random.default_rng(2)
    checked = 0
    for _ in range(12):
        o = rng.uniform([-3, -3], [9, 4])
        if WORLD.clearance([o])[0] <= 0.05:
            continue
        yaw = rng.uniform(-math.pi, math.pi)
        angles = np.linspace(-math.pi, math.pi, 90, endpoint=False)
        ranges = WORLD.ray_cast((o[0], o[1], yaw), angles, 8.0)
        assert ranges.dtype == np.float32
        for a, r in zip(angles, ranges):
            ref = sphere_traced(WORLD, o, yaw + a, 8.0)
            if math.isnan(ref):
                continue        # a beam grazing a corner that the march did not settle: no reference
            checked += 1
            if math.isinf(ref):
                assert math.isinf(r)
            else:
                assert float(r) == pytest.approx(ref, abs=1e-5)
    assert checked > 700


def test_ray_cast_hits_lie_on_surfaces_and_misses_are_inf_beyond_range():
    angles = np.linspace(-math.pi, math.pi, 360, endpoint=False)
    pose = (1.0, 0.5, 0.3)
    ranges = WORLD.ray_cast(pose, angles, 8.0).astype(float)
    hit = np.isfinite(ranges)
    assert 50 < hit.sum() < 360
    a = pose[2] + angles[hit]
    points = np.column_stack([pose[0] + ranges[hit] * np.cos(a), pose[1] + ranges[hit] * np.sin(a)])
    assert np.abs(WORLD.clearance(points)).max() < 1e-5
    near = WORLD.ray_cast(pose, angles, 1.0)
    assert np.all(np.isinf(near[ranges > 1.0])) and np.array_equal(near[ranges <= 1.0], ranges[ranges <= 1.0])
    assert np.all(np.isinf(uw.World().ray_cast(pose, angles, 8.0)))


def test_a_beam_from_inside_a_disc_meets_its_far_side():
    ranges = uw.ray_disc((0.5, 0.0), [[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]], [[0.0, 0.0]], [1.0])
    assert ranges[:, 0] == pytest.approx([0.5, 1.5, math.sqrt(0.75)])
    assert uw.ray_disc((3.0, 0.0), [[1.0, 0.0]], [[0.0, 0.0]], [1.0])[0, 0] == math.inf, 'behind the sensor'


def test_unicycle_arcs_are_exact_and_compose():
    s0 = np.array([1.0, 2.0, 0.3])
    assert uw.unicycle_step(s0, 0.5, 0.0, 2.0) == pytest.approx([1.0 + math.cos(0.3), 2.0 + math.sin(0.3), 0.3])
    # a full circle at v/w = 0.5 comes back; a quarter of it ends where geometry says
    full = s0
    for _ in range(100):
        full = uw.unicycle_step(full, 0.5, 1.0, 2 * math.pi / 100)
    assert full[:2] == pytest.approx(s0[:2], abs=1e-12)
    quarter = uw.unicycle_step([0.0, 0.0, 0.0], 0.5, 1.0, math.pi / 2)
    assert quarter == pytest.approx([0.5, 0.5, math.pi / 2])
    # steps of any size on one arc agree (the arc is exact, not an Euler step)
    once = uw.unicycle_step(s0, 0.4, -0.7, 0.6)
    thrice = s0
    for _ in range(3):
        thrice = uw.unicycle_step(thrice, 0.4, -0.7, 0.2)
    assert once == pytest.approx(thrice, abs=1e-12)
    # tiny turn rates: no loss of digits against the straight line
    assert uw.unicycle_step(s0, 0.5, 1e-12, 1.0)[:2] == pytest.approx(uw.unicycle_step(s0, 0.5, 0.0, 1.0)[:2])
    # turning in place: the position stays
    assert uw.unicycle_step(s0, 0.0, 1.0, 0.5)[:2] == pytest.approx(s0[:2])


def test_collisions_count_entries_and_depth():
    world = uw.World(discs=((2.0, 0.0, 0.5),))
    x = np.linspace(0.0, 4.0, 401)
    through = np.column_stack([x, np.zeros_like(x)])
    c = uw.collides(world, through, radius=0.25)
    assert c.entries == 1 and c.depth == pytest.approx(0.75) and c.poses_inside == np.sum(np.abs(x - 2) < 0.75)
    back_and_forth = np.concatenate([through, through[::-1]])
    assert uw.collides(world, back_and_forth, 0.25).entries == 2
    beside = np.column_stack([x, np.full_like(x, 0.76)])
    assert uw.collides(world, beside, 0.25) == uw.Contact(0, 0, 0.0)
    assert uw.collides(world, [[2.0, 0.0]], 0.25).entries == 1      # starting inside counts


def test_the_planner_follows_its_path_slows_and_stops_within_tolerance():
    waypoints = ((0.0, 0.0), (4.0, 0.0), (4.0, 3.0))
    follower = uw.PathFollower(waypoints)
    c = follower.config
    state = np.array([0.0, 0.0, 0.0])
    poses, speeds = [state], []
    for _ in range(3000):
        v, w = follower.command(state)
        assert abs(w) <= c.w_max and 0.0 <= v <= c.cruise
        speeds.append(v)
        if v == 0.0 and w == 0.0:
            break
        state = uw.unicycle_step(state, v, w, 0.02)
        poses.append(state)
    poses = np.asarray(poses)
    assert follower.arrived and math.hypot(*(poses[-1, :2] - (4.0, 3.0))) <= c.goal_tolerance
    assert follower.command(poses[-1] + [1.0, 0.0, 0.0]) == (0.0, 0.0), 'stopped for good'
    # it drove the path: never far from it, never back along it
    d = np.min(uw.segment_distance(poses[:, :2], np.array(waypoints[:-1]), np.array(waypoints[1:])), axis=1)
    assert d.max() < 0.3
    assert speeds[0] == c.cruise and min(speeds[-20:-1]) < 0.5 * c.cruise, 'slowed near the goal'
    assert min(s for s in speeds if s > 0) >= c.least_fraction * c.cruise - 1e-12


def test_progress_on_the_path_never_goes_back():
    waypoints = ((0.0, 0.0), (5.0, 0.0), (5.0, 5.0), (0.0, 5.0))
    assert uw.progress_on_path(waypoints, (2.0, 1.0)) == pytest.approx(2.0)
    assert uw.progress_on_path(waypoints, (2.0, 4.0)) == pytest.approx(13.0)      # nearest: the last leg
    assert uw.progress_on_path(waypoints, (2.0, 1.0), least=6.0) == pytest.approx(6.0)
    # nearest to the first leg's start, which is behind it: the nearest point from there on
    assert uw.progress_on_path(waypoints, (0.5, 2.0), least=4.9) == pytest.approx(14.5)
    assert uw.point_at(waypoints, 7.5) == pytest.approx([5.0, 2.5])
    assert uw.point_at(waypoints, 99.0) == pytest.approx([0.0, 5.0])


@pytest.mark.parametrize('goal_tolerance', [0.1, 0.02])       # 0.02: the speed's floor acts from 0.1 m on
def test_planner_time_is_the_drive_along_the_path(goal_tolerance):
    c = uw.PlannerConfig(goal_tolerance=goal_tolerance)
    for name in uw.SCENARIOS:
        s = uw.scenario(name)
        length = uw.path_arc_lengths(s.waypoints)[-1]
        t = uw.planner_time(s, config=c)
        # cruise to slow_radius, then v = cruise d / slow_radius down to the floor, then the floor
        floor_d = c.least_fraction * c.slow_radius
        expected = ((length - c.slow_radius) / c.cruise + c.slow_radius / c.cruise * math.log(1 / c.least_fraction)
                    + max(0.0, floor_d - c.goal_tolerance) / (c.least_fraction * c.cruise))
        assert t == pytest.approx(expected, abs=0.05), name


# -- the trips as the issue describes them --------------------------------------------------------
def beam(world, origin, angle):
    return float(world.ray_cast((origin[0], origin[1], angle), [0.0], 20.0)[0])


def test_every_scenario_is_built_from_its_geometry():
    for name in uw.SCENARIOS:
        s = getattr(uw, name)()
        assert s == uw.scenario(name) and s.name == name and s.goal == s.waypoints[-1]
        assert s.robot_radius == 0.25 and s.about
        assert s.path_clearance == pytest.approx(
            float(s.world.clearance(uw.path_points(s.waypoints)).min()) - 0.25, abs=1e-12)


def test_the_door_is_1_2_m_on_the_path_and_the_robot_drives_straight_at_it():
    s = uw.door()
    x_door = s.world.walls[0][0]
    assert beam(s.world, (x_door, -0.3), math.pi / 2) + beam(s.world, (x_door, -0.3), -math.pi / 2) == \
        pytest.approx(1.2, abs=1e-6)
    assert s.world.clearance([[x_door, 0.0]])[0] == pytest.approx(0.6)
    assert s.start[1] == s.goal[1] == 0.0 and s.start[2] == 0.0 and x_door - s.start[0] >= 3.0
    assert s.path_clearance == pytest.approx(0.6 - 0.25)
    assert math.isinf(beam(s.world, s.start, 0.0)), 'the laser sees through the door'
    assert beam(s.world, s.start, 0.3) == pytest.approx((x_door - 0.05) / math.cos(0.3), abs=1e-5)


def test_the_open_field_keeps_its_path_clear_by_radius_and_0_3_m():
    s = uw.open_field()
    assert s.path_clearance >= 0.3
    assert uw.path_arc_lengths(s.waypoints)[-1] == pytest.approx(9.0)
    assert len(s.world.polygons) == 1 and len(s.world.walls) >= 1
    assert len({r for _, _, r in s.world.discs}) == 3, 'posts of three sizes'
    # the box is turned 45 degrees: a corner, not a side, toward the robot coming along +x
    v = np.asarray(s.world.polygons[0])
    toward = v[np.argmin(v[:, 0])]
    assert np.sum(np.isclose(v[:, 0], toward[0])) == 1


def test_the_lane_is_3_1_m_wide_a_wall_2_2_m_one_side_a_post_0_9_m_the_other():
    s = uw.lane()
    assert uw.path_arc_lengths(s.waypoints)[-1] == pytest.approx(12.0)
    (px, py, pr), = s.world.discs
    assert beam(s.world, (px, 0.0), math.pi / 2) == pytest.approx(2.2, abs=1e-6)
    assert beam(s.world, (px, 0.0), -math.pi / 2) == pytest.approx(0.9, abs=1e-6)
    assert s.path_clearance == pytest.approx(0.9 - 0.25)


def test_the_facing_wall_is_1_5_m_ahead_and_the_path_runs_into_it():
    s = uw.facing_wall()
    assert beam(s.world, s.start, s.start[2]) == pytest.approx(1.5, abs=1e-6)
    assert s.path_clearance < -s.robot_radius
    follower = uw.PathFollower(s.waypoints)
    assert follower.command(s.start) == (uw.CRUISE_SPEED, 0.0), 'straight at it'


def test_the_combined_trip_has_a_door_a_box_corner_and_three_sizes():
    s = uw.combined()
    doors = [w for w in s.world.walls if abs(w[1]) > 1 or abs(w[3]) > 1]
    assert len(doors) == 2
    x_door = doors[0][0]
    assert beam(s.world, (x_door, 0.1), math.pi / 2) + beam(s.world, (x_door, 0.1), -math.pi / 2) == \
        pytest.approx(1.2, abs=1e-6)
    assert len(s.world.polygons) == 1 and len({r for _, _, r in s.world.discs}) == 3
    assert 0.3 <= s.path_clearance <= 0.6 - 0.25 + 1e-12
