"""Regular state grids over (x, y, theta) with a periodic heading axis.

Conventions (shared by the solver, the value-function files and the ROS messages):

* x and y nodes include both ends: ``x_i = x_min + i (x_max - x_min) / (nx - 1)``.
* theta nodes are ``theta_k = -pi + k 2 pi / nth`` (periodic, no node at +pi).
* value arrays are indexed ``values[i, j, k]`` (axes x, y, theta).

Interpolation is trilinear: exact for functions linear in each axis, monotone
(never overshoots the node values), and cheap enough to evaluate for thousands of
robot-obstacle pairs per call.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

TWO_PI = 2.0 * np.pi


def wrap_angle(theta):
    """Wrap angles to [-pi, pi)."""
    return (np.asarray(theta, dtype=float) + np.pi) % TWO_PI - np.pi


@dataclass(frozen=True)
class Grid:
    """A rectangle in (x, y) times the full circle of headings."""

    lo: tuple[float, float]
    hi: tuple[float, float]
    shape: tuple[int, int, int]

    def __post_init__(self):
        lo = tuple(float(v) for v in self.lo)
        hi = tuple(float(v) for v in self.hi)
        shape = tuple(int(n) for n in self.shape)
        if len(lo) != 2 or len(hi) != 2 or len(shape) != 3:
            raise ValueError('a grid needs lo=(xmin, ymin), hi=(xmax, ymax), shape=(nx, ny, nth)')
        if not all(np.isfinite(lo + hi)):
            raise ValueError(f'grid bounds must be finite, got lo={lo} hi={hi}')
        if not (hi[0] > lo[0] and hi[1] > lo[1]):
            raise ValueError(f'grid needs hi > lo on both axes, got lo={lo} hi={hi}')
        if shape[0] < 2 or shape[1] < 2 or shape[2] < 3:
            raise ValueError(f'grid shape must be at least 2 x 2 x 3, got {shape}')
        object.__setattr__(self, 'lo', lo)
        object.__setattr__(self, 'hi', hi)
        object.__setattr__(self, 'shape', shape)

    # -- node coordinates -------------------------------------------------
    @property
    def spacing(self) -> tuple[float, float, float]:
        nx, ny, nth = self.shape
        return ((self.hi[0] - self.lo[0]) / (nx - 1),
                (self.hi[1] - self.lo[1]) / (ny - 1),
                TWO_PI / nth)

    @property
    def x(self) -> np.ndarray:
        return np.linspace(self.lo[0], self.hi[0], self.shape[0])

    @property
    def y(self) -> np.ndarray:
        return np.linspace(self.lo[1], self.hi[1], self.shape[1])

    @property
    def theta(self) -> np.ndarray:
        return -np.pi + np.arange(self.shape[2]) * (TWO_PI / self.shape[2])

    def mesh(self):
        """Node coordinates as three arrays of the grid's shape."""
        return np.meshgrid(self.x, self.y, self.theta, indexing='ij')

    def contains(self, states) -> np.ndarray:
        """Whether (x, y) of each state lies in the rectangle (theta is periodic)."""
        s = np.asarray(states, dtype=float)
        return ((s[..., 0] >= self.lo[0]) & (s[..., 0] <= self.hi[0])
                & (s[..., 1] >= self.lo[1]) & (s[..., 1] <= self.hi[1]))

    def to_dict(self) -> dict:
        return {'lo': list(self.lo), 'hi': list(self.hi), 'shape': list(self.shape)}

    @classmethod
    def from_dict(cls, d) -> 'Grid':
        return cls(tuple(d['lo']), tuple(d['hi']), tuple(d['shape']))

    # -- interpolation ----------------------------------------------------
    def _cell(self, states):
        """Lower corner indices and fractional offsets of each state's cell.

        x and y are clamped to the rectangle; theta wraps.
        """
        s = np.asarray(states, dtype=float)
        nth = self.shape[2]
        ix, iy, wx, wy = self._xy_cell(s[..., 0], s[..., 1])
        ft = ((s[..., 2] + np.pi) / self.spacing[2]) % nth
        it = np.minimum(ft.astype(np.intp), nth - 1)
        return ix, iy, it, wx, wy, ft - it

    def _xy_cell(self, x, y):
        """Lower corner indices and offsets in (x, y), clamped to the rectangle."""
        nx, ny, _ = self.shape
        dx, dy, _ = self.spacing
        fx = np.clip((x - self.lo[0]) / dx, 0.0, nx - 1)
        fy = np.clip((y - self.lo[1]) / dy, 0.0, ny - 1)
        ix = np.minimum(fx.astype(np.intp), nx - 2)
        iy = np.minimum(fy.astype(np.intp), ny - 2)
        return ix, iy, fx - ix, fy - iy

    def _xy_cell_at(self, x: float, y: float):
        """``_xy_cell`` of one state, in Python floats (the same operations, the same bits)."""
        nx, ny, _ = self.shape
        dx, dy, _ = self.spacing
        fx = min(max((x - self.lo[0]) / dx, 0.0), float(nx - 1))      # np.clip
        fy = min(max((y - self.lo[1]) / dy, 0.0), float(ny - 1))
        ix, iy = min(int(fx), nx - 2), min(int(fy), ny - 2)
        return ix, iy, fx - ix, fy - iy

    def _corners(self, x_near, x_far, y_near, y_far):
        """The cell's four (x, y) corners in summation order: (offset of the node from the
        cell's first one in C-ordered values, its x part, its y part), the parts given for
        the near (lower) and far corner on each axis (weights, or distances)."""
        ny, nth = self.shape[1], self.shape[2]
        return ((0, x_near, y_near), (nth, x_near, y_far), (ny * nth, x_far, y_near), (ny * nth + nth, x_far, y_far))

    def interpolate(self, values, states) -> np.ndarray:
        """Trilinear interpolation of node ``values`` at ``states`` (..., 3)."""
        values = np.asarray(values)
        if values.shape[:3] != self.shape:
            raise ValueError(f'values of shape {values.shape} do not match grid {self.shape}')
        ix, iy, it, wx, wy, wt = self._cell(states)
        if values.ndim == 3 and values.flags.c_contiguous:
            return self._interpolate_flat(values.reshape(-1), ix, iy, it, wx, wy, wt)
        it1 = (it + 1) % self.shape[2]
        if values.ndim > 3:  # vector-valued nodes (e.g. gradients): weights broadcast over them
            extra = (None,) * (values.ndim - 3)
            wx, wy, wt = wx[(...,) + extra], wy[(...,) + extra], wt[(...,) + extra]
        out = 0.0
        for cx, ax in ((ix, 1.0 - wx), (ix + 1, wx)):
            for cy, ay in ((iy, 1.0 - wy), (iy + 1, wy)):
                axy = ax * ay
                out = out + axy * ((1.0 - wt) * values[cx, cy, it] + wt * values[cx, cy, it1])
        return np.asarray(out, dtype=float)

    def _interpolate_flat(self, flat, ix, iy, it, wx, wy, wt) -> np.ndarray:
        """``interpolate`` of C-ordered node values ``flat`` (one gather index per node instead
        of three, the cell's corner indices by offsets from its first, 1 - wt once: the same
        values and the same arithmetic per corner, at about half the cost)."""
        ny, nth = self.shape[1], self.shape[2]
        first = (ix * ny + iy) * nth + it
        step = np.where(it == nth - 1, 1 - nth, 1)      # to the next heading node, periodic
        wt0 = 1.0 - wt
        out = None
        for offset, ax, ay in self._corners(1.0 - wx, wx, 1.0 - wy, wy):
            node = first + offset if offset else first
            term = (ax * ay) * (wt0 * flat.take(node) + wt * flat.take(node + step))
            out = term + 0.0 if out is None else out + term       # 0.0 + term first, as the sum from 0.0
        return np.asarray(out, dtype=float)

    def interpolate_layer(self, values, x, y, layer) -> np.ndarray:
        """Bilinear interpolation in (x, y) of node ``values`` (nx, ny, nth) on the heading
        layers ``layer`` (integers, taken modulo nth): V at heading nodes themselves, no
        weight on a neighbouring layer (a rotationally symmetric value function is read on
        nodes, see ``ValueFunction.value``). x and y are clamped to the rectangle."""
        ny, nth = self.shape[1], self.shape[2]
        ix, iy, wx, wy = self._xy_cell(x, y)
        flat = np.ascontiguousarray(values).reshape(-1)
        first = (ix * ny + iy) * nth + np.remainder(layer, nth)
        out = None
        for offset, ax, ay in self._corners(1.0 - wx, wx, 1.0 - wy, wy):
            term = (ax * ay) * flat.take(first + offset if offset else first)
            out = term + 0.0 if out is None else out + term       # 0.0 + term first, as from 0.0
        return np.asarray(out, dtype=float)

    def interpolate_layer_at(self, flat, x: float, y: float, layer: int) -> float:
        """``interpolate_layer`` at one state, in Python floats (the same operations in the
        same order, so the same value bit for bit; ``flat`` as for ``interpolate_at``)."""
        ny, nth = self.shape[1], self.shape[2]
        ix, iy, wx, wy = self._xy_cell_at(x, y)
        first = (ix * ny + iy) * nth + layer % nth
        out = 0.0
        for offset, ax, ay in self._corners(1.0 - wx, wx, 1.0 - wy, wy):
            out = out + (ax * ay) * flat[first + offset]
        return out

    def interpolate_at(self, flat, x: float, y: float, theta: float) -> float:
        """``interpolate`` at one state, in Python floats: the same operations in the same
        order, so the same value bit for bit, without numpy's cost per call (about 40 calls,
        most of the time for a handful of states). ``flat``: the node values as a flat
        sequence in C order (e.g. a memoryview of the contiguous array, see
        ``ValueFunction.flat_values``); ``x``, ``y``, ``theta`` finite."""
        ny, nth = self.shape[1], self.shape[2]
        ix, iy, wx, wy = self._xy_cell_at(x, y)
        ft = ((theta + math.pi) / self.spacing[2]) % nth
        it = min(int(ft), nth - 1)
        wt = ft - it
        it1 = (it + 1) % nth
        first = (ix * ny + iy) * nth
        out = 0.0
        for offset, ax, ay in self._corners(1.0 - wx, wx, 1.0 - wy, wy):
            base = first + offset
            out = out + (ax * ay) * ((1.0 - wt) * flat[base + it] + wt * flat[base + it1])
        return out


