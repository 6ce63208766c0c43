"""One avoid value for everything the local map holds: solved over a window, in the background.

The problem. A Dubins car (speed v, turn bound w) and the map's occupied cells grown by the
robot's radius ``clearance``: l = ``reach.field.occupancy_field`` (the distance to the nearest
occupied cell's centre less the cell's half diagonal and the clearance, a lower bound of the
true clearance at the field's nodes, bilinear between them), and

    V(x) = max over u(.) of min over t in [0, T] of l(x(t)),   T = ``horizon``,

by ``reach.solver.AvoidSolver`` over a window of the plane about the robot, in map coordinates:
the "obstacle" is at the origin, so a filter reads V and dV/dtheta at the robot's own state.
One value for the union of everything seen: a door is as wide as it is, not a heap of discs.

The window. Value nodes lie on the world-fixed lattice map_cell/2 + cell (i, j): with ``cell`` a
multiple of the map's cell they are cell centres, where l is the field's own node value (no
interpolation term). The window is centred on the node nearest the centre asked for and has
half-width h = n cell. The solver pads its grid and holds l there, not V_n: a node within the
rim distance r_dep of the edge (``AvoidSolver.rim_distance``: the sum over the steps but the
first of each step's farthest read, about v T plus up to a cell a step) may read that rim; a
node farther in has the value of an unbounded grid. So n is the least with h >= ``reach`` +
r_dep (capped by ``max_half_width``; a cap that leaves nothing sound is refused), and V is the
value over the whole map within ``MapValue.sound_half_width`` = h - r_dep >= ``reach`` of the
centre (``MapValue.covers``). ``reach`` is the robot's room: where it may be when the value is
read. The worker keeps a window while the robot is within ``recentre`` of its centre, so
reach - recentre is the travel between a submit and the read (robot (1) below: 1 m, 2 s).
A step that reads just under a whole number of cells spreads least: at v 3, w 1, cell 0.25,
32 headings need the solver's 2x heading refinement (steps of 0.098 s, 1.18 cells: r_dep 15 m
for v T = 9 m), 38 do not (0.165 s, 1.98 cells: r_dep 9 m); 6x less work for the same reach.
The field covers everything the solver reads (``AvoidSolver.read_bounds``), from the map padded
with free cells, the distance transform over the whole map: no occupied cell outside the
window is missed, and the field's ``outside`` is never read.

Re-solving. The issue asked for a re-solve "warm-started from the last one":

* A warm start from the last V is not a value of horizon T. The step operator G_l (V_n+1 =
  G_l V_n, V_0 = l, V_T = G_l^N(l)) is monotone, and G_l V <= l. From the previous value W, m
  steps with the map unchanged give G_l^m(V_T) = V_(T + m dt): a longer horizon, lower, and lower
  again at every re-solve; where the map cleared a cell, W <= l_old < l_new there, and
  G_l^m(W) <= G_l^m(l_new) stays below the cleared map's value wherever a trajectory ends near
  the old obstacle: an iteration from below never recovers. And G_l^N(W) <= G_l^N(l) = V_T for
  any W <= l: N steps from W are conservative, stale, and cost what N steps from l cost. Not done.
* (a) An exact incremental re-solve: V_n at a node depends on l only within its numerical
  domain of dependence, so one could keep each step's layer and recompute only what a change
  can reach. ``bench/bench_map_value.py`` propagates that region exactly (through the solver's
  own gathers and path minima) for robot (1) driving 6 m through two rooms, a 360-beam scan
  every 0.1 s: with 1 cm range noise (surfaces flicker by a cell, as a Nav2 obstacle layer's
  do) every scan changed the window's field, and an incremental re-solve would redo a median
  84 % of the steps' work (p10 70 %); 53 % of the nodes did change. Noise-free, a median 3
  cells change per scan; 39 of 90 such scans left the field in the window as it was (no solve,
  below), and the rest would redo a median 4 % (p90 32 %). The realistic case does not pay,
  and the other is already cheap (tens of ms, below): not built.
* (b) Reuse of what does not depend on the map: one ``AvoidSolver`` per (speed, w, window
  shape), its step plans, gather indices, weights and padded buffer kept across solves and
  window moves; each solve computes the field, l, the path minima and the steps from l.
* (c) No solve when nothing changed: the same occupancy (contents, origin, cell), window, w,
  speed and clearance as the last solve keep the last value (its ``stamp`` and version
  updated). Nor when the map changed beyond the window's reach: a solve reads l only through
  the window's field, so the same field on the same lattice and the same problem give the
  same value (``solve_map_value(..., previous=...)``: the field costs ~2 ms, a solve ~35).

Figures (``bench/bench_map_value.py``, two runs in bench/results/map_value.md; this 2-core
machine beside other work, load 1.5-2.2): robot (1) (v 0.5, w 1, clearance 0.25, map cell
0.05, value cell 0.1, 32 headings, T 3 s, reach 1.5 m): window half-width 2.9 m (59 x 59 x 32
nodes, 8 steps); first solve 37-40 ms, re-solve after five cells changed 31-36 ms, after the
window moved 0.5 m 32-39 ms, nothing changed 0.05 ms, a change beyond the window's reach 2 ms.
Robot (2) (v 3, w 1, clearance 0.1, map cell 0.2, value cell 0.25, 38 headings, reach 3 m):
half-width 12 m (97 x 97 x 38, 19 steps): 166-174, 149-159, 146-156 ms, 0.05 ms, 0.7 ms (at 32
headings: half-width 18 m, 0.8-1.2 s). Reuse (b) saves 1-5 ms of robot (1)'s solve and 7-11 ms
of robot (2)'s; the field's separable path (``reach.field``) ~60 ms of robot (1)'s (91-98 ms
through the general bilinear path).

``MapValueWorker`` solves in a daemon thread, latest wins: a submit while a solve runs replaces
the pending request (one slot, never a queue); ``latest()`` is a reference read. numpy releases
the GIL only inside large array operations, so the threads share it: a ~1 ms pure-Python loop
of value reads beside a worker solving robot (1)'s window continuously kept its p50 and p90
(0.7-1.0 ms); its p99 went from 2.2 to 2.3 ms and its max from 8.2 to 5.0 ms in alternated
blocks (a sequential run: p99 4.9 -> 5.1 ms, max 8.9 -> 97 ms; the machine's other load moves
these more than the solve does), and the solve took 72 ms beside the loop against 27 alone.
``inline=True`` solves in the caller's thread instead (deterministic trials and tests).
"""
from __future__ import annotations

