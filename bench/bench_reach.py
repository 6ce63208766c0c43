#!/usr/bin/env python3
"""Speed and accuracy of `supersafe reach` against hj_reachability 0.7.0 (issue 2).

The problem: a Dubins car of speed 3 and turn bound 1, a disc of radius 1 at the origin,
a 3 s horizon, a 101 x 101 x 64 grid over [-10, 10]^2 x [-pi, pi). Each solver runs as a
whole process (start-up, imports, JIT compilation, solve, writing the .npz), timed from
outside; both results are compared with the exact reference
(supersafe_ros.reach.reference) over the issue's nodes: -1 < V < 3 in the inner three
quarters of the domain. Then the time to load the cached candidate library.

Run with the package's venv:  .venv/bin/python bench/bench_reach.py
hj_reachability needs its own venv first:  bash bench/setup_hj.sh
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

REPO = Path(__file__).resolve().parent.parent
SUPERSAFE = REPO / '.venv' / 'bin' / 'supersafe'
HJ_PYTHON = REPO / 'bench' / '.venv-hj' / 'bin' / 'python'
HJ_SOLVE = REPO / 'bench' / 'hj_solve.py'

sys.path.insert(0, str(REPO))
from supersafe_ros.reach.grid import Grid  # noqa: E402
from supersafe_ros.reach.reference import accuracy_mask, compare, reference_on_grid  # noqa: E402
from supersafe_ros.reach.value_function import ValueFunction  # noqa: E402


def problem_args(p) -> list[str]:
    return ['--speed', str(p.speed), '--omega-max', str(p.omega_max), '--radius', str(p.radius),
            '--horizon', str(p.horizon), '--grid-min', str(p.lo), str(p.lo),
            '--grid-max', str(p.hi), str(p.hi), '--shape', *map(str, p.shape)]


def timed_process(cmd, env=None) -> float:
    """Wall time of one whole process; its output is shown only if it fails."""
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    elapsed = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f'{" ".join(map(str, cmd))} failed ({done.returncode}):\n'
                           f'{done.stdout}\n{done.stderr}')
    return elapsed


def run_solver(name, cmd, out, repeat, grid, v_ref, mask) -> dict:
    times = [timed_process(cmd + ['--out', str(out)]) for _ in range(repeat)]
    vf = ValueFunction.load_npz(out)
    if vf.grid.shape != grid.shape or not np.allclose(vf.grid.x, grid.x):
        raise RuntimeError(f'{name} wrote a different grid: {vf.grid}')
    row = {'solver': name, 'times_s': times, 'best_s': min(times), 'median_s': statistics.median(times),
           'solve_time_in_process_s': vf.meta.get('solve_time_s')}
    row.update(compare(vf.values, v_ref, mask))
    return row


LIBRARY_TIMER = """
import json, sys, time
t0 = time.perf_counter()
from supersafe_ros.reach.library import load_or_build_library
t1 = time.perf_counter()
cache = sys.argv[1] if len(sys.argv) > 1 else None
lib = load_or_build_library(cache_dir=cache)
t2 = time.perf_counter()
lib = load_or_build_library(cache_dir=cache)
t3 = time.perf_counter()
print(json.dumps({'import_s': t1 - t0, 'first_call_s': t2 - t1, 'second_call_s': t3 - t2,
                  'entries': len(lib.entries)}))
