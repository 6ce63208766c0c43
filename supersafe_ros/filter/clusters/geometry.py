"""A cluster's geometry and its union value read at robot states (the package's doc has the math).

* ``ClusterSettings``: how clusters are formed and solved;
* ``components`` and ``link_pairs``: which obstacles interact;
* ``canonical`` and ``to_frame``: a cluster up to translation and rotation, its cache key;
* ``ClusterValue``, ``lower_bound``: the union's value between grid nodes as its Lipschitz lower bound;
* ``orbit_value``: the clearance of the clearer loiter circle, the fallback while a cluster is solved.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ...reach.value_function import ValueFunction


@dataclass(frozen=True)
class ClusterSettings:
    """How clusters are formed and solved (lengths in m, times in s)."""

    radius: float = 1.8            # obstacle radius
    speed: float = 3.0             # true dynamics (the standard set's)
    omega_max: float = 1.0
    link: float = 0.0              # centres closer than this interact; 0 = 2 radius + turning diameter
    key_resolution: float = 0.05   # the canonical geometry is rounded to this
    margin: float = 0.1            # disc inflation: >= key rounding error (0.035) + solver error
    cell: float = 0.35             # grid spacing in x and y
    headings: int = 32             # grid nodes in theta
    reach: float = 7.0             # grid extends this far beyond the outermost centres
    horizon: float = 3.0           # as the standard set
    lower_bound: bool = True       # read V between nodes as its Lipschitz lower bound (else trilinear)
    disk_cache: bool = True        # keep solved clusters on disk (shared by processes and runs)

    @property
    def link_distance(self) -> float:
        if self.link > 0:
            return self.link
        return 2.0 * self.radius + 2.0 * self.speed / max(self.omega_max, 1e-9)

    @property
    def turning_radius(self) -> float:
        return self.speed / max(self.omega_max, 1e-9)

    @property
    def turn_hold(self) -> float:
        """The shortest hold over which a cluster value tells the two bangs apart: their ends
        are one heading cell (2 pi / headings) apart at full turn rate. The avoid turn is the
        bang whose hold ends at the larger V; over a shorter hold both ends read the same
        between grid nodes (a tie, turned left whichever side is safe)."""
        return 2.0 * math.pi / self.headings / max(self.omega_max, 1e-9)


def components(centres, link: float) -> list:
    """Index arrays of the clusters (connected within ``link``), singletons included: in the
    order of their first members, each ascending (as a union-find over all pairs gives them).

    Near-linear: the pairs within ``link`` come from a k-d tree (``link_pairs``) and the
    clusters from scipy's connected components, so the cost grows with the detections and
    their neighbours, not with all pairs (100,000 centres: an all-pairs matrix of 74.5 GiB).
    """
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    n = len(c)
    if n == 0:
        return []
    i, j = link_pairs(c, link)
    graph = coo_matrix((np.ones(len(i), np.int8), (i, j)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    order = np.argsort(label, kind='stable')            # members ascending within a cluster
    cut = np.flatnonzero(np.diff(label[order])) + 1
    groups = np.split(order, cut)
    groups.sort(key=lambda g: g[0])                     # clusters by their first member
    return groups


def link_pairs(centres, link: float):
    """(i, j), i < j: the pairs of ``centres`` (N, 2) at most ``link`` apart, by np.hypot as an
    all-pairs matrix would judge them (the tree's candidates, taken a hair wider, are
    checked again)."""
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    if len(c) < 2:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    pairs = cKDTree(c).query_pairs(link * (1.0 + 1e-9) + 1e-12, output_type='ndarray')
    i, j = pairs[:, 0].astype(np.intp), pairs[:, 1].astype(np.intp)
    close = np.hypot(c[i, 0] - c[j, 0], c[i, 1] - c[j, 1]) <= link
    return i[close], j[close]


def canonical(centres, resolution: float):
    """(key, origin, angle, rounded canonical centres) of a cluster's geometry.

    Canonical frame: origin at the centroid, x along the farthest pair of centres
    (of the two orientations, the one with the smaller key). A map point p is
    R(-angle) (p - origin) there.
    """
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    origin = c.mean(axis=0)
    rel = c - origin
    d = np.hypot(rel[:, None, 0] - rel[None, :, 0], rel[:, None, 1] - rel[None, :, 1])
    i, j = np.unravel_index(np.argmax(d), d.shape)
    base = math.atan2(rel[j, 1] - rel[i, 1], rel[j, 0] - rel[i, 0])
    best = None
    for angle in (base, base + math.pi):
        cs, sn = math.cos(angle), math.sin(angle)
        rot = np.stack([cs * rel[:, 0] + sn * rel[:, 1], -sn * rel[:, 0] + cs * rel[:, 1]], axis=1)
        q = np.round(rot / resolution).astype(int)
        key = tuple(sorted(map(tuple, q.tolist())))
        if best is None or key < best[0]:
            best = (key, angle)
    key, angle = best
    return key, origin, angle, np.array(key, dtype=float) * resolution


def to_frame(states, origin, angle) -> np.ndarray:
    """Map states (N, 3) into a cluster's canonical frame."""
    s = np.asarray(states, dtype=float).reshape(-1, 3)
    cs, sn = math.cos(angle), math.sin(angle)
    dx, dy = s[:, 0] - origin[0], s[:, 1] - origin[1]
    return np.stack([cs * dx + sn * dy, -sn * dx + cs * dy, s[:, 2] - angle], axis=1)


