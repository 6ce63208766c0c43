"""A short study through the real node graph: 1 subject, 3 Phase II offsets, 20 s games."""
import io
import json

from supersafe_ros.study import cli
from supersafe_ros.study.analysis import CONDITIONS


def test_one_subject_study_through_the_graph(tmp_path):
    import argparse
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest='command')
    cli.add_parser(sub)
    out_json = tmp_path / 'out.json'
    args = parser.parse_args(['study', '--subjects', '1', '--seed', '5', '--game-seconds', '20',
                              '--phase2-offsets=-1.0,0.0,1.0', '--sweep-subjects', '0',
                              '--out', str(tmp_path / 'study'), '--json', str(out_json)])
    text = io.StringIO()
    assert cli.run(args, out=text) == 0
    printed = text.getvalue()
    assert 'phase II done' in printed and 'phase III conservative' in printed
    assert 'Interventions' in printed          # Table 1 header

    res = json.loads(out_json.read_text())
    assert set(res['conditions']) == set(CONDITIONS)
    for c in CONDITIONS:
        cond = res['conditions'][c]
        for key in ('false_positives', 'interventions', 'crashes', 'trips'):
            assert len(cond[key]) == 1 and cond[key][0] >= 0
        assert cond['false_positives'][0] <= cond['interventions'][0]
        assert cond['trips'][0] > 0                       # 20 s at 3 m/s: the 33 m to the far goal line take 11 s
        assert 'predicted_fp_ratio' in cond and 'observed_fp_ratio' in cond
    assert res['conditions']['standard']['predicted_fp_ratio'] == 1.0
    assert res['conditions']['standard']['observed_fp_ratio'] == 1.0
    assert 'anova' in res and 'tukey' in res
    subj = res['subjects'][0]
    # the Phase II protocol ran through the graph: one scene per offset, each from x = -8
    scenes = subj['phase2']['scenes']
    assert [s['y0'] for s in scenes] == [-1.0, 0.0, 1.0]
    for s in scenes:
        if s['intervened']:
            assert -8.0 <= s['state'][0] <= 2.6 and abs(s['state'][1] - s['y0']) < 1e-6
    for g in subj['games'].values():
        assert g['complete'] and g['sim_time'] >= 20.0
    assert (tmp_path / 'study' / 'false_positives.png').is_file()
