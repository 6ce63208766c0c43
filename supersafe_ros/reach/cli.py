"""`supersafe reach`, `supersafe library` and `supersafe convert`."""
from __future__ import annotations

import sys
import time

from .dynamics import DubinsCar
from .grid import Grid
from .library import LibrarySpec, PAPER_OMEGAS, default_cache_dir, load_or_build_library
from .sets import Disc, keepout_from_discs
from .solver import solve_avoid
from .value_function import ValueFunction


def add_grid_args(p, lo=(-8.0, -8.0), hi=(8.0, 8.0), shape=(65, 65, 42)):
    p.add_argument('--grid-min', nargs=2, type=float, default=list(lo), metavar=('XMIN', 'YMIN'))
    p.add_argument('--grid-max', nargs=2, type=float, default=list(hi), metavar=('XMAX', 'YMAX'))
    p.add_argument('--shape', nargs=3, type=int, default=list(shape), metavar=('NX', 'NY', 'NTH'))


def add_parser(sub) -> None:
    p = sub.add_parser('reach', help='avoid value of a Dubins car for discs (HJI, to .npz)',
                       description='V(x) = max_u min_{t<=T} l(x(t)) for x\' = v cos th, '
                       'y\' = v sin th, th\' = u, |u| <= w_max; l = signed distance to the discs.')
    p.add_argument('--speed', type=float, required=True)
    p.add_argument('--omega-max', type=float, required=True)
    p.add_argument('--radius', type=float, help='a disc of this radius at the origin')
    p.add_argument('--disc', nargs=3, type=float, action='append', metavar=('X', 'Y', 'R'),
                   help='a disc of the keep-out set (repeatable)')
    p.add_argument('--horizon', type=float, help='seconds; without it, solve to convergence')
    add_grid_args(p)
    p.add_argument('--out', required=True, help='FILE.npz (or FILE.json for helperOC format)')
    p.set_defaults(func=run_reach)

    p = sub.add_parser('library', help='build or load the cached candidate library')
    p.add_argument('--speed', type=float, default=3.0)
    p.add_argument('--radius', type=float, default=1.8)
    p.add_argument('--horizon', type=float, default=3.0)
    p.add_argument('--omega-max', nargs='+', type=float, default=list(PAPER_OMEGAS), dest='omegas')
    add_grid_args(p)
    p.add_argument('--cache-dir', default=None, help=f'default: {default_cache_dir()}')
    p.add_argument('--plot', metavar='FILE.png', help='zero level sets at theta = 0')
    p.set_defaults(func=run_library)

    p = sub.add_parser('convert', help='convert a value function between .npz and helperOC .json')
    p.add_argument('src')
    p.add_argument('dst')
    p.set_defaults(func=run_convert)


def _load_any(path) -> ValueFunction:
    if str(path).endswith('.json'):
        return ValueFunction.load_helperoc_json(path)
    return ValueFunction.load_npz(path)


def _save_any(vf: ValueFunction, path) -> None:
    if str(path).endswith('.json'):
        vf.save_helperoc_json(path)
    else:
        vf.save_npz(path)


def run_reach(args) -> int:
    discs = [Disc(*d) for d in (args.disc or [])]
    if args.radius is not None:
        discs.insert(0, Disc(0.0, 0.0, args.radius))
    if not discs:
        print('supersafe reach: give --radius R or at least one --disc X Y R', file=sys.stderr)
        return 2
    try:
        grid = Grid(tuple(args.grid_min), tuple(args.grid_max), tuple(args.shape))
        dyn = DubinsCar(args.speed, args.omega_max)
        vf = solve_avoid(grid, dyn, keepout_from_discs(discs), args.horizon)
    except ValueError as exc:
        print(f'supersafe reach: {exc}', file=sys.stderr)
        return 2
    _save_any(vf, args.out)
    m = vf.meta
    if args.horizon is None:
        state = 'converged' if m['converged'] else 'did NOT converge'
        print(f'{state} after {m["steps"]} steps ({m["time_reached"]:.2f} s of horizon, '
              f'last change {m["last_change"]:.2e})')
    print(f'solved {grid.shape} in {m["solve_time_s"]:.2f} s; V in [{vf.values.min():.3f}, '
          f'{vf.values.max():.3f}]; wrote {args.out}')
    return 0


def run_library(args) -> int:
    spec = LibrarySpec(speed=args.speed, radius=args.radius, omegas=tuple(args.omegas),
                       horizon=args.horizon, lo=tuple(args.grid_min), hi=tuple(args.grid_max),
                       shape=tuple(args.shape))
    t0 = time.perf_counter()
    lib = load_or_build_library(
        spec, args.cache_dir,
        progress=lambda w, vf: print(
            f'  w_max {w:6.3f}: ' + ('cached' if getattr(vf, 'from_cache', False)
                                     else f'solved in {vf.meta["solve_time_s"]:.2f} s'), flush=True))
    print(f'library of {len(lib.entries)} entries ready in {time.perf_counter() - t0:.2f} s '
          f'(cache: {args.cache_dir or default_cache_dir()})')
    if args.plot:
        from .plots import plot_library
        plot_library(lib, args.plot)
        print(f'wrote {args.plot}')
    return 0


def run_convert(args) -> int:
    try:
        vf = _load_any(args.src)
    except (OSError, ValueError, KeyError) as exc:
        print(f'supersafe convert: cannot read {args.src}: {exc}', file=sys.stderr)
        return 2
    _save_any(vf, args.dst)
    print(f'wrote {args.dst} ({vf.grid.shape})')
    return 0
