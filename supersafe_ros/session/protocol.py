"""The paper's protocol for one human participant, without ROS: the bookkeeping.

``supersafe session`` (runner.py) runs the phases; this module decides what
they are and keeps the record:

* Phase II offsets: the 42 lateral offsets in [-2.25, 2.25], shuffled by a generator
  seeded from the participant ID (the same participant always gets the same order).
* Phase III: the plan of ``study.design`` for the participant's design row (the ID's
  number mod 6): by default the paper's form (three comparisons of two games, six
  task versions), ``--phase3 short`` the quick three-game form; the plan is fixed when
  the participant is created and kept in session.json.
* The questionnaire after each comparison (``study.subjective``: five statements rated
  for each of the two games, and the preference between them, 7 points).
* ``SessionStore``: <out>/<participant>/session.json, written atomically after every
  scene, fit, game and answer, so a closed tab or Ctrl-C loses at most the scene or
  game that was running. A complete participant is never overwritten.
* ``subject_record`` / ``write_subject`` / ``load_subject``: the same record a
  simulated subject of ``supersafe study`` has (subject, phase2, fit, states,
  learned_vf, games: per treatment, the mean of its games), plus the plan, every game
  played (``plays``), Phase I (with the driven path) and the answers, in
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

from ..study.design import SHORT_ORDERS, TREATMENTS, plan, short_plan, treatment_means
from ..study.records import jsonable
from ..study.subjective import POINTS as LIKERT_POINTS, check_answers  # noqa: F401  (the session's)

CONDITIONS = TREATMENTS
LATIN_ORDERS = SHORT_ORDERS          # the short form's orders (a Williams design)
PHASE2_N_OFFSETS = 42
PHASE2_HALF_SPAN = 2.25
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


class ParticipantExists(RuntimeError):
    pass


class SessionStore:
    """<out>/<participant>/session.json: everything done so far."""

    def __init__(self, out_dir, pid: str, n_offsets: int = PHASE2_N_OFFSETS, phase3: str = 'paper'):
        self.pid = check_participant_id(pid)
        self.dir = Path(out_dir) / pid
        self.path = self.dir / 'session.json'
        if self.path.exists():
            self.data = json.loads(self.path.read_text())
            if self.data.get('complete'):
                raise ParticipantExists(f'participant {pid} is complete in {self.dir}; '
                                        'results are never overwritten (choose another ID)')
            self.resumed = True
            if 'plan' not in self.data:     # a session begun before the plan: the short form
                self.data.update(short_form_of(self.data))
                self.save()
        else:
            if self.dir.exists() and any(self.dir.iterdir()):
                raise ParticipantExists(f'{self.dir} exists and is not a session; refusing to touch it')
            self.dir.mkdir(parents=True, exist_ok=True)
            design = plan(phase3, participant_number(pid))
            self.data = {'participant': pid, 'created': time.strftime('%Y-%m-%dT%H:%M:%S%z'),
                         'plan': design, 'order': [g['treatment'] for g in design['games']],
                         'offsets': phase2_offsets(pid, n_offsets),
                         'phase1': None, 'scenes': [], 'fit': None, 'plays': [], 'answers': [],
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


def short_form_of(data: dict) -> dict:
    """The plan and plays of a session.json written before the plan existed (three games
    keyed by condition, in the order of the Latin square): the short form."""
    order = tuple(data.get('order') or SHORT_ORDERS[0])
    design = short_plan(SHORT_ORDERS.index(order) if order in SHORT_ORDERS else 0)
    plays = []
    for g in design['games']:
        done = (data.get('games') or {}).get(g['treatment'])
        if done is None:
            break
        plays.append(dict(done, **g))
    return {'plan': design, 'plays': plays}


def intervention_states(scenes) -> np.ndarray:
    return np.array([s['state'] for s in scenes if s['intervened']], dtype=float).reshape(-1, 3)


def subject_record(data: dict, learned_vf=None, estimator: str = 'paper') -> dict:
    """A study record (see study.records) for a participant's session data;
    ``fit`` is the estimator whose set the Learned game used, ``fits`` holds both."""
    pid = data['participant']
    scenes = data['scenes']
    return {
        'subject': {'index': pid, 'kind': 'human', 'participant': pid, 'order': data['order']},
        'design': {k: data['plan'][k] for k in ('form', 'row')},
        'phase1': data.get('phase1'),
        'phase2': {'scenes': [{k: v for k, v in s.items() if k != 'frames'} for s in scenes],
                   'interventions': int(sum(1 for s in scenes if s['intervened']))},
        'fit': (data.get('fit') or {}).get(estimator.replace('-', '_')),
        'fits': data.get('fit'),
        'states': intervention_states(scenes).tolist(),
        'learned_vf': learned_vf,
        'games': treatment_means(data['plays']),
        'plays': data['plays'],
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
