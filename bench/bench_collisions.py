"""Collisions with detected obstacles: ROS-free replays and the real team graph.

Sections (run all by default, or name some):

* ``replay``  - single-disc encounters, the issue's timing replay: 7.3 % of
  decisions on the previous step's pose, steps 0.05 and 0.2 s; "before" = pose
  judged as if current with the old fixed 0.1 s lookahead (compensate_delay
  False), "after" = the filter as shipped.
* ``layouts`` - rows (4.5 m), cups (3-3.6 m gaps) and random dense layouts: the
  smallest per-obstacle value (clusters off) against the cluster values.
* ``speeds``  - planners that slow, stop, wait and speed up (``trials.speed_profiles``)
  through single discs, rows, cups and random dense layouts, clusters by union values,
  7.3 % stale decisions; and discs of three radii (0.4, 1.8, 3.5 m; the largest as a
  ring of 1.8 m discs): collisions, and the most a robot was sent beyond its planner.
* ``scan``    - crossings of a team world (``trials.field_trials``: 10 discs of radii 0.8,
  1.8, 2.6 m) seen only through a 360-beam laser (``trials.ScanSensor``: the filter node's
  pipeline: REP 117 readings into a local map of 0.2 m cells, obstacle_depth 5.2, judged by
  the map's value solved every other step and in force a step later; 30 % of decisions on
  the previous scan), at each --steps: the exact discs seen (the MarkerArray reference), the
  map at the node's lookahead (0.1 s) and at the scan team's (0.5 s), each without and with
  the speed cut, and the map's value solved once only (the cut alone, near enough).
* ``latency`` - a new cluster's value: solve time and request -> in force (the
  control loop keeps deciding meanwhile, on the fallback), in a background thread.
* ``graph``   - the real graph (``supersafe team --no-supervisor --no-learner``,
  every obstacle detected: dubins_robot.miss_probability 0) for --robot-hours at
  each --steps, counting crashes deeper than 1 cm (world.crash_tolerance 0.01).

    .venv/bin/python bench/bench_collisions.py replay layouts latency --encounters 2000
    .venv/bin/python bench/bench_collisions.py speeds --encounters 400
    .venv/bin/python bench/bench_collisions.py scan --encounters 100 --steps 0.05 0.1 0.2
    .venv/bin/python bench/bench_collisions.py graph --robot-hours 1 --robots 4 --steps 0.2 0.05

Prints the figures and the machine's load (timings depend on it).
"""
import argparse
import os
import sys
import time

import numpy as np

from supersafe_ros.filter.clusters.geometry import ClusterSettings
from supersafe_ros.filter.clusters.store import ClusterStore
from supersafe_ros.filter import FilterConfig, RobotFilter, SafeSet, step_many
from supersafe_ros.sim.trials import (ScanSensor, cup_layout, field_trials, layout_trials, random_layout,
                                      row_layout, run_trials, single_disc_trials, speed_profiles, standard_guard)
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.library import load_or_solve

STALE = 0.073


def load():
    return f'load {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores'


def standard_set():
    vf = load_or_solve(Grid((-8, -8), (8, 8), (65, 65, 42)), 3.0, 1.0, 1.8, 3.0)
    return SafeSet(vf, 0.0, 'standard')


def replay(args, safe):
    print(f'== replay: {args.encounters} single-disc encounters per row, {STALE:.1%} decisions on '
          f'the previous pose, standard set 65x65x42 ==')
    for step in args.steps:
        for label, cfg in (('before (as if current, lookahead 0.1)',
                            FilterConfig(lookahead=0.1, compensate_delay=False)),
                           ('after  (propagated, lookahead >= period)', FilterConfig(lookahead=0.1))):
            t0 = time.perf_counter()
            r = run_trials(single_disc_trials(args.encounters, np.random.default_rng(1)),
                           standard_guard(safe), step=step, stale_probability=STALE, config=cfg,
                           rng=np.random.default_rng(2))
            print(f'step {step:4.2f}  {label}: {r.summary()}  [{time.perf_counter() - t0:.0f} s]',
                  flush=True)


