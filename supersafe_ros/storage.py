"""Where the package keeps files on disk, how much, and what may go.

Three places grow as the package runs:

* **value functions** (``reach.library.default_cache_dir()``: $SUPERSAFE_CACHE, else
  $XDG_CACHE_HOME or ~/.cache, then supersafe_ros/): the candidate library and standard
  sets (``dubins-*.npz``), solved once per grid and kept; rebuilt on demand if removed;
* **cluster values** (``clusters/`` in that folder, ``cluster-*.npz``): union values of
  detected obstacle clusters, shared by every filter process and run; bounded by
  $SUPERSAFE_CLUSTER_CACHE_MB (1024 MB, least recently used first:
  ``filter.clusters.prune_disk_cache``); solved again if removed;
* **learner runs** (``runs_dir()``: $XDG_DATA_HOME or ~/.local/share, then
  supersafe_ros/runs/): one folder ``<UTC time>-<pid>`` per learner started without a
  ``store_path``, holding that run's interventions and encounters. These are data, not a
  cache: a learner keeps the newest ``keep_runs`` (``prune_runs``) and never touches a
  folder whose learner is still running, a folder of another name, or a named store.

``usage()`` measures each place (``supersafe cache info``); ``clear(...)`` empties the
chosen ones (``supersafe cache clear``). No ROS here.
"""
from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import re
import shutil
import time

RUN_NAME = re.compile(r'^\d{8}T\d{6}Z-(\d+)$')     # <UTC time>-<pid>, as new_run_store names it


def runs_dir() -> Path:
    """$XDG_DATA_HOME (or ~/.local/share)/supersafe_ros/runs."""
    base = os.environ.get('XDG_DATA_HOME') or os.path.expanduser('~/.local/share')
    return Path(base) / 'supersafe_ros' / 'runs'


def new_run_store(runs: Path | None = None) -> Path:
    """The intervention file of a fresh run folder (not created here): runs/<UTC time>-<pid>/."""
    run = time.strftime('%Y%m%dT%H%M%SZ', time.gmtime()) + f'-{os.getpid()}'
    return (runs or runs_dir()) / run / 'interventions.jsonl'


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:        # someone else's process: alive
        return True
    return True


def prune_runs(keep: int, runs: Path | None = None, current: Path | None = None) -> list[Path]:
    """Remove the oldest run folders (by name: their UTC start time) beyond the newest ``keep``
    (``current``, the run starting now, counts as one of them and is never removed); a folder
    whose learner process is still running, or whose name is not a run's, is left alone.
    ``keep`` 0 keeps everything. Returns the folders removed."""
    runs = runs or runs_dir()
    if keep <= 0 or not runs.is_dir():
        return []
    current = Path(current).resolve() if current is not None else None
    folders = sorted((p for p in runs.iterdir() if p.is_dir() and RUN_NAME.match(p.name)),
                     key=lambda p: p.name, reverse=True)
    kept = 1 if current is not None and current.parent == runs.resolve() else 0
    removed = []
    for folder in folders:
        if current is not None and folder.resolve() == current:
            continue
        if kept < keep:
            kept += 1
            continue
        if _running(int(RUN_NAME.match(folder.name).group(1))):
            continue
        shutil.rmtree(folder, ignore_errors=True)
        if not folder.exists():
            removed.append(folder)
    return removed


@dataclass(frozen=True)
class Usage:
    """One place: what it holds, where, how many entries and bytes."""

    what: str
    path: Path
    entries: int
    bytes: int
    note: str = ''


def _size(path: Path) -> int:
    total = 0
    for root, _, files in os.walk(path):
        for name in files:
            try:
                total += os.lstat(os.path.join(root, name)).st_size
            except OSError:
                pass
    return total


def _value_files(cache: Path) -> list[Path]:
    return sorted(cache.glob('*.npz')) if cache.is_dir() else []


def _cluster_files(cache: Path) -> list[Path]:
    folder = cache / 'clusters'
    return sorted(folder.glob('cluster-*.npz')) if folder.is_dir() else []


def _run_folders(runs: Path) -> list[Path]:
    return sorted(p for p in runs.iterdir() if p.is_dir() and RUN_NAME.match(p.name)) if runs.is_dir() else []


def usage(cache: Path | None = None, runs: Path | None = None) -> list[Usage]:
    """Entries and bytes of the value functions, the cluster values and the learner runs."""
    from .filter.clusters.store import disk_cache_limit
    from .reach.library import default_cache_dir
    cache = Path(cache) if cache is not None else default_cache_dir()
    runs = Path(runs) if runs is not None else runs_dir()
    values, clusters, folders = _value_files(cache), _cluster_files(cache), _run_folders(runs)
    live = sum(1 for f in folders if _running(int(RUN_NAME.match(f.name).group(1))))
    return [
        Usage('value functions (library, standard sets)', cache, len(values),
              sum(f.stat().st_size for f in values), 'solved again when needed'),
        Usage('cluster values', cache / 'clusters', len(clusters), sum(f.stat().st_size for f in clusters),
              f'bounded at {disk_cache_limit() / 1e6:.0f} MB ($SUPERSAFE_CLUSTER_CACHE_MB), least recently '
              'used first; solved again when needed'),
        Usage('learner runs (interventions, encounters)', runs, len(folders), sum(_size(f) for f in folders),
              f'data, not a cache: a learner keeps the newest keep_runs; {live} still running'),
    ]


def clear(cache: Path | None = None, runs: Path | None = None, values: bool = False, clusters: bool = False,
          learner_runs: bool = False) -> list[tuple[str, int, int]]:
    """Remove the chosen places' entries; returns (what, entries removed, bytes freed). Run
    folders of learners still running are kept."""
    from .reach.library import default_cache_dir
    cache = Path(cache) if cache is not None else default_cache_dir()
    runs = Path(runs) if runs is not None else runs_dir()
    out = []
    for chosen, what, entries in ((values, 'value functions', _value_files(cache)),
                                  (clusters, 'cluster values', _cluster_files(cache))):
        if chosen:
            n = freed = 0
            for f in entries:
                try:
                    size = f.stat().st_size
                    f.unlink()
                except OSError:
                    continue
                n, freed = n + 1, freed + size
            out.append((what, n, freed))
    if learner_runs:
        n = freed = 0
        for folder in _run_folders(runs):
            if _running(int(RUN_NAME.match(folder.name).group(1))):
                continue
            size = _size(folder)
            shutil.rmtree(folder, ignore_errors=True)
            if not folder.exists():
                n, freed = n + 1, freed + size
        out.append(('learner runs', n, freed))
    return out
