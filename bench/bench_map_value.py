"""The local map's avoid value (filter.sensing.map_value): solve times, what reuse saves, whether an
incremental re-solve would pay, and what a background solve does to another thread (prints figures).

    .venv/bin/python bench/bench_map_value.py                  # everything
    .venv/bin/python bench/bench_map_value.py --only solves --repeat 15

Sections:

* ``solves``, for two robots: (1) speed 0.5, w 1, clearance 0.25, map cell 0.05, value cell 0.1,
  32 headings, horizon 3 s (a Nav2 differential-drive robot); (2) speed 3, w 1, clearance 0.1,
  map cell 0.2, value cell 0.25, horizon 3 s, reach 3 m (a fast robot), at 38 headings (the
  fewest with which the solver does not refine headings) and at 32. Each: the window; the first
  solve of a new worker (its solver built); a re-solve after five cells changed; after the window
  moved by 0.5 m; a submit with nothing changed (skipped); the field alone; the same re-solve
  with a new solver each time (what reuse saves, alternated with the reused one in pairs); and
  the solve with the field read through its general bilinear path (what the separable path saves).
  Medians over ``--repeat`` runs, and the slowest.
* ``incremental``: robot (1) drives 6 m through two rooms and a door at 0.5 m/s, a 360-beam scan
  (range 5 m, 1 cm noise) every 0.1 s marking returns and clearing along beams in a map of
  0.05 m cells. For each scan whose window did not move: the share of the window's nodes
  (x, y, theta) whose value may change (the exact numerical domain of dependence of the cells
  that changed, propagated through the solver's own gathers and path minima), the share of the
  steps' work an exact incremental re-solve would have to redo (that region summed over the
  steps), and the share of nodes whose value did change.
* ``gil``: a main-thread loop of small decisions (value_at reads, ~1 ms of pure Python each)
  timed alone and while a worker solves robot (1)'s window continuously (a new map every
  iteration, latest wins), in alternated blocks: p50, p90, p99, max, the share over twice the
  lone p50; and the solve's own time beside the loop (the GIL is shared both ways).

Each section prints /proc/loadavg before and after.
"""
from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from supersafe_ros.filter.sensing import map_value as mvmod  # noqa: E402
from supersafe_ros.filter.sensing.map_value import (MapArrays, MapValueSettings, MapValueWorker,  # noqa: E402
                                                    solve_map_value, window_half_widths)
from supersafe_ros.reach.field import FieldKeepout  # noqa: E402
from supersafe_ros.reach.solver import _steps  # noqa: E402


def load() -> str:
    with open('/proc/loadavg') as f:
        return f'{f.read().strip()} ({os.cpu_count()} cores)'


def ms(seconds) -> str:
    return f'{1e3 * seconds:7.1f} ms'


def summary(times) -> str:
    return f'median {ms(statistics.median(times))}  max {ms(max(times))}'


class Robot:
    """One configuration: the car, its clearance, the map's cell, the value's settings."""

    def __init__(self, name, speed, omega, clearance, map_cell, settings):
        self.name, self.speed, self.omega, self.clearance = name, speed, omega, clearance
        self.map_cell, self.settings = map_cell, settings


FAST = dict(cell=0.25, horizon=3.0, reach=3.0, recentre=1.0, max_half_width=25.0)
ROBOTS = (
    Robot('(1) Nav2 robot: v 0.5, w 1, clearance 0.25, map cell 0.05, value cell 0.1, 32 headings',
          0.5, 1.0, 0.25, 0.05, MapValueSettings(cell=0.1, headings=32, horizon=3.0, reach=1.5)),
    Robot('(2) fast robot: v 3, w 1, clearance 0.1, map cell 0.2, value cell 0.25, 38 headings, reach 3 m',
          3.0, 1.0, 0.1, 0.2, MapValueSettings(headings=38, **FAST)),
    Robot('(2) the same at 32 headings (the solver refines them 2x)',
          3.0, 1.0, 0.1, 0.2, MapValueSettings(headings=32, **FAST)),
)


