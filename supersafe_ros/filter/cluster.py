"""Values of clusters of detected obstacles: the union's avoid value, not the min.

The smallest of the per-obstacle values is not the value of their union: two discs
closer than a turning diameter can each be avoidable while their union is not (the
turn away from one leads into the other). Obstacles close enough to interact are
therefore judged together:

* ``components``: obstacles whose centres lie within ``link`` of each other
  (transitively) form a cluster;
* ``canonical``: a cluster's geometry up to translation and rotation, rounded to
  ``key_resolution`` - the cache key (the same cup seen by another robot, or
  anywhere else on the map, is solved once);
* ``ClusterStore``: solves each new key with the core's union solver
  (``reach.solver.solve_avoid`` on ``sets.Union``) in a background thread, so
  control never waits, and keeps the values (LRU);
* ``ClusterValue.evaluate``: V and the avoid turn of robot states relative to a
  cluster, in its canonical frame.

Soundness margins. The solve uses discs inflated by ``margin`` >= the key's
rounding error (the rounded disc contains the true one) plus an allowance for the
solver's error. The value between grid nodes is read as a Lipschitz lower bound
(``lower_bound``): V is 1-Lipschitz in position (l is, and the flow commutes with
translation) and L_theta-Lipschitz in heading (L_theta = the largest |dV/dtheta| of
the nodes), so V(x) >= V(node) - |dp| - L_theta |dtheta| for each of the 8
corners of the cell, and the largest of those is kept. Trilinear interpolation
would instead overestimate V in the valley of head-on states by up to
L_theta dtheta / 2 - exactly where the filter must not act late.

Fallback while a cluster is being solved: ``orbit_value``, the clearance of the
best loiter circle. A Dubins robot that turns at +-w_max forever stays on a circle
of radius r = v / w_max; if that circle clears every disc of the cluster by
c > 0, holding that turn keeps the robot out of all of them forever, and the
circle stays the same as long as the turn is held. The filter keeps "some loiter
circle is clear" invariant: it passes the planner's command only if a circle is
still clear at the end of the hold, and otherwise turns onto the clearer circle.
That is sound for any layout and needs no grid (it is conservative: it wants a
whole clear circle of diameter 2r, so it is only a stop-gap until the union's
value is in force).
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
import math
import os
import queue
import threading
import time

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..reach.dynamics import DubinsCar
from ..reach.grid import Grid
from ..reach.sets import Disc, Union
from ..reach.solver import solve_avoid
from ..reach.value_function import ValueFunction


# a cluster of more obstacles is never solved (its grid and union grow with it: a lidar's thousands
# of points would keep the solver busy for minutes): the loiter fallback and the per-obstacle rows
# judge it (filter.cluster_rows)
SOLVE_MEMBERS_MAX = 32


@dataclass(frozen=True)
class ClusterSettings:
    """How clusters are formed and solved (lengths in m, times in s)."""

    radius: float = 1.8            # obstacle radius
    speed: float = 3.0             # true dynamics (the standard set's)
    omega_max: float = 1.0
    link: float = 0.0              # centres closer than this interact; 0 = 2 radius + turning diameter
    key_resolution: float = 0.05   # the canonical geometry is rounded to this
    margin: float = 0.1            # disc inflation: >= key rounding error (0.035) + solver error
    cell: float = 0.35             # grid spacing in x and y
    headings: int = 32             # grid nodes in theta
    reach: float = 7.0             # grid extends this far beyond the outermost centres
    horizon: float = 3.0           # as the standard set
    lower_bound: bool = True       # read V between nodes as its Lipschitz lower bound (else trilinear)
    disk_cache: bool = True        # keep solved clusters on disk (shared by processes and runs)

    @property
    def link_distance(self) -> float:
        if self.link > 0:
            return self.link
        return 2.0 * self.radius + 2.0 * self.speed / max(self.omega_max, 1e-9)

    @property
    def turning_radius(self) -> float:
        return self.speed / max(self.omega_max, 1e-9)

    @property
    def turn_hold(self) -> float:
        """The shortest hold over which a cluster value tells the two bangs apart: their ends
        are one heading cell (2 pi / headings) apart at full turn rate. The avoid turn is the
        bang whose hold ends at the larger V; over a shorter hold both ends read the same
        between grid nodes (a tie, turned left whichever side is safe)."""
        return 2.0 * math.pi / self.headings / max(self.omega_max, 1e-9)


def components(centres, link: float) -> list:
    """Index arrays of the clusters (connected within ``link``), singletons included: in the
    order of their first members, each ascending (as a union-find over all pairs gives them).

    Near-linear: the pairs within ``link`` come from a k-d tree (``link_pairs``) and the
    clusters from scipy's connected components, so the cost grows with the detections and
    their neighbours, not with all pairs (100,000 centres: an all-pairs matrix of 74.5 GiB).
    """
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    n = len(c)
    if n == 0:
        return []
    i, j = link_pairs(c, link)
    graph = coo_matrix((np.ones(len(i), np.int8), (i, j)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    order = np.argsort(label, kind='stable')            # members ascending within a cluster
    cut = np.flatnonzero(np.diff(label[order])) + 1
    groups = np.split(order, cut)
    groups.sort(key=lambda g: g[0])                     # clusters by their first member
    return groups


def link_pairs(centres, link: float):
    """(i, j), i < j: the pairs of ``centres`` (N, 2) at most ``link`` apart, by np.hypot as an
    all-pairs matrix would judge them (the tree's candidates, taken a hair wider, are
    checked again)."""
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    if len(c) < 2:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    pairs = cKDTree(c).query_pairs(link * (1.0 + 1e-9) + 1e-12, output_type='ndarray')
    i, j = pairs[:, 0].astype(np.intp), pairs[:, 1].astype(np.intp)
    close = np.hypot(c[i, 0] - c[j, 0], c[i, 1] - c[j, 1]) <= link
    return i[close], j[close]


def canonical(centres, resolution: float):
    """(key, origin, angle, rounded canonical centres) of a cluster's geometry.

    Canonical frame: origin at the centroid, x along the farthest pair of centres
    (of the two orientations, the one with the smaller key). A map point p is
    R(-angle) (p - origin) there.
    """
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    origin = c.mean(axis=0)
    rel = c - origin
    d = np.hypot(rel[:, None, 0] - rel[None, :, 0], rel[:, None, 1] - rel[None, :, 1])
    i, j = np.unravel_index(np.argmax(d), d.shape)
    base = math.atan2(rel[j, 1] - rel[i, 1], rel[j, 0] - rel[i, 0])
    best = None
    for angle in (base, base + math.pi):
        cs, sn = math.cos(angle), math.sin(angle)
        rot = np.stack([cs * rel[:, 0] + sn * rel[:, 1], -sn * rel[:, 0] + cs * rel[:, 1]], axis=1)
        q = np.round(rot / resolution).astype(int)
        key = tuple(sorted(map(tuple, q.tolist())))
        if best is None or key < best[0]:
            best = (key, angle)
    key, angle = best
    return key, origin, angle, np.array(key, dtype=float) * resolution


def to_frame(states, origin, angle) -> np.ndarray:
    """Map states (N, 3) into a cluster's canonical frame."""
    s = np.asarray(states, dtype=float).reshape(-1, 3)
    cs, sn = math.cos(angle), math.sin(angle)
    dx, dy = s[:, 0] - origin[0], s[:, 1] - origin[1]
    return np.stack([cs * dx + sn * dy, -sn * dx + cs * dy, s[:, 2] - angle], axis=1)


