"""Avoid values by semi-Lagrangian dynamic programming over exact Dubins arcs.

The avoid value over horizon T,

    V(x) = max_{u(.)} min_{t in [0, T]} l(x(t)),

satisfies the dynamic programming principle over a step dt with the control
held constant (Hamiltonian linear in u: the extreme controls {-w, 0, +w} suffice):

    V_{n+1}(x) = max_u  min( min_{t in [0, dt]} l(Phi_u^t(x)),  V_n(Phi_u^dt(x)) ),
    V_0 = l.

For the Dubins car, Phi_u^dt moves every node of one heading slice by the same
(x, y) displacement and the same heading change. With dt chosen so that
w dt is a whole number of heading cells, the heading lands exactly on a node,
and the (x, y) interpolation uses one set of bilinear weights per slice:
each step is a few shifted array slices, no per-node index arithmetic.
The first (partial) step acts on V_0 = l, which does not depend on the
heading, so it can land between heading nodes without error.

States whose step leaves the grid read V = l there: exact for states moving
away from the keep-out set (the common case at the rim), an upper bound otherwise.
A step reads at most a few cells from each node, so only nodes within the sum of
those reads (``AvoidSolver.rim_distance``, about v T plus up to a cell a step) of
the edge can see that rim; the nodes farther in have an unbounded grid's values.

``AvoidSolver`` keeps what does not depend on the keep-out set (step plans, gather
indices and weights, the padded buffer) across solves of one grid shape, which may
move; ``solve_avoid`` is one solve of a new one.

Without a horizon the iteration runs until the largest change of a step falls
below ``tol`` (V_n decreases monotonically in n).
"""
from __future__ import annotations

from dataclasses import dataclass
import math
import time

import numpy as np

from .dynamics import DubinsCar
from .grid import Grid
from .value_function import ValueFunction


@dataclass(frozen=True)
class SolverSettings:
    """Numerical knobs; the defaults are what the accuracy tests and benchmarks use."""

    max_cells_per_step: float = 2.0     # |v dt| bound, in (x, y) cells
    path_samples: int = 3               # interior points per step where l is checked
    tol: float = 1e-4                   # convergence threshold without a horizon
    max_horizon: float = 200.0          # give up converging after this much time

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _step_plan(grid: Grid, dyn: DubinsCar, settings: SolverSettings):
    """Step dt, heading refinement q and heading cells per turning step.

    Turning steps must land on heading nodes. When the car turns slowly, one
    heading cell takes longer than a step may last, so the solver works on a
    heading axis refined q times (the output slices are every q-th of them).
    """
    dx, dy, dth = grid.spacing
    dt_space = settings.max_cells_per_step * min(dx, dy) / dyn.speed
    if dyn.omega_max == 0.0:
        return dt_space, 1, 0
    q = max(1, math.ceil(dth / (dyn.omega_max * dt_space) - 1e-9))
    dth_fine = dth / q
    cells = max(1, int(dt_space * dyn.omega_max / dth_fine + 1e-9))
    return cells * dth_fine / dyn.omega_max, q, cells