from dataclasses import dataclass, field as dataclass_field, replace
import math
import threading
import time

import numpy as np

from ...reach.dynamics import DubinsCar
from ...reach.field import FREE, FieldKeepout, occupancy_field
from ...reach.grid import Grid
from ...reach.solver import AvoidSolver, SolverSettings
from ...reach.value_function import ValueFunction

MAX_ERRORS = 64          # errors kept by a worker (the count goes on)
THREAD_NAME = 'map_value'     # the worker's thread, by this name in top -H and /proc/<pid>/task/*/comm


def _name_os_thread(name: str) -> None:
    """Give the calling thread ``name`` in the kernel too (Linux prctl PR_SET_NAME), so that its CPU can be
    told from the rest of the process (``top -H``, a benchmark reading /proc); elsewhere nothing."""
    try:
        import ctypes
        ctypes.CDLL(None).prctl(15, name.encode()[:15], 0, 0, 0)
    except (OSError, AttributeError):
        pass


@dataclass(frozen=True)
class MapArrays:
    """A map snapshot as plain arrays (what ``LocalMap.snapshot()`` gives; any object with these
    attributes will do): cell (i, j) covers [x0 + i cell, x0 + (i+1) cell) x [y0 + j cell, ...)."""

    origin: tuple
    cell: float
    occupied: np.ndarray
    version: int = 0


