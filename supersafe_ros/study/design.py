"""Phase III's design as the paper ran it (Sec. IV, "Subject Allocation"): who plays which
treatment, in which comparison, in which place, on which task version.

Each participant completes the three pairwise comparisons of the three treatments
(Standard-Learned, Standard-Conservative, Learned-Conservative), two games each: six
games, each on a different one of six task versions (world layouts). A participant's
design row r (``participant_row``) fixes everything:

* comparison order: row r of a Williams design for three comparisons (``COMPARISON_ORDERS``:
  two mirrored 3 x 3 Latin squares, so over six rows each comparison is in each position
  twice and directly follows each other comparison twice);
* who goes first in each pair: one of the two ``ORIENTATIONS``, r mod 2. Three pairs, each
  treatment first in exactly one: with these comparisons the only two ways are the cycles
  S before L, L before C, C before S, and its reverse. So no treatment is first in a pair
  twice, and over six rows each treatment is first in each of its comparisons three times;
* versions: the k-th game (k = 0, 1) of treatment t (index in ``TREATMENTS``) is on
  version (2 t + k + 2 r) mod 6. Within a row the six values are 0..5 (all different);
  over any three consecutive rows, (2 r) mod 6 takes 0, 2, 4, so each treatment meets
  each version exactly once.

A block is ``BLOCK`` = 6 participants (rows 0..5): every balance above holds over a block.
Version balance alone holds over every 3 consecutive rows. A study of n = 6 q + m
participants (m > 0) has the last m rows unbalanced: some comparison is more often in a
place, some treatment first more often in a pair, and, unless m = 3, some treatment meets
some version more often (the paper's 12 participants are two blocks).

A task version v is a world seed, ``version_world_seed`` (the layout, the goals and the
robots' sensing faults), the same for every participant of a study.

``SHORT``: today's quick three-game form (one game per treatment, Latin-square order, the
participant's own world, questionnaires after games 2 and 3 on the last two games) for
demos; it does not compare Learned with Standard for every participant.
"""
from __future__ import annotations

import math

TREATMENTS = ('standard', 'learned', 'conservative')
COMPARISONS = (('standard', 'learned'), ('standard', 'conservative'), ('learned', 'conservative'))
# Williams design over the comparisons (indices into COMPARISONS)
COMPARISON_ORDERS = ((0, 1, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0), (0, 2, 1), (1, 0, 2))
# the treatment played first in each comparison (S-L, S-C, L-C)
ORIENTATIONS = (('standard', 'conservative', 'learned'), ('learned', 'standard', 'conservative'))
N_VERSIONS = 6
BLOCK = 6
VERSION_SEED_BASE = 900_000
FORMS = ('paper', 'short')
# the short form: Williams orders of the treatments (as the session ran them before)
SHORT_ORDERS = (
    ('standard', 'learned', 'conservative'),
    ('learned', 'conservative', 'standard'),
    ('conservative', 'standard', 'learned'),
    ('conservative', 'learned', 'standard'),
    ('standard', 'conservative', 'learned'),
    ('learned', 'standard', 'conservative'),
)


def comparison_name(a: str, b: str) -> str:
    """'standard-learned' for either order of the pair (the order of ``COMPARISONS``)."""
    for pair in COMPARISONS:
        if {a, b} == set(pair):
            return f'{pair[0]}-{pair[1]}'
    raise ValueError(f'no comparison of {a} and {b}')


def version_world_seed(version: int, study_seed: int = 0) -> int:
    """The world seed of task version ``version`` (0..5): 900000 + 10 seed + version."""
    if not 0 <= int(version) < N_VERSIONS:
        raise ValueError(f'task version {version}: 0..{N_VERSIONS - 1}')
    return VERSION_SEED_BASE + 10 * int(study_seed) + int(version)