class _SlabStepper:
    """One DP step for every slice and control, on a padded copy of V.

    Internally V is laid out slice-major, (nth, nx, ny). For one control every
    slice k reads the padded slice it lands on through a window at its own
    integer (x, y) offset; one fancy-indexed gather over a sliding-window view
    fetches all of them at once, and the bilinear weights are one scalar pair
    per slice.

    What depends only on the grid's shape and spacing and the dynamics (the padded
    buffer, each step kind's gather indices and weights) is built once; ``bind``
    puts a keep-out set and the grid's position in place (l on the padded plane,
    the path minima), so one stepper serves many keep-out sets.
    """

    def __init__(self, grid: Grid, dyn: DubinsCar, dt: float, settings: SolverSettings):
        self.grid, self.dyn, self.dt = grid, dyn, dt
        nx, ny, nth = grid.shape
        dx, dy, dth = grid.spacing
        self.pad = int(math.ceil(dyn.speed * dt / min(dx, dy))) + 2
        p = self.pad
        # padded V, slice-major; the rim keeps l, each step overwrites the interior
        self.Vp = np.empty((nth, nx + 2 * p, ny + 2 * p), dtype=np.float32)
        self.windows = np.lib.stride_tricks.sliding_window_view(self.Vp, (nx + 1, ny + 1), axis=(1, 2))
        self.controls = dyn.extreme_controls()
        self.theta = grid.theta
        self.samples = settings.path_samples
        self._geometry = {}
        self._paths = {}
        self.keepout = None

    def bind(self, lo, keepout) -> None:
        """Set up a solve for ``keepout`` on the grid translated to lower corner ``lo`` (same shape, spacing)."""
        nx, ny, nth = self.grid.shape
        dx, dy, _ = self.grid.spacing
        p = self.pad
        xs = lo[0] + dx * np.arange(-p, nx + p)
        ys = lo[1] + dy * np.arange(-p, ny + p)
        X, Y = np.meshgrid(xs, ys, indexing='ij')
        # l on the padded plane: the value assumed beyond the grid
        l_pad = keepout.signed_distance(np.stack([X, Y], axis=-1)).astype(np.float32)
        self.l_grid = np.ascontiguousarray(l_pad[p:p + nx, p:p + ny])
        self.Vp[...] = l_pad[None]
        self.X, self.Y = np.meshgrid(xs[p:p + nx], ys[p:p + ny], indexing='ij')
        self.keepout = keepout
        self._paths = {}

    def _displacement(self, u: float, t: float):
        """(x, y) displacement of every slice's heading after t under control u."""
        v, th = self.dyn.speed, self.theta
        if abs(u * t) < 1e-12:
            return v * t * np.cos(th), v * t * np.sin(th)
        return (v / u * (np.sin(th + u * t) - np.sin(th)),
                v / u * (np.cos(th) - np.cos(th + u * t)))

    def _plan(self, u: float, dt: float, shift: float):
        """Per-slice gather indices and weights (kept per step kind) and the path minimum of l
        (kept per step kind until the next ``bind``)."""
        key = (u, dt, shift)
        plan = self._paths.get(key)
        if plan is not None:
            return plan
        geometry = self._geometry.get(key)
        if geometry is None:
            geometry = self._geometry[key] = self._step_geometry(u, dt, shift)
        path = np.full(geometry['path_shape'], np.inf, dtype=np.float32)
        for sx, sy in geometry['path_offsets']:
            # x varies along the grid's first axis only, y along its second: the distances
            # broadcast from (nth, nx, 1) and (nth, 1, ny) columns, the same values as full arrays
            l_path = self.keepout.signed_distance_xy(self.X[None, :, :1] + sx[:, None, None],
                                                     self.Y[None, :1, :] + sy[:, None, None])
            np.minimum(path, l_path.astype(np.float32), out=path)
        plan = dict(geometry, path_min=path)
        self._paths[key] = plan
        return plan

    def _step_geometry(self, u: float, dt: float, shift: float) -> dict:
        """What a step kind reads, independent of the keep-out set and of the grid's position."""
        nth = self.grid.shape[2]
        dx, dy, _ = self.grid.spacing
        ddx, ddy = self._displacement(u, dt)
        a, b = ddx / dx, ddy / dy
        ia, ib = np.floor(a).astype(np.intp), np.floor(b).astype(np.intp)
        k0 = math.floor(shift)
        ks = np.arange(nth)
        offsets = [self._displacement(u, dt * i / (self.samples + 1)) for i in range(1, self.samples + 1)]
        return {
            'k': (ks + k0) % nth, 'k_next': (ks + k0 + 1) % nth, 'ft': shift - k0,
            'ia': ia + self.pad, 'ib': ib + self.pad,
            'fa': (a - ia).astype(np.float32)[:, None, None],
            'fb': (b - ib).astype(np.float32)[:, None, None],
            'path_offsets': offsets, 'path_shape': (nth,) + self.grid.shape[:2],
            # the farthest node a step reads, in cells along x or y (the gather reads ia and ia + 1)
            'reach_cells': int(max(np.max(np.abs(ia)), np.max(np.abs(ia + 1)),
                                   np.max(np.abs(ib)), np.max(np.abs(ib + 1)))),
        }

    def _gather(self, plan, k):
        src = self.windows[k, plan['ia'], plan['ib']]          # (nth, nx + 1, ny + 1)
        fb = plan['fb']
        lo = src[:, :-1, :-1] + fb * (src[:, :-1, 1:] - src[:, :-1, :-1])
        hi = src[:, 1:, :-1] + fb * (src[:, 1:, 1:] - src[:, 1:, :-1])
        return lo + plan['fa'] * (hi - lo)

    def step(self, V: np.ndarray, dt: float, heading_cells: dict) -> np.ndarray:
        """V_{n+1} from V_n (both slice-major) over a step dt; heading_cells[u] = shift in cells."""
        nx, ny, _ = self.grid.shape
        p = self.pad
        self.Vp[:, p:p + nx, p:p + ny] = V
        out = None
        for u in self.controls:
            plan = self._plan(u, dt, heading_cells[u])
            cand = self._gather(plan, plan['k'])
            if plan['ft'] > 1e-9:
                cand = (1.0 - plan['ft']) * cand + plan['ft'] * self._gather(plan, plan['k_next'])
            np.minimum(cand, plan['path_min'], out=cand)
            out = cand if out is None else np.maximum(out, cand, out=out)
        # the trajectory starts at x itself: V <= l(x)
        np.minimum(out, self.l_grid[None], out=out)
        return out


