"""The decision core's cost, checkouts side by side: ``step_many`` per tick in each checkout, in
turns (prints figures; no assertions, no files).

    .venv/bin/python bench/bench_core.py --checkout /tmp/base .          # every scenario
    .venv/bin/python bench/bench_core.py --checkout /tmp/base . --only lone fleet-1000-union

One worker process per checkout (PYTHONPATH = that checkout), each building the same scenarios
from the same seeds; the bench asks them for blocks of ticks in turns (the order alternating from
round to round), so that both see the same machine: its speed drifts with the load of the other
jobs on it. A tick is the fleet node's: the batched inputs taken (``update_detections_all`` every
fifth tick, ``update_commands``, ``update_poses``; not timed), then ``step_many`` (timed: CPU
seconds, ``time.process_time``). Each block's median, then per checkout the median and the range
over the rounds. Each worker also digests its decisions (every command, action and reason of
the block's last tick): equal digests mean the same decisions.

Scenarios (``--only``):

* ``lone``: one robot's own filter (safety_filter_node's ``decide_many`` of one filter and its
  record): three obstacles, one near; ``lone-cluster``: two close obstacles near, their union
  value in force (solved inline, disk-cached);
* ``dense-N-V`` (N = 1 or 1,000): bench_nodes.py's ``core`` section: ten obstacles over 24 x 16 m,
  robots over 30 x 20 m given three of them each, or all ten (``union``);
* ``fleet-N-V``: the batched fleet of bench_headroom.py's ``batched`` section, N robots (1,000 or
  2,000) over 80 x 80 m among 30 obstacles, one configuration and one detections array for all,
  every planner asking (3 m/s, 0.1 rad/s); V the clusters: ``off``, ``fallback`` (loiter circles:
  no union value in force, as before the solves end or for sensor discs) or ``union`` (in force:
  solved inline, disk-cached).

``--callgrind SCENARIO --ticks K``: this checkout only, K ticks of one scenario in this process,
each ``step_many`` called through ``operator.call`` (nothing else calls it) after the inputs are
fed, the garbage collector off (its collections fall on ticks of their own): under callgrind,
collecting only inside that call, the instructions of K ticks of ``step_many`` alone, whatever
the load. ``python -S`` with the venv's site-packages on PYTHONPATH: a .pth file the venv runs at
start-up keeps valgrind from writing its counts at exit (ros_wheels_bootstrapper)::

    PYTHONHASHSEED=0 PYTHONPATH=CHECKOUT:.venv/lib/python3.11/site-packages valgrind --tool=callgrind \
        --collect-atstart=no --toggle-collect=_operator_call --callgrind-out-file=OUT \
        python3.11 -S bench/bench_core.py --callgrind lone --ticks 300    # "summary:" in OUT / 300
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
from pathlib import Path
import subprocess
import sys
import time

HERE = Path(__file__).resolve().parent
SCENARIOS = ('lone', 'lone-cluster', 'fleet-1000-off', 'fleet-1000-fallback', 'fleet-1000-union',
             'fleet-2000-off', 'fleet-2000-fallback', 'fleet-2000-union', 'dense-1-off', 'dense-1-fallback',
             'dense-1-union', 'dense-1000-off', 'dense-1000-fallback', 'dense-1000-union')


def build(name):
    """(filters, cluster store, feed(k) -> t): the scenario's robots and its inputs at tick k."""
    import numpy as np
    from supersafe_ros.filter import FilterConfig, RobotFilter, update_commands, update_detections_all, update_poses
    from supersafe_ros.filter.clusters.geometry import ClusterSettings
    from supersafe_ros.filter.clusters.store import ClusterStore
    if name.startswith('lone'):
        f = RobotFilter(FilterConfig())
        dets = (np.array([[2.0, 1.5], [12.0, -20.0], [-30.0, 4.0]]) if name == 'lone' else
                np.array([[2.0, 1.5], [4.5, 5.5], [-30.0, 4.0]]))
        store = ClusterStore(ClusterSettings(), background=False)

        def feed_one(k):
            t = 0.02 * k
            if k % 5 == 0:
                f.update_detections(dets.copy(), t)
            f.update_command(0.1, t, 1.5)
            f.update_pose((-4.0, -1.0, 0.3), t)
            return t
        return [f], store, feed_one
    kind, n, variant = name.split('-')
    n = int(n)
    if kind == 'dense':
        return _dense(n, variant)
    rng = np.random.default_rng(2)
    field = np.stack([rng.uniform(-40, 40, 30), rng.uniform(-40, 40, 30)], axis=1)
    states = np.stack([rng.uniform(-40, 40, n), rng.uniform(-40, 40, n), rng.uniform(-3, 3, n)], axis=1)
    config = FilterConfig(clusters=variant != 'off')     # one for all, as the fleet node's robots share
    filters = [RobotFilter(config, name=f'r{i}') for i in range(n)]
    store = {'off': None, 'fallback': ClusterStore(ClusterSettings(), fallback_only=True),
             'union': ClusterStore(ClusterSettings(), background=False)}[variant]
    omegas, linears = np.full(n, 0.1), np.full(n, 3.0)

    def feed(k):
        t = 0.02 * k
        if k % 5 == 0:
            update_detections_all(filters, field.copy(), t)
        update_commands(filters, omegas, t, linears=linears)
        update_poses(filters, states, t)
        return t
    return filters, store, feed


