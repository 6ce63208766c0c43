"""The exact avoid reference: its closed-form pieces, its control family, known cases,
and the authors' own helperOC value function."""
import os

import numpy as np
import pytest

from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.reference import (
    accuracy_mask, accuracy_report, arc_end, arc_min_distance, compare, reference_on_grid,
    reference_value, segment_min_distance)
from supersafe_ros.reach.value_function import ValueFunction

S3 = os.path.join(os.path.dirname(__file__), '..', '..', 'shared', 'data', 's3')
STANDARD = os.path.join(S3, 'standard_reachset.json')


def random_states(rng, n, radius, r_max):
    """Positions from inside the disc to r_max, any heading."""
    r = rng.uniform(0.2 * radius, r_max, n)
    a = rng.uniform(-np.pi, np.pi, n)
    return np.stack([r * np.cos(a), r * np.sin(a), rng.uniform(-np.pi, np.pi, n)], axis=1)


# -- the closed forms ---------------------------------------------------------------
def test_arc_and_segment_minima_match_dense_sampling():
    rng = np.random.default_rng(1)
    n = 500
    px, py = rng.uniform(-5, 5, n), rng.uniform(-5, 5, n)
    heading = rng.uniform(-np.pi, np.pi, n)
    rate = rng.choice([-1.0, 1.0], n) * rng.uniform(0.1, 3.0, n)
    duration = rng.uniform(0.0, 8.0, n)
    t = np.linspace(0.0, 1.0, 20001)[None, :] * duration[:, None]
    xs, ys, _ = arc_end(px[:, None], py[:, None], heading[:, None], 2.5, rate[:, None], t)
    dense = np.hypot(xs, ys).min(axis=1)
    exact = arc_min_distance(px, py, heading, 2.5, rate, duration)
    assert np.all(exact <= dense + 1e-12)          # a true minimum is never above a sample
    assert np.max(dense - exact) < 1e-4            # and the samples come down to it

    xs = px[:, None] + 2.5 * t * np.cos(heading)[:, None]
    ys = py[:, None] + 2.5 * t * np.sin(heading)[:, None]
    dense = np.hypot(xs, ys).min(axis=1)
    exact = segment_min_distance(px, py, heading, 2.5, duration)
    assert np.all(exact <= dense + 1e-12)
    assert np.max(dense - exact) < 1e-4


# -- the control family is enough -----------------------------------------------------
def piecewise_min_distance(states, speed, rates, durations, ray_after):
    """min over the path of |p| for piecewise-constant turn rates (..., k) held for
    durations (..., k); then, if ``ray_after``, straight on forever."""
    px, py, h = states[..., 0], states[..., 1], states[..., 2]
    best = np.hypot(px, py)
    for i in range(rates.shape[-1]):
        u, dt = rates[..., i], durations[..., i]
        turning = np.abs(u) > 1e-9
        safe_u = np.where(turning, u, 1.0)
        arc = arc_min_distance(px, py, h, speed, safe_u, dt)
        ex, ey, eh = arc_end(px, py, h, speed, safe_u, dt)
        seg = segment_min_distance(px, py, h, speed, dt)
        best = np.minimum(best, np.where(turning, arc, seg))
        px = np.where(turning, ex, px + speed * dt * np.cos(h))
        py = np.where(turning, ey, py + speed * dt * np.sin(h))
        h = np.where(turning, eh, h)
    if ray_after:
        best = np.minimum(best, segment_min_distance(px, py, h, speed, np.inf))
    return best


def random_controls(rng, shape, pieces, omega_max, total):
    """Turn rates: mostly -w, 0 or +w, some anywhere in [-w, w]; durations summing to
    ``total`` (an array broadcast over the last axis)."""
    bang = rng.choice([-1.0, 0.0, 1.0], shape + (pieces,))
    rates = omega_max * np.where(rng.random(shape + (pieces,)) < 0.7, bang,
                                 rng.uniform(-1, 1, shape + (pieces,)))
    durations = rng.dirichlet(np.full(pieces, 0.7), shape) * total[..., None]
    return rates, durations