def _steps(horizon, dt: float):
    """The steps of a finite horizon: (the partial step's length or None, the number of whole steps)."""
    n_whole = int(math.floor(horizon / dt + 1e-9))
    rest = horizon - n_whole * dt
    return (rest if rest > 1e-9 else None), n_whole


class AvoidSolver:
    """``solve_avoid`` for many keep-out sets on one grid shape and spacing (the grid may move).

    What does not depend on the keep-out set or on where the grid lies (the step plan, each
    step kind's gather indices and weights, the padded buffer) is built once, at construction
    and at the first solve of a horizon; ``solve`` computes l, the path minima and the steps.
    ``solve(keepout, horizon)`` equals ``solve_avoid(grid, dynamics, keepout, horizon, settings)``
    bit for bit (solve_avoid is that call on a new solver; test_reach_field checks it after
    other solves, and against the solver as it was, test/solver_oracle.py). ``solve(..., lo=...)``
    solves on the grid translated to lower corner ``lo``. One solve at a time (shared buffers).
    """

    def __init__(self, grid: Grid, dynamics: DubinsCar, settings: SolverSettings | None = None):
        self.grid, self.dynamics = grid, dynamics
        self.settings = settings or SolverSettings()
        self.dt, self.q, self.cells = _step_plan(grid, dynamics, self.settings)
        fine = Grid(grid.lo, grid.hi, (grid.shape[0], grid.shape[1], grid.shape[2] * self.q))
        self.stepper = _SlabStepper(fine, dynamics, self.dt, self.settings)
        self.whole = {u: self.cells * np.sign(u) for u in self.stepper.controls}

    def translated(self, lo) -> Grid:
        """The grid moved to lower corner ``lo`` (the same shape and, up to rounding, spacing)."""
        g = self.grid
        lo = (float(lo[0]), float(lo[1]))
        return Grid(lo, (lo[0] + (g.hi[0] - g.lo[0]), lo[1] + (g.hi[1] - g.lo[1])), g.shape)

    def read_bounds(self, lo=None):
        """((x_min, y_min), (x_max, y_max)): where a solve reads l (the padded plane, which holds
        every point of every step's arcs), for the grid at lower corner ``lo``."""
        g = self.grid if lo is None else self.translated(lo)
        dx, dy, _ = g.spacing
        p = self.stepper.pad
        return (g.lo[0] - p * dx, g.lo[1] - p * dy), (g.hi[0] + p * dx, g.hi[1] + p * dy)

    def rim_distance(self, horizon: float) -> float:
        """Metres from the grid's edge (along x and along y) beyond which a node's value over
        ``horizon`` never reads the rim (the padded plane holds l, not V_n): the sum of the
        farthest read of every step but the first (the first reads V_0 = l, which the rim is).
        Nodes that far inside have the values of an unbounded grid."""
        rest, n_whole = _steps(horizon, self.dt)
        kinds = ([(rest, self._partial(rest))] if rest is not None else []) + [(self.dt, self.whole)] * n_whole
        cells = 0
        for dt, shifts in kinds[1:]:
            cells += max(self._geometry(u, dt, shifts[u])['reach_cells'] for u in self.stepper.controls)
        dx, dy, _ = self.grid.spacing
        return cells * max(dx, dy)

    def _partial(self, rest: float) -> dict:
        dth = self.stepper.grid.spacing[2]
        return {u: u * rest / dth for u in self.stepper.controls}

    def _geometry(self, u, dt, shift) -> dict:
        key = (u, dt, shift)
        geometry = self.stepper._geometry.get(key)
        if geometry is None:
            geometry = self.stepper._geometry[key] = self.stepper._step_geometry(u, dt, shift)
        return geometry

    def solve(self, keepout, horizon=None, lo=None) -> ValueFunction:
        """The avoid value of ``keepout`` over ``horizon`` (s, or None: to convergence) on the grid
        at lower corner ``lo`` (default: the grid's own); meta as ``solve_avoid``'s."""
        if horizon is not None and not (np.isfinite(horizon) and horizon >= 0):
            raise ValueError(f'horizon must be a non-negative number of seconds, got {horizon}')
        t0 = time.perf_counter()
        grid = self.grid if lo is None else self.translated(lo)
        settings, stepper, dt, q = self.settings, self.stepper, self.dt, self.q
        stepper.bind(grid.lo, keepout)
        V = np.repeat(stepper.l_grid[None], stepper.grid.shape[2], axis=0)      # slice-major
        steps, elapsed, converged, change = 0, 0.0, None, float('nan')

        if horizon is not None:
            rest, n_whole = _steps(horizon, dt)
            if rest is not None:
                # the partial step first: V_0 = l has no heading dependence, so a
                # fractional heading shift is exact here
                V = stepper.step(V, rest, self._partial(rest))
                steps, elapsed = 1, rest
            for _ in range(n_whole):
                V = stepper.step(V, dt, self.whole)
                steps += 1
                elapsed += dt
        else:
            converged = False
            while elapsed < settings.max_horizon:
                V_next = stepper.step(V, dt, self.whole)
                change = float(np.max(np.abs(V_next - V)))
                V = V_next
                steps += 1
                elapsed += dt
                if change < settings.tol:
                    converged = True
                    break

        V = np.ascontiguousarray(np.moveaxis(V[::q], 0, -1))          # back to (x, y, theta)
        solve_time = time.perf_counter() - t0
        meta = dict(self.dynamics.params())
        meta.update({
            'keepout': keepout.params(),
            'horizon': None if horizon is None else float(horizon),
            'solver': 'semi-lagrangian-dubins-arcs',
            'settings': settings.to_dict(),
            'dt': dt,
            'heading_refinement': q,
            'steps': steps,
            'time_reached': elapsed,
            'converged': converged,
            'last_change': change,
            'solve_time_s': solve_time,
        })
        discs = keepout.discs()
        if len(discs) == 1:
            meta['radius'] = float(discs[0].radius)
        return ValueFunction(grid, V, meta)


def solve_avoid(grid: Grid, dynamics: DubinsCar, keepout, horizon=None,
                settings: SolverSettings | None = None) -> ValueFunction:
    """Avoid value of ``keepout`` for ``dynamics`` on ``grid``.

    ``horizon`` in seconds, or None to iterate to convergence. Returns a
    ValueFunction whose meta records the problem, the settings, the number of
    steps, whether it converged, and the solve time.
    """
    if horizon is not None and not (np.isfinite(horizon) and horizon >= 0):
        raise ValueError(f'horizon must be a non-negative number of seconds, got {horizon}')
    t0 = time.perf_counter()
    vf = AvoidSolver(grid, dynamics, settings).solve(keepout, horizon)
    vf.meta['solve_time_s'] = time.perf_counter() - t0
    return vf
