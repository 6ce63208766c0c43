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
        return np.hypot(p[..., 0] - self.cx, p[..., 1] - self.cy) - self.radius

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
        return np.min(np.stack([m.signed_distance(xy) for m in self.members]), axis=0)

    def inflated(self, margin: float) -> 'Union':
        return Union(tuple(m.inflated(margin) for m in self.members))

    def params(self) -> dict:
        return {'type': 'union', 'members': [m.params() for m in self.members]}

    def discs(self):
        return tuple(d for m in self.members for d in m.discs())


def keepout_from_discs(discs) -> 'Disc | Union':
    """A single disc stays a Disc (the solver has an exact path for it)."""
    discs = [d if isinstance(d, Disc) else Disc(*d) for d in discs]
    return discs[0] if len(discs) == 1 else Union(tuple(discs))
