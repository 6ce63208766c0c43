"""learned_online (study.online): the Learned game's learner keeps learning from the team."""
import argparse

import pytest

from supersafe_ros.study import cli, engine
from supersafe_ros.study.game_trace import bearing_class, bearing_deg
from supersafe_ros.study.online import OnlineLearner, fp_by_quarter, online_report
from supersafe_ros.study.population import Subject
from supersafe_ros.study.protocol import StudyOptions


def test_the_online_game_starts_as_learned_fp_and_refits_from_the_teams_own_encounters():
    core = engine.CoreStudy()
    subject = Subject(0, 0.375, 1.3, 0.5, 4321)          # the paper population's conservative-like member
    opts = StudyOptions(game_seconds=25.0)
    p2 = core.phase2(subject, opts)
    assert p2.fp_vf is not None and len(p2.fp_records) == len(opts.phase2_offsets)
    start, _, ran = core.safe_set('learned_online', {'learned_online': (p2.fp_vf, p2.fp_fit)})
    assert ran == 'learned_online' and start.alpha == pytest.approx(p2.fp_fit['alpha'])
    fixed = core.play(subject, 5, start, opts)
    online = core.play(subject, 5, start, opts, online_records=p2.fp_records)
    again = core.play(subject, 5, start, opts, online_records=p2.fp_records)
    assert online['online'] == again['online'] and online['stats'] == again['stats']      # deterministic
    history = [h for h in online['online'] if 'omega_max' in h]
    assert history and history[0]['game_interventions'] >= 1
    assert [h['game_encounters'] for h in history] == sorted(h['game_encounters'] for h in history)
    assert all(b['time'] - a['time'] >= 5.0 - 1e-9 for a, b in zip(history, history[1:]))   # refit period
    # until the first refit is in force the game is learned_fp's own (the same set, the same seeds)
    first = next(h['time'] for h in history if h['in_force'])
    before = [(i['time'], i['obstacle'], i['false_positive']) for i in online['trace']['interventions']
              if i['time'] <= first]
    assert before == [(i['time'], i['obstacle'], i['false_positive']) for i in fixed['trace']['interventions']
                      if i['time'] <= first]
    assert history[-1]['encounters'] == len(p2.fp_records) + history[-1]['game_encounters']


def test_the_online_learner_takes_encounters_at_every_bearing():
    core = engine.CoreStudy()
    subject = Subject(0, 1.0, 0.1, 0.5, 99)
    opts = StudyOptions(game_seconds=20.0)
    p2 = core.phase2(subject, opts)
    start, _, _ = core.safe_set('learned_online', {'learned_online': (p2.fp_vf, p2.fp_fit)})
    learner = OnlineLearner(engine.learners(), p2.fp_records, start)
    loop = engine.TeamLoop(engine.world_config(), 2, dict(zip(engine.robot_names(2), engine.start_poses(2))),
                           {n: 2001 + i for i, n in enumerate(engine.robot_names(2))}, engine.robot_params(),
                           engine.filter_config(0.2), start, engine.make_watcher(subject, 7), 0.2, learner=learner)
    loop.run(20.0)
    records = learner.game_records
    assert learner.game_encounters == len(records) > 5
    bearings = {bearing_class(bearing_deg(r.frames[0])) for r in records}
    assert len(bearings) >= 2          # not only head-on, as Phase II
    assert len(learner.intervals.intervened) == len(p2.fp_records) + len(records)


def test_online_report_counts_fp_per_quarter_and_compares_the_change():
    def game(times, fps, condition):
        return {'false_positives': sum(fps), 'sim_time': 120.0,
                'trace': {'interventions': [{'time': t, 'false_positive': f} for t, f in zip(times, fps)],
                          'onsets': {'v_minus_alpha': [], 'bearing': [], 'time': []}},
                'online': [{'time': 10.0, 'omega_max': 0.5, 'mu': 1.0, 'sigma': 0.3, 'game_encounters': 4}]
                if condition == 'learned_online' else None}
    records = []
    for i in range(4):
        records.append({'subject': {'index': i, 'omega_max': 0.5, 'mu': 1.0, 'sigma': 0.3},
                        'fits': {'learned_fp': {'omega_max': 0.5, 'mu': 0.9}},
                        'games': {'learned_fp': game([5, 40, 70, 100 + i], [1, 1, 1, 1], 'learned_fp'),
                                  'learned_online': game([5, 20, 70 + i], [1, 1, 0], 'learned_online')}})
    assert fp_by_quarter(records[0]['games']['learned_fp']) == [1, 1, 1, 1]
    rep = online_report(records, ['learned_fp', 'learned_online'])
    assert rep['fp_per_quarter']['learned_online'] == [2.0, 0.0, 0.0, 0.0]
    assert rep['second_minus_first_half']['learned_online'] == [-2] * 4
    comp = rep['comparisons']['learned_online-learned_fp']
    assert comp['change']['mean_difference'] == -2.0 and comp['total']['mean_difference'] == -2.0
    assert rep['fits'][0]['last']['omega_max'] == 0.5 and rep['fits'][0]['refits'] == 1


def test_learned_online_is_a_core_engine_condition():
    parser = argparse.ArgumentParser()
    cli.add_parser(parser.add_subparsers())
    assert 'learned_online' in cli.options_from_args(parser.parse_args(['study'])).conditions
    graph = cli.options_from_args(parser.parse_args(['study', '--engine', 'graph']))
    assert 'learned_online' not in graph.conditions and 'learned_fp' in graph.conditions
    with pytest.raises(ValueError, match='learned_online does not run on the graph engine'):
        cli.options_from_args(parser.parse_args(['study', '--engine', 'graph', '--conditions', 'learned_online']))
