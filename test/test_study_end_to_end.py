"""A short study through the real node graph (``--engine graph``): 1 subject, 3 Phase II
offsets, four 20 s games (every condition but the core engine's learned_online) on one
kept-alive Phase III graph (reset between games); and the same subject's Phase II on the
in-process engine agrees with the graph's."""
import io
import json
import math

import pytest

from supersafe_ros.study import cli
from supersafe_ros.study.analysis import CONDITIONS, H2_MEASURES

pytestmark = [pytest.mark.ros, pytest.mark.slow]   # the study's graph engine: node processes, ~25 s


def test_one_subject_study_through_the_graph(tmp_path):
    import argparse
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest='command')
    cli.add_parser(sub)
    out_json = tmp_path / 'out.json'
    args = parser.parse_args(['study', '--subjects', '1', '--seed', '5', '--game-seconds', '20',
                              '--phase2-offsets=-1.0,0.0,1.0', '--sweep-subjects', '0',
                              '--out', str(tmp_path / 'study'), '--json', str(out_json), '--engine', 'graph'])
    text = io.StringIO()
    assert cli.run(args, out=text) == 0
    printed = text.getvalue()
    assert 'phase II done' in printed and 'phase III conservative' in printed
    assert 'Interventions' in printed and 'paper Learned' in printed     # Table 1 beside the paper's
    assert 'arcs shorter than Conservative' in printed                    # the H2 panel

    res = json.loads(out_json.read_text())
    graph_conditions = [c for c in CONDITIONS if c != 'learned_online']      # a core-engine condition
    assert list(res['conditions']) == graph_conditions
    games = res['subjects'][0]['games']
    for c in graph_conditions:
        cond = res['conditions'][c]
        for key in ('false_positives', 'interventions', 'crashes', 'trips') + H2_MEASURES:
            assert len(cond[key]) == 1
        assert 0 <= cond['false_positives'][0] <= cond['interventions'][0]
        # 20 s at 3 m/s: each robot crosses the field (33 m) at most twice; counts that
        # carried over from the previous game on the kept-alive graph would exceed that
        assert 0 < cond['trips'][0] <= 4
        assert cond['path_per_trip'][0] >= 32.0                  # at least the 32 m between the lines
        assert 0.0 <= cond['override_fraction'][0] <= 1.0
        assert cond['min_clearance'][0] is not None and cond['min_clearance'][0] > -1.8
        assert games[c]['complete'] and math.isclose(games[c]['sim_time'], 20.0, abs_tol=0.01)
    assert res['conditions']['standard']['predicted_fp_ratio'] == 1.0
    assert res['conditions']['standard']['observed_fp_ratio'] == 1.0
    assert 'anova' in res and 'tukey' in res and 'shorter_arcs_than_conservative' in res['h2']
    subj = res['subjects'][0]
    assert subj['fits']['learned'] is not None, subj['phase2']      # its notes say what went wrong
    assert subj['fits']['learned']['estimator'] == 'paper'
    # learned_fp is the first-passage learner node's fit: it built one encounter per scene
    # from robot_0/pose and /obstacle_markers, with the scenes' interventions
    fp = subj['fits']['learned_fp']
    assert fp is not None, subj['phase2']
    assert fp['estimator'] == 'first-passage'
    n_int = sum(s['intervened'] for s in subj['phase2']['scenes'])
    # at least one encounter per scene; a scene reset can add one that ends at the teleport
    # (a 'jump', as specified; see test_nodes_learner_graph)
    assert fp['encounters'] >= 3 and fp['interventions'] == n_int
    assert fp['unmatched_interventions'] == 0
    assert subj['phase2']['offline_first_passage']['encounters'] == 3      # the runner's cross-check
    # the Phase II protocol ran through the graph: one scene per offset, each from x = -8
    scenes = subj['phase2']['scenes']
    assert [s['y0'] for s in scenes] == [-1.0, 0.0, 1.0]
    for s in scenes:
        if s['intervened']:
            assert -8.0 <= s['state'][0] <= 2.6 and abs(s['state'][1] - s['y0']) < 1e-6
    for name in ('false_positives.png', 'efficiency.png'):
        assert (tmp_path / 'study' / name).is_file()
    assert res['options']['engine'] == 'graph' and games['standard']['engine'] == 'graph'

    # the in-process engine plays the same scenes: the supervisor's draws are keyed by
    # (seed, robot, obstacle id, approach), and both number the scenes' discs from 0
    from supersafe_ros.study.engine import CoreStudy
    from supersafe_ros.study.population import Subject
    from supersafe_ros.study.protocol import StudyOptions
    core = CoreStudy().phase2(Subject(**subj['subject']), StudyOptions(phase2_offsets=(-1.0, 0.0, 1.0)))
    # one scene may differ: in one of 38 compared scenes (bench_study --compare) the graph's
    # supervisor intervened and the engine's did not, not yet explained (docs/study.md)
    same = [c['intervened'] == g['intervened'] for c, g in zip(core.scenes, scenes)]
    assert len(same) == 3 and sum(same) >= 2, same
    for c, g in zip(core.scenes, scenes):
        if g['intervened'] and c['intervened']:
            assert math.dist(c['state'][:2], g['state'][:2]) < 1e-3
    if subj['fits']['learned'] and all(same):
        assert core.fit['omega_max'] == subj['fits']['learned']['omega_max']
        assert math.isclose(core.fit['mu'], subj['fits']['learned']['mu'], abs_tol=1e-3)
