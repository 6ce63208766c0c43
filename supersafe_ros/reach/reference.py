"""An independent, semi-analytic reference for the avoid value of a Dubins car and one disc.

Problem (issue 2): x' = v cos(theta), y' = v sin(theta), theta' = u, |u| <= w, a disc of
radius R at the origin, and

    V(x) = max over u(.) of  min over t in [0, T] of  ( |p(t)| - R ),   p = (x, y).

This module shares no code with the grid solver; it is what the solver is measured against.

How it is computed
------------------
* Symmetry: rotating the plane about the origin maps trajectories to trajectories and
  keeps |p|, so V depends only on r = |p| and the relative heading
  phi = theta - atan2(y, x); mirroring in the line through the car's position maps
  phi to -phi, so V(r, phi) = V(r, -phi). Equal (r, |phi|) pairs are evaluated once.
* Control family: "turn at the full rate w in direction d in {-1, +1} for a time s,
  then drive straight". This is the classical optimal structure for escaping a disc
  (the switching function of the maximum principle vanishes only on the radial line,
  which makes the straight part the singular arc); ``test/test_reach_reference.py`` checks
  empirically that random piecewise-constant controls with several switches and any
  |u| <= w never do better. V = max over d and s in [0, S] of f_d(s), with
  S = min(T, 2 pi / w) (turning a full circle more only adds path) and s = 0 the
  straight line; w = 0 leaves only the straight line.
* Each f_d(s) is exact: the minimum distance to the origin along a circular arc and
  along a segment (or a ray when T is None) are closed forms, see ``arc_min_distance``
  and ``segment_min_distance``.
* The maximum over s: a coarse grid of ``coarse`` points, then golden-section search in
  the two cells around each of the best ``brackets`` coarse points. f_d is Lipschitz in s
  (constant about v + w |p|), so the bracket width 2 S / coarse * 0.618^iters bounds the
  remaining error; the defaults give < 1e-5 on the grids of the issue.

T = None means the infinite horizon: the straight part is a ray, and V is the limit of the
finite-horizon values as T grows (they decrease monotonically to it).
"""
from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * np.pi
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


# -- exact minimum distances ------------------------------------------------------
def segment_min_distance(px, py, heading, speed, duration):
    """min over t in [0, duration] of |p + speed t e(heading)| (duration may be inf)."""
    ex, ey = np.cos(heading), np.sin(heading)
    # closest approach along the line, cut to the segment
    t = np.clip(-(px * ex + py * ey) / speed, 0.0, duration)
    return np.hypot(px + speed * t * ex, py + speed * t * ey)


def arc_end(px, py, heading, speed, rate, duration):
    """State after turning at constant ``rate`` != 0 for ``duration`` (exact arc)."""
    h1 = heading + rate * duration
    k = speed / rate
    return px + k * (np.sin(h1) - np.sin(heading)), py + k * (np.cos(heading) - np.cos(h1)), h1


def arc_min_distance(px, py, heading, speed, rate, duration):
    """min over t in [0, duration] of |p(t)| along the arc of constant turn ``rate`` != 0.

    The arc lies on the circle of centre c = p + (v / rate) n (n the left normal of
    the heading) and radius rho = v / |rate|; the angle of p(t) - c grows at ``rate``.
    |p(t)|^2 = |c|^2 + rho^2 + 2 rho |c| cos(alpha - gamma) is smallest at the circle's
    point nearest the origin (alpha = angle of -c), giving ||c| - rho|; when the arc does
    not pass that point, the minimum over the arc is at one of its ends.
    """
    rate = np.asarray(rate, dtype=float)
    k = speed / rate
    cx = px - k * np.sin(heading)
    cy = py + k * np.cos(heading)
    rho = np.abs(k)
    d = np.hypot(cx, cy)
    # angle of p - c now, and of the circle point nearest the origin
    alpha0 = np.arctan2(py - cy, px - cx)
    alpha_near = np.arctan2(-cy, -cx)
    t_near = ((np.sign(rate) * (alpha_near - alpha0)) % TWO_PI) / np.abs(rate)
    ex, ey, _ = arc_end(px, py, heading, speed, rate, duration)
    ends = np.minimum(np.hypot(px, py), np.hypot(ex, ey))
    return np.where(t_near <= duration, np.abs(d - rho), ends)


def turn_then_straight(px, py, heading, speed, rate, turn_time, horizon):
    """min distance to the origin over [0, horizon] for: turn at ``rate`` for
    ``turn_time`` (<= horizon), then straight to the horizon (a ray if horizon is inf)."""
    if np.all(rate == 0):
        return segment_min_distance(px, py, heading, speed, horizon)
    arc = arc_min_distance(px, py, heading, speed, rate, turn_time)
    ex, ey, eh = arc_end(px, py, heading, speed, rate, turn_time)
    return np.minimum(arc, segment_min_distance(ex, ey, eh, speed, horizon - turn_time))


# -- the value --------------------------------------------------------------------------
def _check(speed, omega_max, radius, horizon):
    if not (np.isfinite(speed) and speed > 0):
        raise ValueError(f'speed must be positive and finite, got {speed}')
    if not (np.isfinite(omega_max) and omega_max >= 0):
        raise ValueError(f'omega_max must be >= 0 and finite, got {omega_max}')
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f'radius must be positive and finite, got {radius}')
    if horizon is not None and not (np.isfinite(horizon) and horizon >= 0):
        raise ValueError(f'horizon must be >= 0 and finite, or None for infinite, got {horizon}')


