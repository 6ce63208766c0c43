"""Model validity (study.validity) and the game traces it reads (study.game_trace)."""
import numpy as np
import pytest

from supersafe_ros.study.game_trace import bearing_class, bearing_deg
from supersafe_ros.study.validity import format_validity, model_validity, poisson_ratio_ci


class XValue:
    """V(x, y, theta) = x + offset."""

    def __init__(self, offset=0.0):
        self.offset = offset

    def value(self, states):
        return np.asarray(states, dtype=float).reshape(-1, 3)[:, 0] + self.offset


def iv(x, fp, after=False, bearing=0.0, v=0.5):
    return {'state': [x, 0.0, 0.0], 'false_positive': fp, 'after_override': after, 'bearing': bearing,
            'v_minus_alpha': v}


def trace(interventions, onsets=((0.4, 5.0), (0.2, 40.0))):
    return {'interventions': interventions,
            'onsets': {'v_minus_alpha': [o[0] for o in onsets], 'bearing': [o[1] for o in onsets], 'time': [0, 1]}}


def test_bearings_and_the_poisson_ratio_interval():
    assert bearing_deg([-5.0, 0.0, 0.0]) == pytest.approx(0.0)          # heading at the centre
    assert bearing_deg([0.0, -3.0, 0.0]) == pytest.approx(90.0)         # abreast: tangential
    assert bearing_deg([-3.0, -3.0, 0.0]) == pytest.approx(45.0)
    assert [bearing_class(b) for b in (5, 30, 75)] == ['head-on', 'oblique', 'tangential']
    lo, hi = poisson_ratio_ci(10, 10)
    assert lo < 1 < hi and lo * hi == pytest.approx(1.0)                 # symmetric in log
    assert poisson_ratio_ci(0, 5)[0] == 0.0 and poisson_ratio_ci(5, 0)[1] == float('inf')
    assert all(np.isnan(poisson_ratio_ci(0, 0)))


def test_model_validity_puts_the_prediction_beside_the_observation_and_finds_the_gap():
    # Phase II x: [-2, -1, 1, 2, 3] -> inside Standard (x > 0): 3; inside Learned (x > 1.5): 2 -> 2/3
    # Standard games' states x: [0.5, 2, 4] -> inside std 3, inside learned 2 -> 2/3
    records = []
    for i in range(4):
        games = {'standard': {'false_positives': 6, 'trace': trace([iv(0.5, True), iv(2.0, True), iv(4.0, False)])},
                 'learned': {'false_positives': 3 + (i % 2), 'crashes': i % 2,
                             'trace': trace([iv(2.0, True, after=True, bearing=80.0), iv(3.0, True, v=-0.1)])}}
        records.append({'subject': {'index': i}, 'states': [[x, 0, 0] for x in (-2, -1, 1, 2, 3)],
                        'games': games})
    sets = {'standard': (XValue(), 0.0), 'learned': (XValue(), 1.5)}
    v = model_validity(records, lambda r: sets, ['standard', 'learned'], seed=1, draws=200)
    p = v['pooled']['learned']
    assert p['predicted'] == pytest.approx(2 / 3) and p['games_predicted'] == pytest.approx(2 / 3)
    assert p['observed'] == pytest.approx(14 / 24)
    assert p['observed_ci'][0] <= p['observed'] <= p['observed_ci'][1]
    assert p['gap'] == pytest.approx(14 / 24 - 2 / 3)
    rows = v['per_subject']['learned']
    assert [r['observed'] for r in rows] == [0.5, 4 / 6, 0.5, 4 / 6] and rows[0]['predicted'] == pytest.approx(2 / 3)
    g = v['gap']['learned']
    assert g['false_positives'] == 8 and g['fp_after_override'] == 0.5 and g['fp_tangential'] == 0.5
    assert g['fp_inside_set'] == 0.5 and g['onset_v_minus_alpha']['head-on']['median'] == pytest.approx(0.4)
    assert v['gap']['standard']['fp_after_override'] == 0.0
    assert g['crashes'] == 2 and v['gap']['standard']['crashes'] == 0     # beside the false positives
    text = format_validity(v).splitlines()
    assert 'crashes' in text[-3] and text[-1].startswith('Learned') and text[-1].rstrip().endswith(' 2')
