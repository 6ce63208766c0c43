"""The issue's trips, before and after: each scenario through the filter of each checkout, side by side
(prints figures; no assertions, no files).

    source scripts/ros-env.sh
    .venv/bin/python bench/bench_trips.py                                  # this checkout
    .venv/bin/python bench/bench_trips.py --checkout /work/wt-old . --repeat 3
    .venv/bin/python bench/bench_trips.py --scenarios facing_wall --fault scan_nan --fault-step 25

Each trip (test/unicycle_graph_support.py: a unicycle with odometry at 50 Hz, a 360-beam laser at
10 Hz and TwistStamped, its planner at 0.5 m/s, the managed filter with that checkout's
config/nav2_safety_filter.yaml, stepped by events on sim time) runs in a process of its own with
PYTHONPATH = the checkout, so supersafe_ros (the filter node and its config) is that checkout's,
while the harness and the world (sim/unicycle_world.py, loaded by its path) are this script's
tree's: every checkout drives the same robot through the same world. The checkouts take turns
(their order flips from one trip to the next), so that the machine's load falls evenly on them.

Printed per trip: reached, the trip's sim time (``>cap``: not within ``--max-time``), the
planner's own time (its path driven with no filter), their ratio, the path driven, the time and
share of commands turning in place (|v| < 0.01, |w| > 0.05), the least clearance of the robot's
disc (m; negative inside an obstacle), collisions (entries into an obstacle), the wall seconds
the trip took and the machine's load (/proc/loadavg) when it started. The sim time of a trip is
capped (``--max-time``, 90 s), so a trip that never gets there costs about 40-50 wall seconds.
"""
from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import time

HERE = Path(__file__).resolve().parent
TREE = HERE.parent
SCENARIOS = ('door', 'open_field', 'lane', 'combined')
RESULT = 'TRIP '          # the worker's result line


def load() -> str:
    """The machine's load averages over 1, 5 and 15 minutes."""
    with open('/proc/loadavg') as f:
        return ' '.join(f.read().split()[:3])


def label(checkout: Path) -> str:
    """The checkout's commit and branch (``+`` if its tracked files differ from the commit)."""
    def git(*args):
        out = subprocess.run(['git', '-C', str(checkout), *args], capture_output=True, text=True)
        return out.stdout.strip() if out.returncode == 0 else ''
    commit = git('rev-parse', '--short', 'HEAD') or checkout.name
    branch = git('rev-parse', '--abbrev-ref', 'HEAD')
    dirty = '+' if git('status', '--porcelain', '--untracked-files=no') else ''
    return f'{commit}{dirty} ({branch})' if branch and branch != 'HEAD' else commit + dirty


def check_checkout(checkout: Path):
    for part in ('supersafe_ros/nodes/safety_filter_node.py', 'config/nav2_safety_filter.yaml'):
        if not (checkout / part).is_file():
            raise SystemExit(f'{checkout}: no {part}: not a checkout of supersafe_ros')


# -- the worker: one trip, in a process whose supersafe_ros is the checkout's ----------------------
def worker(args) -> int:
    sys.path.insert(0, str(TREE / 'test'))        # the harness of this tree (it imports no test module)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'     # (before rclpy: loopback only)
    import rclpy
    import unicycle_graph_support as trips
    expected = Path(args.worker_checkout).resolve()
    if trips.checkout_root() != expected:
        raise SystemExit(f'supersafe_ros imported from {trips.checkout_root()}, not from the checkout {expected}')
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        began = time.monotonic()
        start = None
        if args.start_shift:
            x, y, theta = trips.own_simulator().scenario(args.worker).start
            start = (x, y + args.start_shift, theta)
        result = trips.run_trip(ctx, args.worker, max_time=args.max_time, fault=args.fault,
                                fault_step=args.fault_step, detections=args.detections, start=start)
        figures = result.figures()
        figures['wall'] = time.monotonic() - began
    finally:
        ctx.try_shutdown()
    print(RESULT + json.dumps(figures), flush=True)
    return 0


def run_one(checkout: Path, scenario: str, args) -> dict:
    """One trip in a process of its own with PYTHONPATH = ``checkout``: its figures, or why it failed."""
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join([str(checkout)] + ([env['PYTHONPATH']] if env.get('PYTHONPATH') else []))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env.setdefault('ROS_DOMAIN_ID', str(110 + os.getpid() % 90))
    env.setdefault('SUPERSAFE_CACHE', str(checkout / '.cache' / 'test-values'))   # its own solver's values
    env.setdefault('ROS_LOG_DIR', str(TREE / '.cache' / 'ros-log'))
    command = [sys.executable, str(Path(__file__).resolve()), '--worker', scenario, '--worker-checkout',
               str(checkout), '--max-time', str(args.max_time), '--fault-step', str(args.fault_step),
               '--detections', args.detections, '--start-shift', repr(args.start_shift)] + (
                   ['--fault', args.fault] if args.fault else [])
    before = load()
    done = subprocess.run(command, env=env, cwd=str(checkout), capture_output=True, text=True)
    lines = [line for line in done.stdout.splitlines() if line.startswith(RESULT)]
    if done.returncode != 0 or not lines:
        why = (done.stderr.strip().splitlines() or [f'exit {done.returncode}'])[-1]
        return dict(scenario=scenario, failed=why, load=before)
    figures = json.loads(lines[-1][len(RESULT):])
    figures['load'] = before
    return figures


