#!/usr/bin/env python3
"""Speed of the supervisor-safe-set estimators (issue 3), and optionally how often they
recover synthetic supervisors.

* paper's estimator: 13 library entries x 1,000 intervention states (target < 50 ms);
* first-passage estimator: 13 entries x 200 Phase II encounters (target < 2 s), split
  into evaluating the entries along the frames and maximising over (mu, sigma).

The library is the paper's (speed 3, radius 1.8, horizon 3, 65 x 65 x 42), from the
reachability core's cache (built on first use). Times are the median of --repeats runs,
wall clock, on whatever else the machine is doing.

    .venv/bin/python bench/bench_fit.py [--repeats 7] [--recovery --seeds 20]
"""
from __future__ import annotations

import argparse
from pathlib import Path
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from supersafe_ros.learning import estimators as E  # noqa: E402
from supersafe_ros.learning.data import PHASE2_OFFSETS, intervention_states, phase2_encounters  # noqa: E402
from supersafe_ros.learning.supervisor import NoisySupervisor  # noqa: E402
from supersafe_ros.reach.library import LibrarySpec, load_or_build_library  # noqa: E402

RECOVERY_CASES = [(0.5, 1.0, 0.3), (0.25, 0.5, 0.2), (0.75, 0.3, 0.1), (1.0, 0.8, 0.2),
                  (1.0, 0.8, 0.4), (1.5, 1.2, 0.3), (2.0, 1.5, 0.5)]


def timed(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), min(times), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--repeats', type=int, default=7)
    ap.add_argument('--shape', type=int, nargs=3, default=(65, 65, 42))
    ap.add_argument('--cache-dir', default=None)
    ap.add_argument('--recovery', action='store_true',
                    help='also fit synthetic supervisors over several seeds and print recovery rates')
    ap.add_argument('--seeds', type=int, default=20)
    ap.add_argument('--passes', type=int, default=209, help='Phase II passes per synthetic data set')
    ap.add_argument('--pilots', metavar='DIR', default=None,
                    help='also print the table of fits to DIR/pilot{1..5}_interventions.csv (markdown)')
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    lib = load_or_build_library(LibrarySpec(shape=tuple(args.shape)), cache_dir=args.cache_dir)
    print(f'library: {len(lib.entries)} entries on {tuple(args.shape)}, loaded in '
          f'{time.perf_counter() - t0:.2f} s')
    rng = np.random.default_rng(0)
    entries = lib.entries

    # -- paper's estimator: 1,000 interventions drawn from a synthetic supervisor -----------
    sup = NoisySupervisor(lib.entry(0.75), 0.6, 0.3, rng=rng)
    enc = phase2_encounters(sup, np.tile(PHASE2_OFFSETS, 60))
    states = intervention_states(enc)[:1000]
    med, best, res = timed(lambda: E.fit_paper(entries, states, true_vf=lib.entry(1.0)), args.repeats)
    print(f'paper estimator, {len(entries)} entries x {len(states)} interventions: '
          f'median {1e3 * med:.1f} ms (best {1e3 * best:.1f} ms; target < 50 ms)  '
          f'-> omega_max {res.omega_max:g}')

    # -- first passage: 200 encounters ---------------------------------------------------------
    sup = NoisySupervisor(lib.entry(0.5), 1.0, 0.3, rng=rng)
    enc = phase2_encounters(sup, rng.choice(PHASE2_OFFSETS, 200))
    frames = sum(len(e.states) for e in enc)
    med, best, res = timed(lambda: E.fit_first_passage(entries, enc, true_vf=lib.entry(1.0)),
                           args.repeats)
    med_iv, _, iv = timed(lambda: E.encounter_intervals(entries, enc), args.repeats)
    med_mx, _, _ = timed(lambda: E.maximise_first_passage(iv), args.repeats)
    print(f'first-passage estimator, {len(entries)} entries x {len(enc)} encounters ({frames} frames): '
          f'median {1e3 * med:.0f} ms (best {1e3 * best:.0f} ms; target < 2 s)  '
          f'[values along frames {1e3 * med_iv:.0f} ms, maximisation {1e3 * med_mx:.0f} ms]  '
          f'-> omega_max {res.omega_max:g}, mu {res.mu:.3f}, sigma {res.sigma:.3f} (true 0.5, 1.0, 0.3)')

    if args.recovery:
        reps = int(np.ceil(args.passes / len(PHASE2_OFFSETS)))
        offsets = np.tile(PHASE2_OFFSETS, reps)[:args.passes]
        print(f'\nrecovery over {args.seeds} seeds, {len(offsets)} Phase II passes each '
              f'(no prior): exact omega_max hits, and the spread of mu, sigma when hit')
        for w, mu, sigma in RECOVERY_CASES:
            hits_p = hits_f = 0
            err = []
            for seed in range(args.seeds):
                s = NoisySupervisor(lib.entry(w), mu, sigma, rng=seed)
                e = phase2_encounters(s, offsets)
                p = E.fit_paper(entries, intervention_states(e))
                f = E.fit_first_passage(entries, e)
                hits_p += p.omega_max == w
                hits_f += f.omega_max == w
                if f.omega_max == w:
                    err.append((f.mu - mu, f.sigma / sigma - 1.0))
            err = np.array(err).reshape(-1, 2)
            spread = (f'max |mu err| {np.abs(err[:, 0]).max():.3f}, max |sigma rel err| '
                      f'{np.abs(err[:, 1]).max():.3f}') if len(err) else ''
            print(f'  omega_max {w:<5g} mu {mu:<4g} sigma {sigma:<4g}: paper {hits_p:2d}/{args.seeds}, '
                  f'first-passage {hits_f:2d}/{args.seeds}  {spread}', flush=True)
    if args.pilots:
        print()
        print(pilot_table(lib, args.pilots))
    return 0