def _dense(n, variant):
    """bench_nodes.py's ``core`` section: n robots over 30 x 20 m among ten obstacles over 24 x 16
    m, each given three of them (``off``, ``fallback``) or all ten (``union``), the planner's command
    0.1 rad/s at the speed, a new pose each tick."""
    import numpy as np
    from supersafe_ros.filter import FilterConfig, RobotFilter
    from supersafe_ros.filter.clusters.geometry import ClusterSettings
    from supersafe_ros.filter.clusters.store import ClusterStore
    rng = np.random.default_rng(0)
    field = np.stack([rng.uniform(-12, 12, 10), rng.uniform(-8, 8, 10)], axis=1)
    config = FilterConfig(clusters=variant != 'off')
    store = {'off': None, 'fallback': ClusterStore(ClusterSettings(), fallback_only=True),
             'union': ClusterStore(ClusterSettings(), background=False)}[variant]
    filters, poses, dets = [], [], []
    for i in range(n):
        filters.append(RobotFilter(config))
        poses.append((rng.uniform(-15, 15), rng.uniform(-10, 10), rng.uniform(-np.pi, np.pi)))
        dets.append(field if variant == 'union' else field[rng.choice(len(field), 3, replace=False)])

    def feed(k):
        t = 0.02 * k
        for f, pose, det in zip(filters, poses, dets):
            f.update_pose(pose, t)
            if k % 5 == 0:
                f.update_detections(det, t)
            f.update_command(0.1, t)
        return t
    return filters, store, feed


def digest(decisions) -> str:
    """SHA-256 of every robot's command, action and reason (all the outputs built)."""
    h = hashlib.sha256()
    h.update(repr((decisions.omega, decisions.linear, decisions.action)).encode())
    for out in decisions:
        h.update(repr(sorted(out.record().items())).encode())
    return h.hexdigest()[:16]


def worker():
    """Serve blocks: a JSON line {"scenario", "ticks"} in, a JSON line of CPU seconds per tick out."""
    from supersafe_ros.filter import SafeSet, step_many
    from supersafe_ros.reach.grid import Grid
    from supersafe_ros.reach.library import load_or_solve
    vf = load_or_solve(Grid((-8, -8), (8, 8), (65, 65, 42)), 3.0, 1.0, 1.8, 3.0)
    safe = SafeSet(vf, 0.0)
    built = {}
    for line in sys.stdin:
        ask = json.loads(line)
        name = ask['scenario']
        if name not in built:
            filters, store, feed = build(name)
            built[name] = [filters, store, feed, 0]
            for _ in range(3):      # warm: cluster frames, union values read from the disk cache
                entry = built[name]
                step_many(filters, safe, feed(entry[3]), store)
                entry[3] += 1
        filters, store, feed, k = built[name]
        times = []
        for _ in range(ask['ticks']):
            t = feed(k)
            k += 1
            c0 = time.process_time()
            decisions = step_many(filters, safe, t, store)
            times.append(time.process_time() - c0)
        built[name][3] = k
        print(json.dumps({'times': times, 'digest': digest(decisions)}), flush=True)