@dataclass(frozen=True)
class MapValueSettings:
    """The window's value: grid spacing ``cell`` (m), ``headings``, ``horizon`` (s); ``reach`` (m): how far
    (along x and y) from the window's centre the robot may be with its value sound; the window's
    half-width is reach + the solver's rim distance (~ speed horizon), at most ``max_half_width``;
    ``recentre`` (m): the worker keeps a window while the robot is within this of its centre."""

    cell: float = 0.1
    headings: int = 32
    horizon: float = 3.0
    reach: float = 1.5
    recentre: float = 0.5
    max_half_width: float = 15.0
    solver: SolverSettings = SolverSettings()

    def __post_init__(self):
        for name in ('cell', 'horizon', 'reach', 'max_half_width'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f'MapValueSettings.{name} must be a positive finite number, got {value!r}')
        if not (isinstance(self.recentre, (int, float)) and 0 <= self.recentre <= self.reach):
            raise ValueError(f'MapValueSettings.recentre must be in [0, reach = {self.reach}], got {self.recentre!r}')
        if not (isinstance(self.headings, int) and 3 <= self.headings <= 1024):
            raise ValueError(f'MapValueSettings.headings must be an integer in [3, 1024], got {self.headings!r}')
        if self.max_half_width < self.cell:
            raise ValueError(f'MapValueSettings.max_half_width ({self.max_half_width}) is below one cell ({self.cell})')


@dataclass(frozen=True)
class MapValue:
    """The window's value ``vf`` (a ValueFunction in map coordinates), the map ``version`` solved, the
    window's ``centre``, ``omega_max``, ``solve_s`` (s, the field and the solve) and ``stamp`` (the
    snapshot's time, as passed in); ``keepout`` the window's field it was solved from (l itself, e.g.
    the robot's clearance now), ``problem`` what else it depends on (speed, w, clearance, settings)."""

    vf: ValueFunction
    version: object
    centre: tuple
    omega_max: float
    solve_s: float
    stamp: object = None
    keepout: FieldKeepout | None = dataclass_field(default=None, repr=False, compare=False)
    problem: tuple = dataclass_field(default=(), repr=False, compare=False)

    @property
    def sound_half_width(self) -> float:
        """Along x and y from ``centre``: where V is that of the whole map (module docstring)."""
        return self.vf.meta['window']['sound_half_width']

    def covers(self, x: float, y: float) -> bool:
        """Whether V at (x, y) is sound: within ``sound_half_width`` of the centre along x and y."""
        h = self.sound_half_width
        return abs(x - self.centre[0]) <= h and abs(y - self.centre[1]) <= h


def value_lattice_node(centre_xy, map_cell: float, cell: float) -> tuple:
    """The node of the value lattice map_cell/2 + cell (i, j) nearest ``centre_xy``."""
    anchor = 0.5 * map_cell
    return tuple(anchor + cell * round((float(c) - anchor) / cell) for c in centre_xy)


class _Windows:
    """An AvoidSolver per (speed, w, window) and the window's geometry, kept across solves."""

    def __init__(self):
        self.key, self.solver, self.n, self.sound = None, None, None, None

    def get(self, speed, omega_max, settings: MapValueSettings):
        key = (float(speed), float(omega_max), settings)
        if key != self.key:
            dyn = DubinsCar(speed, omega_max)
            c = settings.cell
            probe = AvoidSolver(Grid((-c, -c), (c, c), (3, 3, settings.headings)), dyn, settings.solver)
            rim = probe.rim_distance(settings.horizon)
            n = max(1, math.ceil((settings.reach + rim) / c - 1e-9))
            n = min(n, int(math.floor(settings.max_half_width / c + 1e-9)))
            sound = n * c - rim
            if sound < 0.0:
                raise ValueError(f'a window of half-width {n * c:.3g} m (max_half_width) cannot hold the rim distance '
                                 f'{rim:.3g} m of speed {speed} over {settings.horizon} s: no state would be sound')
            grid = Grid((-n * c, -n * c), (n * c, n * c), (2 * n + 1, 2 * n + 1, settings.headings))
            self.solver, self.n = AvoidSolver(grid, dyn, settings.solver), n
            self.sound = n * c - self.solver.rim_distance(settings.horizon)     # the same, up to rounding
            self.key = key
        return self.solver, self.n, self.sound


