"""CSV formats, Phase II reconstruction, and the pilot files' layout."""
from pathlib import Path

import numpy as np
import pytest

from supersafe_ros.learning.data import (Encounter, detect_csv_kind,
                                         encounters_from_phase2_interventions, intervention_states,
                                         phase2_pass, read_encounters_csv, read_interventions_csv,
                                         write_encounters_csv)

S3 = Path(__file__).resolve().parents[1] / '..' / 'shared' / 'data' / 's3'


def test_encounters_round_trip_through_csv(tmp_path):
    rng = np.random.default_rng(0)
    enc = [Encounter(rng.normal(size=(5, 3)), True, 0, t=np.arange(5) * 0.1),
           Encounter(rng.normal(size=(3, 3)), False, 'b'),
           Encounter(rng.normal(size=(1, 3)), True, 7)]
    path = tmp_path / 'enc.csv'
    write_encounters_csv(path, enc)
    assert detect_csv_kind(path) == 'encounters'
    back = read_encounters_csv(path)
    assert [e.scene for e in back] == [0, 'b', 7]
    assert [e.intervened for e in back] == [True, False, True]
    for a, b in zip(enc, back):
        assert np.array_equal(a.states, b.states)          # repr() keeps every bit
    assert np.array_equal(read_interventions_csv(path), intervention_states(enc))


def test_encounter_rows_are_grouped_by_scene_and_ordered_by_time(tmp_path):
    path = tmp_path / 'enc.csv'
    path.write_text('scene,t,x,y,theta,intervened\n'
                    '1,0.2,-7.4,0,0,1\n'
                    '2,0.0,-8,1,0,0\n'
                    '1,0.0,-8,0,0,0\n'
                    '1,0.1,-7.7,0,0,0\n')
    a, b = read_encounters_csv(path)
    assert a.scene == 1 and a.intervened and np.allclose(a.states[:, 0], [-8, -7.7, -7.4])
    assert b.scene == 2 and not b.intervened and len(b.states) == 1


@pytest.mark.parametrize('body, message', [
    ('scene,t,x,y,theta,intervened\n1,0,0,0,0,1\n1,1,0,0,0,0\n', 'before its last frame'),
    ('scene,t,x,y,theta,intervened\n1,0,nan,0,0,0\n', ':2: column'),
    ('scene,t,x,y,theta,intervened\n1,0,0,0,0,2\n', 'must be 0 or 1'),
    ('scene,t,x,y,intervened\n1,0,0,0,0\n', 'missing column'),
])
def test_bad_encounter_files_are_rejected_with_the_line(tmp_path, body, message):
    path = tmp_path / 'bad.csv'
    path.write_text(body)
    with pytest.raises(ValueError, match=message):
        read_encounters_csv(path)


def test_bad_intervention_files_are_rejected_with_the_line(tmp_path):
    path = tmp_path / 'bad.csv'
    path.write_text('t_ms,x,y,theta\n0,1,2,0\n5,abc,2,0\n')
    with pytest.raises(ValueError, match=r'bad.csv:3: column .x.'):
        read_interventions_csv(path)
    path.write_text('t_ms,x,y\n0,1,2\n')
    with pytest.raises(ValueError, match='missing column'):
        read_interventions_csv(path)


def test_phase2_reconstruction_ends_exactly_at_the_intervention():
    states = np.array([[-2.987, 0.75, 0.0], [-8.0, -1.0, 0.0], [0.495, 2.25, 0.0]])
    enc = encounters_from_phase2_interventions(states, speed=3.0, dt=0.02)
    for s, e in zip(states, enc):
        assert e.intervened and np.array_equal(e.states[-1], s)
        assert e.states[0, 0] >= -8.0 > e.states[0, 0] - 0.06
        assert np.allclose(np.diff(e.states[:, 0]), 0.06) and np.all(e.states[:, 1] == s[1])
        # the full pass continues from the intervention to the crash or the far side
        assert np.array_equal(e.full_pass[:len(e.states)], e.states)
        rest, _ = phase2_pass(s[1], x0=s[0], dt=0.02, x_end=8.0)
        assert np.allclose(e.full_pass[len(e.states) - 1:], rest)
    with pytest.raises(ValueError, match='theta = 0'):
        encounters_from_phase2_interventions([[-3.0, 0.0, 0.5]])
    with pytest.raises(ValueError, match='before the start'):
        encounters_from_phase2_interventions([[-9.0, 0.0, 0.0]])


def test_pilot_files_are_phase2_intervention_states():
    if not S3.is_dir():
        pytest.skip(f'pilot data not found at {S3} (shared/data/s3 next to the repository)')
    for n in range(1, 6):
        s = read_interventions_csv(S3 / f'pilot{n}_interventions.csv')
        assert s.ndim == 2 and s.shape[1] == 3 and 14 <= len(s) <= 70
        assert np.all(s[:, 2] == 0.0) and np.all(np.abs(s[:, 1]) <= 2.25)
        assert np.allclose(s[:, 1] * 4, np.round(s[:, 1] * 4))     # the 0.25 m offset ladder