def world_map(map_cell: float, size_m: float, seed: int = 0) -> MapArrays:
    """A map of ``size_m`` square about the origin: walls of rooms with doors, and boxes (scaled to the
    map's size), as a robot's local map might hold after a while."""
    n = int(round(size_m / map_cell))
    origin = (-map_cell * (n // 2), -map_cell * (n // 2))
    occupied = np.zeros((n, n), bool)
    centres = origin[0] + map_cell * (np.arange(n) + 0.5)
    X, Y = np.meshgrid(centres, centres, indexing='ij')
    s = size_m / 12.0
    walls = [(-6, 6, -6, -5.9), (-6, 6, 5.9, 6), (-6, -5.9, -6, 6), (5.9, 6, -6, 6),
             (1.5, 1.6, -6, -0.6), (1.5, 1.6, 0.6, 6), (-6, -2, 2.5, 2.6), (-1, 1.5, 2.5, 2.6)]
    rng = np.random.default_rng(seed)
    corners = zip(rng.uniform(-5, 5, 12), rng.uniform(-5, 5, 12), rng.uniform(0.2, 0.6, 12), rng.uniform(0.2, 0.6, 12))
    boxes = [(x, x + w, y, y + h) for x, y, w, h in corners if not (abs(x) < 1.0 and abs(y) < 1.0)]
    for xa, xb, ya, yb in walls + boxes:
        occupied |= (X >= xa * s) & (X < xb * s) & (Y >= ya * s) & (Y < yb * s)
    return MapArrays(origin, map_cell, occupied, 1)


def changed(snapshot: MapArrays, centre, count: int, seed: int) -> MapArrays:
    """The map with ``count`` cells within 1.5 m of ``centre`` flipped."""
    rng = np.random.default_rng(seed)
    occupied = snapshot.occupied.copy()
    c = snapshot.cell
    i0 = int((centre[0] - snapshot.origin[0]) / c)
    j0 = int((centre[1] - snapshot.origin[1]) / c)
    reach = int(1.5 / c)
    for _ in range(count):
        i, j = i0 + rng.integers(-reach, reach + 1), j0 + rng.integers(-reach, reach + 1)
        occupied[i, j] = not occupied[i, j]
    return MapArrays(snapshot.origin, c, occupied, snapshot.version + 1)


class GeneralField(FieldKeepout):
    """The same field read only through its general bilinear path (what the separable one saves)."""

    def signed_distance_xy(self, x, y):
        return self._general(*np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float)))


def timed_solve(robot, snapshot, centre, windows, field_class=None):
    original = mvmod.FieldKeepout
    if field_class is not None:
        mvmod.FieldKeepout = field_class
    try:
        t0 = time.perf_counter()
        value = solve_map_value(snapshot, centre, robot.speed, robot.omega, robot.clearance, robot.settings,
                                _windows=windows)
        return time.perf_counter() - t0, value
    finally:
        mvmod.FieldKeepout = original


