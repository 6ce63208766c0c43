"""The study's disc robots decide as before: six core-engine games, step by step, in each checkout
(prints digests; no assertions, no files).

    .venv/bin/python bench/bench_same_games.py                       # this checkout
    .venv/bin/python bench/bench_same_games.py --checkout /work/base .

Six games of the study's core engine (``study.engine.CoreStudy.play``: two robots, the pilot-like
subject, Standard, Conservative and a learned set of w_max 0.5, on two worlds each, 40 s at a 0.2 s
step), run in a process per checkout with PYTHONPATH = that checkout. For each game it prints
the stats, the interventions, the decisions' counts and a SHA-256 of every robot's state at every
step (``TeamLoop.record``: the states come from the commands, so equal digests mean the same
commands step after step) and of the game's trace (override onsets, interventions). The core
engine is deterministic: equal lines mean the same games.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
from pathlib import Path
import subprocess
import sys

HERE = Path(__file__).resolve().parent
GAMES = (('standard', 3), ('standard', 4), ('conservative', 3), ('conservative', 5), ('learned', 3),
         ('learned', 6))


def play_all() -> list:
    """Play the six games in this process (the supersafe_ros on sys.path); one record each."""
    import numpy as np
    from supersafe_ros.reach.library import LibrarySpec, load_or_build_library
    from supersafe_ros.sim import team_loop
    from supersafe_ros.study import engine
    from supersafe_ros.study.population import Subject
    from supersafe_ros.study.protocol import StudyOptions

    recorded = []
    original = team_loop.TeamLoop.__init__

    def recording(self, *args, **kwargs):        # every game's loop keeps its per-step states
        original(self, *args, **kwargs)
        self.record = True
        recorded.append(self)

    team_loop.TeamLoop.__init__ = recording
    core = engine.CoreStudy()
    subject = Subject(0, 0.75, 0.5, 0.2, 1234)
    opts = StudyOptions(step=0.2, game_seconds=40.0)
    library = load_or_build_library(LibrarySpec())
    learned_vf = library.entry(0.5)
    out = []
    for condition, seed in GAMES:
        if condition == 'learned':
            safe, _, _ = core.safe_set('learned_paper', {'learned_paper': (learned_vf, {'mu': 0.3, 'sigma': 0.2})})
        else:
            safe, _, _ = core.safe_set(condition, {})
        result = core.play(subject, seed, safe, opts)
        loop = recorded[-1]
        states = hashlib.sha256()
        for t, s in loop.trace:
            states.update(np.asarray([t], dtype=float).tobytes())
            states.update(np.ascontiguousarray(s, dtype=float).tobytes())
        trace = hashlib.sha256(json.dumps(result['trace'], sort_keys=True, default=str).encode()).hexdigest()
        out.append({'game': f'{condition} world {seed}', 'set': safe.source, 'steps': result['steps'],
                    'decisions': result['decisions'], 'stats': result['stats'],
                    'interventions': result['interventions'], 'states': states.hexdigest()[:16],
                    'trace': trace[:16]})
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--checkout', nargs='+', default=[str(HERE.parent)], help='checkouts to compare')
    ap.add_argument('--worker', action='store_true', help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(play_all()))
        return 0
    results = {}
    for checkout in args.checkout:
        env = dict(os.environ, PYTHONPATH=str(Path(checkout).resolve()))
        env.setdefault('SUPERSAFE_CACHE', str(HERE.parent / '.cache' / 'test-values'))
        done = subprocess.run([sys.executable, __file__, '--worker'], env=env, capture_output=True, text=True,
                              cwd=str(Path(checkout).resolve()))
        if done.returncode:
            print(done.stderr[-2000:])
            return 1
        commit = subprocess.run(['git', '-C', checkout, 'rev-parse', '--short', 'HEAD'], capture_output=True,
                                text=True).stdout.strip()
        results[checkout] = (commit, json.loads(done.stdout.strip().splitlines()[-1]))
    print(f'{"game":24s} ' + ' '.join(f'{c:>36s}' for c, _ in results.values()))
    rows = list(zip(*(games for _, games in results.values())))
    for games in rows:
        cells = [f'{g["steps"]} steps, {sum(g["decisions"].values())} decisions, '
                 f'{len(g["interventions"])} interventions, states {g["states"]}, trace {g["trace"]}' for g in games]
        same = all(json.dumps(g, sort_keys=True) == json.dumps(games[0], sort_keys=True) for g in games)
        print(f'{games[0]["game"]:24s} ' + ' | '.join(cells) + ('   same' if same else '   DIFFERENT'))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
