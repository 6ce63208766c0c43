"""A keep-out set given as a sampled signed distance, and the one of an occupancy map.

``FieldKeepout`` is l(x, y) known at the nodes of a regular lattice,

    node (i, j) at  p_ij = lo + cell (i, j),   l(p_ij) = values[i, j],

and bilinear between nodes: in the lattice cell of p = p_ij + cell (a, b), a, b in [0, 1],

    l(p) = (1 - a)(1 - b) l_ij + a (1 - b) l_i+1,j + (1 - a) b l_i,j+1 + a b l_i+1,j+1,

which is (1 - b) r_j + b r_j+1 with r_j = (1 - a) l_ij + a l_i+1,j: along x, then along y.
The lattice covers the closed rectangle R = [lo, lo + cell (nx - 1, ny - 1)]. Beyond R,
l = ``outside``, a number (default ``FREE``: a large positive distance, "unknown, taken as
free", as an occupancy map's never-seen cells): l jumps there from the rim's values to
``outside``. So a lattice must cover everything read at its values: the avoid solver reads
l on its grid padded by a few cells and along each step's arcs (``AvoidSolver.read_bounds``),
and ``filter.sensing.map_value`` builds the field over all of that, from a map padded with free
cells, so that its solver never reads ``outside``.

The solver reads l through ``signed_distance_xy(x, y)`` with x of shape (..., n, 1) and y of
shape (..., 1, m): x varies along one axis, y along the other. Then the interpolation is
separable: the weights a, b and the lattice indices are computed once per x and once per y
(not per point), the rows r_j once per x for the span of lattice columns the y's need, and
the result is two gathers of those rows, in float32 (what the solver keeps): equal to the
general path to float32 rounding (~1e-7 relative; test_reach_field), several times faster on
the solver's calls (figures in bench/bench_map_value.py).

``occupancy_field(origin, cell, occupied, clearance)`` is the field of an occupancy map
(cell (i, j) the square [x0 + i c, x0 + (i+1) c) x [y0 + j c, y0 + (j+1) c)): on the
lattice of cell centres c_ij = (x0, y0) + c (i + 1/2, j + 1/2),

    l(c_ij) = D_ij - c sqrt(2)/2 - clearance,   D_ij = min over occupied (k, m) |c_ij - c_km|,

D by scipy.ndimage.distance_transform_edt (exact Euclidean distances between centres).
At the nodes this is a lower bound of the clearance to everything in an occupied cell: a
cell lies in the disc of radius c sqrt(2)/2 (its half diagonal) about its centre, so for any
point q of cell (k, m), |p - q| >= |p - c_km| - c sqrt(2)/2 >= D(p) - c sqrt(2)/2: the robot
(a disc of radius ``clearance`` about p) touches no occupied cell while l(p) > 0. The bound
is loose by at most c sqrt(2)/2 (the distance to a cell is at most that to its centre; the
worst case is a node inside an occupied cell); a node squarely facing a wall of cells is
c (sqrt(2) - 1)/2 low (0.0104 m at c = 0.05), one facing a lone cell's corner diagonally is exact.

Between nodes the bilinear interpolant is a convex combination of the four node values, so
it lies between their minimum and maximum, but it is not a lower bound of the true
clearance f(p) = dist(p, occupied) - clearance: f is 1-Lipschitz, so l(p_n) <= f(p_n) <=
f(p) + |p - p_n| at each node and

    l(p) <= f(p) + sum_n w_n |p - p_n| <= f(p) + c sqrt(2)/2

(the weighted distance to the corners is largest, c sqrt(2)/2, at the cell's centre). The
node bound's own slack covers part of it; a caller that needs l <= f everywhere adds
c sqrt(2)/2 to the clearance. Where D is the distance to one centre (a convex function),
bilinear interpolation overestimates it, never underestimates it.

No occupied cell: l = ``FREE`` on every node.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import distance_transform_edt

FREE = 1.0e3            # m: the distance assumed with no obstacle (unknown, taken as free)


class FieldKeepout:
    """l(x, y) at the nodes lo + cell (i, j) of a lattice, bilinear between them, ``outside`` beyond it."""

    def __init__(self, lo, cell, values, outside: float = FREE):
        lo = tuple(float(v) for v in lo)
        values = np.array(values, dtype=float)
        if len(lo) != 2 or not all(math.isfinite(v) for v in lo):
            raise ValueError(f'a field needs a finite lower corner (x, y), got {lo}')
        if not (math.isfinite(cell) and cell > 0):
            raise ValueError(f'a field needs a positive finite cell size, got {cell}')
        if values.ndim != 2 or values.shape[0] < 2 or values.shape[1] < 2:
            raise ValueError(f'a field needs values of shape (nx, ny), nx, ny >= 2, got {values.shape}')
        if not np.all(np.isfinite(values)) or not math.isfinite(outside):
            raise ValueError('a field needs finite values and a finite outside value')
        values.setflags(write=False)
        self.lo, self.cell, self.values, self.outside = lo, float(cell), values, float(outside)
        self._values32 = np.ascontiguousarray(values, dtype=np.float32)     # the separable path's
        self.shape = values.shape

    @property
    def hi(self) -> tuple[float, float]:
        """The last node's position: the lattice covers [lo, hi]."""
        return (self.lo[0] + self.cell * (self.shape[0] - 1), self.lo[1] + self.cell * (self.shape[1] - 1))

    def signed_distance(self, xy) -> np.ndarray:
        """l at points (..., 2)."""
        p = np.asarray(xy, dtype=float)
        return self.signed_distance_xy(p[..., 0], p[..., 1])

    def signed_distance_xy(self, x, y) -> np.ndarray:
        """l at points (x, y) given as two arrays that broadcast; separable when x has shape (..., n, 1)
        and y (..., 1, m) (the solver's calls, see the module docstring)."""
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        if x.ndim >= 2 and x.ndim == y.ndim and x.shape[-1] == 1 and y.shape[-2] == 1:
            return self._separable(x[..., 0], y[..., 0, :])
        return self._general(*np.broadcast_arrays(x, y))

    def _axis(self, coord, axis: int):
        """Lower node index, weight of the upper node, and whether inside, of each coordinate on one axis."""
        n = self.shape[axis]
        f = (coord - self.lo[axis]) / self.cell
        inside = (f >= 0.0) & (f <= n - 1)
        i = np.clip(np.floor(f), 0, n - 2).astype(np.intp)
        return i, np.clip(f - i, 0.0, 1.0), inside

    def _general(self, x, y) -> np.ndarray:
        ix, wx, in_x = self._axis(x, 0)
        iy, wy, in_y = self._axis(y, 1)
        v = self.values
        lo = v[ix, iy] + wx * (v[ix + 1, iy] - v[ix, iy])
        hi = v[ix, iy + 1] + wx * (v[ix + 1, iy + 1] - v[ix, iy + 1])
        out = lo + wy * (hi - lo)
        return np.where(in_x & in_y, out, self.outside)

    def _separable(self, xs, ys) -> np.ndarray:
        """l at (xs[..., i], ys[..., j]) for every i, j: shape (..., n, m), in float32."""
        lead = np.broadcast_shapes(xs.shape[:-1], ys.shape[:-1])
        xs = np.broadcast_to(xs, lead + xs.shape[-1:])
        ys = np.broadcast_to(ys, lead + ys.shape[-1:])
        ix, wx, in_x = self._axis(xs, 0)
        iy, wy, in_y = self._axis(ys, 1)
        first, last = int(iy.min()), int(iy.max()) + 2      # the lattice columns the y's need
        band = self._values32[:, first:last]
        # along x: the rows r(x) = (1 - a) l_i + a l_i+1 over the needed columns, (..., n, columns)
        rows = band.take(ix + 1, axis=0)
        low = band.take(ix, axis=0)
        rows -= low
        rows *= wx.astype(np.float32)[..., None]
        rows += low
        # along y: two gathers of each row at its own columns (flat indices: one take each)
        n, columns = xs.shape[-1], last - first
        starts = (np.arange(rows.size // columns) * columns).reshape(lead + (n, 1))
        at = starts + (iy - first)[..., None, :]
        flat = rows.reshape(-1)
        out = flat.take(at + 1)
        left = flat.take(at)
        out -= left
        out *= wy.astype(np.float32)[..., None, :]
        out += left
        return np.where(in_x[..., :, None] & in_y[..., None, :], out, np.float32(self.outside))

    def inflated(self, margin: float) -> 'FieldKeepout':
        """The set grown by ``margin``: l - margin everywhere, ``outside`` too."""
        return FieldKeepout(self.lo, self.cell, self.values - margin, self.outside - margin)

    def params(self) -> dict:
        return {'type': 'field', 'lo': list(self.lo), 'cell': self.cell, 'shape': list(self.shape),
                'outside': self.outside}

    def discs(self):
        """No discs: the set is a field."""
        return ()


def occupancy_field(origin, cell, occupied, clearance=0.0):
    """(lo, values): the signed distance field of an occupancy map on the lattice of its cell centres
    (module docstring): lo = origin + cell/2, values = D - cell sqrt(2)/2 - clearance, FREE without
    an occupied cell."""
    occupied = np.asarray(occupied, dtype=bool)
    if occupied.ndim != 2 or occupied.shape[0] < 2 or occupied.shape[1] < 2:
        raise ValueError(f'an occupancy map needs a 2-D array of at least 2 x 2 cells, got {occupied.shape}')
    if not (math.isfinite(cell) and cell > 0) or not math.isfinite(clearance):
        raise ValueError(f'an occupancy map needs a positive finite cell and a finite clearance, '
                         f'got {cell}, {clearance}')
    lo = (float(origin[0]) + 0.5 * cell, float(origin[1]) + 0.5 * cell)
    if not occupied.any():
        return lo, np.full(occupied.shape, FREE)
    distance = distance_transform_edt(~occupied, sampling=cell)
    return lo, distance - (cell * math.sqrt(2.0) / 2.0 + clearance)
