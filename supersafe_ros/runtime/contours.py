"""The level set a filter uses, as lines a person can look at.

``level_set_contour(vf, theta, alpha)`` is the contour {V(x, y, theta) = alpha} of a
value function at one heading, in the value function's own frame (obstacle at the
origin): a list of (K, 2) polylines (closed ones end on their first point). V is
sampled on the grid's (x, y) nodes refined ``refine`` times (each cell split in
``refine`` x ``refine``) through ``ValueFunction.value``, the same evaluation the
filter's law uses, and contoured by marching squares (contourpy, matplotlib's
contour engine), which places each vertex on a cell edge by linear interpolation.

``level_sets_around(vf, state, obstacles_xy, alpha)``: the contour at the robot's
heading, translated to each obstacle's centre (map frame): what the filter in force
checks the robot against, drawn where it applies.
"""
from __future__ import annotations

import numpy as np

from ..reach.value_function import ValueFunction


def heading_slice(vf: ValueFunction, theta: float, refine: int = 2):
    """(x nodes, y nodes, V[i, j]) at heading ``theta`` on a grid ``refine`` times finer."""
    if refine < 1:
        raise ValueError(f'refine must be >= 1, got {refine}')
    g = vf.grid
    x = np.linspace(g.x[0], g.x[-1], (len(g.x) - 1) * refine + 1)
    y = np.linspace(g.y[0], g.y[-1], (len(g.y) - 1) * refine + 1)
    X, Y = np.meshgrid(x, y, indexing='ij')
    return x, y, vf.value(np.stack([X, Y, np.full_like(X, float(theta))], axis=-1))


def level_set_contour(vf: ValueFunction, theta: float, alpha: float, refine: int = 2) -> list[np.ndarray]:
    """Polylines (K, 2) of {V(., ., theta) = alpha}, obstacle frame; [] if V never crosses alpha."""
    import contourpy
    if not (np.isfinite(theta) and np.isfinite(alpha)):
        raise ValueError(f'theta and alpha must be finite, got {theta}, {alpha}')
    x, y, v = heading_slice(vf, theta, refine)
    gen = contourpy.contour_generator(x, y, v.T, line_type=contourpy.LineType.Separate)
    return [np.asarray(line, dtype=float) for line in gen.lines(float(alpha)) if len(line) >= 2]


def level_sets_around(vf: ValueFunction, state, obstacles_xy, alpha: float, refine: int = 2,
                      nearest: int | None = None) -> list[list]:
    """For each obstacle centre (N, 2): the contour at the robot's heading state[2], in map
    coordinates (one contour computation, translated per obstacle); with ``nearest``, only
    around that many nearest to the robot (in their order: a lidar's thousands of points
    would make a million marker points)."""
    centres = np.asarray(obstacles_xy, dtype=float).reshape(-1, 2)
    if len(centres) == 0:
        return []
    if nearest is not None and len(centres) > nearest:
        d = np.hypot(centres[:, 0] - float(state[0]), centres[:, 1] - float(state[1]))
        centres = centres[np.sort(np.argpartition(d, nearest - 1)[:nearest])]
    lines = level_set_contour(vf, float(state[2]), alpha, refine)
    return [[line + c for line in lines] for c in centres]
