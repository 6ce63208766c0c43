"""A value function on a grid, with its parameters, and its file formats.

``ValueFunction`` is what every other part of the package passes around: the
solver returns one, the library holds many, the learner publishes one, the
safety filter and the simulated supervisor evaluate one at robot states.

File formats:

* ``.npz`` (the package's own): ``value`` float32 (nx, ny, nth), ``x``, ``y``,
  ``theta`` node coordinates, and ``meta`` (JSON text: parameters, solver
  settings, solve time).
* helperOC / Level Set Toolbox JSON (as exported from MATLAB, see
  shared/data/s3/README.md): keys gdim, gmin, gmax, gN, gdx, gperiodicity, data.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import json
import math
import os
import threading
import zipfile

import numpy as np

from .grid import Grid, TWO_PI, node_gradient, theta_node_gradient


@dataclass
class ValueFunction:
    """V on ``grid`` (values[i, j, k] at x_i, y_j, theta_k) plus metadata.

    ``meta`` carries what produced it, e.g. speed, omega_max, radius, horizon.
    """

    grid: Grid
    values: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        v = np.asarray(self.values, dtype=np.float32)
        if v.shape != self.grid.shape:
            raise ValueError(f'values of shape {v.shape} do not match grid shape {self.grid.shape}')
        if not np.all(np.isfinite(v)):
            raise ValueError('value function contains NaN or infinite values')
        self.values = v
        self._grad = None
        self._grad_theta = None
        self._flat = None
        self._flat_grad_theta = None
        self._radial = None
        self._theta_bound = None

    # -- evaluation -------------------------------------------------------
    @property
    def rotationally_symmetric(self) -> bool:
        """A Dubins car and one disc at the origin: V(R x, R y, th + b) = V(x, y, th)."""
        k = self.meta.get('keepout')
        return (self.meta.get('model') == 'dubins' and isinstance(k, dict)
                and k.get('type') == 'disc' and k.get('cx') == 0.0 and k.get('cy') == 0.0)

    def value(self, states, outside=None) -> np.ndarray:
        """V at states (..., 3). Outside the (x, y) rectangle: ``outside`` if given,
        else the value at the nearest edge.

        Rotationally symmetric value functions are not interpolated across heading
        nodes: V has a V-shaped valley in theta (heading straight at the obstacle)
        that linear interpolation between nodes 2 pi / nth apart overestimates by up
        to |dV/dtheta| dtheta / 2 (0.2 on the paper's grid), which is exactly where a
        filter must not act late. The state is rotated about the obstacle onto each
        of the two neighbouring heading nodes and interpolated in (x, y) there (on the
        node's own layer, ``Grid.interpolate_layer``); both
        are estimates of the same V, and the interpolation of a convex kink only
        overestimates, so the smaller one is kept.
        """
        s = np.asarray(states, dtype=float)
        if self.rotationally_symmetric:
            v = self._value_rotated(s)
        else:
            v = self.grid.interpolate(self.values, s)
        if outside is not None:
            v = np.where(self.grid.contains(s), v, outside)
        return v

    def _value_rotated(self, s) -> np.ndarray:
        dth = self.grid.spacing[2]
        x, y, th = s[..., 0], s[..., 1], s[..., 2]
        k0 = np.floor((th + np.pi) / dth)
        out = None
        for k in (k0, k0 + 1.0):
            node = -np.pi + k * dth
            beta = node - th
            c, sn = np.cos(beta), np.sin(beta)
            v = self.grid.interpolate_layer(self.values, c * x - sn * y, sn * x + c * y, k.astype(np.intp))
            out = v if out is None else np.minimum(out, v)
        return out

    def value_at(self, x: float, y: float, theta: float, outside=None) -> float:
        """``value`` at one finite state, in Python floats: the same operations in the same
        order (``Grid.interpolate_at``; numpy's float64 cos and sin are the C library's,
        test_reach_io checks it), so the same value bit for bit. For callers that read V at
        a handful of states, where numpy's cost per call is most of the time."""
        g = self.grid
        if outside is not None and not (g.lo[0] <= x <= g.hi[0] and g.lo[1] <= y <= g.hi[1]):
            return outside
        flat = self.flat_values()
        if not self.rotationally_symmetric:
            return g.interpolate_at(flat, x, y, theta)
        dth = g.spacing[2]
        k0 = float(math.floor((theta + math.pi) / dth))
        out = None
        for k in (k0, k0 + 1.0):
            node = -math.pi + k * dth
            beta = node - theta
            c, sn = math.cos(beta), math.sin(beta)
            v = g.interpolate_layer_at(flat, c * x - sn * y, sn * x + c * y, int(k))
            out = v if out is None or not out < v else out     # np.minimum(out, v), signed zeros too
        return out

    def radial_minimum(self, r_lo, r_hi) -> np.ndarray:
        """A lower bound of ``value(s)`` over every state s on the grid whose (x, y) lies at a
        distance in [r_lo, r_hi] from the origin (arrays; +inf where no read can be there,
        -inf where a radius is not finite).

        Either read of V is a convex combination of node values (trilinear, or bilinear on a
        heading layer) of the nodes of one (x, y) cell, all within the cell's diagonal h of
        the point read. A trilinear read is at (x, y) itself. A rotationally symmetric read is
        at (x, y) rotated about the origin by at most one heading step dth, so at the same
        radius r, unless the rotation leaves the rectangle: then it is clamped onto it, which
        moves it no farther than its distance r dth from (x, y) (a projection onto a convex
        set that holds (x, y)). If the rectangle holds the origin, the clamped point is no
        farther out than r (the projection holds the origin too) and, if r > rho (the largest
        disc about the origin inside the rectangle), no nearer than max(rho, r (1 - dth));
        otherwise it is within r (1 -+ dth). So every node a read can use has its radius in
        [f(r_lo) - h, g(r_hi) + h], and V read >= the smallest node value (over every
        heading) in that band: a range minimum over radius bins (a sparse table, built
        once). The band is widened by 1e-5 m for round-off (``arc_flow``'s nearly straight
        arcs end within ~1e-6 m of the exact arc).
        """
        if self._radial is None:
            self._radial = _radial_table(self.grid, self.values)
        width, table, h, rho, origin_inside = self._radial
        lo, hi = np.asarray(r_lo, dtype=float), np.asarray(r_hi, dtype=float)
        if self.rotationally_symmetric:
            dth = self.grid.spacing[2]
            lo = np.where(lo > rho, np.maximum(rho, lo * (1.0 - dth)), lo)
            if not origin_inside:
                hi = hi * (1.0 + dth)
        finite = np.isfinite(lo) & np.isfinite(hi)
        lo = np.where(finite, np.maximum(lo - h - 1e-5, 0.0), 0.0)
        hi = np.where(finite, hi + h + 1e-5, 0.0)
        n_bins = table.shape[1] - 1      # the last column: the padding
        first = np.minimum(np.floor(lo / width), n_bins).astype(np.intp)
        last = np.minimum(np.floor(hi / width), n_bins - 1).astype(np.intp)
        level = np.floor(np.log2(np.maximum(last - first + 1, 1))).astype(np.intp)
        # the range's minimum is that of its first 2**level bins and its last 2**level bins (an
        # empty range, beyond every node: the padding column, +inf)
        b = np.where(last >= first, last - (1 << level) + 1, n_bins)
        return np.where(finite, np.minimum(table[level, first], table[level, b]), -np.inf)

    def __getstate__(self):
        state = dict(self.__dict__)
        state['_flat'] = state['_flat_grad_theta'] = None    # memoryviews do not pickle; rebuilt on use
        state['_radial'] = None     # rebuilt on use
        return state

    def flat_values(self):
        """The node values as a flat memoryview (C order; items read as Python floats)."""
        if self._flat is None:
            self._flat = memoryview(np.ascontiguousarray(self.values).reshape(-1))
        return self._flat

    def flat_theta_gradient(self):
        """``theta_gradient()`` as a flat memoryview."""
        if self._flat_grad_theta is None:
            self._flat_grad_theta = memoryview(self.theta_gradient().reshape(-1))
        return self._flat_grad_theta

    def node_gradient(self) -> np.ndarray:
        if self._grad is None:
            self._grad = node_gradient(self.grid, self.values).astype(np.float32)
        return self._grad

    def theta_gradient(self) -> np.ndarray:
        """dV/dtheta at the nodes (``node_gradient()[..., 2]``), contiguous: the filter
        interpolates it at every robot-obstacle pair."""
        if self._grad_theta is None:
            self._grad_theta = (np.ascontiguousarray(self._grad[..., 2]) if self._grad is not None
                                else theta_node_gradient(self.grid, self.values))
        return self._grad_theta

    def theta_gradient_bound(self) -> float:
        """The largest |dV/dtheta| over the nodes (the scale of a turn's preference; cached)."""
        bound = getattr(self, '_theta_bound', None)      # (None too in a copy pickled before it was kept)
        if bound is None:
            bound = self._theta_bound = float(np.max(np.abs(self.theta_gradient())))
        return bound

    def gradient(self, states) -> np.ndarray:
        """dV/d(x, y, theta) at states (..., 3): trilinear interpolation of the
        central-difference node gradients."""
        return self.grid.interpolate(self.node_gradient(), states)

    @property
    def omega_max(self):
        return self.meta.get('omega_max')

    # -- .npz ---------------------------------------------------------------
    def save_npz(self, path) -> None:
        path = os.fspath(path)
        # a temporary name of this process and thread: processes that solve the same set at
        # once (a team's filters on a cold cache) must not write into one another's file
        tmp = f'{path}.{os.getpid()}-{threading.get_ident()}.tmp.npz'
        try:
            np.savez(tmp, value=self.values.astype(np.float32), x=self.grid.x, y=self.grid.y,
                     theta=self.grid.theta, meta=np.array(json.dumps(self.meta, sort_keys=True)))
            os.replace(tmp, path)  # atomic: a reader never sees half a file
        except BaseException:
            if os.path.exists(tmp):
                os.remove(tmp)
            raise

    @classmethod
    def load_npz(cls, path) -> 'ValueFunction':
        """Read a value function saved by ``save_npz``; ValueError if the file is damaged."""
        try:
            with np.load(os.fspath(path), allow_pickle=False) as f:
                x, y, theta = f['x'], f['y'], f['theta']
                value = f['value']
                meta = json.loads(str(f['meta'])) if 'meta' in f else {}
        except (EOFError, zipfile.BadZipFile, KeyError, json.JSONDecodeError) as exc:
            raise ValueError(f'{path}: not a readable value-function file ({type(exc).__name__}: {exc})') from exc
        grid = Grid((x[0], y[0]), (x[-1], y[-1]), value.shape)
        if not (np.allclose(grid.x, x) and np.allclose(grid.y, y) and np.allclose(grid.theta, theta)):
            raise ValueError(f'{path}: node coordinates are not a regular grid of this package')
        return cls(grid, value, meta)

    # -- helperOC JSON ---------------------------------------------------------
    @classmethod
    def load_helperoc_json(cls, path, meta=None) -> 'ValueFunction':
        """Read a helperOC export; theta must be periodic over [-pi, pi)."""
        with open(path) as f:
            d = json.load(f)
        gmin = np.asarray(d['gmin'], dtype=float).ravel()
        gmax = np.asarray(d['gmax'], dtype=float).ravel()
        gN = [int(n) for n in np.asarray(d['gN']).ravel()]
        data = np.asarray(d['data'], dtype=float)
        if int(np.asarray(d.get('gdim', 3))) != 3 or data.shape != tuple(gN):
            raise ValueError(f'{path}: expected 3-D data of shape gN={gN}, got {data.shape}')
        if abs(gmin[2] + np.pi) > 1e-6:
            raise ValueError(f'{path}: theta must start at -pi, starts at {gmin[2]}')
        dth = (gmax[2] - gmin[2]) / (gN[2] - 1)
        if abs(dth * gN[2] - TWO_PI) > 1e-6:
            # helperOC stores periodic gmax = -pi + 2 pi (N - 1) / N
            raise ValueError(f'{path}: theta nodes do not cover the circle periodically')
        grid = Grid((gmin[0], gmin[1]), (gmax[0], gmax[1]), tuple(gN))
        m = {'source': os.path.basename(os.fspath(path)), 'format': 'helperOC'}
        m.update(meta or {})
        return cls(grid, data, m)

    def save_helperoc_json(self, path) -> None:
        g = self.grid
        gmin = [g.lo[0], g.lo[1], -np.pi]
        gmax = [g.hi[0], g.hi[1], float(g.theta[-1])]
        d = {
            'gdim': 3,
            'gmin': gmin,
            'gmax': gmax,
            'gN': list(g.shape),
            'gdx': list(g.spacing),
            'gperiodicity': [0, 0, 1],
            'data': self.values.astype(float).tolist(),
        }
        with open(path, 'w') as f:
            json.dump(d, f)


def _radial_table(grid: Grid, values):
    """(bin width, sparse table, cell diagonal, rho, whether the rectangle holds the origin)
    of ``ValueFunction.radial_minimum``: the node values' minimum over headings, binned by
    node radius (bins of half the smaller spacing); row k of the table the minimum over 2**k
    bins from each bin on, with a last column of +inf (no node); rho the radius of the
    largest disc about the origin inside the rectangle (0 if the origin is outside)."""
    dx, dy, _ = grid.spacing
    width = 0.5 * min(dx, dy)
    radius = np.hypot(grid.x[:, None], grid.y[None, :]).reshape(-1)
    lowest = np.asarray(values, dtype=float).min(axis=2).reshape(-1)
    bins = np.floor(radius / width).astype(np.intp)
    n_bins = int(bins.max()) + 1
    row = np.full(n_bins + 1, np.inf)
    np.minimum.at(row, bins, lowest)
    table = [row]
    while 2 ** len(table) <= n_bins:
        span = 2 ** (len(table) - 1)
        prev = table[-1]
        table.append(np.concatenate([np.minimum(prev[:-span], prev[span:]), np.full(span, np.inf)]))
    margin = min(-grid.lo[0], -grid.lo[1], grid.hi[0], grid.hi[1])     # < 0: the origin is outside
    return width, np.array(table), math.hypot(dx, dy), max(0.0, margin), margin >= 0.0
