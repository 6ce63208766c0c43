"""Wall time of `supersafe study`, and how the in-process engine compares with the graph.

Timing (default): runs the study as a whole process, timed from outside (interpreter,
imports, cache loads, every Phase II and Phase III game, statistics, plots, JSON), then
prints the total, the per-subject and per-game wall times and the machine's load average
(os.getloadavg, before and after: the machine is shared).

    .venv/bin/python bench/bench_study.py --subjects 12              # issue 10's target: < 240 s
    .venv/bin/python bench/bench_study.py --subjects 12 --population paper   # issue 21's: < 300 s
    .venv/bin/python bench/bench_study.py --subjects 12 --step 0.05  # target: < 600 s
    .venv/bin/python bench/bench_study.py --subjects 12 --engine graph

Agreement (``--compare``): the same study (same subjects, seeds, layouts) on both engines,
side by side: per subject the Phase II interventions and both fits, and per game the
false positives, interventions, crashes and trips; then the mean |difference| per game.
The graph is slow: keep --subjects small (default 2, no sweep).

    .venv/bin/python bench/bench_study.py --compare --subjects 2
"""
import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time


def run_study(args, engine: str, out: Path, sweep: int):
    exe = Path(sys.executable).with_name('supersafe')
    cmd = [str(exe), 'study', '--subjects', str(args.subjects), '--seed', str(args.seed),
           '--step', str(args.step), '--sweep-subjects', str(sweep), '--out', str(out),
           '--engine', engine, '--population', args.population] + (['--no-plots'] if args.no_plots else [])
    if args.conditions:
        cmd += ['--conditions', args.conditions]
    if args.game_seconds:
        cmd += ['--game-seconds', str(args.game_seconds)]
    load0 = os.getloadavg()
    t0 = time.monotonic()
    rc = subprocess.call(cmd, stdout=subprocess.DEVNULL if args.quiet else None)
    wall = time.monotonic() - t0
    load1 = os.getloadavg()
    if rc != 0:
        raise SystemExit(f'study ({engine}) failed with exit code {rc}')
    return json.loads((out / 'study.json').read_text()), wall, load0, load1


def timing(args) -> int:
    out = args.out or Path(tempfile.mkdtemp(prefix='supersafe-bench-study-'))
    res, wall, load0, load1 = run_study(args, args.engine, out, args.sweep_subjects)
    t = res['timing']
    games = t['game_wall_s']
    print(f'\n== bench_study: {args.subjects} subjects, step {args.step} s, sweep on {args.sweep_subjects}, '
          f'{args.engine} engine')
    target = (300 if args.population == 'paper' else 240) if args.step >= 0.2 else 600
    print(f'total wall (process, timed outside) {wall:7.1f} s   target {target} s for 12 subjects '
          f'(population {args.population}, conditions {",".join(res["conditions"])})')
    print(f'Phase II per subject  mean {sum(t["phase2_wall_s"]) / len(t["phase2_wall_s"]):5.1f} s  '
          f'max {max(t["phase2_wall_s"]):5.1f} s')
    print(f'Phase III per game    mean {sum(games) / len(games):5.1f} s  max {max(games):5.1f} s '
          f'({len(games)} games of {res["options"]["game_seconds"]:g} sim s)')
    played = [g for subj in res['subjects'] for g in list(subj['games'].values())
              + [v for k, v in subj['sweep'].items() if float(k) != 0.0]]
    cpu = [g['cpu_s'] for g in played if 'cpu_s' in g]
    if cpu:
        who = 'this process' if args.engine == 'core' else 'the graph processes (+ the runner, which hosts the clock)'
        print(f'  CPU per game mean {sum(cpu) / len(cpu):5.2f} s, all games {sum(cpu):6.1f} s ({who})')
    print(f'load average before {load0[0]:.2f}, after {load1[0]:.2f} (1-min; {os.cpu_count()} cores); '
          f'5-min after {load1[1]:.2f}')
    return 0