"""


def time_library(cache_dir) -> dict | None:
    """First and second load_or_build_library() call in a fresh process (the first one
    builds whatever is missing from the cache, so run it twice for a warm-cache figure)."""
    python = REPO / '.venv' / 'bin' / 'python'
    cmd = [str(python), '-c', LIBRARY_TIMER] + ([str(cache_dir)] if cache_dir else [])
    runs = []
    for _ in range(2):
        done = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
        if done.returncode != 0:
            print(f'library timing failed:\n{done.stderr[-2000:]}')
            return None
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    return {'cold_build_or_load': runs[0], 'warm_cache': runs[1]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--speed', type=float, default=3.0)
    ap.add_argument('--omega-max', type=float, default=1.0)
    ap.add_argument('--radius', type=float, default=1.0)
    ap.add_argument('--horizon', type=float, default=3.0)
    ap.add_argument('--lo', type=float, default=-10.0)
    ap.add_argument('--hi', type=float, default=10.0)
    ap.add_argument('--shape', type=int, nargs=3, default=[101, 101, 64])
    ap.add_argument('--repeat', type=int, default=2, help='runs of each solver (best and median shown)')
    ap.add_argument('--hj-accuracy', default='very_high', choices=['low', 'medium', 'high', 'very_high'])
    ap.add_argument('--skip-hj', action='store_true')
    ap.add_argument('--skip-library', action='store_true')
    ap.add_argument('--cache-dir', default=None, help='library cache (default: the package default)')
    ap.add_argument('--json', metavar='FILE', help='also write the figures here')
    a = ap.parse_args(argv)

    grid = Grid((a.lo, a.lo), (a.hi, a.hi), tuple(a.shape))
    print(f'problem: speed {a.speed}, w_max {a.omega_max}, radius {a.radius}, horizon {a.horizon} s, '
          f'grid {a.shape[0]}x{a.shape[1]}x{a.shape[2]} over [{a.lo}, {a.hi}]^2')
    t0 = time.perf_counter()
    v_ref = reference_on_grid(grid, a.speed, a.omega_max, a.radius, a.horizon)
    mask = accuracy_mask(grid, v_ref)
    print(f'exact reference: {time.perf_counter() - t0:.1f} s; {int(mask.sum())} nodes compared '
          f'(-1 < V < 3, inner three quarters)')

    rows = []
    with tempfile.TemporaryDirectory(prefix='bench_reach_') as tmp:
        if not SUPERSAFE.exists():
            print(f'missing {SUPERSAFE}: run scripts/setup.sh first')
            return 1
        rows.append(run_solver('supersafe reach', [str(SUPERSAFE), 'reach', *problem_args(a)],
                               Path(tmp) / 'supersafe.npz', a.repeat, grid, v_ref, mask))
        if not a.skip_hj:
            if not HJ_PYTHON.exists():
                print(f'missing {HJ_PYTHON}: run `bash bench/setup_hj.sh` first (or --skip-hj)')
                return 1
            rows.append(run_solver(f'hj_reachability 0.7.0 ({a.hj_accuracy})',
                                   [str(HJ_PYTHON), str(HJ_SOLVE), *problem_args(a),
                                    '--accuracy', a.hj_accuracy],
                                   Path(tmp) / 'hj.npz', a.repeat, grid, v_ref, mask))

    print()
    print(f'{"solver":<34} {"wall s (best)":>13} {"median":>8} {"solve s¹":>8} '
          f'{"mean|err|":>10} {"max|err|":>9} {"sign err":>9}')
    for r in rows:
        solve = r['solve_time_in_process_s']
        print(f'{r["solver"]:<34} {r["best_s"]:>13.2f} {r["median_s"]:>8.2f} '
              f'{(f"{solve:.2f}" if solve is not None else "-"):>8} {r["mean_abs_error"]:>10.5f} '
              f'{r["max_abs_error"]:>9.4f} {100 * r["sign_error_fraction"]:>8.3f}%')
    print('¹ in-process solve time of the last run, as written in its .npz metadata')
    if len(rows) == 2:
        ratio = rows[1]['best_s'] / rows[0]['best_s']
        print(f'\nhj_reachability / supersafe wall time: {ratio:.1f}x '
              f'(goal >= 10x: {"met" if ratio >= 10 else "NOT met"}); '
              f'supersafe error {"<=" if rows[0]["mean_abs_error"] <= rows[1]["mean_abs_error"] else ">"} '
              f'hj_reachability error')
    print('issue targets: mean |err| <= 0.01, sign err <= 0.3%: supersafe '
          + ('met' if rows[0]['mean_abs_error'] <= 0.01 and rows[0]['sign_error_fraction'] <= 0.003
             else 'NOT met'))

    library = None
    if not a.skip_library:
        library = time_library(a.cache_dir)
        if library:
            cold, warm = library['cold_build_or_load'], library['warm_cache']
            print(f'\ncandidate library ({warm["entries"]} entries): first process '
                  f'{cold["first_call_s"]:.2f} s (builds what the cache lacks); fresh process on a '
                  f'warm cache: import {warm["import_s"]:.2f} s, load {warm["first_call_s"]:.3f} s, '
                  f'second call {warm["second_call_s"]:.4f} s (goal < 0.2 s: '
                  f'{"met" if warm["first_call_s"] < 0.2 else "NOT met"})')
    if a.json:
        with open(a.json, 'w') as f:
            json.dump({'problem': vars(a), 'solvers': rows, 'library': library}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
