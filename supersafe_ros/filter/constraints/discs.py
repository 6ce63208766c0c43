"""Obstacles of their own radius: discs (x, y, r) judged with the library's value of radius R.

The value function of the avoid problem of one disc of radius R (its keep-out set, the
library's ``radius`` = ``FilterConfig.radius``) is V_R(s) = the signed distance to the disc
along optimal play, l_R(x, y) = |(x, y)| - R at its closest. A disc of radius r has l_r =
l_R + (R - r): the same payoff shifted by a constant, so the same optimal play (for any
dynamics: the shift is independent of the state) and

    V_r(s) = V_R(s) + (R - r)                                                   (exact)

up to the grid's error (test_filter_discs solves two radii and compares). Each pair row of a
disc of radius r adds ``R - r`` to V and to V after the lookahead's holds (``filter.constraints.pairs``);
the avoid turn, sign(dV/dtheta) or the better bang, is unchanged by a constant.

Off the value function's grid V is read as +inf (never constraining): sound for r <= R (V_r
>= V_R there), not for r > R (the shifted level set can reach past the grid). A disc larger
than R is therefore judged as a ring of discs of radius R (``covering_ring``): k centres on
the circle of radius c = r cos(pi/k) about its centre, k the least with r sin(pi/k) <=
RING_SLACK R. Every point of the disc's boundary circle is then within RING_SLACK R of a
ring centre (the farthest, halfway between two centres, is at r sin(pi/k)), so a robot
outside the disc meets a ring disc before it can reach the disc: avoiding the ring avoids
the disc. The ring's members are ordinary obstacles of radius R (pairs, clusters, nearby,
max_detections), each named by the disc it covers (``origin``).

Clusters (``filter.clusters``: union values, loiter fallback) judge every member as a disc of
radius R about its centre: a disc of radius r <= R lies inside it, so the union (and the
fallback's clear circle) is a conservative covering of the mixed radii, and the same
geometry keys the same solved value whatever its members' radii.
"""
from __future__ import annotations

from itertools import repeat
import math
from operator import is_

import numpy as np

RING_SLACK = 0.95        # a ring's centres cover the boundary circle within this fraction of R
SPLIT_ROWS_MAX = 200000  # a message whose rings would hold more discs than this is rejected


def checked_discs(rows, radius):
    """(centres (M, 2), radii (M,) or None if all are ``radius``, origin (M,): the row of the
    message each comes from, or None if row i is row i) of detections given as (N, 2) centres
    (each of ``radius``) or (N, 3) rows [x, y, r], every r finite and > 0; rows with r >
    ``radius`` become their ``covering_ring``. Raises ValueError if malformed."""
    c = np.asarray(rows, dtype=float)
    if c.size == 0:
        return np.zeros((0, 2)), None, None
    if c.ndim != 2 or c.shape[1] not in (2, 3) or not np.all(np.isfinite(c)):
        raise ValueError(f'detections must be finite (N, 2) centres or (N, 3) [x, y, r] rows, got shape '
                         f'{np.shape(rows)}')
    if c.shape[1] == 2:
        return c, None, None
    r = c[:, 2]
    if not np.all(r > 0.0):
        raise ValueError(f'detection radii must be > 0, got {float(r.min()):g}')
    big = r > radius
    if not big.any():
        return np.ascontiguousarray(c[:, :2]), r.copy(), None
    if not radius > 0.0:
        raise ValueError(f'detections of radius up to {float(r.max()):g} m, but the value function\'s radius is '
                         f'{radius:g}: no ring of its discs can cover them')
    counts = np.ones(len(c), dtype=np.intp)
    counts[big] = ring_size(r[big], radius)
    total = int(counts.sum())
    if total > SPLIT_ROWS_MAX:
        raise ValueError(f'detections too large to judge: discs larger than the value function\'s radius '
                         f'{radius:g} are judged as rings of discs of that radius, and these would need {total} '
                         f'(more than {SPLIT_ROWS_MAX}); the largest radius is {float(r.max()):g} m')
    origin = np.repeat(np.arange(len(c)), counts)
    centres = np.repeat(c[:, :2], counts, axis=0)
    radii = np.repeat(r, counts)
    first = np.cumsum(counts) - counts
    for i in np.flatnonzero(big).tolist():
        k = int(counts[i])
        centres[first[i]:first[i] + k] = covering_ring(c[i, 0], c[i, 1], r[i], k)
        radii[first[i]:first[i] + k] = radius
    return centres, radii, origin


def ring_size(r, radius):
    """The least k with r sin(pi/k) <= RING_SLACK ``radius`` (r > radius > 0; arrays)."""
    r = np.asarray(r, dtype=float)
    k = np.ceil(np.pi / np.arcsin(np.minimum(RING_SLACK * radius / r, 1.0))).astype(np.intp)
    k = np.maximum(k, 3)
    # round-off at the boundary: one more where the inequality misses by a hair
    return np.where(r * np.sin(np.pi / k) <= RING_SLACK * radius, k, k + 1)


def covering_ring(x, y, r, k) -> np.ndarray:
    """k centres (k, 2) on the circle of radius r cos(pi/k) about (x, y), evenly spaced: with
    discs of radius >= r sin(pi/k) they cover the circle of radius r (see the module)."""
    c = r * math.cos(math.pi / k)
    a = 2.0 * np.pi * np.arange(k) / k
    return np.stack([x + c * np.cos(a), y + c * np.sin(a)], axis=1)


def value_shift(radius, radii):
    """Per disc, what its pair rows add to the library's V: ``radius`` - r (None: all 0)."""
    return None if radii is None else radius - radii


def pair_shifts(radii, configs, pair_robot, position):
    """Per pair row (its robot row ``pair_robot``, ascending, and ``position``, its index in the
    robot's detections): ``value_shift`` of its disc, or None if every robot's discs are of its
    configured radius. ``radii``: per robot row its detections' radii (None: all its radius)."""
    if all(map(is_, radii, repeat(None))):     # (most decisions: checked in C)
        return None
    r0, c0 = radii[0], configs[0]
    if all(map(is_, radii, repeat(r0))) and all(map(is_, configs, repeat(c0))):    # one array for all
        return c0.radius - r0[position]
    out = np.zeros(len(pair_robot))
    bounds = np.searchsorted(pair_robot, np.arange(len(radii) + 1)).tolist()
    for i, (r, cfg) in enumerate(zip(radii, configs)):
        lo, hi = bounds[i], bounds[i + 1]
        if r is not None and hi > lo:
            out[lo:hi] = cfg.radius - r[position[lo:hi]]
    return out