@dataclass
class ClusterValue:
    """The union's value of one canonical cluster."""

    vf: ValueFunction
    centres: np.ndarray        # canonical centres (rounded)
    solve_time: float          # seconds of solving
    lower: bool = True         # Lipschitz lower bound between nodes (else trilinear)
    lipschitz_theta: float = 0.0

    def __post_init__(self):
        self.lipschitz_theta = float(np.max(np.abs(self.vf.node_gradient()[..., 2])))
        from .law import tie_tolerance
        self.tie = tie_tolerance(self.vf)

    def evaluate(self, frame_states):
        """(V lower bound, unit turn) at states in the canonical frame; +inf/0 off the grid."""
        s = np.asarray(frame_states, dtype=float).reshape(-1, 3)
        value, inside = self._value(s)
        turn = np.zeros(len(s))
        if np.any(inside):
            grad = self.vf.grid.interpolate(self.vf.theta_gradient(), s[inside])
            turn[inside] = np.where(grad >= -self.tie, 1.0, -1.0)
        return value, turn

    def value(self, frame_states):
        """V lower bound at states in the canonical frame (``evaluate``'s); +inf off the grid."""
        return self._value(np.asarray(frame_states, dtype=float).reshape(-1, 3))[0]

    def _value(self, s):
        value = np.full(len(s), np.inf)
        inside = self.vf.grid.contains(s)
        if np.any(inside):
            si = s[inside]
            value[inside] = (lower_bound(self.vf, si, self.lipschitz_theta) if self.lower
                             else self.vf.value(si))
        return value, inside


