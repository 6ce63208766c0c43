"""Simulated subjects: the authors' five pilot supervisors, fitted with the package's estimators.

The paper's experiment software came with five pilot files of Phase II interventions
(``../shared/data/s3/pilot*_interventions.csv``: the robot's state relative to the obstacle
when a pilot supervisor intervened, straight passes from x = -8 at 42 offsets). They are the
only human data there is, so the simulated population is built from them rather than from
invented ranges:

* each pilot file is fitted with the package's first-passage estimator
  (``learning.estimators.fit_first_passage`` on the approaches rebuilt by
  ``learning.data.encounters_from_phase2_interventions``, conditioned on an intervention,
  since the files hold intervened passes only; the study's library and conservative prior,
  true omega_max 1). First-passage is the estimator that recovers a simulated supervisor's
  w_S and mu (docs/fit.md); where no entry explains every intervention (pilot 2: an
  intervention after a frame with a lower value), the lapse model with lapse 0.01;
* a subject is one pilot's fitted (w_S, mu, sigma), with a noise seed of its own. The
  pilots are dealt in rounds of five, each round in an order drawn from the seed, so every
  pilot is used floor(n/5) or ceil(n/5) times;
* the files are looked up in ``$SUPERSAFE_PILOT_DATA``, else ``../shared/data/s3`` next to
  the repository. Without them the population falls back to ``PILOT_TABLE``: the same fits,
  written down (a test checks the table against the files).

The paper's estimator on the same files (for comparison; ``PILOT_TABLE_PAPER``) picks
w 0.75 for pilots 3 and 5 and mu ~ 0 for all but pilot 5: on straight approaches it
prefers a lower turn rate and margin, as docs/fit.md explains.

Everything is drawn from numpy's default_rng(seed): the same seed gives the same subjects.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
import os
from pathlib import Path

import numpy as np

PILOT_NAMES = tuple(f'pilot{n}' for n in range(1, 6))
PILOT_LAPSE = 0.01          # only where the pure model cannot explain every intervention

# first-passage fits of the five pilot files (name: interventions, w_S, mu, sigma, lapse),
# library 65 x 65 x 42 on [-8, 8]^2, speed 3, radius 1.8, horizon 3, prior true w 1
PILOT_TABLE = {
    'pilot1': (14, 1.0, 0.0, 0.5479, 0.0),
    'pilot2': (24, 1.0, 0.0, 0.4608, PILOT_LAPSE),
    'pilot3': (70, 1.0, 0.0492, 0.5122, 0.0),
    'pilot4': (63, 1.0, 0.0, 0.3973, 0.0),
    'pilot5': (36, 1.0, 0.2359, 0.4469, 0.0),
}
# the paper's estimator (eqs. 3-4) on the same files, for the documentation
PILOT_TABLE_PAPER = {
    'pilot1': (14, 1.0, 0.0, 0.5012),
    'pilot2': (24, 1.0, 0.0, 0.4448),
    'pilot3': (70, 0.75, 0.0, 0.4059),
    'pilot4': (63, 1.0, 0.0, 0.3853),
    'pilot5': (36, 0.75, 0.1014, 0.4059),
}


@dataclass(frozen=True)
class Subject:
    index: int
    omega_max: float
    mu: float
    sigma: float
    seed: int
    pilot: str = ''

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class PilotFit:
    name: str
    interventions: int
    omega_max: float
    mu: float
    sigma: float
    lapse: float = 0.0


def pilot_dir() -> Path:
    env = os.environ.get('SUPERSAFE_PILOT_DATA')
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / '..' / 'shared' / 'data' / 's3'


def table_fits() -> list[PilotFit]:
    return [PilotFit(name, *PILOT_TABLE[name]) for name in PILOT_NAMES]


def fit_pilot(path, library=None) -> PilotFit:
    """First-passage fit of one pilot file over the study's library (see the module doc)."""
    from ..learning.data import encounters_from_phase2_interventions, read_interventions_csv
    from ..learning.estimators import fit_first_passage
    from ..reach.library import load_or_build_library
    lib = library or load_or_build_library()
    states = read_interventions_csv(path)
    enc = encounters_from_phase2_interventions(states)
    true_vf = lib.entry(1.0)
    lapse = 0.0
    try:
        fit = fit_first_passage(lib.entries, enc, true_vf=true_vf, conditional=True)
    except ValueError:          # no entry explains every intervention: allow lapses
        lapse = PILOT_LAPSE
        fit = fit_first_passage(lib.entries, enc, true_vf=true_vf, conditional=True, lapse=lapse)
    return PilotFit(Path(path).name.split('_')[0], len(states), float(fit.omega_max),
                    float(fit.mu), float(fit.sigma), lapse)


def pilot_fits(directory=None, library=None) -> tuple[list[PilotFit], str]:
    """(the five pilots' fits, where they came from): the files when all five are there,
    else the documented table."""
    d = Path(directory) if directory is not None else pilot_dir()
    files = [d / f'{name}_interventions.csv' for name in PILOT_NAMES]
    if all(f.is_file() for f in files):
        return [fit_pilot(f, library) for f in files], str(d.resolve())
    return table_fits(), 'PILOT_TABLE (pilot files not found)'


def draw_subjects(n: int, seed: int, pilots: list[PilotFit] | None = None) -> list[Subject]:
    """``n`` subjects dealt from the pilots' fits (default the table) in shuffled rounds."""
    if n < 1:
        raise ValueError(f'need at least one subject, got {n}')
    pilots = list(pilots) if pilots is not None else table_fits()
    if not pilots:
        raise ValueError('no pilots to draw subjects from')
    rng = np.random.default_rng(seed)
    order = []
    while len(order) < n:
        order.extend(rng.permutation(len(pilots)).tolist())
    out = []
    for i in range(n):
        p = pilots[order[i]]
        out.append(Subject(i, float(p.omega_max), round(float(p.mu), 4), round(float(p.sigma), 4),
                           int(rng.integers(0, 2**31 - 1)), p.name))
    return out
