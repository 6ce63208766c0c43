"""Wall time of `supersafe study` through the real node graph, and where it goes.

Runs the study as a whole process, timed from outside (interpreter, imports, cache
loads, every Phase II graph and Phase III game, statistics, plots, JSON), then prints
the total, the per-subject and per-game wall times and the machine's load average.

    .venv/bin/python bench/bench_study.py --subjects 12              # issue 10's target: < 240 s
    .venv/bin/python bench/bench_study.py --subjects 12 --step 0.05  # target: < 600 s
"""
import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--subjects', type=int, default=12)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--step', type=float, default=0.2)
    ap.add_argument('--sweep-subjects', type=int, default=2)
    ap.add_argument('--out', type=Path, default=None, help='study output (default a temporary directory)')
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix='supersafe-bench-study-'))
    exe = Path(sys.executable).with_name('supersafe')
    cmd = [str(exe), 'study', '--subjects', str(args.subjects), '--seed', str(args.seed),
           '--step', str(args.step), '--sweep-subjects', str(args.sweep_subjects), '--out', str(out)]
    load0 = os.getloadavg()
    t0 = time.monotonic()
    rc = subprocess.call(cmd)
    wall = time.monotonic() - t0
    load1 = os.getloadavg()
    if rc != 0:
        print(f'study failed with exit code {rc}')
        return rc
    res = json.loads((out / 'study.json').read_text())
    t = res['timing']
    games = t['game_wall_s']
    print(f'\n== bench_study: {args.subjects} subjects, step {args.step} s, sweep on {args.sweep_subjects}')
    target = 240 if args.step >= 0.2 else 600
    print(f'total wall (process, timed outside) {wall:7.1f} s   target {target} s for 12 subjects')
    print(f'Phase II per subject  mean {sum(t["phase2_wall_s"]) / len(t["phase2_wall_s"]):5.1f} s  '
          f'max {max(t["phase2_wall_s"]):5.1f} s')
    print(f'Phase III per game    mean {sum(games) / len(games):5.1f} s  max {max(games):5.1f} s '
          f'({len(games)} games of {res["options"]["game_seconds"]:g} sim s)')
    played = [g for subj in res['subjects'] for g in list(subj['games'].values())
              + [v for k, v in subj['sweep'].items() if float(k) != 0.0]]
    running = [g['wall_running'] for g in played if 'wall_running' in g]
    cpu = [g['cpu_s'] for g in played if 'cpu_s' in g]
    if running:
        print(f'  of which the clock ran mean {sum(running) / len(running):5.1f} s; resets and '
              f'graph start-up the rest (first game of each subject: start-up of its graph)')
    if cpu:
        print(f'  CPU of the graph processes per game mean {sum(cpu) / len(cpu):5.1f} s '
              f'(+ the runner, which hosts the clock)')
    print(f'load average before {load0[0]:.2f}, after {load1[0]:.2f} (1-min; 2 cores); '
          f'5-min after {load1[1]:.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
