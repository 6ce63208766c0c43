"""The avoid solver's oracle (not a test module): ``reach.solver.solve_avoid`` and its stepper as
they were before ``AvoidSolver`` (commit a6316f5), kept verbatim as the reference the library and
the study's cached values must equal bit for bit (test_reach_field.py). Only the imports differ
and ``solve_avoid`` is named ``solve_avoid_before`` (its signature's second line indented to match).
"""
from __future__ import annotations

import math
import time

import numpy as np

from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.solver import SolverSettings
from supersafe_ros.reach.value_function import ValueFunction


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
    """

    def __init__(self, grid: Grid, dyn: DubinsCar, keepout, dt: float, settings: SolverSettings):
        self.grid, self.dyn, self.dt = grid, dyn, dt
        nx, ny, nth = grid.shape
        dx, dy, dth = grid.spacing
        self.pad = int(math.ceil(dyn.speed * dt / min(dx, dy))) + 2
        p = self.pad
        xs = grid.lo[0] + dx * np.arange(-p, nx + p)
        ys = grid.lo[1] + dy * np.arange(-p, ny + p)
        X, Y = np.meshgrid(xs, ys, indexing='ij')
        # l on the padded plane: the value assumed beyond the grid
        l_pad = keepout.signed_distance(np.stack([X, Y], axis=-1)).astype(np.float32)
        self.l_grid = np.ascontiguousarray(l_pad[p:p + nx, p:p + ny])
        # padded V, slice-major; the rim keeps l, each step overwrites the interior
        self.Vp = np.repeat(l_pad[None], nth, axis=0)
        self.windows = np.lib.stride_tricks.sliding_window_view(self.Vp, (nx + 1, ny + 1), axis=(1, 2))
        self.controls = dyn.extreme_controls()
        self.theta = grid.theta
        self.X, self.Y = np.meshgrid(xs[p:p + nx], ys[p:p + ny], indexing='ij')
        self.keepout = keepout
        self.samples = settings.path_samples
        self._plans = {}

    def _displacement(self, u: float, t: float):
        """(x, y) displacement of every slice's heading after t under control u."""
        v, th = self.dyn.speed, self.theta
        if abs(u * t) < 1e-12:
            return v * t * np.cos(th), v * t * np.sin(th)
        return (v / u * (np.sin(th + u * t) - np.sin(th)),
                v / u * (np.cos(th) - np.cos(th + u * t)))

    def _plan(self, u: float, dt: float, shift: float):
        """Per-slice gather indices, weights and path minimum of l (cached per step kind)."""
        key = (u, dt, shift)
        plan = self._plans.get(key)
        if plan is not None:
            return plan
        nth = self.grid.shape[2]
        dx, dy, _ = self.grid.spacing
        ddx, ddy = self._displacement(u, dt)
        a, b = ddx / dx, ddy / dy
        ia, ib = np.floor(a).astype(np.intp), np.floor(b).astype(np.intp)
        k0 = math.floor(shift)
        ks = np.arange(nth)
        path = np.full((nth,) + self.X.shape, np.inf, dtype=np.float32)
        for i in range(1, self.samples + 1):
            t = dt * i / (self.samples + 1)
            sx, sy = self._displacement(u, t)
            # x varies along the grid's first axis only, y along its second: the distances
            # broadcast from (nth, nx, 1) and (nth, 1, ny) columns, the same values as full arrays
            l_path = self.keepout.signed_distance_xy(self.X[None, :, :1] + sx[:, None, None],
                                                     self.Y[None, :1, :] + sy[:, None, None])
            np.minimum(path, l_path.astype(np.float32), out=path)
        plan = {
            'k': (ks + k0) % nth, 'k_next': (ks + k0 + 1) % nth, 'ft': shift - k0,
            'ia': ia + self.pad, 'ib': ib + self.pad,
            'fa': (a - ia).astype(np.float32)[:, None, None],
            'fb': (b - ib).astype(np.float32)[:, None, None],
            'path_min': path,
        }
        self._plans[key] = plan
        return plan

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


def solve_avoid_before(grid: Grid, dynamics: DubinsCar, keepout, horizon=None,
                       settings: SolverSettings | None = None) -> ValueFunction:
    """Avoid value of ``keepout`` for ``dynamics`` on ``grid``.

    ``horizon`` in seconds, or None to iterate to convergence. Returns a
    ValueFunction whose meta records the problem, the settings, the number of
    steps, whether it converged, and the solve time.
    """
    settings = settings or SolverSettings()
    if horizon is not None and not (np.isfinite(horizon) and horizon >= 0):
        raise ValueError(f'horizon must be a non-negative number of seconds, got {horizon}')
    t0 = time.perf_counter()
    dt, q, cells = _step_plan(grid, dynamics, settings)
    fine = Grid(grid.lo, grid.hi, (grid.shape[0], grid.shape[1], grid.shape[2] * q))
    stepper = _SlabStepper(fine, dynamics, keepout, dt, settings)
    V = np.repeat(stepper.l_grid[None], fine.shape[2], axis=0)      # slice-major
    whole = {u: cells * np.sign(u) for u in stepper.controls}
    steps, elapsed, converged, change = 0, 0.0, None, float('nan')

    if horizon is not None:
        n_whole = int(math.floor(horizon / dt + 1e-9))
        rest = horizon - n_whole * dt
        if rest > 1e-9:
            # the partial step first: V_0 = l has no heading dependence, so a
            # fractional heading shift is exact here
            dth = fine.spacing[2]
            partial = {u: u * rest / dth for u in stepper.controls}
            V = stepper.step(V, rest, partial)
            steps, elapsed = 1, rest
        for _ in range(n_whole):
            V = stepper.step(V, dt, whole)
            steps += 1
            elapsed += dt
    else:
        converged = False
        while elapsed < settings.max_horizon:
            V_next = stepper.step(V, dt, whole)
            change = float(np.max(np.abs(V_next - V)))
            V = V_next
            steps += 1
            elapsed += dt
            if change < settings.tol:
                converged = True
                break

    V = np.ascontiguousarray(np.moveaxis(V[::q], 0, -1))          # back to (x, y, theta)
    solve_time = time.perf_counter() - t0
    meta = dict(dynamics.params())
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
