"""The durable intervention store (supersafe_ros.learning.intervention_store)."""
import json
import math

import numpy as np
import pytest

from supersafe_ros.learning.intervention_store import Intervention, InterventionStore, StoreLockedError


def iv(i, frame='obstacle_1'):
    return Intervention(1_000_000_000 + i, frame, -3.0 + 0.1 * i, 0.5, 0.01 * i)


def test_append_persists_and_reloads(tmp_path):
    path = tmp_path / 'sub' / 'interventions.jsonl'
    with InterventionStore(path) as store:
        for i in range(5):
            assert store.append(iv(i))
        states = store.states()
    with InterventionStore(path) as again:
        assert len(again) == 5
        assert np.array_equal(again.states(), states)
        assert again.entries[0].received > 0


def test_duplicates_are_not_stored_twice(tmp_path):
    with InterventionStore(tmp_path / 's.jsonl') as store:
        assert store.append(iv(1))
        assert not store.append(iv(1))
        assert store.append(iv(1, frame='obstacle_2'))   # same time, other obstacle: a new event
        assert len(store) == 2
        # the obstacle's number, not the frame's spelling (issue 29: three records for one)
        assert not store.append(iv(1, frame='obstacle_01')) and not store.append(iv(1, frame='obstacle_0001'))
        assert store.append(iv(1, frame='obstacle_10'))
        assert len(store) == 3


def test_a_reloaded_store_knows_spellings_of_one_event_as_one(tmp_path):
    path = tmp_path / 's.jsonl'
    with open(path, 'w') as f:      # a file written before the key was the obstacle's number
        for frame in ('obstacle_7', 'obstacle_07', 'obstacle_007'):
            f.write(iv(3, frame).to_json() + '\n')
    with InterventionStore(path) as store:
        assert len(store) == 1 and store.entries[0].frame == 'obstacle_7' and store.entries[0].obstacle == 7
        assert not store.append(iv(3, 'obstacle_0007'))


def test_torn_last_line_is_cut_and_appends_stay_clean(tmp_path):
    path = tmp_path / 's.jsonl'
    with InterventionStore(path) as store:
        store.append(iv(0))
        store.append(iv(1))
    with open(path, 'ab') as f:
        f.write(iv(2).to_json().encode()[:17])   # the process died mid-write
    with InterventionStore(path) as store:
        assert len(store) == 2 and store.torn_bytes == 17
        store.append(iv(3))
    lines = path.read_text().splitlines()
    assert len(lines) == 3 and all(json.loads(line) for line in lines)


def test_complete_json_without_newline_counts_as_torn(tmp_path):
    path = tmp_path / 's.jsonl'
    path.write_text(iv(0).to_json() + '\n' + iv(1).to_json())
    with InterventionStore(path) as store:
        assert len(store) == 1 and store.torn_bytes > 0


def test_damaged_middle_line_is_skipped_not_deleted(tmp_path):
    path = tmp_path / 's.jsonl'
    path.write_text(iv(0).to_json() + '\n' + 'garbage\n' + iv(1).to_json() + '\n')
    with InterventionStore(path) as store:
        assert len(store) == 2 and store.skipped_lines == 1
    assert 'garbage' in path.read_text()


def test_second_writer_is_refused(tmp_path):
    path = tmp_path / 's.jsonl'
    with InterventionStore(path):
        with pytest.raises(StoreLockedError):
            InterventionStore(path)


def test_archive_moves_data_aside_and_starts_empty(tmp_path):
    path = tmp_path / 's.jsonl'
    with InterventionStore(path) as store:
        store.append(iv(0))
        archived = store.archive()
        assert len(store) == 0
        store.append(iv(1))
    with open(archived) as f:
        assert len(f.read().splitlines()) == 1
    with InterventionStore(path) as store:
        assert [e.stamp_ns for e in store.entries] == [iv(1).stamp_ns]


@pytest.mark.parametrize('bad', [dict(x=math.nan), dict(theta=math.inf), dict(frame='')])
def test_invalid_interventions_are_refused(bad):
    kw = dict(stamp_ns=1, frame='obstacle_1', x=0.0, y=0.0, theta=0.0)
    kw.update(bad)
    with pytest.raises(ValueError):
        Intervention(**kw)