def window_half_widths(speed: float, omega_max: float, settings: MapValueSettings | None = None) -> tuple:
    """(half-width, sound half-width) in metres of the window ``solve_map_value`` solves over."""
    settings = settings or MapValueSettings()
    _, n, sound = _Windows().get(speed, omega_max, settings)
    return n * settings.cell, sound


def _window_field(snapshot, clearance, bounds) -> FieldKeepout:
    """The occupancy field over ``bounds`` ((x_min, y_min), (x_max, y_max)), from the map padded with free
    cells to cover them; the distance transform runs over the whole map (cells outside the bounds count)."""
    occupied = np.asarray(snapshot.occupied, dtype=bool)
    cell = float(snapshot.cell)
    ox, oy = float(snapshot.origin[0]), float(snapshot.origin[1])
    (x0, y0), (x1, y1) = bounds
    # centres (origin + cell (i + 1/2)) from one below x_min to one above x_max
    first = (math.floor((x0 - ox) / cell - 0.5) - 1, math.floor((y0 - oy) / cell - 0.5) - 1)
    last = (math.ceil((x1 - ox) / cell - 0.5) + 1, math.ceil((y1 - oy) / cell - 0.5) + 1)
    before = [max(0, -f) for f in first]
    after = [max(0, end + 1 - n) for end, n in zip(last, occupied.shape)]
    padded = np.pad(occupied, ((before[0], after[0]), (before[1], after[1])))
    lo, values = occupancy_field((ox - before[0] * cell, oy - before[1] * cell), cell, padded, clearance)
    i0, j0 = first[0] + before[0], first[1] + before[1]
    i1, j1 = last[0] + before[0] + 1, last[1] + before[1] + 1
    return FieldKeepout((lo[0] + i0 * cell, lo[1] + j0 * cell), cell, values[i0:i1, j0:j1], outside=FREE)


def _check_snapshot(snapshot):
    occupied = np.asarray(snapshot.occupied)
    cell = float(snapshot.cell)
    if occupied.ndim != 2 or min(occupied.shape) < 2:
        raise ValueError(f'a map snapshot needs a 2-D occupancy of at least 2 x 2 cells, got shape {occupied.shape}')
    if not (math.isfinite(cell) and cell > 0):
        raise ValueError(f'a map snapshot needs a positive finite cell, got {snapshot.cell!r}')
    if len(snapshot.origin) != 2 or not all(math.isfinite(float(v)) for v in snapshot.origin):
        raise ValueError(f'a map snapshot needs a finite origin (x0, y0), got {snapshot.origin!r}')


def solve_map_value(snapshot, centre_xy, speed: float, omega_max: float, clearance: float,
                    settings: MapValueSettings | None = None, stamp=None, previous: MapValue | None = None,
                    _windows: _Windows | None = None) -> MapValue:
    """The avoid value of the map's occupancy over the window centred on the value node nearest
    ``centre_xy`` (module docstring), for a Dubins car of ``speed`` and turn bound ``omega_max``
    keeping ``clearance`` (m) from every occupied cell. If ``previous`` was solved from the same
    window's field for the same problem, it is returned (with this ``stamp`` and version) unsolved."""
    settings = settings or MapValueSettings()
    t0 = time.perf_counter()
    _check_snapshot(snapshot)
    if not (math.isfinite(clearance) and clearance >= 0):
        raise ValueError(f'clearance must be a non-negative finite number of metres, got {clearance!r}')
    if len(centre_xy) != 2 or not all(math.isfinite(float(v)) for v in centre_xy):
        raise ValueError(f'the window centre must be a finite (x, y), got {centre_xy!r}')
    windows = _windows or _Windows()
    solver, n, sound = windows.get(speed, omega_max, settings)
    centre = value_lattice_node(centre_xy, float(snapshot.cell), settings.cell)
    half = n * settings.cell
    lo = (centre[0] - half, centre[1] - half)
    field = _window_field(snapshot, clearance, solver.read_bounds(lo))
    version = getattr(snapshot, 'version', None)
    problem = (float(speed), float(omega_max), float(clearance), settings)
    if (previous is not None and previous.problem == problem and previous.keepout is not None
            and previous.keepout.lo == field.lo and previous.keepout.shape == field.shape
            and np.array_equal(previous.keepout.values, field.values)):
        return replace(previous, stamp=stamp, version=version)
    vf = solver.solve(field, settings.horizon, lo=lo)
    solve_s = time.perf_counter() - t0
    vf.meta.update({
        'keepout': {'type': 'occupancy', 'clearance': float(clearance), 'map_cell': float(snapshot.cell)},
        'clearance': float(clearance),
        'window': {'centre': list(centre), 'half_width': half, 'cell': settings.cell,
                   'sound_half_width': sound, 'reach': settings.reach},
        'map': {'version': version if isinstance(version, (int, float, str)) or version is None else str(version),
                'origin': [float(v) for v in snapshot.origin], 'cell': float(snapshot.cell),
                'shape': list(np.shape(snapshot.occupied))},
        'solve_time_s': solve_s,
        'field_free': FREE,
    })
    return MapValue(vf, version, centre, float(omega_max), solve_s, stamp, field, problem)


