#!/usr/bin/env python3
"""The learner node's figures (issues 9 and 10).

* burst: N interventions published from another process as fast as rclpy can, with K
  CPU burners (busy loops) running; prints how long after the last publish
  /safe_set/fit counted all of them (goal: 200 ms for 1,000), and whether all were stored;
* refit: the first-passage refit (maximisation over cached encounter intervals, the
  paper's 13-entry library) with 500 and 5,000 encounters (goal < 100 ms at 500), and
  the cost of adding one encounter (its values along the frames, computed once);
* builder: EncounterBuilder cost per pose;
* clicks (issue 29): a learner node (first-passage, 13 entries on 41 x 41 x 24) fed Phase II
  scenes, then a click flood (clicks just after the robot passed its obstacle, and clicks
  on obstacles far from it), then Phase II scenes again; prints the fits published
  before, during and after the flood, what was set aside, and "fit failed" lines;
* junk (issue 29): N malformed or duplicate interventions (five kinds, round robin) at
  full speed to a learner node; prints the counters on /safe_set/fit, the learner's
  log lines on /rosout (during the burst, after it, at shutdown), how long after the
  last message each reason's count was told, and the process's resident memory.

Every figure is printed with /proc/loadavg. Run with the project's ROS environment:

    source scripts/ros-env.sh; .venv/bin/python bench/bench_learner.py [--burst 1000 --burners 2]
    .venv/bin/python bench/bench_learner.py --only clicks junk [--junk 10000]
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


def _ros_context():
    from supersafe_ros.rosenv import ensure_local_ros_env
    ensure_local_ros_env()
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import rclpy
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    return ctx


def _rss_mb():
    with open('/proc/self/status') as f:
        return next(int(line.split()[1]) for line in f if line.startswith('VmRSS')) / 1024


def bench_clicks(hasty_rounds):
    """Phase II, a flood of hasty and far clicks, Phase II: what the learner publishes."""
    from graph_support import Rosout, Spinner
    from learner_phase2_support import Driver, click_flood, make_learner, play
    from supersafe_ros.learning.data import PHASE2_OFFSETS
    from supersafe_ros.learning.phase2_stream import phase2_events
    from supersafe_ros.reach.library import PAPER_OMEGAS, LibrarySpec, load_or_build_library
    from supersafe_ros.sim.watcher import Watcher
    ctx = _ros_context()
    lib = load_or_build_library(LibrarySpec(shape=(41, 41, 24), omegas=tuple(float(w) for w in PAPER_OMEGAS)))
    with tempfile.TemporaryDirectory() as d:
        node = make_learner(ctx, Path(d) / 'clicks.jsonl')
        driver = Driver(ctx)
        rosout = Rosout(driver.node)
        spin = Spinner(ctx, node, driver.node)
        try:
            driver.wait_for(spin, rosout.sub)
            watcher = Watcher(lib.entry(0.5), mu=1.0, sigma=0.3, seed=5)
            n = len(PHASE2_OFFSETS)
            phases = []

            def phase(name, events, want_encounters=None):
                published, t0 = int(driver.fit().get('published', 0)), time.perf_counter()
                play(spin, node, driver, events)
                if want_encounters is not None:
                    driver.publish(('pose', 'robot_0', driver_time[0], (-30.0, 0.0, 0.0)))
                    try:
                        spin.until(lambda: driver.fit().get('fitted_encounters') == str(want_encounters), 60.0, name)
                    except AssertionError as exc:      # (the learner before issue 29 stopped fitting)
                        print(f'clicks, {name}: {exc}', flush=True)
                else:
                    spin.until(lambda: node.builder.open_count == 0, 60.0, name)
                    spin.spin_for(0.5)
                driver_time[0] += 1000.0
                phases.append((name, int(driver.fit()['published']) - published, dict(driver.fit()),
                               time.perf_counter() - t0))

            driver_time = [900.0]
            phase('before: 19 Phase II scenes', phase2_events(watcher, PHASE2_OFFSETS, dt=0.2, t0=1.0), n)
            flood = []
            for r in range(hasty_rounds):
                flood += list(click_flood(2000.0 + 200.0 * r, 500 + 10 * r))
            driver_time[0] = 2000.0 + 200.0 * hasty_rounds + 100.0
            phase(f'flood: {6 * hasty_rounds} hasty clicks, {4 * hasty_rounds} far clicks', flood)
            driver_time[0] += 1000.0
            phase('after: 19 Phase II scenes', phase2_events(watcher, PHASE2_OFFSETS, dt=0.2, t0=driver_time[0] - 900.0,
                                                             first_obstacle=5000), 2 * n)
            failed = sum('fit failed' in m.msg for m in rosout.logs if m.name == 'learner')
            warns = sum(m.level == 30 for m in rosout.logs if m.name == 'learner')
            for name, published, fit, wall in phases:
                print(f'clicks, {name}: {published} fits published ({fit.get("published")} in all, '
                      f'{fit.get("refits")} refits), '
                      f'fitted encounters {fit.get("fitted_encounters")} of {fit.get("encounters")}, '
                      f'interventions {fit.get("interventions")}, set aside {fit.get("set_aside")}, '
                      f'omega_max {fit.get("omega_max")}, mu {float(fit.get("mu", "nan")):.3f}; '
                      f'{wall:.1f} s; load {load()}', flush=True)
            print(f'clicks: "fit failed" lines {failed}, learner WARN lines {warns}; load {load()}', flush=True)
        finally:
            spin.shutdown()
            node.close()
            node.destroy_node()
            driver.node.destroy_node()
    ctx.try_shutdown()


def bench_junk(n):
    """n junk interventions of five kinds at full speed: counters, log lines, memory."""
    from geometry_msgs.msg import PoseStamped
    from learner_phase2_support import JunkSender, make_learner
    ctx = _ros_context()

    def junk(k):
        msg = PoseStamped()
        kind = k % 5
        msg.header.frame_id = ['map', 'obstacle_' + '9' * 1000, 'obstacle_1', 'obstacle_2', 'obstacle_3'][kind]
        msg.header.stamp.sec = 1 + k
        if kind == 2:
            msg.header.stamp.nanosec = 2_000_000_000          # invalid stamp
        msg.pose.position.x, msg.pose.position.y = (float('nan') if kind == 3 else -3.0), 0.5
        if kind == 4:
            msg.header.stamp.sec = 7                          # the same event again and again
        msg.pose.orientation.w = 1.0
        return msg

    with tempfile.TemporaryDirectory() as d:
        node = make_learner(ctx, Path(d) / 'junk.jsonl', estimator='paper')
        sender = JunkSender(ctx, node)
        pub, rosout, spin = sender.pub, sender.rosout, sender.spin
        sender = sender.node
        try:
            spin.spin_for(0.5)
            rss0, lines0 = _rss_mb(), len(rosout.logs)
            t0 = time.perf_counter()
            for k in range(n):
                pub.publish(junk(k))
                if k % 200 == 199:
                    spin.executor.spin_once(timeout_sec=0)
            sent = time.perf_counter()
            c = node.counts
            spin.until(lambda: c['rejected'] + c['duplicates'] == n - 1, 120.0, 'every message counted')
            read = time.perf_counter()
            during = [m for m in rosout.logs[lines0:] if m.name == 'learner']
            k_during = len(during)      # (rosout is read later than the messages: often 0 here)

            def told():
                out = {}
                for m in rosout.logs[lines0:]:
                    if m.name == 'learner' and '(' in m.msg and 'this run' not in m.msg:
                        reason = m.msg.split('(', 1)[1].split(')', 1)[0]
                        words = m.msg.split()
                        out[reason] = out.get(reason, 0) + (int(words[0]) if words[1] == 'more' else 1)
                return out
            try:
                spin.until(lambda: sum(told().values()) == n - 1, 30.0, 'every rejection told')
            except AssertionError as exc:        # (before issue 29: most only counted)
                print(f'junk {n}: {exc}', flush=True)
            told_s = time.perf_counter() - read
            rss1 = _rss_mb()
            lines = [m for m in rosout.logs[lines0:] if m.name == 'learner']
            node.close()
            try:
                spin.until(lambda: any('this run' in m.msg for m in rosout.logs), 10.0, 'the totals')
            except AssertionError as exc:
                print(f'junk {n}: {exc}', flush=True)
            totals = [m.msg for m in rosout.logs if 'this run' in m.msg]
            fit = node.counts
            print(f'junk {n}: published in {sent - t0:.2f} s, all read {read - sent:.2f} s after the last; '
                  f'rejected {fit["rejected"]}, duplicates {fit["duplicates"]}, stored {len(node.store)}; '
                  f'learner log lines: {k_during} by the time all were read, {len(lines)} once every count '
                  f'was told ({told_s:.2f} s after), told per reason {told()}; totals at shutdown: {totals}; '
                  f'RSS {rss0:.0f} -> {rss1:.0f} MB (learner and sender in one process); load {load()}',
                  flush=True)
        finally:
            spin.shutdown()
            node.destroy_node()
            sender.destroy_node()
    ctx.try_shutdown()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--burst', type=int, default=1000)
    ap.add_argument('--burners', type=int, default=2)
    ap.add_argument('--burst-repeats', type=int, default=1)
    ap.add_argument('--sizes', type=int, nargs='+', default=[500, 5000])
    ap.add_argument('--repeats', type=int, default=7)
    ap.add_argument('--skip-burst', action='store_true')
    ap.add_argument('--junk', type=int, default=10000, help='junk interventions (issue 29)')
    ap.add_argument('--flood-rounds', type=int, default=3, help='rounds of 6 hasty and 4 far clicks')
    ap.add_argument('--only', nargs='+', choices=['builder', 'refit', 'burst', 'clicks', 'junk'],
                    help='run only these parts (default: builder, refit, burst)')
    args = ap.parse_args()
    if args.only:
        for part in args.only:
            {'builder': lambda: bench_builder(20000), 'refit': lambda: bench_refit(args.sizes, args.repeats),
             'burst': lambda: bench_burst(args.burst, args.burners, args.burst_repeats),
             'clicks': lambda: bench_clicks(args.flood_rounds), 'junk': lambda: bench_junk(args.junk)}[part]()
        return
    bench_builder(20000)
    bench_refit(args.sizes, args.repeats)
    if not args.skip_burst:
        bench_burst(args.burst, args.burners, args.burst_repeats)


if __name__ == '__main__':
    main()