def _fp_fit(entries, enc, true_vf):
    """Conditional first-passage fit; with a 1 % lapse only when the pure model rules
    out every admissible entry (an intervention no entry can explain)."""
    try:
        return E.fit_first_passage(entries, enc, true_vf=true_vf, conditional=True), 0.0
    except ValueError:
        return E.fit_first_passage(entries, enc, true_vf=true_vf, conditional=True, lapse=0.01), 0.01


def _margin(r) -> float:
    """Log-likelihood lead of the chosen entry over the best other admissible one."""
    others = [c['log_likelihood'] for i, c in enumerate(r.candidates)
              if i != r.index and c['admissible'] and np.isfinite(c['log_likelihood'])]
    return r.log_likelihood - max(others) if others else float('inf')


def pilot_table(lib, folder) -> str:
    """Markdown table: each pilot fitted by both estimators, with and without the prior;
    cells are omega_max, mu, sigma [log-likelihood lead over the runner-up]."""
    from supersafe_ros.learning.data import encounters_from_phase2_interventions, read_interventions_csv
    true = lib.entry(1.0)
    rows = ['| pilot | n | paper, prior (w, mu, sigma) | paper, no prior | first-passage, prior | '
            'first-passage, no prior | FP impossible | pred. FP (paper, prior) |',
            '|---|---|---|---|---|---|---|---|']
    for n in range(1, 6):
        path = Path(folder) / f'pilot{n}_interventions.csv'
        if not path.exists():
            rows.append(f'| {n} | (missing: {path}) |||||||')
            continue
        s = read_interventions_csv(path)
        enc = encounters_from_phase2_interventions(s)
        pp = E.fit_paper(lib.entries, s, true_vf=true)
        pn = E.fit_paper(lib.entries, s)
        fp, lp = _fp_fit(lib.entries, enc, true)
        fn, ln = _fp_fit(lib.entries, enc, None)
        imp = sorted({c['impossible_interventions'] for c in fn.candidates if c['omega_max'] > 0})

        def cell(r, lapse):
            return (f'{r.omega_max:g}, {r.mu:.2f}, {r.sigma:.2f} [{_margin(r):.1f}]'
                    + (f' (lapse {lapse:g})' if lapse else ''))
        pred = E.predicted_false_positive_fraction(pp.value_function, pp.alpha, s)
        rows.append(f'| {n} | {len(s)} | {cell(pp, 0)} | {cell(pn, 0)} | {cell(fp, lp)} | '
                    f'{cell(fn, ln)} | {"/".join(map(str, imp))} | {pred:.0%} |')
    return '\n'.join(rows)


if __name__ == '__main__':
    sys.exit(main())