@dataclass(frozen=True)
class _Request:
    snapshot: MapArrays
    centre: tuple
    omega_max: float
    stamp: object


class MapValueWorker:
    """Solves the window's value as the map changes: in a daemon thread (latest wins), or with
    ``inline=True`` at once in the caller's thread; with ``process=True`` the thread hands each solve
    to a spawned worker process (its solver kept there across solves) and waits for it without the
    GIL: the solve's Python steps then never hold the caller's process against its control path (a
    35 ms solve in a thread of the filter's process raised the sensor -> cmd_vel p99 from 3 to 6 ms;
    bench/results/sensors.md), and the value comes back pickled (0.5 MB). A worker that cannot be
    started or breaks: the solves run in the thread, as without it. ``latest()`` the newest MapValue or None;
    ``errors`` the texts of failed solves (the last MAX_ERRORS), ``error`` the newest; counts
    ``submitted``, ``solved``, ``skipped`` (nothing changed within the window's reach: the last value
    kept, restamped), ``replaced`` (a pending request
    overtaken by a newer one)."""

    def __init__(self, speed: float, omega_max: float, clearance: float,
                 settings: MapValueSettings | None = None, inline: bool = False, process: bool = False):
        DubinsCar(speed, omega_max)                     # the same checks as the solve's, here
        if not (math.isfinite(clearance) and clearance >= 0):
            raise ValueError(f'clearance must be a non-negative finite number of metres, got {clearance!r}')
        self.speed, self.omega_max, self.clearance = float(speed), float(omega_max), float(clearance)
        self.settings = settings or MapValueSettings()
        self.inline = inline
        self.process = bool(process) and not inline     # the solves in a worker process (see the class)
        self._pool = None
        self.errors: list[str] = []
        self.error = ''
        self.submitted = self.solved = self.skipped = self.replaced = self.error_count = 0
        self._latest = None
        self._last_key = None
        self._centre = None
        self._windows = _Windows()
        self._wake = threading.Condition()
        self._pending = None
        self._closed = False
        self._thread = None
        if not inline:
            self._thread = threading.Thread(target=self._run, name=THREAD_NAME, daemon=True)
            self._thread.start()

    def latest(self) -> MapValue | None:
        """The newest value solved (a reference read)."""
        return self._latest

    def submit(self, snapshot, centre_xy, omega_max: float | None = None, stamp=None) -> None:
        """Ask for the value of ``snapshot`` (copied) around the robot at ``centre_xy``: the window
        moves only when the robot is farther than ``settings.recentre`` from its centre."""
        snapshot = MapArrays(tuple(float(v) for v in snapshot.origin), float(snapshot.cell),
                             np.array(snapshot.occupied, dtype=bool), getattr(snapshot, 'version', None))
        centre = (float(centre_xy[0]), float(centre_xy[1]))
        kept = self._centre
        if (kept is None or abs(centre[0] - kept[0]) > self.settings.recentre
                or abs(centre[1] - kept[1]) > self.settings.recentre):
            kept = self._centre = value_lattice_node(centre, snapshot.cell, self.settings.cell)
        request = _Request(snapshot, kept, self.omega_max if omega_max is None else float(omega_max), stamp)
        self.submitted += 1
        if self.inline:
            self._handle(request)
            return
        with self._wake:
            if self._closed:
                return
            if self._pending is not None:
                self.replaced += 1
            self._pending = request
            self._wake.notify()

    def close(self, timeout: float = 5.0) -> bool:
        """Stop the thread (after the solve it may be in) and wait at most ``timeout`` s; True if it ended."""
        with self._wake:
            self._closed = True
            self._pending = None
            self._wake.notify()
        if self._thread is None:
            return True
        self._thread.join(timeout)
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)
        return not self._thread.is_alive()

    def _run(self):
        _name_os_thread(THREAD_NAME)
        if self.process:      # spawned beside: until it is up (a second or so) the solves run here
            threading.Thread(target=self._spawn, name='map_value_spawn', daemon=True).start()
        while True:
            with self._wake:
                while self._pending is None and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                request, self._pending = self._pending, None
            self._handle(request)

    def _spawn(self):
        pool = _start_pool()
        with self._wake:
            if self._closed:
                if pool is not None:
                    pool.shutdown(wait=False, cancel_futures=True)
                return
            self._pool = pool

    def _handle(self, request: _Request):
        try:
            snap = request.snapshot
            key = (snap.origin, snap.cell, request.centre, request.omega_max)
            last = self._latest
            if last is not None and self._last_key is not None and self._last_key[0] == key \
                    and np.array_equal(self._last_key[1], snap.occupied):
                self._latest = replace(last, stamp=request.stamp, version=snap.version)
                self.skipped += 1
                return
            value, pool = None, self._pool
            if pool is not None:
                try:
                    value = pool.submit(_solve_remote, snap, request.centre, self.speed, request.omega_max,
                                        self.clearance, self.settings, request.stamp).result()
                    if value is None:       # the worker's field is its last one's
                        value = None if last is None else replace(last, stamp=request.stamp, version=snap.version)
                except Exception:           # noqa: BLE001  a broken worker: solved here from now on
                    self._pool = None
                    value = None
            if value is None:
                value = solve_map_value(snap, request.centre, self.speed, request.omega_max, self.clearance,
                                        self.settings, stamp=request.stamp, previous=last, _windows=self._windows)
            self._last_key = (key, snap.occupied)
            self._latest = value
            if last is not None and value.vf is last.vf:
                self.skipped += 1           # the map changed, not within the window's reach
            else:
                self.solved += 1
        except Exception as exc:            # kept for the caller; never raised into its thread
            self.error = f'{type(exc).__name__}: {exc}'
            self.errors.append(self.error)
            del self.errors[:-MAX_ERRORS]
            self.error_count += 1