def _value_polar(r, phi, speed, omega_max, radius, horizon, coarse, brackets, iters):
    """V at states (r, 0, phi): position on the +x axis, heading phi. 1-D arrays."""
    T = math.inf if horizon is None else float(horizon)
    px, py, th = r[:, None], np.zeros_like(r)[:, None], phi[:, None]
    best = segment_min_distance(px, py, th, speed, T)[:, 0]
    if omega_max == 0.0 or T == 0.0:
        return best - radius
    s_max = min(T, TWO_PI / omega_max)
    s_grid = np.linspace(0.0, s_max, coarse)[None, :]
    step = s_max / (coarse - 1)
    for d in (-1.0, 1.0):
        rate = d * omega_max
        f = turn_then_straight(px, py, th, speed, rate, s_grid, T)
        best = np.maximum(best, f.max(axis=1))
        # refine around the best few coarse points (f may have more than one local max)
        top = np.argsort(-f, axis=1)[:, :brackets]
        for b in range(top.shape[1]):
            centre = s_grid[0, top[:, b]][:, None]
            lo = np.maximum(centre - step, 0.0)
            hi = np.minimum(centre + step, s_max)
            a = hi - _GOLDEN * (hi - lo)
            c = lo + _GOLDEN * (hi - lo)
            fa = turn_then_straight(px, py, th, speed, rate, a, T)
            fc = turn_then_straight(px, py, th, speed, rate, c, T)
            for _ in range(iters):
                left = fa >= fc          # the maximum lies in [lo, c]
                hi = np.where(left, c, hi)
                lo = np.where(left, lo, a)
                c_new = np.where(left, a, lo + _GOLDEN * (hi - lo))
                a_new = np.where(left, hi - _GOLDEN * (hi - lo), c)
                f_new = turn_then_straight(px, py, th, speed, rate,
                                           np.where(left, a_new, c_new), T)
                fa, fc = np.where(left, f_new, fc), np.where(left, fa, f_new)
                a, c = a_new, c_new
            best = np.maximum(best, np.maximum(fa, fc)[:, 0])
    return best - radius


def reference_value(states, speed, omega_max, radius, horizon, *, coarse=96, brackets=2,
                    iters=28, chunk=8192) -> np.ndarray:
    """Exact (to ~1e-5) avoid value V at ``states`` (N, 3) = (x, y, theta).

    ``horizon`` None means infinite. Evaluated in chunks of ``chunk`` distinct
    (r, |phi|) pairs so memory stays bounded (about chunk * coarse * 100 bytes).
    """
    _check(speed, omega_max, radius, horizon)
    s = np.asarray(states, dtype=float)
    if s.ndim != 2 or s.shape[1] != 3:
        raise ValueError(f'states must be (N, 3), got {s.shape}')
    if not np.all(np.isfinite(s)):
        raise ValueError('states contain NaN or infinite values')
    r = np.hypot(s[:, 0], s[:, 1])
    phi = np.abs((s[:, 2] - np.arctan2(s[:, 1], s[:, 0]) + np.pi) % TWO_PI - np.pi)
    # equal (r, |phi|) up to rounding share one evaluation (grids have many)
    keys = np.stack([np.round(r, 10), np.round(phi, 10)], axis=1)
    uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
    out = np.empty(len(uniq))
    for i in range(0, len(uniq), chunk):
        part = uniq[i:i + chunk]
        out[i:i + chunk] = _value_polar(part[:, 0], part[:, 1], float(speed), float(omega_max),
                                        float(radius), horizon, coarse, brackets, iters)
    return out[np.asarray(inverse).ravel()]


def reference_on_grid(grid, speed, omega_max, radius, horizon, **kw) -> np.ndarray:
    """Reference V at every node of ``grid`` (shape grid.shape)."""
    X, Y, TH = grid.mesh()
    states = np.stack([X.ravel(), Y.ravel(), TH.ravel()], axis=1)
    return reference_value(states, speed, omega_max, radius, horizon, **kw).reshape(grid.shape)


def accuracy_mask(grid, v_ref) -> np.ndarray:
    """The issue's comparison nodes: -1 < V_ref < 3 in the inner three quarters of the
    (x, y) extent (centred), every heading."""
    x, y = grid.x, grid.y
    cx, cy = 0.5 * (grid.lo[0] + grid.hi[0]), 0.5 * (grid.lo[1] + grid.hi[1])
    hx, hy = 0.375 * (grid.hi[0] - grid.lo[0]), 0.375 * (grid.hi[1] - grid.lo[1])
    eps = 1e-9 * max(hx, hy)
    inner = ((np.abs(x - cx) <= hx + eps)[:, None, None]
             & (np.abs(y - cy) <= hy + eps)[None, :, None])
    return inner & (v_ref > -1.0) & (v_ref < 3.0)


def compare(values, v_ref, mask) -> dict:
    """Error figures of ``values`` against ``v_ref`` over ``mask``."""
    a = np.asarray(values, dtype=float)[mask]
    b = np.asarray(v_ref, dtype=float)[mask]
    if a.size == 0:
        raise ValueError('no nodes in the comparison mask')
    err = np.abs(a - b)
    return {
        'mean_abs_error': float(err.mean()),
        'max_abs_error': float(err.max()),
        'sign_error_fraction': float(np.mean((a < 0) != (b < 0))),
        'nodes': int(a.size),
    }


def accuracy_report(vf, speed, omega_max, radius, horizon) -> dict:
    """Compare a ValueFunction's node values with the reference over the issue's mask.

    Returns mean_abs_error, max_abs_error, sign_error_fraction (V < 0 on one side and
    not the other) and the number of nodes compared.
    """
    v_ref = reference_on_grid(vf.grid, speed, omega_max, radius, horizon)
    return compare(vf.values, v_ref, accuracy_mask(vf.grid, v_ref))
