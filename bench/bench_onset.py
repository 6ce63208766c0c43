"""Where the filter starts to override, and what that costs in collisions, by look-ahead.

The lockstepped team holds each command exactly one step and the filter answers every
pose on that pose, so the look-ahead only has to cover one hold: H = one step judges the
planner's command held for the step and then the better bang held for one more step
(``filter.constraints.pairs``). This bench measures, for H = 1 and 2 steps at the study's step (0.2 s)
and the team's (0.05 s):

* onset: V_std - alpha at the first override of each approach (alpha = 0, the standard
  set), head-on, with lateral offsets, and oblique (heading noise); the planner drives
  straight on, so every override is the filter's;
* the smallest V along each pass (below 0: the robot entered the standard unsafe set);
* collisions with detected discs (entries deeper than 1 cm) in closed-loop trials under
  the lockstep's conditions (no stale pose, no late reply): single discs, rows, cups and
  random dense layouts with cluster values.

    .venv/bin/python bench/bench_onset.py [--approaches 400] [--trials 1000]
"""
import argparse
import os
import time

import numpy as np

from supersafe_ros.filter import FilterConfig, RobotFilter, SafeSet, step_many
from supersafe_ros.filter.clusters.geometry import ClusterSettings
from supersafe_ros.filter.clusters.store import ClusterStore
from supersafe_ros.sim.trials import (cup_layout, layout_trials, random_layout, row_layout, run_trials,
                                      single_disc_trials)
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.library import load_or_solve

APPROACHES = (('head-on', 0.0, 0.0), ('offsets |y| < 1.5 m', 1.5, 0.0), ('oblique |dth| < 0.5', 1.0, 0.5))


def onsets(safe, config, step, n, offset, heading, seed=0):
    """(V - alpha at each approach's first override (NaN: none), the smallest V of each pass)."""
    rng = np.random.default_rng(seed)
    car = DubinsCar(config.speed, config.omega_max)
    ys = rng.uniform(-offset, offset, n) if offset else np.zeros(n)
    ths = rng.uniform(-heading, heading, n) if heading else np.zeros(n)
    state = np.stack([np.full(n, -9.0), ys, ths], 1)
    filters = [RobotFilter(config) for _ in range(n)]
    first, vmin = np.full(n, np.nan), np.full(n, np.inf)
    disc = np.zeros((1, 2))
    for k in range(int(round(8.0 / step))):
        t = k * step
        v = safe.vf.value(state)
        vmin = np.minimum(vmin, v)
        for f, s in zip(filters, state):
            f.update_pose(s, t, stamp=t)
            f.update_detections(disc, t)
            f.update_command(0.0, t)
        out = step_many(filters, safe, t)
        newly = np.array([a != 'pass' for a in out.action]) & np.isnan(first)
        first[newly] = v[newly] - safe.alpha
        state = car.flow(state, np.array(out.omega), step)
    return first, vmin


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--approaches', type=int, default=400)
    ap.add_argument('--trials', type=int, default=1000, help='closed-loop trials per layout row')
    ap.add_argument('--steps', type=float, nargs='+', default=[0.2, 0.05])
    ap.add_argument('--holds', type=float, nargs='+', default=[2.0, 1.0], help='look-ahead in steps')
    args = ap.parse_args()
    safe = SafeSet(load_or_solve(Grid((-8, -8), (8, 8), (65, 65, 42)), 3.0, 1.0, 1.8, 3.0), 0.0)
    print(f'load {os.getloadavg()[0]:.2f}; standard set 65x65x42, alpha 0', flush=True)
    rng = np.random.default_rng(3)
    layouts = {'single disc': None, 'row 4.5 m': [row_layout(4.5)] * args.trials,
               'cups 3-3.6 m': [cup_layout(rng) for _ in range(max(args.trials // 20, 1))] * 20,
               'random dense': [random_layout(rng, int(rng.integers(3, 7)), half=6.0, min_gap=0.3)
                                for _ in range(max(args.trials // 20, 1))] * 20}
    for step in args.steps:
        for holds in args.holds:
            config = FilterConfig(control_period=step, lookahead=holds * step)
            for label, offset, heading in APPROACHES:
                first, vmin = onsets(safe, FilterConfig(control_period=step, lookahead=holds * step, clusters=False),
                                     step, args.approaches, offset, heading)
                ok = ~np.isnan(first)
                print(f'step {step:4.2f} look-ahead {holds:g} step(s) {label:20s}: onset V - alpha median '
                      f'{np.median(first[ok]):.3f} (10-90 % {np.percentile(first[ok], 10):.3f} to '
                      f'{np.percentile(first[ok], 90):.3f}; {ok.sum()} of {len(ok)} overrode), smallest V on a '
                      f'pass {vmin.min():.3f}', flush=True)
            for name, lays in layouts.items():
                t0 = time.perf_counter()
                trials = (single_disc_trials(args.trials, np.random.default_rng(1)) if lays is None
                          else layout_trials(lays, np.random.default_rng(4)))
                store = ClusterStore(ClusterSettings(disk_cache=False), background=False)
                r = run_trials(trials, lambda fs, t: step_many(fs, safe, t, store), step=step, config=config,
                               rng=np.random.default_rng(5))
                print(f'step {step:4.2f} look-ahead {holds:g} step(s) {name:14s}: {r.summary()}  '
                      f'[{time.perf_counter() - t0:.0f} s]', flush=True)


if __name__ == '__main__':
    main()
