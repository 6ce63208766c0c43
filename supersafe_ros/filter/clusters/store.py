"""Union values of clusters, solved once per canonical geometry and kept.

``ClusterStore`` solves each new key with the core's union solver (``reach.solver.solve_avoid``
on ``sets.Union``) in a background worker, so control never waits; it keeps the values (LRU)
in memory and on disk (``cache_path``, bounded by ``prune_disk_cache``). ``default_cluster_store``
is the process's store of a robot configuration.
"""
from __future__ import annotations

from collections import OrderedDict
import math
import os
import queue
import threading
import time

import numpy as np

from ...reach.dynamics import DubinsCar
from ...reach.grid import Grid
from ...reach.sets import Disc, Union
from ...reach.solver import solve_avoid
from ...reach.value_function import ValueFunction
from ..types import FilterConfig
from .geometry import ClusterSettings, ClusterValue


# a cluster of more obstacles is never solved (its grid and union grow with it: a lidar's thousands
# of points would keep the solver busy for minutes): the loiter fallback and the per-obstacle rows
# judge it (filter.constraints.cluster_rows)
SOLVE_MEMBERS_MAX = 32


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
    from ...reach.library import SOLVER_VERSION, default_cache_dir
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


_STORES = {}


def settings_of(cfg: FilterConfig) -> ClusterSettings:
    """The cluster settings of a robot configuration (its obstacles, speed and turn rate)."""
    return ClusterSettings(radius=cfg.radius, speed=cfg.speed, omega_max=cfg.omega_max, link=cfg.cluster_link)


def default_cluster_store(cfg: FilterConfig):
    """The process's shared ClusterStore for a robot configuration (background solves)."""
    settings = settings_of(cfg)
    store = _STORES.get(settings)
    if store is None:
        store = _STORES[settings] = ClusterStore(settings)
    return store