def lower_bound(vf: ValueFunction, states, lipschitz_theta: float) -> np.ndarray:
    """max over the cell's 8 nodes of V(node) - |dp| - L_theta |dtheta| (see the module doc)."""
    g = vf.grid
    ix, iy, it, wx, wy, wt = g._cell(states)
    dx, dy, dth = g.spacing
    # offsets to the corners, from the clamped cell coordinates (states outside were excluded)
    ox, oy, ot = wx * dx, wy * dy, wt * dth
    it1 = (it + 1) % g.shape[2]
    flat, ny, nth = np.ascontiguousarray(vf.values).reshape(-1), g.shape[1], g.shape[2]
    first = (ix * ny + iy) * nth      # the cell's corners are fixed offsets from its first node
    heading = ((it, lipschitz_theta * ot), (it1, lipschitz_theta * (dth - ot)))
    best = None
    for offset, ddx, ddy in g._corners(ox, dx - ox, oy, dy - oy):
        dp = np.hypot(ddx, ddy)
        base = first + offset
        for ct, slack in heading:
            bound = flat.take(base + ct) - dp - slack
            best = bound if best is None else np.maximum(best, bound)
    return best


def orbit_value(states, centres, radius: float, turning_radius: float):
    """(clearance of the clearer loiter circle, its turn +1 left / -1 right) per state.

    Clearance of a circle of radius r centred at m from a disc (c, R):
    | |m - c| - r | - R (the circle passes outside or around the disc).
    """
    s = np.asarray(states, dtype=float).reshape(-1, 3)
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    out = []
    for side in (1.0, -1.0):
        mx = s[:, 0] - side * turning_radius * np.sin(s[:, 2])
        my = s[:, 1] + side * turning_radius * np.cos(s[:, 2])
        dist = np.hypot(mx[:, None] - c[None, :, 0], my[:, None] - c[None, :, 1])
        out.append(np.min(np.abs(dist - turning_radius) - radius, axis=1))
    left, right = out
    return np.maximum(left, right), np.where(left >= right, 1.0, -1.0)


