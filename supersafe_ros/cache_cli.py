"""`supersafe cache info|clear`: the package's files on disk (``storage``): sizes, counts, where.

``info`` lists the value functions, the cluster values and the learner's run folders.
``clear`` removes the value functions and cluster values (both are solved again when
needed), and the learner's run folders only with ``--runs`` (they hold recorded data);
nothing is removed without ``--yes``: without it, clear says what it would remove.
"""
from __future__ import annotations

from pathlib import Path

from . import storage


def _mb(n: int) -> str:
    """Bytes at 3-4 significant digits, in kB, MB or GB."""
    for unit, scale in (('GB', 1e9), ('MB', 1e6)):
        if n >= scale:
            return f'{n / scale:.3g} {unit}' if n < 100 * scale else f'{n / scale:.0f} {unit}'
    return f'{n / 1e3:.3g} kB'


def add_parser(subparsers):
    parser = subparsers.add_parser('cache', help='the files the package keeps: sizes, counts, where; clear them',
                                   description=__doc__.splitlines()[0])
    parser.add_argument('action', choices=('info', 'clear'))
    parser.add_argument('--cache-dir', type=Path, default=None,
                        help='value-function cache (default $SUPERSAFE_CACHE, else ~/.cache/supersafe_ros)')
    parser.add_argument('--runs-dir', type=Path, default=None,
                        help="the learner's run folders (default $XDG_DATA_HOME or ~/.local/share, "
                             'then supersafe_ros/runs)')
    parser.add_argument('--values', action='store_true', help='clear: the value functions only')
    parser.add_argument('--clusters', action='store_true', help='clear: the cluster values only')
    parser.add_argument('--runs', action='store_true',
                        help="clear: also the learner's run folders (recorded data; those of running "
                             'learners are kept)')
    parser.add_argument('--yes', action='store_true', help='clear: really remove (without it: say what)')
    parser.set_defaults(func=run)
    return parser


def run(args, out=print) -> int:
    places = storage.usage(args.cache_dir, args.runs_dir)
    if args.action == 'info':
        for u in places:
            out(f'{u.what}: {u.entries} in {u.path}, {_mb(u.bytes)} ({u.note})')
        out(f'in all: {_mb(sum(u.bytes for u in places))}')
        return 0
    values, clusters = args.values, args.clusters
    if not (values or clusters or args.runs):
        values = clusters = True              # the caches; never the recorded runs unless asked
    chosen = [(values, places[0]), (clusters, places[1]), (args.runs, places[2])]
    if not args.yes:
        for on, u in chosen:
            if on:
                out(f'would remove {u.what}: {u.entries} in {u.path}, {_mb(u.bytes)}')
        out('nothing removed: add --yes to remove them')
        return 2
    for what, n, freed in storage.clear(args.cache_dir, args.runs_dir, values=values, clusters=clusters,
                                        learner_runs=args.runs):
        out(f'removed {what}: {n}, {_mb(freed)}')
    return 0
