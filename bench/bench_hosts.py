"""The team across hosts (network namespaces; run as root): scale and same-task figures.

Scale (default): for each robot count, one game on one host (loopback), then on 2 and 3
hosts with simple (multicast) discovery and with the Fast DDS discovery server. Each
row prints
  graph   seconds from starting the processes until host 0 sees every topic of the
          one-host graph with its publisher and subscription counts (process start-up
          and value-function loading included: compare rows, not absolutes);
  x       the real-time factor the lockstep clock achieved (rate factor 0: as fast
          as the graph allows);
  cpu/r   CPU seconds per robot per sim second over the game (robot, planner, filter
          processes), and all/s the whole team's CPU per sim second.
Same task (--same-task): for each seed, --repeats one-host games and one three-host
game; prints the counts, so the three-host game can be judged against the one-host
spread.

    sudo .venv/bin/python bench/bench_hosts.py --robots 2 4 6 --duration 20
    sudo .venv/bin/python bench/bench_hosts.py --same-task --seeds 1 2 3 --repeats 2
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path
import sys
import tempfile

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))   # hosts_support

from supersafe_ros.rosenv import ensure_local_ros_env  # noqa: E402
from supersafe_ros import team  # noqa: E402
from hosts_support import HostsTeam, team_graph  # noqa: E402

FAST = {'supervisor': {'grid_nxy': 33, 'grid_ntheta': 16},
        'safety_filter': {'standard_shape': [33, 33, 16]},
        'learner': {'library_shape': [33, 33, 16]}}
KEYS = ('trips', 'interventions', 'false_positives', 'crashes')


def game(n_robots, n_hosts, ds, seed, duration, step, log_dir, expected=None, fast=True):
    argvs = team.team_processes(n_robots, rate_factor=0.0, seed=seed, duration=duration,
                                overrides=FAST if fast else None, step=step,
                                learner_store=Path(log_dir) / 'store.jsonl')
    with HostsTeam(argvs, n_hosts, log_dir, discovery_server=ds) as t:
        t.wait(lambda: t.sim_time() > 0, 300, 'sim time')
        cpu0 = t.team.cpu_seconds()
        sim0 = t.sim_time()
        t.wait_sim(duration, 900)
        cpu1 = t.team.cpu_seconds()
        sim = t.sim_time() - sim0
        clock = t.monitor.latest('/sim/clock_status')
        graph = team_graph(t.monitor.graphs()[-1]['graph'])
        took = t.graph_complete_at(expected or graph)
        used = {n: cpu1.get(n, 0.0) - cpu0.get(n, 0.0) for n in cpu1}
        robot_cpu = sum(c for n, c in used.items() if n.startswith('robot_'))
        return {'graph_s': took, 'x': float(clock.get('rate_factor_achieved', 'nan')),
                'cpu_robot': robot_cpu / n_robots / sim, 'cpu_all': sum(used.values()) / sim,
                'counts': {k: int(t.stats().get(k, -1)) for k in KEYS}, 'graph': graph,
                'late': int(clock.get('late_steps', 0))}


def scale(args, tmp):
    print(f'# scale: {os.cpu_count()} cores, game {args.duration} sim s, step {args.step} s')
    print(f'{"robots":>6} {"hosts":>5} {"discovery":>9} {"graph s":>8} {"x":>6} {"cpu/r":>7} '
          f'{"all/s":>6} {"late":>5}  load')
    for n in args.robots:
        base = None
        for hosts, ds in [(1, False)] + [(h, d) for h in args.hosts if h > 1 for d in (False, True)]:
            r = game(n, hosts, ds, args.seed, args.duration, args.step,
                     tmp / f'r{n}h{hosts}{"ds" if ds else ""}', base and base['graph'])
            if base is None:
                base = r
            g = f'{r["graph_s"]:.1f}' if r['graph_s'] is not None else 'never'
            print(f'{n:6d} {hosts:5d} {"server" if ds else "simple":>9} {g:>8} {r["x"]:6.2f} '
                  f'{r["cpu_robot"]:7.3f} {r["cpu_all"]:6.2f} {r["late"]:5d}  '
                  f'{os.getloadavg()[0]:.1f}', flush=True)


def same_task(args, tmp):
    print(f'# same task: {args.duration} sim s, 2 robots, step {args.step} s')
    for seed in args.seeds:
        rows = []
        for rep in range(args.repeats):
            rows.append(('1 host', game(2, 1, False, seed, args.duration, args.step,
                                        tmp / f's{seed}r{rep}')))
        rows.append(('3 hosts', game(2, 3, False, seed, args.duration, args.step, tmp / f's{seed}h3')))
        for label, r in rows:
            print(f'seed {seed} {label:8s} ' + '  '.join(f'{k} {r["counts"][k]}' for k in KEYS)
                  + f'  load {os.getloadavg()[0]:.1f}', flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--robots', type=int, nargs='+', default=[2, 4, 6])
    ap.add_argument('--hosts', type=int, nargs='+', default=[2, 3])
    ap.add_argument('--duration', type=float, default=20.0)
    ap.add_argument('--step', type=float, default=0.1)
    ap.add_argument('--seed', type=int, default=3)
    ap.add_argument('--same-task', action='store_true')
    ap.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3])
    ap.add_argument('--repeats', type=int, default=2)
    args = ap.parse_args()
    ensure_local_ros_env()
    print(f'load before: {" ".join(f"{x:.2f}" for x in os.getloadavg())}')
    with tempfile.TemporaryDirectory(prefix='bench-hosts-') as d:
        (same_task if args.same_task else scale)(args, Path(d))
    print(f'load after: {" ".join(f"{x:.2f}" for x in os.getloadavg())}')


if __name__ == '__main__':
    main()
