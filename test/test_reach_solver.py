"""The avoid solver against cases with known answers and against the paper's own data."""
import numpy as np
import pytest

from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid, wrap_angle
from supersafe_ros.reach.sets import Disc, Union
from supersafe_ros.reach.solver import solve_avoid
from supersafe_ros.reach.value_function import ValueFunction

GRID = Grid((-8, -8), (8, 8), (49, 49, 36))


def inner_mask(grid, V=None):
    X, Y, _ = grid.mesh()
    cx, cy = (grid.lo[0] + grid.hi[0]) / 2, (grid.lo[1] + grid.hi[1]) / 2
    m = (np.abs(X - cx) <= 0.375 * (grid.hi[0] - grid.lo[0])) & \
        (np.abs(Y - cy) <= 0.375 * (grid.hi[1] - grid.lo[1]))
    if V is not None:
        m &= (V > -1) & (V < 3)
    return m


def straight_line_value(states, speed, radius, horizon):
    """w_max = 0: the car can only go straight; V = closest approach over [0, T] - R."""
    p = states[..., :2]
    h = np.stack([np.cos(states[..., 2]), np.sin(states[..., 2])], axis=-1)
    tau = np.clip(-(p * h).sum(-1) / speed, 0.0, horizon)
    return np.linalg.norm(p + speed * tau[..., None] * h, axis=-1) - radius


@pytest.fixture(scope='module')
def standard():
    return solve_avoid(GRID, DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=2.0)


def test_straight_only_matches_closed_form():
    vf = solve_avoid(GRID, DubinsCar(3.0, 0.0), Disc(0, 0, 1.8), horizon=2.0)
    X, Y, TH = GRID.mesh()
    exact = straight_line_value(np.stack([X, Y, TH], -1), 3.0, 1.8, 2.0)
    m = inner_mask(GRID, exact)
    err = np.abs(vf.values - exact)
    assert err[m].mean() < 0.01
    # kinks of V (closest approach exactly at T; lines through the centre) are
    # rounded off by interpolation over a few nodes; elsewhere the error is tiny
    assert np.percentile(err[m], 90) < 0.01
    assert err[m & (exact > -0.5)].max() < 0.12
    assert np.mean(np.sign(vf.values[m]) != np.sign(exact[m])) < 0.003


def test_value_never_exceeds_distance_and_equals_it_heading_away(standard):
    X, Y, TH = GRID.mesh()
    distance = np.hypot(X, Y) - 1.8          # l: the signed distance to the disc
    assert np.all(standard.values <= distance + 1e-5)
    # heading straight away from the obstacle: the start is the closest point
    away = standard.value(np.stack([X[:, :, 0], Y[:, :, 0], np.arctan2(Y[:, :, 0], X[:, :, 0])], -1))
    r = np.hypot(X[:, :, 0], Y[:, :, 0])
    ring = (r > 2.0) & (r < 6.0)
    assert np.max(np.abs(away - distance[:, :, 0])[ring]) < 0.05


def test_more_agile_cars_and_shorter_horizons_are_safer():
    slow = solve_avoid(GRID, DubinsCar(3.0, 0.5), Disc(0, 0, 1.8), horizon=2.0)
    fast = solve_avoid(GRID, DubinsCar(3.0, 1.5), Disc(0, 0, 1.8), horizon=2.0)
    assert np.all(fast.values >= slow.values - 0.02)
    assert np.mean(fast.values > slow.values + 0.05) > 0.05   # and strictly, somewhere
    short = solve_avoid(GRID, DubinsCar(3.0, 0.5), Disc(0, 0, 1.8), horizon=1.0)
    assert np.all(short.values >= slow.values - 0.02)


