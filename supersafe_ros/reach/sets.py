"""Keep-out sets as signed distances l(x): negative inside, positive outside.

Only the position (x, y) of a state matters; the heading does not.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Disc:
    """A disc of ``radius`` at (cx, cy): l = |p - c| - radius."""

    cx: float
    cy: float
    radius: float

    def __post_init__(self):
        if not all(np.isfinite([self.cx, self.cy, self.radius])) or self.radius <= 0:
            raise ValueError(f'a disc needs a finite centre and a positive radius, got {self}')

    def signed_distance(self, xy) -> np.ndarray:
        p = np.asarray(xy, dtype=float)
        return self.signed_distance_xy(p[..., 0], p[..., 1])

    def signed_distance_xy(self, x, y) -> np.ndarray:
        """l at points (x, y) given as two arrays (broadcast): sqrt(dx^2 + dy^2) - radius
        (np.hypot guards against overflow that these lengths never reach, at 7x the cost)."""
        return _distances_squared(x, y, ((self.cx, self.cy),)) ** 0.5 - self.radius

    def inflated(self, margin: float) -> 'Disc':
        """The same disc grown by ``margin`` (the paper's Conservative set doubles the radius)."""
        return Disc(self.cx, self.cy, self.radius + margin)

    def params(self) -> dict:
        return {'type': 'disc', 'cx': float(self.cx), 'cy': float(self.cy), 'radius': float(self.radius)}

    def discs(self):
        return (self,)


@dataclass(frozen=True)
class Union:
    """Union of keep-out sets: l = min over members (exact outside, where it matters)."""

    members: tuple

    def __post_init__(self):
        if len(self.members) == 0:
            raise ValueError('a union needs at least one member')
        object.__setattr__(self, 'members', tuple(self.members))

    def signed_distance(self, xy) -> np.ndarray:
        p = np.asarray(xy, dtype=float)
        return self.signed_distance_xy(p[..., 0], p[..., 1])

    def signed_distance_xy(self, x, y) -> np.ndarray:
        """min over members. Discs of one radius share one square root: sqrt is monotone,
        so min_i sqrt(d_i^2) - r = sqrt(min_i d_i^2) - r exactly (the solver's hot path:
        12x faster than a stack of per-disc distances for a cluster of four)."""
        by_radius, others = {}, []
        for m in self.members:
            if isinstance(m, Disc):
                by_radius.setdefault(m.radius, []).append((m.cx, m.cy))
            else:
                others.append(m)
        out = None
        for radius, centres in by_radius.items():
            d = _distances_squared(x, y, centres)
            np.sqrt(d, out=d)
            d -= radius
            out = d if out is None else np.minimum(out, d, out=out)
        for m in others:
            d = m.signed_distance_xy(x, y)
            out = d if out is None else np.minimum(out, d, out=out)
        return out

    def inflated(self, margin: float) -> 'Union':
        return Union(tuple(m.inflated(margin) for m in self.members))

    def params(self) -> dict:
        return {'type': 'union', 'members': [m.params() for m in self.members]}

    def discs(self):
        return tuple(d for m in self.members for d in m.discs())


def _distances_squared(x, y, centres) -> np.ndarray:
    """min over ``centres`` of (x - cx)^2 + (y - cy)^2, as a new float array."""
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    best = None
    for cx, cy in centres:
        dx = x - cx
        dy = y - cy
        dx *= dx
        dy *= dy
        d = dx + dy          # a new array: x and y may broadcast against each other
        best = d if best is None else np.minimum(best, d, out=best)
    return best


def keepout_from_discs(discs) -> 'Disc | Union':
    """A single disc stays a Disc (the solver has an exact path for it)."""
    discs = [d if isinstance(d, Disc) else Disc(*d) for d in discs]
    return discs[0] if len(discs) == 1 else Union(tuple(discs))
