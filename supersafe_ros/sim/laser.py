"""A simulated planar laser: the ranges of beams cast from a pose against discs.

Beam i leaves the sensor at position p (the robot's centre) in direction
d_i = (cos(theta + a_i), sin(theta + a_i)), a_i = angle_min + i angle_increment. It hits the
disc (c, r) at the smallest t >= 0 with |p + t d_i - c| = r:
    t = b - sqrt(b^2 - (|p - c|^2 - r^2)),  b = d_i . (c - p),
when b^2 >= |p - c|^2 - r^2 and t >= 0 (from inside a disc, t = b + sqrt(...), the far side,
so a robot in an obstacle still sees it). Its range is the nearest hit over the discs, +inf
when none is nearer than ``range_max`` (REP 117: no return). Work: beams x discs, vectorised.
"""
from __future__ import annotations

import numpy as np


def beam_angles(count: int, angle_min: float = -np.pi, angle_increment: float | None = None) -> np.ndarray:
    """The beams' angles in the sensor's frame (default: ``count`` beams round the full circle)."""
    inc = 2.0 * np.pi / count if angle_increment is None else angle_increment
    return angle_min + inc * np.arange(count)


def ray_cast(pose, angles, centres, radii, range_max: float) -> np.ndarray:
    """float32 ranges of the beams at ``angles`` from ``pose`` (x, y, theta) against discs
    (``centres`` (K, 2), ``radii`` (K,)); +inf where nothing is within ``range_max``."""
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    r = np.asarray(radii, dtype=float).reshape(-1)
    a = float(pose[2]) + np.asarray(angles, dtype=float)
    out = np.full(len(a), np.inf)
    if len(c):
        d = np.column_stack([np.cos(a), np.sin(a)])                  # (B, 2)
        rel = c - np.asarray(pose[:2], dtype=float)                  # (K, 2)
        b = d @ rel.T                                                 # (B, K)
        q = np.einsum('ij,ij->i', rel, rel) - r * r                  # (K,)
        disc = b * b - q
        root = np.sqrt(np.maximum(disc, 0.0))
        t = np.where(q > 0, b - root, b + root)                      # inside a disc: its far side
        t = np.where((disc >= 0) & (t >= 0), t, np.inf)
        out = t.min(axis=1)
    out[out > range_max] = np.inf
    return out.astype(np.float32)
