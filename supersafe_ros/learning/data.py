"""Intervention data: encounters, CSV files, and the paper's Phase II protocol.

Two kinds of data set:

* **intervention states** (what the paper's experiment recorded): one row per
  intervention, columns ``t_ms,x,y,theta`` -- the robot's state in the obstacle's
  frame at the moment the supervisor intervened.
* **encounters** (what the first-passage estimator needs): every frame of every
  approach, columns ``scene,t,x,y,theta,intervened``; the last row of a scene has
  ``intervened = 1`` when the supervisor intervened there (and the scene stops), and
  all rows of a scene the supervisor let pass have ``intervened = 0``.

Phase II protocol (paper, section III; shared/data/s3/README.md): one robot starts
at x = -8 heading 0 and drives straight (u = 0) at speed 3 toward an obstacle of
radius 1.8 at the origin, from lateral offsets y0 in [-2.25, 2.25]. A pass ends at
the first frame on or inside the obstacle (a crash) or when the robot has crossed
the arena (x >= -x0).
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
import os

import numpy as np


@dataclass
class Encounter:
    """One approach of a robot to an obstacle, judged by a supervisor.

    states: (T, 3) relative states (obstacle at the origin), frame by frame, up to and
        including the intervention frame when ``intervened``, else the whole pass.
    intervened: whether the last frame is where the supervisor intervened.
    scene: an identifier (int or str) of the scene the encounter came from.
    t: (T,) frame times in seconds (optional; only carried to the CSV).
    full_pass: (M, 3) frames of the whole pass had nobody intervened (optional, M >= T).
        Known for protocol-driven data; lets the estimator condition on "an
        intervention happened" when the encounters without one were not recorded.
    """

    states: np.ndarray
    intervened: bool
    scene: object = 0
    t: np.ndarray | None = None
    full_pass: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        s = np.asarray(self.states, dtype=float)
        if s.ndim != 2 or s.shape[1] != 3 or len(s) == 0:
            raise ValueError(f'encounter {self.scene!r}: states must be (T >= 1, 3), got {s.shape}')
        if not np.all(np.isfinite(s)):
            raise ValueError(f'encounter {self.scene!r}: states contain NaN or infinite values')
        self.states = s
        self.intervened = bool(self.intervened)
        if self.t is not None:
            t = np.asarray(self.t, dtype=float).reshape(-1)
            if t.shape != (len(s),):
                raise ValueError(f'encounter {self.scene!r}: t has {t.size} entries for {len(s)} frames')
            self.t = t
        if self.full_pass is not None:
            fp = np.asarray(self.full_pass, dtype=float)
            if fp.ndim != 2 or fp.shape[1] != 3 or len(fp) < len(s) or not np.all(np.isfinite(fp)):
                raise ValueError(f'encounter {self.scene!r}: full_pass must be finite (M >= {len(s)}, 3), '
                                 f'got {fp.shape}')
            self.full_pass = fp


def intervention_states(encounters) -> np.ndarray:
    """(N, 3) states of the encounters that ended with an intervention."""
    rows = [e.states[-1] for e in encounters if e.intervened]
    return np.asarray(rows, dtype=float).reshape(-1, 3)


# -- CSV -------------------------------------------------------------------------------
def _read_rows(path, required):
    path = os.fspath(path)
    with open(path, newline='') as f:
        reader = csv.DictReader(f)
        header = [h.strip() for h in (reader.fieldnames or [])]
        missing = [c for c in required if c not in header]
        if missing:
            raise ValueError(f'{path}: missing column(s) {missing}; header is {header}')
        reader.fieldnames = header
        rows = list(reader)
    return path, header, rows


def _float(path, lineno, row, key):
    try:
        v = float(row[key])
    except (TypeError, ValueError):
        raise ValueError(f'{path}:{lineno}: column {key!r} is not a number: {row[key]!r}') from None
    if not np.isfinite(v):
        raise ValueError(f'{path}:{lineno}: column {key!r} is not finite: {row[key]!r}')
    return v


def detect_csv_kind(path) -> str:
    """'encounters' if the header has scene and intervened columns, else 'interventions'."""
    with open(os.fspath(path), newline='') as f:
        header = [h.strip() for h in next(csv.reader(f), [])]
    return 'encounters' if {'scene', 'intervened'} <= set(header) else 'interventions'


def read_interventions_csv(path) -> np.ndarray:
    """(N, 3) intervention states from a ``t_ms,x,y,theta`` file (extra columns ignored).

    If the file is an encounters file, its intervention frames are returned instead.
    """
    if detect_csv_kind(path) == 'encounters':
        return intervention_states(read_encounters_csv(path))
    path, _, rows = _read_rows(path, ('x', 'y', 'theta'))
    out = np.empty((len(rows), 3))
    for n, row in enumerate(rows):
        out[n] = [_float(path, n + 2, row, k) for k in ('x', 'y', 'theta')]
    return out


def read_encounters_csv(path) -> list[Encounter]:
    """Encounters from a ``scene,t,x,y,theta,intervened`` file (one row per frame).

    Rows are grouped by scene (in order of first appearance) and ordered by t within a
    scene. ``intervened`` may be 1 only on the last frame of a scene.
    """
    path, _, rows = _read_rows(path, ('scene', 't', 'x', 'y', 'theta', 'intervened'))
    scenes: dict[str, list] = {}
    for n, row in enumerate(rows):
        lineno = n + 2
        flag = _float(path, lineno, row, 'intervened')
        if flag not in (0.0, 1.0):
            raise ValueError(f'{path}:{lineno}: intervened must be 0 or 1, got {row["intervened"]!r}')
        frame = (_float(path, lineno, row, 't'),
                 *(_float(path, lineno, row, k) for k in ('x', 'y', 'theta')), flag, lineno)
        scenes.setdefault(row['scene'].strip(), []).append(frame)
    encounters = []
    for scene, frames in scenes.items():
        frames.sort(key=lambda fr: fr[0])
        flags = [fr[4] for fr in frames]
        if any(flags[:-1]):
            bad = frames[flags.index(1.0)][5]
            raise ValueError(f'{path}:{bad}: scene {scene!r} has intervened = 1 before its last frame')
        arr = np.array([fr[:4] for fr in frames], dtype=float)
        encounters.append(Encounter(arr[:, 1:4], bool(flags[-1]), _scene_id(scene), t=arr[:, 0]))
    return encounters


def _scene_id(text):
    try:
        return int(text)
    except ValueError:
        return text


def write_encounters_csv(path, encounters) -> None:
    """Write encounters as ``scene,t,x,y,theta,intervened`` (t = frame index if unknown)."""
    path = os.fspath(path)
    tmp = path + '.tmp'
    with open(tmp, 'w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['scene', 't', 'x', 'y', 'theta', 'intervened'])
        for e in encounters:
            t = e.t if e.t is not None else np.arange(len(e.states), dtype=float)
            last = len(e.states) - 1
            for k, (tk, s) in enumerate(zip(t, e.states)):
                w.writerow([e.scene, repr(float(tk)), repr(float(s[0])), repr(float(s[1])),
                            repr(float(s[2])), int(e.intervened and k == last)])
    os.replace(tmp, path)


# -- Phase II protocol -------------------------------------------------------------------
PHASE2_OFFSETS = np.linspace(-2.25, 2.25, 19)   # the 0.25 m ladder seen in the pilot files


def phase2_pass(y0, speed=3.0, radius=1.8, x0=-8.0, dt=0.02, x_end=None):
    """Frames (T, 3) and times (T,) of one straight pass (u = 0, heading 0) from (x0, y0).

    The pass ends at the first frame on or inside the obstacle disc (included), or
    at the last frame with x <= x_end (default -x0, the far side of the arena).
    """
    if not (speed > 0 and dt > 0 and radius >= 0):
        raise ValueError(f'need speed > 0, dt > 0, radius >= 0; got {speed}, {dt}, {radius}')
    x_end = -x0 if x_end is None else x_end
    n = int(np.floor((x_end - x0) / (speed * dt) + 1e-9)) + 1
    t = np.arange(max(n, 1)) * dt
    x = x0 + speed * t
    frames = np.stack([x, np.full_like(x, y0), np.zeros_like(x)], axis=1)
    inside = np.flatnonzero(np.hypot(x, y0) <= radius)
    if inside.size:
        frames, t = frames[:inside[0] + 1], t[:inside[0] + 1]
    return frames, t


def phase2_encounters(supervisor, offsets=PHASE2_OFFSETS, speed=3.0, radius=1.8, x0=-8.0,
                      dt=0.02, rng=None) -> list[Encounter]:
    """The authors' Phase II protocol, judged by ``supervisor`` frame by frame.

    One encounter per offset y0 (repeat offsets to repeat scenes): the robot drives
    straight from (x0, y0) heading 0; the supervisor's ``judge_encounter`` picks the
    intervention frame (or none). Each encounter keeps its ``full_pass``.

    rng: seed or Generator for the supervisor's draws (None: the supervisor's own).
    """
    offsets = np.asarray(offsets, dtype=float).reshape(-1)
    if not np.all(np.isfinite(offsets)):
        raise ValueError('offsets must be finite')
    saved = getattr(supervisor, 'rng', None)
    if rng is not None:
        supervisor.rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    try:
        out = []
        for scene, y0 in enumerate(offsets):
            frames, t = phase2_pass(y0, speed, radius, x0, dt)
            k = supervisor.judge_encounter(frames)
            if k is None:
                out.append(Encounter(frames, False, scene, t=t, full_pass=frames))
            else:
                out.append(Encounter(frames[:k + 1], True, scene, t=t[:k + 1], full_pass=frames))
        return out
    finally:
        if rng is not None:
            supervisor.rng = saved


def encounters_from_phase2_interventions(states, speed=3.0, radius=1.8, x0=-8.0, dt=0.02,
                                         tol_theta=1e-6) -> list[Encounter]:
    """Rebuild the approaches behind Phase II intervention states (theta = 0, y = y0).

    Assumes the protocol: each intervention ended a straight pass from x0 at the
    intervention's y. Frames step back from the intervention state by speed * dt, so
    the last frame is exactly the recorded state; ``full_pass`` is the whole pass at
    that offset. The passes the supervisor let go by are NOT in such data (the files
    record interventions only), so these encounters are all ``intervened``.
    """
    s = np.asarray(states, dtype=float).reshape(-1, 3)
    if np.any(np.abs(np.asarray(s[:, 2])) > tol_theta):
        raise ValueError('Phase II interventions have theta = 0 (straight passes heading +x); '
                         f'got thetas {np.unique(np.round(s[:, 2], 6))[:5]}')
    out = []
    for n, (x, y, _) in enumerate(s):
        if x < x0:
            raise ValueError(f'intervention {n} at x = {x} lies before the start x0 = {x0}')
        k = int(np.floor((x - x0) / (speed * dt) + 1e-9))
        xs = x - speed * dt * np.arange(k, -1, -1)
        frames = np.stack([xs, np.full_like(xs, y), np.zeros_like(xs)], axis=1)
        t = (xs - x0) / speed
        full, _ = phase2_pass(y, speed, radius, x, dt, x_end=-x0)   # the rest of the pass
        full = np.concatenate([frames[:-1], full]) if len(full) else frames
        out.append(Encounter(frames, True, n, t=t, full_pass=full))
    return out