@pytest.mark.parametrize('speed, omega_max, radius, horizon', [
    (3.0, 1.0, 1.0, 3.0),
    (3.0, 1.0, 1.8, 2.0),
    (2.0, 0.4, 1.0, 5.0),
    (1.0, 2.5, 0.5, 1.0),
    (3.0, 1.0, 1.8, None),
    (3.0, 0.0, 1.8, 3.0),
])
def test_random_piecewise_controls_never_beat_the_family(speed, omega_max, radius, horizon):
    """Empirical evidence that "full turn for s, then straight" is optimal: thousands of
    random controls with up to 5 pieces per state, then a local search from the best of
    them, never end further from the disc than the reference."""
    rng = np.random.default_rng(abs(hash((speed, omega_max, radius, horizon))) % 2**32)
    n, m, pieces = 150, 1500, 5
    states = random_states(rng, n, radius, radius + 2.5 * speed)
    ref = reference_value(states, speed, omega_max, radius, horizon)
    ray = horizon is None
    # with no horizon, random controls act for up to two full turns, then a ray
    total = (rng.uniform(0, 2 * 2 * np.pi / max(omega_max, 0.5), (n, m)) if ray
             else np.full((n, m), horizon))
    rates, durations = random_controls(rng, (n, m), pieces, omega_max, total)
    found = piecewise_min_distance(states[:, None, :], speed, rates, durations, ray) - radius
    best = found.argmax(axis=1)
    rows = np.arange(n)
    best_rates, best_dur = rates[rows, best], durations[rows, best]
    best_val = found[rows, best]
    # local search: perturb the best control's rates and switching times
    for step in (0.3, 0.1, 0.03, 0.01):
        for _ in range(6):
            k = 64
            r2 = np.clip(best_rates[:, None, :] + step * omega_max * rng.normal(size=(n, k, pieces)),
                         -omega_max, omega_max)
            d2 = np.maximum(best_dur[:, None, :] * np.exp(step * rng.normal(size=(n, k, pieces))), 0)
            if not ray:
                d2 *= horizon / d2.sum(axis=2, keepdims=True)
            v2 = piecewise_min_distance(states[:, None, :], speed, r2, d2, ray) - radius
            j = v2.argmax(axis=1)
            better = v2[rows, j] > best_val
            best_val = np.where(better, v2[rows, j], best_val)
            best_rates = np.where(better[:, None], r2[rows, j], best_rates)
            best_dur = np.where(better[:, None], d2[rows, j], best_dur)
    assert np.max(best_val - ref) <= 1e-6, (
        f'a control beat the family by {np.max(best_val - ref):.2e} at {states[np.argmax(best_val - ref)]}')
    # the search is strong enough to come close, so the bound above has teeth
    assert np.mean(ref - best_val) < 0.05
    assert np.all(np.isfinite(ref))


# -- special cases with closed forms -----------------------------------------------------
def test_straight_line_when_the_car_cannot_turn():
    r, phi = np.array([5.0, 5.0, 4.0, 0.5]), np.array([np.pi, 2.5, 1.0, 3.0])
    states = np.stack([r, np.zeros_like(r), phi], axis=1)
    v = reference_value(states, 3.0, 0.0, 1.0, None)
    # heading inward: perpendicular distance; outward: where it starts
    expected = np.where(np.cos(phi) < 0, r * np.abs(np.sin(phi)), r) - 1.0
    np.testing.assert_allclose(v, expected, atol=1e-12)
    # a short horizon stops the approach early: heading at the centre from r = 5, T = 1
    v = reference_value(np.array([[5.0, 0.0, np.pi]]), 3.0, 0.0, 1.0, 1.0)
    np.testing.assert_allclose(v, [5.0 - 3.0 - 1.0], atol=1e-12)


def test_heading_straight_at_the_disc_turns_on_the_tangent_circle():
    """From distance r heading at the centre, the best is a full turn either way: the
    circle of radius rho = v / w passes the centre at sqrt(r^2 + rho^2) - rho."""
    speed, omega_max, radius = 3.0, 1.0, 1.0
    rho = speed / omega_max
    r = np.array([1.5, 3.0, 6.0, 9.0])
    angle = np.array([0.3, -2.0, 1.0, 3.0])   # anywhere on the circle of radius r
    states = np.stack([r * np.cos(angle), r * np.sin(angle), angle + np.pi], axis=1)
    expected = np.hypot(r, rho) - rho - radius
    np.testing.assert_allclose(reference_value(states, speed, omega_max, radius, None),
                               expected, atol=1e-6)
    # the closest point comes after atan(r / rho) / w; any longer horizon gives the same
    needed = np.arctan(r / rho) / omega_max
    np.testing.assert_allclose(reference_value(states, speed, omega_max, radius, needed.max() + 0.1),
                               expected, atol=1e-6)


def test_value_inside_and_heading_out_is_the_start_distance():
    rng = np.random.default_rng(3)
    r = rng.uniform(0.1, 4.0, 50)
    a = rng.uniform(-np.pi, np.pi, 50)
    phi = rng.uniform(-np.pi / 2 + 0.01, np.pi / 2 - 0.01, 50)   # pointing away from the centre
    states = np.stack([r * np.cos(a), r * np.sin(a), a + phi], axis=1)
    np.testing.assert_allclose(reference_value(states, 3.0, 1.0, 1.8, 2.0), r - 1.8, atol=1e-9)
    # and no horizon at all leaves l itself, whatever the heading
    states[:, 2] += np.pi
    np.testing.assert_allclose(reference_value(states, 3.0, 1.0, 1.8, 0.0), r - 1.8, atol=1e-9)


