"""storage and `supersafe cache`: the package's files on disk, how much, and what may go."""
import os
from pathlib import Path
import subprocess
import sys

import pytest

from supersafe_ros import storage
from supersafe_ros.cache_cli import run as cache_run


def make_run(runs: Path, stamp: str, pid: int, size: int = 100) -> Path:
    folder = runs / f'{stamp}-{pid}'
    folder.mkdir(parents=True)
    (folder / 'interventions.jsonl').write_bytes(b'x' * size)
    return folder


@pytest.fixture
def dead_pid():
    """The pid of a process that has exited (reaped)."""
    proc = subprocess.Popen([sys.executable, '-c', 'pass'])
    proc.wait()
    return proc.pid


def test_run_folders_beyond_the_newest_are_removed_but_never_a_running_learners(tmp_path, dead_pid):
    runs = tmp_path / 'runs'
    old = [make_run(runs, f'2026010{d}T120000Z', dead_pid) for d in range(1, 6)]     # oldest first
    running = make_run(runs, '20251231T120000Z', os.getpid())      # older still, but its learner runs
    other = runs / 'my-subject'
    other.mkdir()                                                   # not a run folder's name
    current = storage.new_run_store(runs).parent
    assert storage.RUN_NAME.match(current.name)
    removed = storage.prune_runs(3, runs, current=current)
    # the run starting now counts as one of the 3: the 2 newest old ones stay
    assert sorted(removed) == sorted(old[:3])
    assert all(f.exists() for f in old[3:]) and running.exists() and other.exists()
    assert storage.prune_runs(0, runs) == []                        # 0 keeps everything
    assert storage.prune_runs(3, tmp_path / 'nowhere') == []


def test_usage_counts_and_clear_removes_caches_and_only_asked_for_runs(tmp_path, dead_pid, monkeypatch):
    cache, runs = tmp_path / 'cache', tmp_path / 'runs'
    (cache / 'clusters').mkdir(parents=True)
    for i in range(3):
        (cache / f'dubins-{i}.npz').write_bytes(b'v' * 1000)
    for i in range(2):
        (cache / 'clusters' / f'cluster-{i}.npz').write_bytes(b'c' * 500)
    make_run(runs, '20260101T120000Z', dead_pid, size=300)
    live = make_run(runs, '20260102T120000Z', os.getpid(), size=300)
    values, clusters, learner = storage.usage(cache, runs)
    assert (values.entries, values.bytes, values.path) == (3, 3000, cache)
    assert (clusters.entries, clusters.bytes) == (2, 1000)
    assert (learner.entries, learner.bytes) == (2, 600) and '1 still running' in learner.note
    assert storage.clear(cache, runs, values=True, clusters=True) == [('value functions', 3, 3000),
                                                                      ('cluster values', 2, 1000)]
    assert storage.usage(cache, runs)[2].entries == 2               # runs untouched unless asked
    assert storage.clear(cache, runs, learner_runs=True) == [('learner runs', 1, 300)]
    assert live.exists()


def test_cache_cli_says_what_it_would_remove_and_removes_only_with_yes(tmp_path, dead_pid):
    cache, runs = tmp_path / 'cache', tmp_path / 'runs'
    cache.mkdir()
    (cache / 'dubins-0.npz').write_bytes(b'v' * 2000)
    make_run(runs, '20260101T120000Z', dead_pid)
    from supersafe_ros.cli import build_parser
    parse = build_parser().parse_args

    def cache(*argv):
        lines = []
        code = cache_run(parse(['cache', *argv, '--cache-dir', str(tmp_path / 'cache'),
                                '--runs-dir', str(runs)]), out=lines.append)
        return code, '\n'.join(lines)
    code, text = cache('info')
    assert code == 0 and f'value functions (library, standard sets): 1 in {tmp_path / "cache"}, 2 kB' in text
    assert 'learner runs (interventions, encounters): 1 in' in text
    code, text = cache('clear')
    assert code == 2 and 'nothing removed' in text and (tmp_path / 'cache' / 'dubins-0.npz').exists()
    assert 'learner runs' not in text                            # recorded data only when asked
    code, text = cache('clear', '--yes')
    assert code == 0 and not (tmp_path / 'cache' / 'dubins-0.npz').exists() and any(runs.iterdir())
    code, text = cache('clear', '--runs', '--yes')
    assert code == 0 and 'removed learner runs: 1' in text and not any(runs.iterdir())