def start(checkout):
    env = dict(os.environ, PYTHONPATH=str(checkout))
    return subprocess.Popen([sys.executable, str(HERE / 'bench_core.py'), '--worker'], cwd=str(checkout), env=env,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def ask(proc, scenario, ticks) -> dict:
    proc.stdin.write(json.dumps({'scenario': scenario, 'ticks': ticks}) + '\n')
    proc.stdin.flush()
    return json.loads(proc.stdout.readline())


def ticks_of(scenario) -> int:
    """Ticks a block: about 0.3 s of work."""
    if scenario.startswith('lone') or '-1-' in scenario:
        return 1000
    return 20 if '-1000-' in scenario else 10


def compare(args):
    import numpy as np
    checkouts = [Path(c).resolve() for c in args.checkout]
    procs = [start(c) for c in checkouts]
    print(f'bench_core: {len(checkouts)} checkout(s) in turns, {args.rounds} rounds; load average '
          f'{os.getloadavg()[0]:.2f} ({os.cpu_count()} cores)', flush=True)
    try:
        for scenario in args.only:
            per = [[] for _ in checkouts]
            digests = [set() for _ in checkouts]
            loads = []
            for r in range(args.rounds + 1):      # round 0 builds and warms, not counted
                order = list(range(len(checkouts)))
                if r % 2:
                    order.reverse()
                for i in order:
                    got = ask(procs[i], scenario, ticks_of(scenario) if r else 3)
                    digests[i].add(got['digest'])
                    if r:
                        per[i].append(float(np.median(got['times'])))
                loads.append(os.getloadavg()[0])
            n = 1 if scenario.startswith('lone') else int(scenario.split('-')[1])
            for c, times, dig in zip(checkouts, per, digests):
                t = np.array(times)
                print(f'{scenario:20s} {str(c):28s} {np.median(t) * 1e3:8.3f} ms a tick '
                      f'({t.min() * 1e3:.3f}-{t.max() * 1e3:.3f}), {np.median(t) / n * 1e6:7.2f} us a robot; '
                      f'decisions {",".join(sorted(dig))}', flush=True)
            if len(checkouts) == 2:
                ratio = np.array(per[1]) / np.array(per[0])
                print(f'{"":20s} second / first, round by round: median {np.median(ratio):.3f} (range '
                      f'{ratio.min():.3f}-{ratio.max():.3f}); load {min(loads):.2f}-{max(loads):.2f}', flush=True)
    finally:
        for p in procs:
            p.stdin.close()
            p.wait()


def count(scenario, ticks):
    """``ticks`` ticks of ``scenario`` in this process, each ``step_many`` through ``operator.call``
    (for callgrind; see the module)."""
    import gc
    import operator
    from supersafe_ros.filter import SafeSet, step_many
    from supersafe_ros.reach.grid import Grid
    from supersafe_ros.reach.library import load_or_solve
    vf = load_or_solve(Grid((-8, -8), (8, 8), (65, 65, 42)), 3.0, 1.0, 1.8, 3.0)
    safe = SafeSet(vf, 0.0)
    filters, store, feed = build(scenario)
    for k in range(5):          # warm: cluster frames, union values read from the disk cache
        step_many(filters, safe, feed(k), store)
    gc.collect()
    gc.disable()
    for k in range(5, 5 + ticks):
        operator.call(step_many, filters, safe, feed(k), store)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--checkout', nargs='+', default=[str(HERE.parent)], help='checkouts to compare')
    ap.add_argument('--only', nargs='+', default=list(SCENARIOS), choices=SCENARIOS)
    ap.add_argument('--rounds', type=int, default=8)
    ap.add_argument('--callgrind', choices=SCENARIOS, help='run TICKS ticks of one scenario here')
    ap.add_argument('--ticks', type=int, default=10)
    ap.add_argument('--worker', action='store_true', help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        return worker()
    if args.callgrind:
        return count(args.callgrind, args.ticks)
    return compare(args)


if __name__ == '__main__':
    sys.exit(main())