def layouts(args, safe):
    n = args.encounters
    rng = np.random.default_rng(3)
    sets = {
        'row 4.5 m': [row_layout(4.5)] * n,
        'cup 3-3.6 m gaps': [cup_layout(rng) for _ in range(max(n // 20, 1))] * 20,
        'random dense (3-6 discs, gaps >= 0.3 m)': [random_layout(rng, int(rng.integers(3, 7)), half=6.0,
                                                                  min_gap=0.3)
                                                    for _ in range(max(n // 20, 1))] * 20,
    }
    pairs = []
    for _ in range(n):    # two discs farther apart than the link distance: not clustered
        d, a = rng.uniform(9.6, 16.0), rng.uniform(-np.pi, np.pi)
        rotation = np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
        pairs.append(np.array([[-0.5, 0.0], [0.5, 0.0]]) * d @ rotation)
    sets['pairs beyond the link (9.6-16 m)'] = pairs
    print(f'== layouts: approaches per row as listed, {STALE:.1%} stale decisions ==')
    for step in args.steps:
        for name, lays in sets.items():
            encounters = layout_trials(lays, np.random.default_rng(4))
            for label, cfg, store in (('min per obstacle', FilterConfig(clusters=False), None),
                                      ('cluster values', FilterConfig(),
                                       ClusterStore(ClusterSettings(disk_cache=False), background=False))):
                t0 = time.perf_counter()
                r = run_trials(encounters, lambda fs, t: step_many(fs, safe, t, store), step=step,
                               stale_probability=STALE, config=cfg, rng=np.random.default_rng(5))
                extra = ''
                if store is not None and store.values:
                    times = [v.solve_time for v in store.values.values()]
                    extra = (f'; {len(times)} cluster solves, median {np.median(times):.2f} s, '
                             f'max {max(times):.2f} s')
                print(f'step {step:4.2f}  {name:40s} {label:17s}: {r.summary()}{extra}  '
                      f'[{time.perf_counter() - t0:.0f} s]', flush=True)


def speeds(args, safe):
    n = args.encounters
    rng = np.random.default_rng(31)
    sets = {
        'single disc': [np.zeros((1, 2))] * n,
        'row 4.5 m': [row_layout(4.5)] * n,
        'cup 3-3.6 m gaps': [cup_layout(rng) for _ in range(max(n // 20, 1))] * 20,
        'random dense (3-6 discs, gaps >= 0.3 m)': [random_layout(rng, int(rng.integers(3, 7)), half=6.0,
                                                                  min_gap=0.3)
                                                    for _ in range(max(n // 20, 1))] * 20,
        'radii 0.4, 1.8, 3.5 m': [np.stack([rng.permutation([-9.0, 0.0, 9.0]), rng.uniform(-2, 2, 3),
                                            [0.4, 1.8, 3.5]], axis=1) for _ in range(n)],
    }
    print(f'== speeds: planners that slow, stop, wait and speed up (speed_profiles), {STALE:.1%} stale '
          f'decisions, cluster values, time_before_collision {args.time_before_collision:g} ==')
    for step in args.steps:
        for name, lays in sets.items():
            encounters = layout_trials(lays, np.random.default_rng(4))
            store = ClusterStore(ClusterSettings(disk_cache=False), background=False)
            t0 = time.perf_counter()
            r = run_trials(encounters, lambda fs, t: step_many(fs, safe, t, store), step=step,
                           stale_probability=STALE, rng=np.random.default_rng(5), time_limit=40.0,
                           speeds=speed_profiles(np.random.default_rng(6), len(encounters)),
                           config=FilterConfig(time_before_collision=args.time_before_collision))
            print(f'step {step:4.2f}  {name:40s}: {r.summary()}, at most {r.max_speed_excess:g} m/s beyond '
                  f'the planner  [{time.perf_counter() - t0:.0f} s]', flush=True)


def scan(args, safe):
    print(f'== scan: {args.encounters} crossings of a team world per row (10 discs of radii 0.8, 1.8, 2.6 m), '
          f'seen through a 360-beam laser, {STALE:.1%} stale poses, 30 % stale scans, seed {args.seed} ==')
    # (label, sensor, lookahead, time_before_collision): any value > 0 checks the path over the law's horizon
    rows = (('exact discs seen (markers), lookahead 0.1', ScanSensor(stale_probability=0.3, markers=True), 0.1, 0.0),
            ('scan map and its value, lookahead 0.1 (the node default)', ScanSensor(stale_probability=0.3), 0.1, 0.0),
            ('scan map and its value, lookahead 0.5 (the scan team)', ScanSensor(stale_probability=0.3), 0.5, 0.0),
            ('exact discs seen (markers), lookahead 0.1, stop before collision',
             ScanSensor(stale_probability=0.3, markers=True), 0.1, 0.01),
            ('scan map and its value, lookahead 0.1, stop before collision', ScanSensor(stale_probability=0.3), 0.1,
             0.01),
            ('scan map and its value, lookahead 0.5, stop before collision', ScanSensor(stale_probability=0.3), 0.5,
             0.01),
            ('scan map, its value solved once only, lookahead 0.1, stop before collision',
             ScanSensor(stale_probability=0.3, value_every=10**9), 0.1, 0.01))
    for step in args.steps:
        for label, sensor, lookahead, before in rows:
            if args.rows and not any(word in label for word in args.rows):
                continue
            t0 = time.perf_counter()
            config = FilterConfig(lookahead=lookahead, time_before_collision=before)
            r = run_trials(field_trials(args.encounters, np.random.default_rng(args.seed)),
                           lambda fs, t: step_many(fs, safe, t), step=step, stale_probability=STALE,
                           config=config, rng=np.random.default_rng(args.seed + 1),
                           time_limit=40.0, sensor=sensor, safe_set=safe)
            print(f'step {step:4.2f}  {label:72s}: {r.summary()}, at most {r.max_speed_excess:g} m/s beyond the '
                  f'planner, {r.sim_time / max(1, r.trials):.1f} s a crossing  [{time.perf_counter() - t0:.0f} s, '
                  f'{load()}]', flush=True)


def latency(args, safe):
    """A robot meets a new cluster; its filter keeps deciding at 50 Hz (wall time)
    while the background solve runs: time from first detection to the union in force."""
    print(f'== latency: new cluster -> its value in force (background thread), {load()} ==')
    rng = np.random.default_rng(6)
    cases = [('row of 2 (4.5 m)', row_layout(4.5, 2)), ('row of 3 (4.5 m)', row_layout(4.5)),
             ('cup', cup_layout(rng))] + [(f'random {k}', random_layout(rng, k, half=5.0)) for k in (3, 4, 5)]
    for name, discs in cases:
        store = ClusterStore(ClusterSettings(disk_cache=False), background=True).start()
        store.ready.wait(120.0)          # as in a node: the solver process is up before obstacles
        f = RobotFilter(FilterConfig())
        t0 = time.monotonic()
        decisions, fallback = 0, 0
        while True:
            t = time.monotonic() - t0
            f.update_pose((-12.0, 0.3, 0.0), t)
            f.update_detections(discs, t)
            f.update_command(0.0, t)
            out = f.step(safe, t, clusters=store)
            decisions += 1
            if out.source == 'cluster' or store.values:
                break
            fallback += out.source == 'cluster-fallback'
            time.sleep(0.02)
        in_force = time.monotonic() - t0
        value = next(iter(store.values.values()))
        print(f'{name:18s} grid {value.vf.grid.shape}: solve {value.solve_time * 1e3:6.0f} ms, '
              f'in force after {in_force * 1e3:6.0f} ms ({decisions} decisions meanwhile, '
              f'{fallback} on the fallback)', flush=True)
    print(f'({load()})')


def graph(args):
    from supersafe_ros.team import run_team, team_processes
    duration = args.robot_hours * 3600.0 / args.robots / len(args.steps)
    print(f'== graph: {args.robots} robots x {duration:.0f} sim s per step {args.steps}, perfect detection, '
          f'crashes deeper than 1 cm ==', flush=True)
    total = {'hours': 0.0, 'crashes': 0}
    for step in args.steps:
        overrides = {'dubins_robot': {'miss_probability': 0.0}, 'world': {'crash_tolerance': 0.01}}
        argvs = team_processes(args.robots, 0.0, seed=args.seed, duration=duration, step=step,
                               with_learner=False, with_supervisor=False, overrides=overrides)
        t0 = time.monotonic()
        res = run_team(argvs, duration, args.timeout, print_period=60.0, out=sys.stderr)
        sim = float(res['clock'].get('sim_time', 0.0))
        crashes = [e for e in res['events'] if e.get('event') == 'crash']
        stats = res['stats']
        n_crash = int(stats.get('crashes', 0))
        trips = int(stats.get('trips', 0))
        hours = sim * args.robots / 3600.0
        total['hours'] += hours
        total['crashes'] += n_crash
        print(f'step {step}: {hours:.2f} robot-hours ({sim:.0f} sim s, {time.monotonic() - t0:.0f} wall s, '
              f'{res["reason"]}): {n_crash} crashes > 1 cm, {trips} trips, events {crashes[:5]}  '
              f'[{load()}]', flush=True)
    print(f'graph total: {total["hours"]:.2f} robot-hours, {total["crashes"]} crashes > 1 cm')


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('sections', nargs='*', default=['replay', 'layouts', 'latency'],
                    help='replay layouts speeds scan latency graph (default: replay layouts latency)')
    ap.add_argument('--encounters', type=int, default=1000, help='approaches per replay/layout row')
    ap.add_argument('--steps', type=float, nargs='+', default=[0.05, 0.2])
    ap.add_argument('--robot-hours', type=float, default=0.5, help='graph: robot-hours over all steps')
    ap.add_argument('--robots', type=int, default=4)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--time-before-collision', type=float, default=0.0,
                    help='speeds: FilterConfig.time_before_collision (0: off)')
    ap.add_argument('--rows', nargs='*', default=[], help='scan: only the rows whose label holds one of these')
    ap.add_argument('--timeout', type=float, default=0.0, help='graph: wall seconds per step (0: none)')
    args = ap.parse_args()
    print(f'bench_collisions: {load()}', flush=True)
    safe = standard_set() if set(args.sections) & {'replay', 'layouts', 'speeds', 'scan', 'latency'} else None
    for section in args.sections:
        {'replay': lambda: replay(args, safe), 'layouts': lambda: layouts(args, safe),
         'speeds': lambda: speeds(args, safe), 'scan': lambda: scan(args, safe),
         'latency': lambda: latency(args, safe), 'graph': lambda: graph(args)}[section]()
    return 0


if __name__ == '__main__':
    sys.exit(main())