def section_solves(repeat: int):
    print(f'== solves   load before: {load()}', flush=True)
    for robot in ROBOTS:
        half, sound = window_half_widths(robot.speed, robot.omega, robot.settings)
        snap = world_map(robot.map_cell, max(12.0, 2 * half + 8.0))
        centre = (0.3, 0.1)
        first = []
        for _ in range(max(3, repeat // 3)):
            worker = MapValueWorker(robot.speed, robot.omega, robot.clearance, robot.settings, inline=True)
            t0 = time.perf_counter()
            worker.submit(snap, centre, stamp=0)
            first.append(time.perf_counter() - t0)
        value = worker.latest()
        g = value.vf.grid
        print(f'{robot.name}\n  window: half-width {half:.2f} m, sound within {sound:.2f} m of its centre, '
              f'grid {g.shape[0]} x {g.shape[1]} x {g.shape[2]}, {value.vf.meta["steps"]} steps of '
              f'{value.vf.meta["dt"]:.3f} s, heading refinement {value.vf.meta["heading_refinement"]}; '
              f'map {snap.occupied.shape[0]} x {snap.occupied.shape[1]} cells')
        print(f'  first solve of a new worker:        {summary(first)}')
        windows = mvmod._Windows()
        timed_solve(robot, snap, centre, windows)
        few, moved, fresh, reused, general = [], [], [], [], []
        for k in range(repeat):
            t, _ = timed_solve(robot, changed(snap, centre, 5, k), centre, windows)
            few.append(t)
            t, _ = timed_solve(robot, snap, (centre[0] + 0.5 * (1 - 2 * (k % 2)), centre[1]), windows)
            moved.append(t)
            # reuse: a new solver each time against the kept one, in alternated pairs
            order = (True, False) if k % 2 else (False, True)
            for reuse in order:
                t, _ = timed_solve(robot, changed(snap, centre, 5, 1000 + k), centre,
                                   windows if reuse else mvmod._Windows())
                (reused if reuse else fresh).append(t)
        for k in range(max(3, repeat // 3)):
            t, _ = timed_solve(robot, changed(snap, centre, 5, 2000 + k), centre, windows, GeneralField)
            general.append(t)
        print(f'  re-solve, five cells changed:       {summary(few)}')
        print(f'  re-solve, window moved by 0.5 m:    {summary(moved)}')
        skip = []
        skipped = worker.skipped
        for k in range(repeat):
            same = MapArrays(snap.origin, snap.cell, snap.occupied.copy(), snap.version + 1 + k)
            t0 = time.perf_counter()
            worker.submit(same, centre, stamp=2 + k)
            skip.append(time.perf_counter() - t0)
        assert worker.skipped - skipped == repeat and worker.solved == 1
        print(f'  nothing changed (skipped):          {summary(skip)}')
        # a cell changed in a corner of the rooms, beyond the window's reach: the field compared, no solve
        corner = np.zeros_like(snap.occupied)
        n_map = corner.shape[0]
        rows = np.nonzero(snap.occupied[:, n_map // 2])[0]
        inner = rows[0] + 1                 # the first free cell inside the outer wall
        corner[inner, inner] = True
        far = MapArrays(snap.origin, snap.cell, snap.occupied ^ corner, snap.version + 99)
        base = solve_map_value(snap, centre, robot.speed, robot.omega, robot.clearance, robot.settings,
                               _windows=windows)
        kept_times, kept = [], None
        for _ in range(repeat):
            t0 = time.perf_counter()
            kept = solve_map_value(far, centre, robot.speed, robot.omega, robot.clearance, robot.settings,
                                   previous=base, _windows=windows)
            kept_times.append(time.perf_counter() - t0)
        print(f'  a cell changed beyond its reach:    {summary(kept_times)} '
              f'({"the field compared, no solve" if kept.vf is base.vf else "solved"})')
        fields = []
        solver = windows.solver
        lo = (value.centre[0] - half, value.centre[1] - half)
        for _ in range(repeat):
            t0 = time.perf_counter()
            mvmod._window_field(snap, robot.clearance, solver.read_bounds(lo))
            fields.append(time.perf_counter() - t0)
        print(f'  of which the field (EDT, crop):     {summary(fields)}')
        saved = statistics.median(fresh) - statistics.median(reused)
        print(f'  reuse: new solver {ms(statistics.median(fresh))}, kept {ms(statistics.median(reused))} '
              f'(medians of {repeat} alternated pairs; saves {ms(saved)})')
        print(f'  the field read by its general path: {summary(general)} (the separable path: '
              f'{ms(statistics.median(few))})', flush=True)
    print(f'   load after: {load()}\n', flush=True)


# -- incremental re-solves: the exact domain of dependence of a change ------------------------------------
def scan_update(occupied, truth, origin, cell, pose, rng, beams=360, max_range=5.0, noise=0.01):
    """Mark each beam's return and clear the cells before it (a simple marcher, half-cell steps)."""
    x, y = pose
    n = occupied.shape[0]
    angles = np.linspace(-np.pi, np.pi, beams, endpoint=False)
    steps = np.arange(0.5 * cell, max_range, 0.5 * cell)
    px = x + np.cos(angles)[:, None] * steps[None, :]
    py = y + np.sin(angles)[:, None] * steps[None, :]
    i = np.floor((px - origin[0]) / cell).astype(int)
    j = np.floor((py - origin[1]) / cell).astype(int)
    inside = (i >= 0) & (i < n) & (j >= 0) & (j < n)
    hit = np.zeros_like(inside)
    hit[inside] = truth[i[inside], j[inside]]
    first = np.where(hit.any(axis=1), hit.argmax(axis=1), steps.size)
    seen = steps[np.minimum(first, steps.size - 1)] + rng.normal(0, noise, beams)
    ranges = np.where(first < steps.size, seen, np.inf)
    out = occupied.copy()
    before = (steps[None, :] < np.minimum(ranges, max_range)[:, None] - cell) & inside
    out[i[before], j[before]] = False
    ret = np.isfinite(ranges)
    ri = np.floor((x + np.cos(angles[ret]) * ranges[ret] - origin[0]) / cell).astype(int)
    rj = np.floor((y + np.sin(angles[ret]) * ranges[ret] - origin[1]) / cell).astype(int)
    ok = (ri >= 0) & (ri < n) & (rj >= 0) & (rj < n)
    out[ri[ok], rj[ok]] = True
    return out


def dependence(solver, lo, old_field, new_field, horizon):
    """(the region's share at the end, its share summed over the steps): the nodes whose value may differ
    between the two fields, propagated exactly through the solver's steps (its gathers and path minima; a
    bench's use of the stepper's internals)."""
    stepper = solver.stepper
    rest, n_whole = _steps(horizon, solver.dt)
    kinds = ([(rest, solver._partial(rest))] if rest is not None else []) + [(solver.dt, solver.whole)] * n_whole
    paths, pads, grids = [], [], []
    for field in (old_field, new_field):
        stepper.bind(lo, field)
        pads.append(stepper.Vp[0].copy())
        grids.append(stepper.l_grid.copy())
        paths.append({(u, dt, shifts[u]): stepper._plan(u, dt, shifts[u])['path_min'].copy()
                      for dt, shifts in kinds for u in stepper.controls})
    rim = (pads[0] != pads[1]).astype(np.float32)
    l_changed = grids[0] != grids[1]
    nth = stepper.grid.shape[2]
    region = np.repeat(l_changed[None], nth, axis=0)
    nx, ny, _ = stepper.grid.shape
    p = stepper.pad
    work = 0.0
    for dt, shifts in kinds:
        stepper.Vp[...] = rim[None]
        stepper.Vp[:, p:p + nx, p:p + ny] = region
        reached = l_changed[None].copy()
        for u in stepper.controls:
            key = (u, dt, shifts[u])
            plan = stepper._plan(u, dt, shifts[u])
            read = stepper._gather(plan, plan['k']) > 0
            if plan['ft'] > 1e-9:
                read |= stepper._gather(plan, plan['k_next']) > 0
            reached = reached | read | (paths[0][key] != paths[1][key])
        region = reached
        work += region.mean()
    return region.mean(), work / len(kinds)


def section_incremental(scans: int, noise: float):
    print(f'== incremental re-solves   load before: {load()}', flush=True)
    robot = ROBOTS[0]
    truth = world_map(robot.map_cell, 12.0)
    origin, cell = truth.origin, truth.cell
    rng = np.random.default_rng(1)
    occupied = np.zeros_like(truth.occupied)
    windows = mvmod._Windows()
    solver, n, _ = windows.get(robot.speed, robot.omega, robot.settings)
    half = n * robot.settings.cell
    path = [(-4.0 + 0.05 * k, -0.1 + 0.3 * math.sin(0.05 * k)) for k in range(scans)]
    centre = None
    shares, works, actual, changed_cells, moves, same_field = [], [], [], [], 0, 0
    for k, pose in enumerate(path):
        new = scan_update(occupied, truth.occupied, origin, cell, pose, rng, noise=noise)
        if centre is None or max(abs(pose[0] - centre[0]), abs(pose[1] - centre[1])) > robot.settings.recentre:
            centre = mvmod.value_lattice_node(pose, cell, robot.settings.cell)
            moves += 1
            occupied = new
            continue
        diff = int(np.count_nonzero(new != occupied))
        if k >= 10 and diff:              # after the first second: the map holds the rooms
            lo = (centre[0] - half, centre[1] - half)
            bounds = solver.read_bounds(lo)
            old_f = mvmod._window_field(MapArrays(origin, cell, occupied), robot.clearance, bounds)
            new_f = mvmod._window_field(MapArrays(origin, cell, new), robot.clearance, bounds)
            changed_cells.append(diff)
            if np.array_equal(old_f.values, new_f.values):
                same_field += 1             # (c): no solve
                occupied = new
                continue
            share, work = dependence(solver, lo, old_f, new_f, robot.settings.horizon)
            a = solver.solve(old_f, robot.settings.horizon, lo=lo).values
            b = solver.solve(new_f, robot.settings.horizon, lo=lo).values
            shares.append(share)
            works.append(work)
            actual.append(float(np.mean(a != b)))
        occupied = new
    print(f'{robot.name}; range noise {noise} m; {len(path)} scans, the window moved {moves} times; '
          f'{len(changed_cells)} scans changed the map in a window that stayed (cells changed per scan: median '
          f'{statistics.median(changed_cells)}, min {min(changed_cells)}, max {max(changed_cells)}); '
          f'{same_field} of them left the window\'s field as it was (no solve), {len(shares)} changed it:')
    for name, values in (('share of nodes that may change', shares), ('share of the steps\' work to redo', works),
                         ('share of nodes that did change', actual)):
        if not values:
            continue
        q = np.percentile(values, [10, 50, 90])
        print(f'  {name:34s} p10 {q[0]:.2f}  median {q[1]:.2f}  p90 {q[2]:.2f}  min {min(values):.2f}')
    print(f'   load after: {load()}\n', flush=True)


# -- the GIL: what a background solve does to a pure-Python loop ---------------------------------------
def section_gil(iterations: int):
    print(f'== a background solve and a pure-Python loop   load before: {load()}', flush=True)
    robot = ROBOTS[0]
    snap = world_map(robot.map_cell, 12.0)
    other = changed(snap, (0.3, 0.1), 5, 7)
    vf = solve_map_value(snap, (0.3, 0.1), robot.speed, robot.omega, robot.clearance, robot.settings).vf
    rng = np.random.default_rng(0)
    states = list(zip(rng.uniform(-1, 1, 400).tolist(), rng.uniform(-1, 1, 400).tolist(),
                      rng.uniform(-3, 3, 400).tolist()))
    for x, y, t in states:          # first reads build the flat views
        vf.value_at(x, y, t)
    t0 = time.perf_counter()
    for x, y, t in states:
        vf.value_at(x, y, t)
    reads = min(len(states) - 1, max(1, int(1e-3 / ((time.perf_counter() - t0) / len(states)))))

    def decision(k):
        start = (k * 37) % (len(states) - reads)
        return sum(vf.value_at(x, y, t) for x, y, t in states[start:start + reads])

    solves = {}

    def loop(count, worker=None):
        times = []
        for k in range(count):
            if worker is not None:
                worker.submit(other if k % 2 else snap, (0.3, 0.1), stamp=k)     # always something to solve
                value = worker.latest()
                if value is not None:
                    solves[id(value.vf)] = value.solve_s
            t0 = time.perf_counter()
            decision(k)
            times.append(time.perf_counter() - t0)
        return times

    def idle(worker):
        """Until the worker has nothing left to solve (bounded)."""
        for _ in range(3000):
            if worker._pending is None and worker.latest() is not None and worker.latest().stamp == last[0]:
                return
            time.sleep(0.001)

    loop(200)
    alone, busy, block, last = [], [], max(1, iterations // 4), [None]
    worker = MapValueWorker(robot.speed, robot.omega, robot.clearance, robot.settings)
    try:
        for _ in range(4):              # alternated blocks: the machine's other load falls on both alike
            alone += loop(block)
            busy += loop(block, worker)
            last[0] = block - 1
            idle(worker)
    finally:
        worker.close(30.0)
    for name, times in (('alone', alone), ('beside a worker solving', busy)):
        q = np.percentile(times, [50, 90, 99])
        over = np.mean(np.asarray(times) > 2 * q[0] if name == 'alone' else np.asarray(times) > 2 * np.median(alone))
        print(f'  {name:24s} p50 {ms(q[0])}  p90 {ms(q[1])}  p99 {ms(q[2])}  max {ms(max(times))}  '
              f'over twice the lone p50: {100 * over:4.1f} %  ({len(times)} iterations)')
    print(f'  (a decision: {reads} value_at reads; the worker solved {worker.solved} times meanwhile, '
          f'{worker.replaced} requests replaced; blocks of {block} alternated)')
    lone = [timed_solve(robot, other if k % 2 else snap, (0.3, 0.1), mvmod._Windows())[0] for k in range(5)]
    print(f'  the solve itself beside the loop: median {ms(statistics.median(solves.values()))} '
          f'({len(solves)} seen), alone {ms(statistics.median(lone))}')
    print(f'   load after: {load()}\n', flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--only', choices=('solves', 'incremental', 'gil'), action='append')
    parser.add_argument('--repeat', type=int, default=9)
    parser.add_argument('--scans', type=int, default=120)
    parser.add_argument('--iterations', type=int, default=2000, help='decisions timed alone, and as many beside')
    parser.add_argument('--noise', type=float, action='append', help='scan range noise (m); default 0 and 0.01')
    args = parser.parse_args(argv)
    only = args.only or ('solves', 'incremental', 'gil')
    if 'solves' in only:
        section_solves(args.repeat)
    if 'incremental' in only:
        for noise in args.noise or (0.0, 0.01):
            section_incremental(args.scans, noise)
    if 'gil' in only:
        section_gil(args.iterations)


if __name__ == '__main__':
    main()
