"""The fit screen: what the participant is told, and what the researcher reads.

The participant sees no estimator, no w_max, mu or sigma: a sentence in their words
("the robots will now turn away earlier than before") and a drawing on the field of a
Phase II scene: the obstacle, where they stopped the robots (dots), and the line where
a robot heading that way starts to turn away, before (the Standard set) and now (the
set learned from them, at its level). The numbers go to the researcher: the terminal
and session.json.

"Turns away" is the filter's rule: a robot heading along +x at lateral offset y turns
when its state enters {V <= alpha}; the turn line is, per offset, the first such x
on the way to the obstacle. Earlier / later compares the head-on (y = 0) distances.
"""
from __future__ import annotations

import numpy as np

SCAN_STEP = 0.05       # m between the states read along a robot's straight approach
SAME_WITHIN = 0.25     # m: closer than this, the robots turn "at about the same point"
LINE_OFFSETS = np.linspace(-2.25, 2.25, 19)   # the Phase II offsets' span


def turn_x(vf, alpha: float, y: float = 0.0, x_from: float = -8.0, x_to: float = 0.0) -> float | None:
    """The first x on a straight approach (heading +x at offset y, from ``x_from``) where the
    filter turns the robot (V <= alpha); None if it never does before ``x_to``."""
    xs = np.arange(x_from, x_to + 1e-9, SCAN_STEP)
    states = np.column_stack([xs, np.full_like(xs, y), np.zeros_like(xs)])
    inside = np.flatnonzero(vf.value(states) <= alpha)
    return float(xs[inside[0]]) if len(inside) else None


def turn_line(vf, alpha: float, offsets=LINE_OFFSETS) -> list:
    """[[x, y], ...] where a robot heading +x at each offset turns (offsets it never turns at
    are left out)."""
    out = []
    for y in offsets:
        x = turn_x(vf, alpha, float(y))
        if x is not None:
            out.append([round(x, 2), round(float(y), 2)])
    return out


def compare(standard_x: float | None, learned_x: float | None) -> str:
    """'earlier', 'later' or 'same': when a robot heading at the obstacle turns away with
    the learned set, against the standard one (x further from the obstacle = earlier)."""
    if standard_x is None or learned_x is None:
        return 'same' if standard_x == learned_x else ('earlier' if standard_x is None else 'later')
    if learned_x < standard_x - SAME_WITHIN:
        return 'earlier'
    if learned_x > standard_x + SAME_WITHIN:
        return 'later'
    return 'same'


SENTENCES = {
    'earlier': 'The robots will now turn away from an obstacle earlier than before: further from it, '
               'closer to where you stopped them.',
    'later': 'The robots will now turn away from an obstacle later than before: nearer to it, '
             'as you let them come closer before stopping them.',
    'same': 'The robots will turn away from an obstacle at about the same point as before: '
            'that is about where you stopped them.',
    'none': 'You let every robot pass, so there was nothing to learn from: the robots keep '
            'their usual way of avoiding obstacles.',
}


def fit_view(scenes, fit: dict | None, learned_vf, standard_vf, standard_alpha: float = 0.0) -> dict:
    """(page, researcher): the page's view of the fit (words and a drawing, no numbers in
    its text) and the researcher's summary of the same (numbers)."""
    stops = [[round(float(s['state'][0]), 2), round(float(s['state'][1]), 2)]
             for s in scenes if s.get('intervened') and s.get('state')]
    before = turn_line(standard_vf, standard_alpha)
    std_x = turn_x(standard_vf, standard_alpha)
    if fit and learned_vf is not None:
        alpha = float(fit['mu'])
        now = turn_line(learned_vf, alpha)
        learned_x = turn_x(learned_vf, alpha)
        word = compare(std_x, learned_x)
    else:
        now, learned_x, word = before, std_x, 'none'
    n = len(stops)
    page = {
        'stops': n, 'scenes': len(scenes), 'change': word,
        'summary': (f'You stopped the robot in {n} of {len(scenes)} scenes.' if n
                    else f'You let the robot pass in all {len(scenes)} scenes.'),
        'sentence': SENTENCES[word],
        'drawing': {'obstacle': [0.0, 0.0, 1.8], 'stops': stops, 'before': before, 'now': now},
    }
    researcher = {'turn_distance_standard': None if std_x is None else -std_x,
                  'turn_distance_learned': None if learned_x is None else -learned_x,
                  'change': word}
    return page, researcher