HEADER = (f'{"scenario":<12} {"checkout":<28} {"reached":>7} {"trip s":>7} {"planner s":>9} {"ratio":>6} '
          f'{"path m":>6} {"turning s":>9} {"share":>6} {"least m":>7} {"collisions":>10} {"wall s":>6}  load')


def row(name: str, f: dict, cap: float) -> str:
    """One line of the table."""
    if 'failed' in f:
        return f'{f["scenario"]:<12} {name:<28} failed: {f["failed"]}  [{f["load"]}]'
    reached = f['reached']
    trip = f'{f["time"]:7.2f}' if reached else f'{">" + format(cap, "g"):>7}'
    ratio = f'{f["ratio"]:6.2f}' if reached else f'{">" + format(cap / f["planner_time"], ".1f"):>6}'
    return (f'{f["scenario"]:<12} {name:<28} {"yes" if reached else "no":>7} {trip} {f["planner_time"]:9.2f} {ratio} '
            f'{f["path_length"]:6.2f} {f["turning_time"]:9.2f} {100 * f["turning_share"]:5.1f}% '
            f'{f["least_clearance"]:7.3f} {f["collisions"]:10d} {f["wall"]:6.1f}  {f["load"]}')


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--checkout', nargs='+', default=[str(TREE)], metavar='DIR',
                   help='checkouts of supersafe_ros to run (default: the one this script is in)')
    p.add_argument('--scenarios', nargs='+', default=list(SCENARIOS),
                   help=f'default {" ".join(SCENARIOS)}; also facing_wall')
    p.add_argument('--max-time', type=float, default=90.0, help='sim seconds a trip may take (default 90)')
    p.add_argument('--repeat', type=int, default=1, help='rounds over every scenario and checkout')
    p.add_argument('--fault', default=None, help='a fault of unicycle_graph_support.FAULTS, from --fault-step on')
    p.add_argument('--fault-step', type=int, default=0)
    p.add_argument('--detections', choices=('scan', 'cloud'), default='scan')
    p.add_argument('--start-shift', type=float, default=0.0, metavar='DY',
                   help='start every trip DY m to the left of its start (the path stays): how much the figures '
                        'follow a small change')
    p.add_argument('--json', action='store_true', help='also print each trip\'s figures as a JSON line')
    p.add_argument('--worker', default=None, help=argparse.SUPPRESS)
    p.add_argument('--worker-checkout', default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        return worker(args)
    checkouts = [Path(c).resolve() for c in args.checkout]
    for c in checkouts:
        check_checkout(c)
    names = {c: label(c) for c in checkouts}
    print(f'bench_trips: {len(checkouts)} checkout(s), scenarios {" ".join(args.scenarios)}, cap {args.max_time:g} '
          f'sim s, {args.repeat} round(s); harness and world of {TREE}'
          + (f'; fault {args.fault} from step {args.fault_step}' if args.fault else '')
          + (f'; starts shifted {args.start_shift:+g} m in y' if args.start_shift else ''))
    for c in checkouts:
        print(f'  {names[c]}: {c}')
    print(HEADER, flush=True)
    results = {}
    turn = 0
    for _ in range(args.repeat):
        for scenario in args.scenarios:
            order = checkouts if turn % 2 == 0 else checkouts[::-1]
            turn += 1
            for c in order:
                f = run_one(c, scenario, args)
                results.setdefault((scenario, c), []).append(f)
                print(row(names[c], f, args.max_time), flush=True)
                if args.json:
                    print(json.dumps(dict(f, checkout=str(c), label=names[c])), flush=True)
    if args.repeat > 1 or len(checkouts) > 1:
        print('\nside by side (median over rounds; trips not reached count as the cap):')
        print(HEADER)
        for scenario in args.scenarios:
            for c in checkouts:
                print(row(names[c], median(results[(scenario, c)], args.max_time), args.max_time))
    return 0


def median(runs: list, cap: float) -> dict:
    """The median of each figure over the runs that did not fail (reached only if most did)."""
    ok = [f for f in runs if 'failed' not in f]
    if not ok:
        return runs[-1]

    def mid(values):
        values = sorted(values)
        n = len(values)
        return values[n // 2] if n % 2 else 0.5 * (values[n // 2 - 1] + values[n // 2])
    out = dict(ok[0])
    for key in ('planner_time', 'path_length', 'turning_time', 'turning_share', 'least_clearance', 'wall'):
        out[key] = mid([f[key] for f in ok])
    out['collisions'] = int(round(mid([f['collisions'] for f in ok])))
    times = [f['time'] if f['reached'] else math.inf for f in ok]
    out['time'] = mid(times)
    out['reached'] = math.isfinite(out['time']) and out['time'] <= cap
    out['ratio'] = out['time'] / out['planner_time'] if out['reached'] else math.inf
    out['load'] = f'{len(ok)} runs'
    return out


if __name__ == '__main__':
    raise SystemExit(main())