def compare(args) -> int:
    base = args.out or Path(tempfile.mkdtemp(prefix='supersafe-bench-compare-'))
    runs = {}
    for engine in ('core', 'graph'):
        if engine == 'graph' and args.reuse_graph and (base / engine / 'study.json').is_file():
            runs[engine] = json.loads((base / engine / 'study.json').read_text())
            print(f'graph: reused {base / engine / "study.json"}', flush=True)
            continue
        res, wall, load0, load1 = run_study(args, engine, base / engine, 0)
        runs[engine] = res
        print(f'{engine:5s}: {wall:7.1f} s wall, load {load0[0]:.2f} -> {load1[0]:.2f}', flush=True)
    core, graph = runs['core'], runs['graph']
    print(f'\n== bench_study --compare: {args.subjects} subjects, seed {args.seed}, step {args.step} s')
    print('Phase II (core | graph): interventions; learned w/mu/sigma; learned_fp w/mu/sigma')

    def fit(f):
        return 'no fit' if not f else f"w {f['omega_max']:g} mu {f['mu']:.3f} sigma {f['sigma']:.3f}"
    for sc, sg in zip(core['subjects'], graph['subjects']):
        i = sc['subject']['index']
        print(f"  s{i:02d} {sc['phase2']['interventions']:3d} | {sg['phase2']['interventions']:3d}")
        for c in ('learned', 'learned_fp'):
            if c in sc['fits'] or c in sg['fits']:
                print(f"       {c:11s} {fit(sc['fits'].get(c)):34s} | {fit(sg['fits'].get(c))}")
    keys = ('false_positives', 'interventions', 'crashes', 'trips')
    print('Phase III per game (core | graph): ' + ', '.join(keys))
    diffs = {k: [] for k in keys}
    for sc, sg in zip(core['subjects'], graph['subjects']):
        for c in [c for c in sc['games'] if c in sg['games']]:      # learned_online: core only
            gc, gg = sc['games'][c], sg['games'][c]
            print(f"  s{sc['subject']['index']:02d} {c:13s} " + '   '.join(
                f'{gc[k]:3d} | {gg[k]:3d}' for k in keys))
            for k in keys:
                diffs[k].append(abs(gc[k] - gg[k]))
    n = len(diffs['trips'])
    print('mean |core - graph| per game: ' + ', '.join(f'{k} {sum(v) / n:.2f}' for k, v in diffs.items())
          + f' ({n} games)')
    for k in keys:
        tc = sum(sum(s['games'][c][k] for c in s['games'] if c in graph['conditions']) for s in core['subjects'])
        tg = sum(sum(s['games'][c][k] for c in s['games']) for s in graph['subjects'])
        print(f'  {k:16s} total core {tc:4d}   graph {tg:4d}')
    print(f'results: {base}/core/study.json, {base}/graph/study.json')
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--subjects', type=int, default=None, help='default 12 (timing), 2 (--compare)')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--step', type=float, default=0.2)
    ap.add_argument('--engine', choices=('core', 'graph'), default='core')
    ap.add_argument('--population', default='pilots', help='pilots (default), paper or a population FILE.json')
    ap.add_argument('--conditions', default=None, help='the study\'s --conditions (default its own)')
    ap.add_argument('--sweep-subjects', type=int, default=2)
    ap.add_argument('--game-seconds', type=float, default=None, help='default the study\'s (120)')
    ap.add_argument('--compare', action='store_true', help='the same study on both engines, side by side')
    ap.add_argument('--reuse-graph', action='store_true',
                    help='--compare: reuse <out>/graph/study.json of an earlier run with the same options')
    ap.add_argument('--no-plots', action='store_true')
    ap.add_argument('--quiet', action='store_true', help='hide the study\'s own output')
    ap.add_argument('--out', type=Path, default=None, help='study output (default a temporary directory)')
    args = ap.parse_args()
    if args.subjects is None:
        args.subjects = 2 if args.compare else 12
    return compare(args) if args.compare else timing(args)


if __name__ == '__main__':
    sys.exit(main())