def test_rotational_symmetry(standard):
    """V depends on the distance and the heading relative to the bearing only."""
    rng = np.random.default_rng(3)
    r = rng.uniform(2.0, 5.5, 200)
    bearing = rng.uniform(-np.pi, np.pi, 200)
    rel = rng.uniform(-np.pi, np.pi, 200)
    rot = rng.uniform(-np.pi, np.pi, 200)
    a = np.stack([r * np.cos(bearing), r * np.sin(bearing), wrap_angle(bearing + rel)], -1)
    b = np.stack([r * np.cos(bearing + rot), r * np.sin(bearing + rot), wrap_angle(bearing + rot + rel)], -1)
    assert np.mean(np.abs(standard.value(a) - standard.value(b))) < 0.03


def simulate_escape(vf, state, omega_max, speed, horizon, dt=0.005):
    """Closed loop u* = w sign(dV/dth); returns the smallest distance to the obstacle centre."""
    dyn = DubinsCar(speed, omega_max)
    s = np.array(state, dtype=float)
    closest = np.hypot(s[0], s[1])
    for _ in range(int(horizon / dt)):
        u = omega_max * np.sign(vf.gradient(s[None])[0, 2])
        s = dyn.flow(s, u, dt)
        closest = min(closest, np.hypot(s[0], s[1]))
    return closest


def test_optimal_control_escapes_from_states_the_solver_calls_safe(standard):
    rng = np.random.default_rng(7)
    X, Y, TH = GRID.mesh()
    near = (standard.values > 0.15) & (standard.values < 0.6) & inner_mask(GRID)
    idx = np.argwhere(near)
    for i, j, k in idx[rng.choice(len(idx), 25, replace=False)]:
        v0 = standard.values[i, j, k]
        closest = simulate_escape(standard, (X[i, j, k], Y[i, j, k], TH[i, j, k]), 1.0, 3.0, 2.0)
        assert closest - 1.8 > v0 - 0.15, (X[i, j, k], Y[i, j, k], TH[i, j, k], v0, closest - 1.8)


def test_no_control_escapes_from_states_the_solver_calls_unsafe(standard):
    """From V < 0 every bang-straight manoeuvre (the optimal family) enters the disc."""
    X, Y, TH = GRID.mesh()
    bad = (standard.values < -0.15) & (np.hypot(X, Y) > 1.8) & inner_mask(GRID)
    dyn = DubinsCar(3.0, 1.0)
    rng = np.random.default_rng(11)
    idx = np.argwhere(bad)
    for i, j, k in idx[rng.choice(len(idx), 20, replace=False)]:
        s0 = np.array([X[i, j, k], Y[i, j, k], TH[i, j, k]])
        for d in (-1.0, 1.0):
            for switch in np.linspace(0, 2.0, 21):
                s, hit = s0.copy(), False
                for step in range(400):
                    s = dyn.flow(s, d if step * 0.005 < switch else 0.0, 0.005)
                    hit |= np.hypot(s[0], s[1]) < 1.8
                assert hit


def test_matches_the_authors_value_function(s3_data, standard):
    """helperOC's 'high' accuracy solve of the same problem (65 x 65 x 42, 2 s)."""
    ref = ValueFunction.load_helperoc_json(s3_data / 'standard_reachset.json')
    ours = solve_avoid(ref.grid, DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=2.0)
    m = inner_mask(ref.grid, ref.values)
    diff = np.abs(ours.values - ref.values)[m]
    assert diff.mean() < 0.03
    assert np.mean(np.sign(ours.values[m]) != np.sign(ref.values[m])) < 0.01


def test_union_is_harder_to_avoid_than_each_disc():
    a, b = Disc(-3, 0, 1.0), Disc(3, 1, 1.2)
    dyn = DubinsCar(3.0, 1.0)
    Va = solve_avoid(GRID, dyn, a, 2.0).values
    Vb = solve_avoid(GRID, dyn, b, 2.0).values
    Vu = solve_avoid(GRID, dyn, Union((a, b)), 2.0).values
    assert np.all(Vu <= np.minimum(Va, Vb) + 1e-4)
    assert np.all(Vu >= np.minimum(Va, Vb) - 3.0)   # sanity: bounded below by a far worse value