@dataclass
class ClusterValue:
    """The union's value of one canonical cluster."""

    vf: ValueFunction
    centres: np.ndarray        # canonical centres (rounded)
    solve_time: float          # seconds of solving
    lower: bool = True         # Lipschitz lower bound between nodes (else trilinear)
    lipschitz_theta: float = 0.0

    def __post_init__(self):
        self.lipschitz_theta = float(np.max(np.abs(self.vf.node_gradient()[..., 2])))
        from ..law import tie_tolerance
        self.tie = tie_tolerance(self.vf)

    def evaluate(self, frame_states):
        """(V lower bound, unit turn) at states in the canonical frame; +inf/0 off the grid."""
        s = np.asarray(frame_states, dtype=float).reshape(-1, 3)
        value, inside = self._value(s)
        turn = np.zeros(len(s))
        if np.any(inside):
            grad = self.vf.grid.interpolate(self.vf.theta_gradient(), s[inside])
            turn[inside] = np.where(grad >= -self.tie, 1.0, -1.0)
        return value, turn

    def value(self, frame_states):
        """V lower bound at states in the canonical frame (``evaluate``'s); +inf off the grid."""
        return self._value(np.asarray(frame_states, dtype=float).reshape(-1, 3))[0]

    def _value(self, s):
        value = np.full(len(s), np.inf)
        inside = self.vf.grid.contains(s)
        if np.any(inside):
            si = s[inside]
            value[inside] = (lower_bound(self.vf, si, self.lipschitz_theta) if self.lower
                             else self.vf.value(si))
        return value, inside


def lower_bound(vf: ValueFunction, states, lipschitz_theta: float) -> np.ndarray:
    """max over the cell's 8 nodes of V(node) - |dp| - L_theta |dtheta| (see the module doc)."""
    g = vf.grid
    ix, iy, it, wx, wy, wt = g._cell(states)
    dx, dy, dth = g.spacing
    # offsets to the corners, from the clamped cell coordinates (states outside were excluded)
    ox, oy, ot = wx * dx, wy * dy, wt * dth
    it1 = (it + 1) % g.shape[2]
    flat, ny, nth = np.ascontiguousarray(vf.values).reshape(-1), g.shape[1], g.shape[2]
    first = (ix * ny + iy) * nth      # the cell's corners are fixed offsets from its first node
    heading = ((it, lipschitz_theta * ot), (it1, lipschitz_theta * (dth - ot)))
    best = None
    for offset, ddx, ddy in g._corners(ox, dx - ox, oy, dy - oy):
        dp = np.hypot(ddx, ddy)
        base = first + offset
        for ct, slack in heading:
            bound = flat.take(base + ct) - dp - slack
            best = bound if best is None else np.maximum(best, bound)
    return best


def orbit_value(states, centres, radius: float, turning_radius: float):
    """(clearance of the clearer loiter circle, its turn +1 left / -1 right) per state.

    Clearance of a circle of radius r centred at m from a disc (c, R):
    | |m - c| - r | - R (the circle passes outside or around the disc).
    """
    s = np.asarray(states, dtype=float).reshape(-1, 3)
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    out = []
    for side in (1.0, -1.0):
        mx = s[:, 0] - side * turning_radius * np.sin(s[:, 2])
        my = s[:, 1] + side * turning_radius * np.cos(s[:, 2])
        dist = np.hypot(mx[:, None] - c[None, :, 0], my[:, None] - c[None, :, 1])
        out.append(np.min(np.abs(dist - turning_radius) - radius, axis=1))
    left, right = out
    return np.maximum(left, right), np.where(left >= right, 1.0, -1.0)
