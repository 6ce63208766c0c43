"""The paper's protocol for one human participant, without ROS: the bookkeeping.

``supersafe session`` (session_runner.py) runs the phases; this module decides what
they are and keeps the record:

* Phase II offsets: the 42 lateral offsets in [-2.25, 2.25], shuffled by a generator
  seeded from the participant ID (the same participant always gets the same order).
* Phase III order: a balanced Latin square (Williams design; for three conditions its
  six rows, so that each condition comes first, second and third, and follows each
  other, equally often) indexed by the participant ID.
* Likert items (7 points) after each pair of games.
* ``SessionStore``: <out>/<participant>/session.json, written atomically after every
  scene, fit, game and answer, so a closed tab or Ctrl-C loses at most the scene or
  game that was running. A complete participant is never overwritten.
* ``subject_record`` / ``write_subject`` / ``load_subject``: the same record a
  simulated subject of ``supersafe study`` has (subject, phase2, fit, states,
  learned_vf, games), plus Phase I (with the driven path) and the answers, in
  <dir>/subject.json and <dir>/learned_vf.npz, so ``study.summary.summarize`` runs
  over any mix of human and simulated subjects.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
import re
import time
import zlib

import numpy as np

from ..study.records import jsonable

CONDITIONS = ('standard', 'learned', 'conservative')
# Williams design for three conditions: two mirrored Latin squares
LATIN_ORDERS = (
    ('standard', 'learned', 'conservative'),
    ('learned', 'conservative', 'standard'),
    ('conservative', 'standard', 'learned'),
    ('conservative', 'learned', 'standard'),
    ('standard', 'conservative', 'learned'),
    ('learned', 'standard', 'conservative'),
)
PHASE2_N_OFFSETS = 42
PHASE2_HALF_SPAN = 2.25
LIKERT_ITEMS = (
    ('trust', 'I trusted the robots to avoid the obstacles.'),
    ('performance', 'The team performed well.'),
    ('interpretability', 'I could tell what the robots were going to do.'),
    ('confidence', 'I was confident in my decisions to intervene.'),
    ('fluency', 'The robots and I worked together fluently as a team.'),
    ('preference', 'I would like to work with these robots again.'),
)
LIKERT_POINTS = 7
ID_PATTERN = re.compile(r'[A-Za-z0-9][A-Za-z0-9_.-]{0,63}')


def check_participant_id(pid: str) -> str:
    # fullmatch: with match() and '$', 'a\n' would pass (and make a folder with a newline)
    if not isinstance(pid, str) or not ID_PATTERN.fullmatch(pid):
        raise ValueError(f'participant ID {pid!r}: use 1-64 letters, digits, _ . - (a file name)')
    return pid


def participant_number(pid: str) -> int:
    """A stable number for an ID: the ID itself if it is an integer, else its CRC-32."""
    check_participant_id(pid)
    return int(pid) if pid.isdigit() else zlib.crc32(pid.encode())


def condition_order(pid: str) -> tuple:
    return LATIN_ORDERS[participant_number(pid) % len(LATIN_ORDERS)]


def phase2_offsets(pid: str, n: int = PHASE2_N_OFFSETS) -> list:
    """``n`` offsets evenly spaced over [-2.25, 2.25], shuffled for this participant."""
    if n < 1:
        raise ValueError('need at least one Phase II offset')
    ladder = np.linspace(-PHASE2_HALF_SPAN, PHASE2_HALF_SPAN, n) if n > 1 else np.zeros(1)
    rng = np.random.default_rng(participant_number(pid))
    return [round(float(v), 6) for v in rng.permutation(ladder)]


def game_pairs(order) -> list:
    """The pairs compared in the questionnaires: after game 2 (games 1, 2) and after
    game 3 (games 2, 3)."""
    return [(order[0], order[1]), (order[1], order[2])]


def check_answers(values: dict) -> dict:
    """{item: 1..7} for every Likert item, or ValueError saying what is wrong."""
    if not isinstance(values, dict):
        raise ValueError('answers must be an object {item: 1..7}')
    out = {}
    for key, _ in LIKERT_ITEMS:
        v = values.get(key)
        if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= LIKERT_POINTS:
            raise ValueError(f'answer "{key}" must be an integer 1..{LIKERT_POINTS}')
        out[key] = v
    extra = set(values) - {k for k, _ in LIKERT_ITEMS}
    if extra:
        raise ValueError(f'unknown items {sorted(extra)}')
    return out


class ParticipantExists(RuntimeError):
    pass


class SessionStore:
    """<out>/<participant>/session.json: everything done so far."""

    def __init__(self, out_dir, pid: str, n_offsets: int = PHASE2_N_OFFSETS):
        self.pid = check_participant_id(pid)
        self.dir = Path(out_dir) / pid
        self.path = self.dir / 'session.json'
        if self.path.exists():
            self.data = json.loads(self.path.read_text())
            if self.data.get('complete'):
                raise ParticipantExists(f'participant {pid} is complete in {self.dir}; '
                                        'results are never overwritten (choose another ID)')
            self.resumed = True
        else:
            if self.dir.exists() and any(self.dir.iterdir()):
                raise ParticipantExists(f'{self.dir} exists and is not a session; refusing to touch it')
            self.dir.mkdir(parents=True, exist_ok=True)
            self.data = {'participant': pid, 'created': time.strftime('%Y-%m-%dT%H:%M:%S%z'),
                         'order': list(condition_order(pid)),
                         'offsets': phase2_offsets(pid, n_offsets),
                         'phase1': None, 'scenes': [], 'fit': None, 'games': {}, 'answers': [],
                         'complete': False}
            self.resumed = False
            self.save()

    def save(self) -> None:
        tmp = self.path.with_suffix('.json.tmp')
        tmp.write_text(json.dumps(jsonable(self.data), indent=1))
        os.replace(tmp, self.path)      # atomic: a crash leaves the old or the new file

    def remaining_offsets(self) -> list:
        done = len(self.data['scenes'])
        return self.data['offsets'][done:]

    def add_scene(self, scene: dict) -> None:
        self.data['scenes'].append(scene)
        self.save()


def intervention_states(scenes) -> np.ndarray:
    return np.array([s['state'] for s in scenes if s['intervened']], dtype=float).reshape(-1, 3)


def subject_record(data: dict, learned_vf=None, estimator: str = 'paper') -> dict:
    """A study record (see study.records) for a participant's session data;
    ``fit`` is the estimator whose set the Learned game used, ``fits`` holds both."""
    pid = data['participant']
    scenes = data['scenes']
    return {
        'subject': {'index': pid, 'kind': 'human', 'participant': pid, 'order': data['order']},
        'phase1': data.get('phase1'),
        'phase2': {'scenes': [{k: v for k, v in s.items() if k != 'frames'} for s in scenes],
                   'interventions': int(sum(1 for s in scenes if s['intervened']))},
        'fit': (data.get('fit') or {}).get(estimator.replace('-', '_')),
        'fits': data.get('fit'),
        'states': intervention_states(scenes).tolist(),
        'learned_vf': learned_vf,
        'games': data['games'],
        'sweep': {},
        'answers': data['answers'],
    }


def write_subject(directory, record: dict) -> Path:
    """<dir>/subject.json (+ learned_vf.npz): one subject, human or simulated."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rec = {k: v for k, v in record.items() if k not in ('learned_vf', 'learned_vfs')}
    if record.get('learned_vf') is not None:
        record['learned_vf'].save_npz(directory / 'learned_vf.npz')
        rec['learned_vf'] = 'learned_vf.npz'
    if 'learned_vfs' in record:     # the study's records: one learned set per learned condition
        rec['learned_vfs'] = {}
        for c, vf in record['learned_vfs'].items():
            if vf is not None:
                vf.save_npz(directory / f'learned_vf_{c}.npz')
            rec['learned_vfs'][c] = f'learned_vf_{c}.npz' if vf is not None else None
    path = directory / 'subject.json'
    tmp = path.with_suffix('.json.tmp')
    tmp.write_text(json.dumps(jsonable(rec), indent=1))
    os.replace(tmp, path)
    return path


def load_subject(directory) -> dict:
    from ..reach.value_function import ValueFunction
    directory = Path(directory)
    rec = json.loads((directory / 'subject.json').read_text())
    rec['learned_vf'] = (ValueFunction.load_npz(directory / rec['learned_vf'])
                         if rec.get('learned_vf') else None)
    if 'learned_vfs' in rec:
        rec['learned_vfs'] = {c: ValueFunction.load_npz(directory / f) if f else None
                              for c, f in rec['learned_vfs'].items()}
    rec['sweep'] = {float(k): v for k, v in (rec.get('sweep') or {}).items()}
    return rec