class ClusterStore:
    """Union values by canonical geometry, solved in a background thread (or inline).

    ``get(key)`` never blocks: None until the value is in force. ``request`` queues
    a solve once per key. ``latencies`` records request -> in force (s) per key.
    """

    def __init__(self, settings: ClusterSettings | None = None, background: bool = True,
                 capacity: int = 256, fallback_only: bool = False):
        self.settings = settings or ClusterSettings()
        self.fallback_only = fallback_only     # never solve: the fallback alone (tests, benchmarks)
        self.background = background
        self.capacity = capacity
        self.values: OrderedDict = OrderedDict()
        self.requested: dict = {}          # key -> monotonic time of the first request
        self.latencies: dict = {}          # key -> seconds from request to in force
        self.errors: dict = {}
        self._lock = threading.Lock()
        self._queue: queue.Queue = queue.Queue()
        self._thread = None
        self.ready = threading.Event()     # the solver (thread and worker process) is up
        self._saved = 0                    # values written to the disk cache

    def errors_after(self, told: int) -> list:
        """The (key, why) of the solves that failed, after the first ``told`` of them."""
        with self._lock:
            return list(self.errors.items())[told:]

    def fallback_twin(self) -> 'ClusterStore':
        """A store of the same settings that never solves (``fallback_only``; itself if it is
        one): the store of detections that change every message (``RobotFilter.update_detections``
        with ``solve_clusters=False``), judged by the loiter fallback with no solve queued."""
        if self.fallback_only:
            return self
        twin = self.__dict__.get('_twin')
        if twin is None:
            twin = self._twin = ClusterStore(self.settings, background=False, fallback_only=True)
        return twin

    def get(self, key):
        with self._lock:
            v = self.values.get(key)
            if v is not None:
                self.values.move_to_end(key)
            return v

    def request(self, key, centres) -> None:
        if self.fallback_only or len(centres) > SOLVE_MEMBERS_MAX:
            return
        with self._lock:
            if key in self.values or key in self.requested or key in self.errors:
                return
            self.requested[key] = time.monotonic()
        if not self.background:
            self._solve(key, centres)
            return
        self.start()
        self._queue.put((key, centres))

    def start(self) -> 'ClusterStore':
        """Start the solver thread and its worker process now (a node does this at start,
        so that the first cluster does not wait for a process to spawn)."""
        if self.background and (self._thread is None or not self._thread.is_alive()):
            self._thread = threading.Thread(target=self._work, name='cluster-solver', daemon=True)
            self._thread.start()
        return self

    def solving(self, key) -> bool:
        """True while ``key`` is requested and neither solved nor failed."""
        with self._lock:
            return key in self.requested

    def pending(self) -> int:
        with self._lock:
            return len(self.requested)

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Block until every requested solve is done (tests and benchmarks only)."""
        end = time.monotonic() + timeout
        while self.pending() and time.monotonic() < end:
            time.sleep(0.005)
        return not self.pending()

    def _work(self):
        # the solves run in a worker process when one can be started: the solver's
        # Python steps then never hold this process's GIL against the control path
        pool = None
        _block_stop_signals()
        try:
            import concurrent.futures
            import multiprocessing
            pool = concurrent.futures.ProcessPoolExecutor(
                max_workers=1, mp_context=multiprocessing.get_context('spawn'),
                initializer=_exit_with_parent, initargs=(os.getpid(),))
            pool.submit(math.sqrt, 1.0).result()    # spawn the worker now, not at the first cluster
        except (OSError, ValueError, ImportError, RuntimeError):
            pool = None
        self.ready.set()
        while True:
            key, centres = self._queue.get()
            self._solve(key, centres, pool)

    def _solve(self, key, centres, pool=None):
        st = self.settings
        try:
            c = np.asarray(centres, dtype=float).reshape(-1, 2)
            path = cache_path(st, key) if st.disk_cache else None
            vf, solve_time = None, 0.0
            if path is not None and path.exists():
                try:
                    vf = ValueFunction.load_npz(path)
                    os.utime(path)               # recently used: the last to be pruned
                except (OSError, ValueError):    # damaged or half-copied: solve again
                    vf = None
            if vf is not None:
                pass
            elif pool is not None:
                try:
                    vf, solve_time = pool.submit(solve_cluster, st, c).result()
                except Exception:       # a broken worker: solve here instead
                    vf, solve_time = solve_cluster(st, c)
            else:
                vf, solve_time = solve_cluster(st, c)
            if path is not None and solve_time > 0.0:
                try:
                    path.parent.mkdir(parents=True, exist_ok=True)
                    vf.save_npz(path)
                    self._saved += 1
                    if self._saved % PRUNE_EVERY == 1:
                        prune_disk_cache(path.parent, disk_cache_limit())
                except OSError:
                    pass                 # a read-only cache only costs the next solve
            value = ClusterValue(vf, c, solve_time, lower=st.lower_bound)
        except Exception as exc:   # a failed solve leaves the fallback in force, and says why
            with self._lock:
                self.errors[key] = f'{type(exc).__name__}: {exc}'
                self.requested.pop(key, None)
            return
        with self._lock:
            self.values[key] = value
            while len(self.values) > self.capacity:
                self.values.popitem(last=False)
            t_req = self.requested.pop(key, None)
            if t_req is not None:
                self.latencies[key] = time.monotonic() - t_req


def solve_cluster(settings: ClusterSettings, centres):
    """(ValueFunction, seconds) of the union of inflated discs at canonical ``centres``."""
    st = settings
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    lo = c.min(axis=0) - st.reach
    hi = c.max(axis=0) + st.reach
    shape = (int(math.ceil((hi[0] - lo[0]) / st.cell)) + 1,
             int(math.ceil((hi[1] - lo[1]) / st.cell)) + 1, int(st.headings))
    keepout = Union(tuple(Disc(float(x), float(y), st.radius + st.margin) for x, y in c))
    t0 = time.perf_counter()
    vf = solve_avoid(Grid(tuple(lo), tuple(hi), shape), DubinsCar(st.speed, st.omega_max),
                     keepout, horizon=st.horizon)
    return vf, time.perf_counter() - t0


CACHE_VERSION = 1   # bump when the solve or its settings' meaning changes
DISK_CACHE_MB = 1024    # default bound of the clusters/ folder ($SUPERSAFE_CLUSTER_CACHE_MB)
PRUNE_EVERY = 50        # a store checks the bound at its first write and every 50th after


def disk_cache_limit() -> int:
    """Bytes the clusters/ folder may hold: $SUPERSAFE_CLUSTER_CACHE_MB (default 1024)."""
    try:
        mb = float(os.environ.get('SUPERSAFE_CLUSTER_CACHE_MB', DISK_CACHE_MB))
    except ValueError:
        mb = DISK_CACHE_MB
    return int(max(mb, 0.0) * 1e6)


def prune_disk_cache(folder, limit_bytes: int) -> int:
    """Delete the least recently used cluster files (by mtime: a read touches its file)
    until ``folder`` holds at most ``limit_bytes``; returns how many were deleted.

    Each study layout and detection pattern adds new clusters (a few hundred kB to 1 MB
    each), so without a bound the cache grew to 4 GB on one machine. A file deleted here
    while another process reads it costs that process one solve."""
    entries = []
    try:
        with os.scandir(folder) as it:
            for e in it:
                if e.name.startswith('cluster-') and e.name.endswith('.npz'):
                    try:
                        st = e.stat()
                    except OSError:
                        continue
                    entries.append((st.st_mtime, st.st_size, e.path))
    except OSError:
        return 0
    total = sum(size for _, size, _ in entries)
    deleted = 0
    for _, size, path in sorted(entries):
        if total <= limit_bytes:
            break
        try:
            os.remove(path)
        except OSError:
            continue
        total -= size
        deleted += 1
    return deleted


def cache_path(settings: ClusterSettings, key):
    """Where a cluster's value is kept: the package's value-function cache, by a hash of
    the canonical geometry and every setting that shapes the solve."""
    import hashlib
    import json
    from dataclasses import asdict
    from ..reach.library import SOLVER_VERSION, default_cache_dir
    blob = json.dumps({'key': [list(k) for k in key], 'settings': asdict(settings),
                       'solver': SOLVER_VERSION, 'version': CACHE_VERSION}, sort_keys=True)
    return default_cache_dir() / 'clusters' / f'cluster-{hashlib.sha256(blob.encode()).hexdigest()[:24]}.npz'


def _block_stop_signals() -> None:
    """Block SIGINT and SIGTERM in this thread (never the main thread, where Python handles them),
    before it spawns the worker: a spawned process keeps the signal mask of the thread that
    started it. A Ctrl-C in a terminal (or ``ros2 launch``) signals the whole process group;
    the worker then stops with its filter (the pool's shutdown at exit, or ``_exit_with_parent``)
    instead of printing a KeyboardInterrupt traceback from its queue read."""
    import signal
    from multiprocessing import resource_tracker
    if threading.current_thread() is not threading.main_thread():
        # first: starting the tracker unblocks both signals in the thread that starts it
        resource_tracker.ensure_running()
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})


def _exit_with_parent(parent_pid: int) -> None:
    """In the solver's worker process: exit as soon as the filter process is gone (a
    killed node must not leave its worker behind, blocked on an empty queue)."""
    def watch():
        while os.getppid() == parent_pid:
            time.sleep(0.5)
        os._exit(0)
    threading.Thread(target=watch, daemon=True).start()
