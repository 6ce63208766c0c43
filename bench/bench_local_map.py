"""The local map's cost per message (``filter.sensing.local_map``, ROS-free; prints figures, no assertions).

    .venv/bin/python bench/bench_local_map.py                 # every case, 200 runs each
    .venv/bin/python bench/bench_local_map.py --repeat 500 --only scan

Cases, cell 0.05 m, the sensor near the window's centre (16 poses a few cm apart, taken in turn):

* ``scan``: 360 and 1,440 beams over the full turn, every beam a return at 10 m, and ranges uniform
  in [0.5, 10] m; in the default 10 m window (the beams cut at its edge, 5 to 7 m out) and in a
  25 m window that holds them whole; and the 10 m scans with ``depth`` 1 m and a slack of 0.2 m;
* ``cloud``: 100,000 points (70 % on the surfaces of five discs, 30 % scattered over 20 m x 20 m),
  with slack 0 and 0.2 m (past the budget: merged per cell);
* ``grid``: an OccupancyGrid of 400 x 400 cells of 0.05 m over the window, and ``follow`` (a move
  of the window by 3 m) with ``snapshot``.

Each figure is one call's wall time (time.perf_counter) over ``--repeat`` calls (a cloud: a tenth of them,
at least 20): median and best, in ms, with the load average before and after (the machine has 2 cores
shared with other jobs).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from supersafe_ros.filter.sensing.local_map import LocalMap, MapSettings  # noqa: E402
from supersafe_ros.filter.sensing.readings import scan_rays  # noqa: E402

CELL = 0.05
DISCS = np.array([(4.0, 1.0, 1.8), (6.0, -3.0, 0.8), (8.0, 4.0, 2.6), (-5.0, 2.0, 1.8), (1.0, -6.0, 0.8)])
POSES = [(0.013 * k, -0.007 * k, 0.05 * k) for k in range(16)]


def load() -> str:
    one, five, _ = os.getloadavg()
    return f'load {one:.2f} (5 min {five:.2f}) on {os.cpu_count()} cores'


def timed(call, repeat: int):
    """(median ms, best ms) of ``call(pose)`` over ``repeat`` calls, the poses taken in turn."""
    call(POSES[0])
    times = []
    for k in range(repeat):
        pose = POSES[k % len(POSES)]
        t0 = time.perf_counter()
        call(pose)
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times)), 1e3 * float(np.min(times))


def line(label: str, figures, extra: str = ''):
    print(f'  {label:<52} median {figures[0]:7.3f} ms   best {figures[1]:7.3f} ms  {extra}', flush=True)


def scans(repeat: int):
    rng = np.random.default_rng(1)
    print(f'== scans (cell {CELL} m), {load()} ==')
    for beams in (360, 1440):
        inc = 2.0 * math.pi / beams
        for kind, ranges in (('all at 10 m', np.full(beams, 10.0)), ('0.5 .. 10 m', rng.uniform(0.5, 10.0, beams))):
            rays = scan_rays(ranges, -math.pi, math.pi - inc, inc, 0.1, 30.0)
            for size in (10.0, 25.0):
                m = LocalMap(MapSettings(cell=CELL, size=size))
                m.follow(0.0, 0.0)
                view = None

                def call(pose, m=m, rays=rays):
                    nonlocal view
                    view = m.integrate_rays(pose, rays)

                figures = timed(call, repeat)
                line(f'{beams:5d} beams, {kind}, window {size:g} m', figures,
                     f'({view.cleared} cells cleared, {view.marked} marked)')
        rays = scan_rays(np.full(beams, 10.0), -math.pi, math.pi - inc, inc, 0.1, 30.0)
        for label, settings, slack in (('depth 1 m', MapSettings(cell=CELL, size=25.0, depth=1.0), 0.0),
                                       ('slack 0.2 m', MapSettings(cell=CELL, size=25.0), 0.2)):
            m = LocalMap(settings)
            m.follow(0.0, 0.0)
            line(f'{beams:5d} beams, all at 10 m, window 25 m, {label}',
                 timed(lambda pose, m=m, rays=rays, slack=slack: m.integrate_rays(pose, rays, slack), repeat))
    print(f'   ({load()})')


def cloud_points(n: int = 100_000) -> np.ndarray:
    rng = np.random.default_rng(2)
    on_discs = int(0.7 * n)
    which = rng.integers(0, len(DISCS), on_discs)
    angle = rng.uniform(-math.pi, math.pi, on_discs)
    surface = DISCS[which, :2] + DISCS[which, 2:3] * np.column_stack([np.cos(angle), np.sin(angle)])
    return np.vstack([surface, rng.uniform(-10.0, 10.0, (n - on_discs, 2))])


def clouds(repeat: int):
    points = cloud_points()
    print(f'== a cloud of {len(points)} points, {load()} ==')
    for slack in (0.0, 0.2):
        for size in (10.0, 25.0):
            m = LocalMap(MapSettings(cell=CELL, size=size))
            m.follow(0.0, 0.0)
            view = m.integrate_points(POSES[0], points, slack)
            line(f'slack {slack:g} m, window {size:g} m',
                 timed(lambda pose, m=m, slack=slack: m.integrate_points(pose, points, slack), repeat),
                 f'({view.counts["clearing_rays"]} clearing rays, {view.marked} cells marked)')
    print(f'   ({load()})')


def grids(repeat: int):
    print(f'== an occupancy grid, follow, snapshot, {load()} ==')
    rng = np.random.default_rng(3)
    data = rng.choice(np.array([-1, 0, 0, 0, 100], dtype=np.int8), 400 * 400).tobytes()
    m = LocalMap(MapSettings(cell=CELL, size=10.0))
    m.follow(0.0, 0.0)
    line('400 x 400 grid of 0.05 m, turned 0.3 rad',
         timed(lambda pose: m.integrate_grid((-9.0 + pose[0], -6.0, 0.3), 0.05, 400, 400, data, 65), repeat))
    m.integrate_rays((0.0, 0.0, 0.0), scan_rays(np.full(1440, 4.0), -math.pi, math.pi - 2 * math.pi / 1440,
                                                2 * math.pi / 1440, 0.1, 30.0))
    state = {'x': 0.0}

    def move(pose):
        state['x'] = 3.0 - state['x']
        m.follow(state['x'], 0.0)

    line('follow: the window moved by 3 m (200 x 200 cells)', timed(move, repeat))
    line('snapshot (200 x 200 cells)', timed(lambda pose: m.snapshot(), repeat))
    print(f'   ({load()})')


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeat', type=int, default=200, help='calls per figure')
    parser.add_argument('--only', nargs='*', choices=('scan', 'cloud', 'grid'), default=None)
    args = parser.parse_args(argv)
    print(f'bench_local_map: {load()}, numpy {np.__version__}', flush=True)
    only = args.only or ('scan', 'cloud', 'grid')
    if 'scan' in only:
        scans(args.repeat)
    if 'cloud' in only:
        clouds(max(20, args.repeat // 10))
    if 'grid' in only:
        grids(args.repeat)


if __name__ == '__main__':
    main()