def test_symmetries_and_horizon_monotonicity():
    rng = np.random.default_rng(4)
    states = random_states(rng, 400, 1.0, 10.0)
    v = reference_value(states, 3.0, 1.0, 1.0, 3.0)
    # rotating everything about the origin, and mirroring in the x axis, change nothing
    c, s = np.cos(0.7), np.sin(0.7)
    rotated = np.stack([c * states[:, 0] - s * states[:, 1], s * states[:, 0] + c * states[:, 1],
                        states[:, 2] + 0.7], axis=1)
    mirrored = states * np.array([1.0, -1.0, -1.0])
    np.testing.assert_allclose(reference_value(rotated, 3.0, 1.0, 1.0, 3.0), v, atol=1e-9)
    np.testing.assert_allclose(reference_value(mirrored, 3.0, 1.0, 1.0, 3.0), v, atol=1e-9)
    # a longer horizon can only lower V; turning faster can only raise it
    v_long = reference_value(states, 3.0, 1.0, 1.0, 6.0)
    v_inf = reference_value(states, 3.0, 1.0, 1.0, None)
    assert np.all(v_long <= v + 1e-9) and np.all(v_inf <= v_long + 1e-9)
    assert np.all(reference_value(states, 3.0, 1.5, 1.0, 3.0) >= v - 1e-9)
    assert np.all(v <= np.hypot(states[:, 0], states[:, 1]) - 1.0 + 1e-9)


def test_bad_input_is_refused():
    good = np.zeros((2, 3)) + 5.0
    with pytest.raises(ValueError):
        reference_value(np.zeros((2, 2)), 3.0, 1.0, 1.0, 3.0)
    with pytest.raises(ValueError):
        reference_value(np.array([[np.nan, 0.0, 0.0]]), 3.0, 1.0, 1.0, 3.0)
    for speed, omega, radius, horizon in [(0, 1, 1, 3), (3, -1, 1, 3), (3, 1, 0, 3), (3, 1, 1, -1),
                                          (3, 1, 1, np.inf), (np.nan, 1, 1, 3)]:
        with pytest.raises(ValueError):
            reference_value(good, speed, omega, radius, horizon)


# -- the accuracy report ------------------------------------------------------------------
def test_accuracy_report_measures_what_it_says():
    grid = Grid((-6.0, -4.0), (10.0, 4.0), (33, 17, 16))
    ref = reference_on_grid(grid, 3.0, 1.0, 1.0, 2.0)
    mask = accuracy_mask(grid, ref)
    # inner three quarters: x in [-4, 8], y in [-3, 3]
    X, Y, _ = grid.mesh()
    assert not np.any(mask & ((X < -4 - 1e-9) | (X > 8 + 1e-9) | (np.abs(Y) > 3 + 1e-9)))
    assert np.any(mask & (np.abs(X + 4) < 1e-9)) and np.any(mask & (np.abs(Y - 3) < 1e-9))
    assert np.all((ref[mask] > -1) & (ref[mask] < 3))
    exact = accuracy_report(ValueFunction(grid, ref), 3.0, 1.0, 1.0, 2.0)
    assert exact['mean_abs_error'] < 1e-6 and exact['sign_error_fraction'] == 0.0
    assert exact['nodes'] == mask.sum() > 0
    shifted = compare(ref + 0.05, ref, mask)
    np.testing.assert_allclose([shifted['mean_abs_error'], shifted['max_abs_error']], [0.05, 0.05])
    expected_flips = np.mean((ref[mask] >= -0.05) & (ref[mask] < 0))
    assert shifted['sign_error_fraction'] == pytest.approx(expected_flips)


# -- the authors' own value function ---------------------------------------------------------
@pytest.mark.skipif(not os.path.exists(STANDARD),
                    reason='../shared/data/s3 (the paper authors\' helperOC data) is absent')
def test_agrees_with_the_authors_helperoc_value_function():
    """helperOC (MATLAB, 'high' accuracy), speed 3, w 1, radius 1.8, 2 s, 65x65x42."""
    vf = ValueFunction.load_helperoc_json(STANDARD)
    report = accuracy_report(vf, 3.0, 1.0, 1.8, 2.0)
    print('helperOC standard_reachset vs reference:', report)
    assert report['nodes'] > 40000
    assert report['mean_abs_error'] < 0.01
    assert report['sign_error_fraction'] < 0.003
    # the horizon that was used matters: a 0.5 s reference is measurably different
    assert accuracy_report(vf, 3.0, 1.0, 1.8, 0.5)['mean_abs_error'] > 0.05
