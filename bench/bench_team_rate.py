"""Real-time factor the team graph sustains, and where the CPU goes.

Runs `supersafe team` (clock, world, N x (robot, planner, filter), learner,
supervisor) for --duration sim seconds at --rate-factor (0 = as fast as the graph
allows) and prints the achieved factor (sim seconds per wall second, measured by
the clock after the graph is up), late lockstep steps, and each process's CPU.

    .venv/bin/python bench/bench_team_rate.py --robots 2 --rate-factor 0 --duration 60
"""
import argparse
import os
import sys

from supersafe_ros.team import run_team, team_processes


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--robots', type=int, default=2)
    ap.add_argument('--rate-factor', type=float, default=0.0)
    ap.add_argument('--duration', type=float, default=60.0)
    ap.add_argument('--step', type=float, default=0.05, help='sim seconds per /clock step')
    ap.add_argument('--no-filter', action='store_true')
    ap.add_argument('--no-learner', action='store_true')
    ap.add_argument('--timeout', type=float, default=300.0)
    args = ap.parse_args()
    argvs = team_processes(args.robots, args.rate_factor, seed=1, duration=args.duration,
                           step=args.step,
                           with_filter=not args.no_filter, with_learner=not args.no_learner,
                           learner_store=f'/tmp/supersafe-bench-{os.getpid()}/interventions.jsonl')
    res = run_team(argvs, args.duration, args.timeout, print_period=10.0, out=sys.stderr)
    clock = res['clock']
    print(f"robots {args.robots}  step {args.step} s  target x{args.rate_factor:g}  "
          f"achieved x{clock.get('rate_factor_achieved', '?')}  "
          f"sim {clock.get('sim_time', '?')} s  late steps {clock.get('late_steps', '?')}  "
          f"cores {os.cpu_count()}  load {os.getloadavg()[0]:.2f}")
    # CPU while sim time ran (from the first clock status on; start-up excluded, so the
    # first status period of sim time is excluded too)
    start = res['cpu_seconds_at_start']
    sim = float(clock.get('sim_time', 0.0)) - 1.0
    total = 0.0
    used = {n: c - start.get(n, 0.0) for n, c in res['cpu_seconds'].items()}
    for name, cpu in sorted(used.items(), key=lambda kv: -kv[1]):
        total += cpu
        print(f'  {name:26s} {cpu:7.2f} CPU s  ({cpu / sim * 1000:6.1f} ms per sim s)')
    print(f'  {"total":26s} {total:7.2f} CPU s  ({total / sim * 1000:6.1f} ms per sim s)')
    print(f"stats: {res['stats']}")
    return 0 if res['reason'] == 'duration reached' else 1


if __name__ == '__main__':
    sys.exit(main())