_REMOTE = {}      # in a worker process: its solver windows and its last value (``_solve_remote``)


def _solve_remote(snapshot, centre, speed, omega_max, clearance, settings, stamp):
    """``solve_map_value`` in a worker process, its solver and its last value kept there: the new value,
    or None when the window's field is the last one's (the caller keeps its own, restamped)."""
    windows = _REMOTE.setdefault('windows', _Windows())
    last = _REMOTE.get('last')
    value = solve_map_value(snapshot, centre, speed, omega_max, clearance, settings, stamp=stamp, previous=last,
                            _windows=windows)
    _REMOTE['last'] = value
    return None if last is not None and value.vf is last.vf else value


def _start_pool():
    """A spawned worker process for the solves (None if none can be started), as the cluster store's:
    stop signals blocked in the spawning thread, the worker gone with its parent."""
    from ..clusters.store import _block_stop_signals, _exit_with_parent
    try:
        import concurrent.futures
        import multiprocessing
        import os
        _block_stop_signals()
        pool = concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context('spawn'),
                                                      initializer=_exit_with_parent, initargs=(os.getpid(),))
        pool.submit(math.sqrt, 1.0).result()      # spawned now, not at the first solve
        return pool
    except (OSError, ValueError, ImportError, RuntimeError):
        return None
