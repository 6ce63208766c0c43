"""The candidate library of value functions, cached on disk by its parameters.

The paper's experiment library: Dubins cars of speed 3 with turn-rate bounds
w_max in {0, 0.125, ..., 1, 1.5, 2, 2.5, 3}, a disc of radius 1.8 at the origin,
3 s horizon, on [-8, 8]^2 x [-pi, pi). Every entry is solved once and kept as an
.npz file whose name is a hash of everything that determines it (problem,
grid, solver version and settings), so a second call only loads.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from .dynamics import DubinsCar
from .grid import Grid
from .sets import Disc
from .solver import SolverSettings, solve_avoid
from .value_function import ValueFunction

# Bump when the solver's numbers change, so stale caches are not reused.
SOLVER_VERSION = 2

PAPER_OMEGAS = (0.0, 0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0, 1.5, 2.0, 2.5, 3.0)


def default_cache_dir() -> Path:
    env = os.environ.get('SUPERSAFE_CACHE')
    if env:
        return Path(env)
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    return Path(base) / 'supersafe_ros'


def _key(grid: Grid, speed, omega_max, radius, horizon, settings: SolverSettings) -> str:
    blob = json.dumps({
        'grid': grid.to_dict(), 'speed': float(speed), 'omega_max': float(omega_max),
        'radius': float(radius), 'horizon': None if horizon is None else float(horizon),
        'settings': settings.to_dict(), 'solver_version': SOLVER_VERSION,
    }, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def load_or_solve(grid: Grid, speed: float, omega_max: float, radius: float, horizon=None,
                  cache_dir=None, settings: SolverSettings | None = None) -> ValueFunction:
    """Avoid value of a disc of ``radius`` at the origin, from the cache or solved and cached
    (``vf.from_cache`` says which, ``vf.cache_path`` where the file is)."""
    settings = settings or SolverSettings()
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    path = cache / f'dubins-{_key(grid, speed, omega_max, radius, horizon, settings)}.npz'
    if path.exists():
        try:
            vf = ValueFunction.load_npz(path)
            vf.from_cache, vf.cache_path = True, path
            return vf
        except (OSError, ValueError, KeyError) as exc:  # a damaged file is solved again
            print(f'supersafe: cached value function {path} unreadable ({exc}); solving again')
    vf = solve_avoid(grid, DubinsCar(speed, omega_max), Disc(0.0, 0.0, radius), horizon, settings)
    cache.mkdir(parents=True, exist_ok=True)
    vf.save_npz(path)
    vf.from_cache, vf.cache_path = False, path
    return vf


@dataclass(frozen=True)
class LibrarySpec:
    speed: float = 3.0
    radius: float = 1.8
    omegas: tuple = PAPER_OMEGAS
    horizon: float | None = 3.0
    lo: tuple = (-8.0, -8.0)
    hi: tuple = (8.0, 8.0)
    shape: tuple = (65, 65, 42)
    settings: SolverSettings = field(default_factory=SolverSettings)

    @property
    def grid(self) -> Grid:
        return Grid(self.lo, self.hi, self.shape)

    def to_dict(self) -> dict:
        return {'speed': self.speed, 'radius': self.radius, 'omegas': list(self.omegas),
                'horizon': self.horizon, 'lo': list(self.lo), 'hi': list(self.hi),
                'shape': list(self.shape)}


@dataclass
class Library:
    spec: LibrarySpec
    entries: list

    @property
    def omegas(self) -> np.ndarray:
        return np.array([e.meta['omega_max'] for e in self.entries])

    def entry(self, omega_max: float) -> ValueFunction:
        i = int(np.argmin(np.abs(self.omegas - omega_max)))
        if abs(self.omegas[i] - omega_max) > 1e-9:
            raise KeyError(f'no library entry with omega_max={omega_max}; have {list(self.omegas)}')
        return self.entries[i]


def load_or_build_library(spec: LibrarySpec | None = None, cache_dir=None, progress=None) -> Library:
    """Every entry of ``spec`` from the cache, solving (and caching) the missing ones."""
    spec = spec or LibrarySpec()
    grid = spec.grid
    entries = []
    for w in sorted(spec.omegas):
        entries.append(load_or_solve(grid, spec.speed, w, spec.radius, spec.horizon,
                                     cache_dir, spec.settings))
        if progress:
            progress(w, entries[-1])
    return Library(spec, entries)
