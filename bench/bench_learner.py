#!/usr/bin/env python3
"""The learner node's figures (issues 9 and 10).

* burst: N interventions published from another process as fast as rclpy can, with K
  CPU burners (busy loops) running; prints how long after the last publish
  /safe_set/fit counted all of them (goal: 200 ms for 1,000), and whether all were stored;
* refit: the first-passage refit (maximisation over cached encounter intervals, the
  paper's 13-entry library) with 500 and 5,000 encounters (goal < 100 ms at 500), and
  the cost of adding one encounter (its values along the frames, computed once);
* builder: EncounterBuilder cost per pose.

Every figure is printed with /proc/loadavg. Run with the project's ROS environment:

    source scripts/ros-env.sh; .venv/bin/python bench/bench_learner.py [--burst 1000 --burners 2]
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
import statistics
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / 'test'))


def load():
    with open('/proc/loadavg') as f:
        return ' '.join(f.read().split()[:3])


def bench_burst(n, burners, repeats):
    from supersafe_ros.rosenv import ensure_local_ros_env
    ensure_local_ros_env()
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import rclpy
    from learner_burst_support import run_burst
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        for k in range(repeats):
            with tempfile.TemporaryDirectory() as d:
                f = run_burst(ctx, Path(d) / 'burst.jsonl', n, burners=burners)
            print(f"burst {n}, {burners} burners, load {f['load'][0]}->{f['load'][1]}: stored {f['stored']}, "
                  f"fit counts {f['final']['interventions']}; publishing took {f['publish_s'] * 1e3:.0f} ms; "
                  f"counted {f['latency'] * 1e3:.0f} ms after the last publish "
                  f"({f['final']['refits']} refits, {f['vfs']} value functions)", flush=True)
    finally:
        ctx.try_shutdown()


def bench_refit(sizes, repeats):
    from supersafe_ros.learning import estimators as E
    from supersafe_ros.learning.data import PHASE2_OFFSETS
    from supersafe_ros.learning.encounters import EncounterBuilder
    from supersafe_ros.learning.phase2_stream import feed, phase2_events
    from supersafe_ros.reach.library import LibrarySpec, load_or_build_library
    from supersafe_ros.sim.watcher import Watcher
    lib = load_or_build_library(LibrarySpec())
    entries = list(lib.entries)
    admissible = E.admissible_mask(entries, lib.entry(1.0))
    for size in sizes:
        reps = int(np.ceil(size / len(PHASE2_OFFSETS)))
        builder = EncounterBuilder((-8, -8), (8, 8), 3.0)
        feed(builder, phase2_events(Watcher(lib.entry(0.5), mu=1.0, sigma=0.3, seed=1),
                                    np.tile(PHASE2_OFFSETS, reps)[:size], dt=0.05))
        builder.finish_all()
        records = builder.pop_finished()
        encounters = [r.to_encounter() for r in records]
        t0 = time.perf_counter()
        iv = E.encounter_intervals(entries, encounters)
        values_s = time.perf_counter() - t0
        frames = sum(len(e.states) for e in encounters)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fit = E.fit_first_passage_intervals(entries, iv, admissible=admissible)
            times.append(time.perf_counter() - t0)
        warm = []
        for _ in range(repeats):
            # the online case: the previous fit (on one encounter fewer) as the start
            prev = E.fit_first_passage_intervals(entries, E.EncounterIntervals(
                iv.lo[:, :-1], iv.hi[:, :-1], None, iv.outcomes[:-1], iv.intervened[:-1]), admissible=admissible)
            start = (np.array([c['mu'] for c in prev.candidates]), np.array([c['sigma'] for c in prev.candidates]))
            t0 = time.perf_counter()
            E.fit_first_passage_intervals(entries, iv, admissible=admissible, start=start)
            warm.append(time.perf_counter() - t0)
        one = []
        for e in encounters[:20]:
            t0 = time.perf_counter()
            E.encounter_intervals(entries, [e])
            one.append(time.perf_counter() - t0)
        print(f'refit, {len(records)} encounters ({frames} frames), 13 entries: median '
              f'{statistics.median(times) * 1e3:.1f} ms, max {max(times) * 1e3:.1f} ms '
              f'(omega_max {fit.omega_max:g}, mu {fit.mu:.3f}); started from the previous fit: median '
              f'{statistics.median(warm) * 1e3:.1f} ms; values along all frames once: '
              f'{values_s * 1e3:.0f} ms, per new encounter {statistics.median(one) * 1e3:.2f} ms; '
              f'load {load()}', flush=True)


def bench_builder(n_poses):
    from supersafe_ros.learning.encounters import EncounterBuilder
    b = EncounterBuilder((-8, -8), (8, 8), 3.0)
    rng = np.random.default_rng(0)
    ids = np.arange(10)
    b.set_obstacles(ids, rng.uniform(-20, 20, (10, 2)), 0.0)
    x = np.array([-20.0, 0.0])
    t0 = time.perf_counter()
    for k in range(n_poses):
        x += (0.15, 0.0)
        if x[0] > 20:
            x[:] = (-20.0, rng.uniform(-10, 10))
        b.pose('robot_0', 0.05 * (k + 1), (x[0], x[1], 0.0))
        b.pop_finished()
    dt = time.perf_counter() - t0
    print(f'builder: {dt / n_poses * 1e6:.0f} us per pose against 10 obstacles; load {load()}', flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--burst', type=int, default=1000)
    ap.add_argument('--burners', type=int, default=2)
    ap.add_argument('--burst-repeats', type=int, default=1)
    ap.add_argument('--sizes', type=int, nargs='+', default=[500, 5000])
    ap.add_argument('--repeats', type=int, default=7)
    ap.add_argument('--skip-burst', action='store_true')
    args = ap.parse_args()
    bench_builder(20000)
    bench_refit(args.sizes, args.repeats)
    if not args.skip_burst:
        bench_burst(args.burst, args.burners, args.burst_repeats)


if __name__ == '__main__':
    main()