def test_converges_without_horizon_and_says_so():
    vf = solve_avoid(GRID, DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=None)
    assert vf.meta['converged'] is True and vf.meta['last_change'] < 1e-4
    long = solve_avoid(GRID, DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=6.0)
    assert np.max(np.abs(vf.values - long.values)) < 1e-3


def test_rejects_bad_problems():
    with pytest.raises(ValueError):
        solve_avoid(GRID, DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=-1.0)
    with pytest.raises(ValueError):
        DubinsCar(float('nan'), 1.0)
    with pytest.raises(ValueError):
        Disc(0, 0, 0.0)
    with pytest.raises(ValueError):
        Grid((0, 0), (0, 1), (10, 10, 10))


def test_symmetric_values_do_not_overshoot_the_head_on_valley():
    """Near heading straight at the obstacle V has a valley in theta; evaluation
    rotates onto heading nodes instead of interpolating across it."""
    from supersafe_ros.reach.reference import reference_value
    grid = Grid((-8, -8), (8, 8), (65, 65, 42))
    vf = solve_avoid(grid, DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=3.0)
    assert vf.rotationally_symmetric
    rng = np.random.default_rng(0)
    r, b = rng.uniform(2.5, 6.0, 1500), rng.uniform(-np.pi, np.pi, 1500)
    states = np.stack([r * np.cos(b), r * np.sin(b),
                       wrap_angle(b + np.pi + rng.normal(0, 0.3, 1500))], -1)
    ref = reference_value(states, 3.0, 1.0, 1.8, 3.0)
    err = vf.value(states) - ref
    plain = ValueFunction(grid, vf.values, {})          # no symmetry known: trilinear
    err_plain = plain.value(states) - ref
    assert err.max() < 0.1 and np.abs(err).mean() < 0.012
    assert err_plain.max() > 1.5 * err.max()           # what the rotation buys
    # rotating the whole scene about the obstacle changes nothing
    beta = 0.37
    c, s = np.cos(beta), np.sin(beta)
    turned = np.stack([c * states[:, 0] - s * states[:, 1], s * states[:, 0] + c * states[:, 1],
                       wrap_angle(states[:, 2] + beta)], -1)
    assert np.max(np.abs(vf.value(turned) - vf.value(states))) < 0.06


def test_signed_distances_of_discs_and_unions_are_the_geometric_ones():
    """The solver's fast path (one square root per radius, no stacked arrays) gives the
    distance to the nearest rim, for mixed radii and nested unions, on any array shape."""
    rng = np.random.default_rng(3)
    discs = [Disc(*rng.uniform(-5, 5, 2), r) for r in (1.8, 1.8, 2.5, 0.7, 1.8)]
    keepout = Union((Union(tuple(discs[:2])), *discs[2:]))
    xy = rng.uniform(-9, 9, (7, 11, 2))
    expected = np.min([np.hypot(xy[..., 0] - d.cx, xy[..., 1] - d.cy) - d.radius for d in discs], axis=0)
    np.testing.assert_allclose(keepout.signed_distance(xy), expected, rtol=0, atol=1e-12)
    np.testing.assert_allclose(keepout.signed_distance_xy(xy[..., 0], xy[..., 1]), expected, rtol=0, atol=1e-12)
    # broadcasting, as the solver calls it: a column of x against a row of y
    x, y = np.linspace(-9, 9, 5)[:, None], np.linspace(-9, 9, 4)[None, :]
    grid = np.stack(np.broadcast_arrays(x, y), axis=-1)
    np.testing.assert_allclose(discs[3].signed_distance_xy(x, y),
                               np.hypot(grid[..., 0] - discs[3].cx, grid[..., 1] - discs[3].cy) - 0.7,
                               rtol=0, atol=1e-12)
    assert keepout.signed_distance_xy(x, y).shape == (5, 4)