def node_gradient(grid: Grid, values: np.ndarray) -> np.ndarray:
    """Central-difference gradient at the nodes, shape grid.shape + (3,).

    One-sided differences at the x and y edges; theta is periodic.
    """
    dx, dy, dth = grid.spacing
    v = np.asarray(values, dtype=float)
    gx = np.gradient(v, dx, axis=0)
    gy = np.gradient(v, dy, axis=1)
    gth = (np.roll(v, -1, axis=2) - np.roll(v, 1, axis=2)) / (2.0 * dth)
    return np.stack([gx, gy, gth], axis=-1)


def theta_node_gradient(grid: Grid, values: np.ndarray, rows: int = 16) -> np.ndarray:
    """``node_gradient(grid, values)[..., 2].astype(float32)``, bit for bit, without the x and y
    components: the same float64 arithmetic, ``rows`` x-rows at a time (a 50 MB value function
    took 5 s and 450 MB for the full gradient, which the filter does not need)."""
    dth = grid.spacing[2]
    out = np.empty(grid.shape, dtype=np.float32)
    for i in range(0, grid.shape[0], rows):
        v = np.asarray(values[i:i + rows], dtype=float)
        out[i:i + rows] = (np.roll(v, -1, axis=2) - np.roll(v, 1, axis=2)) / (2.0 * dth)
    return out
