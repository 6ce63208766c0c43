"""Crashes at start-up under load: many short teams with sensors that never miss.

Each run starts the team graph as processes (`supersafe team --no-supervisor
--no-learner`, ``dubins_robot.miss_probability 0``) for --duration sim seconds at
rate factor 0 (sim time as fast as the graph allows, so a late message costs the
most sim time), with --burners CPU burners (busy Python loops) beside it, and counts
the world's crashes. Seeds are those whose obstacles stand 5-7 m ahead of both
robots' start (a robot that drives blind for 2 s reaches them).

    .venv/bin/python bench/bench_startup.py --runs 30 --burners 2

Prints one line per run (crashes, trips, wall seconds) and the total, with the load.
"""
import argparse
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

from supersafe_ros.team import run_team, team_processes

# seeds of the default world with an obstacle 5-7 m ahead of both robots' start (2 robots)
CLOSE_START_SEEDS = (4, 18, 33, 56, 6, 37, 49, 2, 9, 12)


def start_team(seed, duration, step, log_dir):
    """One short team run: the world's stats and crash events."""
    argvs = team_processes(2, rate_factor=0.0, seed=seed, duration=duration, step=step,
                           with_supervisor=False, with_learner=False,
                           overrides={'dubins_robot': {'miss_probability': 0.0}})
    return run_team(argvs, duration=duration, timeout=300.0, log_dir=log_dir, print_period=1e9,
                    out=open(os.devnull, 'w'))


def burners(n):
    """``n`` busy Python loops (the caller kills them)."""
    return [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(n)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--runs', type=int, default=30)
    ap.add_argument('--burners', type=int, default=2)
    ap.add_argument('--duration', type=float, default=6.0, help='sim seconds per run')
    ap.add_argument('--step', type=float, default=0.05)
    args = ap.parse_args()
    procs = burners(args.burners)
    total, trips = 0, 0
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for i in range(args.runs):
                seed = CLOSE_START_SEEDS[i % len(CLOSE_START_SEEDS)]
                t0 = time.monotonic()
                res = start_team(seed, args.duration, args.step, Path(tmp) / f'run{i}')
                crashes = [e for e in res['events'] if e.get('event') == 'crash']
                total += len(crashes)
                trips += int(res['stats'].get('trips', 0))
                print(f'run {i:3d} seed {seed:3d}: {res["reason"]}, crashes {len(crashes)} '
                      f'{[(e.get("robot"), e.get("obstacle"), e.get("time")) for e in crashes]}, '
                      f'{time.monotonic() - t0:.1f} s wall, load {os.getloadavg()[0]:.1f}', flush=True)
    finally:
        for p in procs:
            p.kill()
            p.wait()
    print(f'{args.runs} runs of {args.duration:g} sim s (step {args.step:g}), {args.burners} burners: '
          f'{total} crashes; load {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores')
    return 0 if total == 0 else 1


if __name__ == '__main__':
    sys.exit(main())