def paper_plan(row: int) -> dict:
    """The six games and three questionnaires of design row ``row`` (any integer; mod 6).

    games: [{'game' (1..6), 'treatment', 'comparison' ('standard-learned'), 'comparison_number'
    (1..3), 'position_in_pair' (1, 2), 'version' (0..5)}]; questionnaires: [{'after_game',
    'games' (the two game numbers), 'comparison'}]."""
    r = int(row) % BLOCK
    first = dict(zip(COMPARISONS, ORIENTATIONS[r % 2]))
    seen = dict.fromkeys(TREATMENTS, 0)
    games, questionnaires = [], []
    for q, ci in enumerate(COMPARISON_ORDERS[r]):
        pair = COMPARISONS[ci]
        a = first[pair]
        b = pair[1] if a == pair[0] else pair[0]
        name = comparison_name(*pair)
        for pos, t in enumerate((a, b), start=1):
            k = seen[t]
            seen[t] += 1
            games.append({'game': len(games) + 1, 'treatment': t, 'comparison': name,
                          'comparison_number': q + 1, 'position_in_pair': pos,
                          'version': (2 * TREATMENTS.index(t) + k + 2 * r) % N_VERSIONS})
        questionnaires.append({'after_game': len(games), 'games': [len(games) - 1, len(games)],
                               'comparison': name})
    return {'form': 'paper', 'row': r, 'games': games, 'questionnaires': questionnaires}


def short_plan(row: int) -> dict:
    """The quick form: three games (one per treatment), questionnaires after games 2 and 3
    on games (1, 2) and (2, 3); no task version (the participant's own world)."""
    r = int(row) % len(SHORT_ORDERS)
    order = SHORT_ORDERS[r]
    games = [{'game': i + 1, 'treatment': t, 'comparison': None, 'comparison_number': None,
              'position_in_pair': None, 'version': None} for i, t in enumerate(order)]
    questionnaires = [{'after_game': k + 1, 'games': [k, k + 1], 'comparison': comparison_name(order[k - 1], order[k])}
                      for k in (1, 2)]
    return {'form': 'short', 'row': r, 'games': games, 'questionnaires': questionnaires}


def plan(form: str, row: int) -> dict:
    if form not in FORMS:
        raise ValueError(f"Phase III form '{form}': one of {', '.join(FORMS)}")
    return paper_plan(row) if form == 'paper' else short_plan(row)


COUNT_KEYS = ('trips', 'crashes', 'interventions', 'false_positives')
PLAN_KEYS = ('game', 'treatment', 'comparison', 'comparison_number', 'position_in_pair', 'version',
             'world_seed')


def treatment_means(plays: list) -> dict:
    """treatment -> its games' entries averaged, in the order the treatments were first played:
    a number is the mean over the treatment's games (a count played once stays as it is),
    None / NaN values left out of a mean (None if no game has one), a flag true when true
    for every game; anything else is its first game's. ``totals``: the counts summed over
    its games (for count models); ``games`` and ``versions``: its game numbers and task
    versions. The other plan keys (comparison, place) are per game, not per treatment."""
    out = {}
    for t in dict.fromkeys(p['treatment'] for p in plays):
        mine = [p for p in plays if p['treatment'] == t]
        entry = {}
        for k in mine[0]:
            if k in PLAN_KEYS:
                continue
            vals = [p.get(k) for p in mine]
            if all(isinstance(v, bool) for v in vals):       # e.g. complete: every game was
                entry[k] = all(vals)
                continue
            numeric = all(v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in vals)
            if len(mine) == 1 or not numeric or all(v is None for v in vals):
                entry[k] = vals[0]
                continue
            nums = [float(v) for v in vals if v is not None and math.isfinite(float(v))]
            entry[k] = sum(nums) / len(nums) if nums else None
        entry['games'] = [p.get('game') for p in mine]
        entry['versions'] = [p.get('version') for p in mine]
        entry['totals'] = {k: sum(int(p[k]) for p in mine) for k in COUNT_KEYS if k in mine[0]}
        out[t] = entry
    return out
