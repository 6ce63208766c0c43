"""The study's bookkeeping: per-subject records -> JSON conditions, Table 1, sweep; counts
from the world's stats; Phase II scenes -> encounters; the CLI's subcommands."""
import argparse
import json
import math

import numpy as np
import pytest

from supersafe_ros.learning.levels import learned_alpha
from supersafe_ros.study import fits, games, graph_phase2, protocol, records, summary
from supersafe_ros.study.analysis import CONDITIONS
from supersafe_ros.study.population import Subject


class XValue:
    """A stand-in value function: V(x, y, theta) = x + offset (inside the set iff V > alpha)."""

    def __init__(self, offset=0.0):
        self.offset = offset

    def value(self, states):
        return np.asarray(states, dtype=float).reshape(-1, 3)[:, 0] + self.offset


def game(fp, interventions, crashes=0, trips=5, arc=float('nan')):
    return {'false_positives': fp, 'interventions': interventions, 'crashes': crashes, 'trips': trips,
            'path_per_trip': 33.0, 'avoidance_length': arc, 'override_fraction': 0.1,
            'min_clearance': 0.5}


def record(i, states, fit, learned_vf, games, sweep=None):
    return {'subject': Subject(i, 0.5, 1.0, 0.2, 100 + i).to_dict(), 'fit': fit, 'states': states,
            'learned_vf': learned_vf, 'games': games, 'sweep': sweep or {}}


def two_subjects():
    # x of the intervention states: subject 0 -> [-3, -1, 1, 2]; subject 1 -> [-2, 0.5, 3]
    s0 = [[-3, 0, 0], [-1, 0, 0], [1, 0, 0], [2, 0, 0]]
    s1 = [[-2, 0, 0], [0.5, 0, 0], [3, 0, 0]]
    r0 = record(0, s0, {'mu': 0.5, 'sigma': 1.0}, XValue(0.0),
                {'standard': game(6, 8), 'learned': game(3, 5), 'conservative': game(1, 2)},
                sweep={0.0: game(3, 5), 1.0: game(2, 4), 2.0: game(0, 3)})
    r1 = record(1, s1, {'mu': 1.0, 'sigma': 0.5}, XValue(0.0),
                {'standard': game(4, 6), 'learned': game(3, 4), 'conservative': game(0, 1)})
    return [r0, r1]


def test_summarize_pools_table1_and_lists_one_value_per_subject():
    # standard: V = x, alpha 0 -> inside x > 0: 2 + 2 = 4 of 7
    # conservative: V = x - 2, alpha 0 -> x > 2: 0 + 1 = 1
    # learned: V = x, alpha = mu -> s0: x > 0.5 -> 2; s1: x > 1.0 -> 1 => 3
    s = summary.summarize(two_subjects(), XValue(0.0), XValue(-2.0))
    t = s['table1']
    assert (t['standard']['inside'], t['standard']['total']) == (4, 7)
    assert (t['learned']['inside'], t['conservative']['inside']) == (3, 1)
    assert t['learned']['predicted_fp_ratio'] == pytest.approx(3 / 4)
    assert t['conservative']['predicted_fp_ratio'] == pytest.approx(1 / 4)
    c = s['conditions']
    assert list(c) == ['standard', 'learned', 'conservative']        # the conditions that ran
    assert c['standard']['false_positives'] == [6, 4]
    assert c['learned']['interventions'] == [5, 4]
    assert c['conservative']['trips'] == [5, 5]
    assert c['standard']['predicted_fp_ratio'] == 1.0 and c['standard']['observed_fp_ratio'] == 1.0
    assert c['learned']['average_fp'] == pytest.approx(3.0)
    assert c['learned']['observed_fp_ratio'] == pytest.approx(3.0 / 5.0)
    assert c['conservative']['observed_fp_ratio'] == pytest.approx(0.5 / 5.0)
    assert set(s['anova']) >= {'F', 'p'}
    assert set(s['tukey']) == {'standard-learned', 'standard-conservative', 'learned-conservative'}
    post = s['posthoc']['pairs']
    assert set(post) == set(s['tukey']) and 'Holm' in s['posthoc']['method']
    # standard 6, 4 vs learned 3, 3 (two_subjects): paired differences 3, 1
    assert post['standard-learned']['mean_difference'] == pytest.approx(2.0)
    assert {'p', 'ci_low', 'ci_high', 'effect_size'} <= set(post['standard-learned'])
    assert 'independent groups' in s['tukey_method']


def test_both_learned_conditions_get_their_row_and_the_h2_comparison():
    # learned_fp: V = x + 1 at alpha = mu (s0: x > -0.5 -> 2; s1: x > 0 -> 2) => 4 of 7
    recs = two_subjects()
    arcs = {'standard': (0.5, 0.6), 'learned': (1.0, 3.0), 'learned_fp': (0.8, 0.7),
            'conservative': (2.0, 2.0)}
    for i, r in enumerate(recs):
        r['fits'] = {'learned': r.pop('fit'), 'learned_fp': {'mu': 0.5, 'sigma': 0.1}}
        r['learned_vfs'] = {'learned': r.pop('learned_vf'), 'learned_fp': XValue(1.0)}
        r['games']['learned_fp'] = game(2, 3)
        for c, a in arcs.items():
            r['games'][c]['avoidance_length'] = a[i]
    s = summary.summarize(recs, XValue(0.0), XValue(-2.0))
    assert list(s['conditions']) == ['standard', 'learned', 'learned_fp', 'conservative']
    assert s['table1']['learned_fp']['inside'] == 4 and s['table1']['learned']['inside'] == 3
    assert s['conditions']['learned_fp']['avoidance_length'] == [0.8, 0.7]
    assert s['conditions']['learned']['path_per_trip'] == [33.0, 33.0]
    # per subject: learned 1.0 < 2.0 yes, 3.0 < 2.0 no -> 1 of 2; learned_fp both shorter
    h2 = s['h2']['shorter_arcs_than_conservative']
    assert h2['learned'] == {'shorter': 1, 'of': 2} and h2['learned_fp'] == {'shorter': 2, 'of': 2}
    assert s['h2']['means']['learned']['avoidance_length']['mean'] == pytest.approx(2.0)
    assert set(s['tukey']) >= {'learned-learned_fp', 'standard-learned_fp'}
    assert s['anova']['df_num'] == 3


def test_alpha_sweep_predicted_per_subject_and_observed_for_the_swept_ones():
    s = summary.summarize(two_subjects(), XValue(0.0), XValue(-2.0))
    sw = s['alpha_sweep']
    assert list(sw) == ['mu', 'mu+1sigma', 'mu+2sigma']
    # s0: alpha 0.5, 1.5, 2.5 over x [-3,-1,1,2] -> 2/4, 1/4, 0; s1: alpha 1, 1.5, 2 over [-2,.5,3] -> 1/3 each
    assert sw['mu']['predicted'] == pytest.approx([0.5, 1 / 3])
    assert sw['mu+1sigma']['predicted'] == pytest.approx([0.25, 1 / 3])
    assert sw['mu+2sigma']['predicted'] == pytest.approx([0.0, 1 / 3])
    assert sw['mu+2sigma']['observed'] == [0] and sw['mu+2sigma']['observed_subjects'] == [0]
    # predicted shares never rise with alpha
    for k in range(2):
        a, b = sw[['mu', 'mu+1sigma', 'mu+2sigma'][k]], sw[['mu', 'mu+1sigma', 'mu+2sigma'][k + 1]]
        assert all(y <= x for x, y in zip(a['predicted'], b['predicted']))


def test_subject_without_fit_counts_the_standard_set_for_learned():
    recs = two_subjects()
    recs[1]['fit'], recs[1]['learned_vf'] = None, None
    s = summary.summarize(recs, XValue(0.0), XValue(-2.0))
    # s0 learned 2 (as before) + s1 with the standard set (x > 0: 2)
    assert s['table1']['learned']['inside'] == 4
    assert len(s['alpha_sweep']['mu']['predicted']) == 1


def test_json_output_is_strict_json():
    s = summary.summarize(two_subjects(), XValue(0.0), XValue(-2.0))
    s['nan'] = float('nan')
    s['np'] = np.float32(1.5)
    text = json.dumps(records.jsonable(s), allow_nan=False)
    back = json.loads(text)
    assert back['nan'] is None and back['np'] == 1.5
    assert back['conditions']['standard']['false_positives'] == [6, 4]


def test_game_counts_from_world_stats_and_log():
    result = {'stats': {'trips': '12', 'crashes': '1', 'interventions': '7', 'false_positives': '5',
                        'sim_time': '120.0'},
              'interventions': [{'false_positive': 'true'}, {'false_positive': 'false'},
                                {'false_positive': 'True'}]}
    c = records.game_counts(result)
    assert (c['trips'], c['crashes'], c['interventions'], c['false_positives']) == (12, 1, 7, 5)
    assert c['sim_time'] == 120.0
    assert (c['logged_interventions'], c['logged_false_positives']) == (3, 2)
    empty = records.game_counts({'stats': {}, 'interventions': []})
    assert empty['trips'] == 0 and empty['sim_time'] == 0.0


def test_phase2_scenes_become_encounters_ending_at_the_intervention():
    frames = [(-8.0 + 0.6 * k, 1.0, 0.0) for k in range(10)]
    scenes = [
        {'y0': 1.0, 'intervened': True, 'state': [-5.1, 1.0, 0.0], 'frames': frames[:6] + [(-5.1, 1.0, 0.0)]},
        {'y0': 2.0, 'intervened': False, 'state': None, 'frames': frames},
    ]
    enc = fits.phase2_encounters_from_scenes(scenes)
    assert [e.intervened for e in enc] == [True, False]
    assert np.allclose(enc[0].states[-1], [-5.1, 1.0, 0.0])
    assert np.all(enc[0].states[:-1, 0] < -5.1)
    assert len(enc[1].states) == 10


def test_kept_alive_graph_has_no_clock_process_and_filters_take_the_set_from_the_topic():
    argvs, clock = games.graph_argvs(3, {'w_max': 0.5, 'mu': 0.8, 'sigma': 0.2}, 0.2, 0.0)

    def params(name):
        argv = next(a for a in argvs if f'supersafe_ros.nodes.{name}' in a)
        return [argv[i + 1] for i, a in enumerate(argv) if a == '-p']
    assert not any('sim_clock_node' in ' '.join(a) or 'learner_node' in ' '.join(a) for a in argvs)
    assert sum('safety_filter_node' in ' '.join(a) for a in argvs) == 2
    assert 'use_learned:=true' in params('safety_filter_node')
    assert 'alpha_offset:=0.0' in params('safety_filter_node')
    assert 'seed:=3' in params('world_node') and 'w_max:=0.5' in params('supervisor_node')
    assert clock['step'] == 0.2 and clock['observers'] == ['/world/step_done', '/supervisor/step_done']


def test_condition_messages_carry_the_set_and_alpha_the_filter_uses():
    from supersafe_ros.ros_io.vfmsg import msg_metadata
    from supersafe_ros.learning.levels import learned_alpha as filter_alpha   # what the filter node uses
    std, cons = protocol.reference_sets()
    fit = {'omega_max': 0.5, 'mu': 0.8, 'sigma': 0.3}
    learned = {'learned': (cons, fit), 'learned_fp': (None, None)}
    msg, alpha, ran = games.condition_message('learned', learned, alpha_offset=2.0)
    meta = msg_metadata(msg)
    assert ran == 'learned' and alpha == pytest.approx(1.4)
    assert meta['source'] == 'learned' and filter_alpha(meta, 0.0) == pytest.approx(1.4)
    msg, alpha, ran = games.condition_message('conservative', learned)
    meta = msg_metadata(msg)
    # not 'standard': a filter replaces a 'standard' message by its own standard set (radius
    # 1.8), which is how the Conservative games once ran on the Standard set
    assert ran == 'conservative' and alpha is None and meta['source'] == 'conservative'
    assert filter_alpha(meta, 0.0) == 0.0 and meta['grid'] == cons.grid.to_dict()
    msg, alpha, ran = games.condition_message('standard', learned)
    assert ran == 'standard' and msg_metadata(msg)['source'] == 'standard'
    # no fit: the learned condition runs (and is reported as) the standard set
    msg, alpha, ran = games.condition_message('learned_fp', learned)
    assert ran == 'standard' and msg_metadata(msg)['condition'] == 'standard'


def test_cli_registers_study_and_demo():
    from supersafe_ros.study import cli
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest='command')
    cli.add_parser(sub)
    args = parser.parse_args(['study', '--subjects', '2', '--phase2-offsets=-1,0.5', '--conditions',
                              'conservative, learned_fp,standard'])
    opts = cli.options_from_args(args)
    assert opts.subjects == 2 and opts.phase2_offsets == (-1.0, 0.5)
    assert opts.conditions == ('standard', 'learned_fp', 'conservative')     # Table 1 order
    assert cli.options_from_args(parser.parse_args(['study'])).conditions == CONDITIONS
    with pytest.raises(ValueError, match='unknown'):
        cli.parse_conditions('standard,learnt')
    assert parser.parse_args(['demo']).func is cli.run_demo
    assert math.isclose(learned_alpha({'mu': 1.0, 'sigma': 0.5}, 2.0), 2.0)


def test_stored_frames_of_the_learner_store(tmp_path):
    store = tmp_path / 'interventions.jsonl'
    assert graph_phase2._stored_frames(store) == set()          # no file yet: nothing stored
    store.write_text('{"frame": "obstacle_3", "x": -5.0}\nnot json\n{"frame": "obstacle_7"}\n')
    assert graph_phase2._stored_frames(store) == {'obstacle_3', 'obstacle_7'}


def test_phase2_graph_runs_a_first_passage_learner_on_its_own_topics_and_store(tmp_path):
    from supersafe_ros.team import process_name
    subject = Subject(0, 0.5, 1.0, 0.2, 100)
    argvs = graph_phase2.phase2_argvs(subject, protocol.StudyOptions(), tmp_path / 'i.jsonl', 0.0,
                                      tmp_path / 'fp' / 'i.jsonl')
    learners = {process_name(a): a for a in argvs if 'supersafe_ros.nodes.learner_node' in a}
    assert set(learners) == {'learner', 'learner_fp'}        # two processes, two logs

    def ros_args(argv, flag):
        return [argv[i + 1] for i, a in enumerate(argv) if a == flag]
    paper, fp = (ros_args(learners[n], '-p') for n in ('learner', 'learner_fp'))
    assert 'estimator:=paper' in paper and f'store_path:={tmp_path / "i.jsonl"}' in paper
    assert 'estimator:=first-passage' in fp and 'robots:=[robot_0]' in fp
    assert f'store_path:={tmp_path / "fp" / "i.jsonl"}' in fp
    assert 'library_shape:=[65,65,42]' in fp                  # the config file's, re-keyed to the new name
    remaps = ros_args(learners['learner_fp'], '-r')
    assert '__node:=learner_fp' in remaps
    assert f'/safe_set/value_function:={protocol.FP_VF_TOPIC}' in remaps
    assert f'/safe_set/fit:={protocol.FP_FIT_TOPIC}' in remaps
    assert not any(a.startswith('__node') or a.startswith('/safe_set') for a in ros_args(learners['learner'], '-r'))
    # without an fp store (the console's Phase II) the graph has the paper learner only
    argvs = graph_phase2.phase2_argvs(subject, protocol.StudyOptions(), tmp_path / 'i.jsonl', 0.0)
    assert [process_name(a) for a in argvs].count('learner_fp') == 0


def test_learned_fp_is_the_first_passage_learner_message_with_its_newest_counts():
    from supersafe_ros.ros_io.vfmsg import value_function_to_msg
    std, _ = protocol.reference_sets()
    msg = value_function_to_msg(std, source='learned', estimator='first-passage', omega_max=1.0, mu=0.9,
                                sigma=0.3, alpha=0.9, log_likelihood=-5.0, interventions=2, encounters=3,
                                index=8)
    # the newest refit chose the same set (not re-sent) on more data: its status has the counts
    status = {'index': '8', 'published_index': '8', 'alpha': '0.900000', 'published_alpha': '0.900000',
              'omega_max': '1.0', 'mu': '0.900000', 'sigma': '0.310000', 'log_likelihood': '-6.0',
              'fitted_interventions': '3', 'fitted_encounters': '4', 'encounters': '4',
              'unmatched_interventions': '0'}
    fit = graph_phase2.first_passage_learner_fit(msg, status)
    assert fit['estimator'] == 'first-passage'
    assert (fit['interventions'], fit['encounters'], fit['sigma']) == (3, 4, 0.31)
    # a newer fit that was refused: the set in force is the message's, with its own values
    refused = dict(status, index='9', alpha='1.2', sigma='0.5')
    fit = graph_phase2.first_passage_learner_fit(msg, refused)
    assert (fit['interventions'], fit['encounters'], fit['sigma'], fit['mu']) == (2, 3, 0.3, 0.9)
    assert graph_phase2.first_passage_learner_fit(None, status) is None
    p2 = protocol.Phase2Result([], np.zeros((0, 3)), 'paper-msg', {'estimator': 'paper'}, 0.0, 0.0,
                               fp_msg=msg, fp_fit=fit)
    sets = fits.learned_sets(p2, ('learned', 'learned_fp'))
    assert sets['learned'] == ('paper-msg', {'estimator': 'paper'}) and sets['learned_fp'] == (msg, fit)


def test_both_graphs_run_the_studys_supervisor_model(tmp_path):
    """The graph engine's supervisor nodes get the study's model (Phase II and the games)."""
    from supersafe_ros.study.graph_engine import supervisor_params
    subject = Subject(0, 0.5, 1.0, 0.2, 100)
    for model in ('memoryless', 'attentive'):
        argvs = graph_phase2.phase2_argvs(subject, protocol.StudyOptions(supervisor=model), tmp_path / 'i.jsonl', 0.0)
        sup = [a for a in argvs if 'supersafe_ros.nodes.supervisor_node' in a]
        assert len(sup) == 1 and f'model:={model}' in sup[0]
        argvs, _ = games.graph_argvs(3, supervisor_params(subject, model), 0.2, 0.0)
        sup = [a for a in argvs if 'supersafe_ros.nodes.supervisor_node' in a]
        assert len(sup) == 1 and f'model:={model}' in sup[0]


def test_a_conditions_set_runs_at_the_same_level_on_both_engines():
    """``condition_set`` chooses once; the core engine's filter set and the graph's message
    put the same value function in force at the same level."""
    from supersafe_ros.learning.levels import learned_alpha as filter_alpha    # what the filter node uses
    from supersafe_ros.ros_io.vfmsg import msg_metadata
    from supersafe_ros.study.engine import filter_safe_set, node_params
    std, cons = protocol.reference_sets()
    std_alpha = float(node_params('safety_filter')['standard_alpha'])
    fit = {'omega_max': 1.0, 'mu': 0.5, 'sigma': 0.2}
    learned = {'learned': (cons, fit), 'learned_online': (cons, fit), 'learned_fp': (None, None)}
    cases = [('standard', 0.0, 'standard', std, None), ('conservative', 0.0, 'conservative', cons, None),
             ('learned', 2.0, 'learned', cons, 0.9), ('learned_fp', 0.0, 'standard', std, None)]
    for condition, k, ran, vf, alpha in cases:
        chosen = protocol.condition_set(condition, learned, k)
        assert (chosen.condition, chosen.ran, chosen.value_function) == (condition, ran, vf)
        assert chosen.alpha == (None if alpha is None else pytest.approx(alpha))
        core = filter_safe_set(chosen)
        meta = msg_metadata(games.set_message(chosen))
        graph_level = std_alpha if meta['source'] == 'standard' else filter_alpha(meta, 0.0)
        assert core.vf is vf and core.alpha == pytest.approx(graph_level)
        assert core.source == ('standard' if ran == 'standard' else 'learned')
        assert meta['condition'] == ran and not chosen.learns_during_game
    assert protocol.condition_set('learned_online', learned).learns_during_game
    assert not protocol.condition_set('learned_online', learned, 1.0).learns_during_game
    assert not protocol.condition_set('learned_online', {}).learns_during_game      # no fit: Standard
    # a set whose unsafe set is smaller than the standard one: the filters would reject it
    below = protocol.condition_set('learned', {'learned': (std, {'mu': -0.5, 'sigma': 0.1})})
    with pytest.raises(RuntimeError, match='would reject the learned set'):
        filter_safe_set(below)


class RecordingEngine:
    """An engine (engines.Engine) that records what the runner asks of it; its games end
    with no counts, and ``fail_at`` makes that game fail."""

    name = 'recording'
    parallel_subjects = False
    conditions = ('standard', 'learned', 'learned_online', 'conservative')

    def __init__(self, fail_at=None):
        self.calls, self.fail_at = [], fail_at
        std, self.learned_vf = protocol.reference_sets()
        self.fit = {'omega_max': 0.75, 'mu': 0.5, 'sigma': 0.2, 'estimator': 'paper'}

    def phase2(self, i, subject, opts, with_fp):
        self.calls.append(('phase2', i, subject.index, with_fp))
        p2 = protocol.Phase2Result([], np.zeros((0, 3)), None, self.fit, 1.0, 0.0, fp_fit=dict(self.fit))
        p2.vf = p2.fp_vf = self.learned_vf
        return p2

    def games(self, i, subject, world_seed, phase2, opts):
        self.calls.append(('games', i, world_seed))
        engine = self

        class Games:
            def play(self, chosen, seed):
                engine.calls.append(('play', chosen.condition, chosen.ran, chosen.alpha, chosen.learns_during_game,
                                     seed))
                if len(engine.calls) == engine.fail_at:
                    raise RuntimeError('the game failed')
                return {'stats': {'sim_time': f'{opts.game_seconds:.3f}'}, 'interventions': [], 'wall': 0.0,
                        'wall_running': 0.0, 'cpu_s': 0.0, 'cpu_by_process': {}, 'resends': 0}

            def close(self):
                engine.calls.append(('close', i))
        return Games()


def test_the_runner_asks_the_engine_for_phase2_and_each_game():
    import io
    from supersafe_ros.study import runner
    engine = RecordingEngine()
    opts = protocol.StudyOptions(seed=4, game_seconds=10.0, sweep_k=(0.0, 1.0), conditions=RecordingEngine.conditions)
    subject = Subject(1, 0.5, 1.0, 0.2, 100)
    rec = runner.run_subject(engine, 1, subject, opts, list(opts.conditions), runner.Progress(2, io.StringIO()))
    world = 4 * 1000 + 1
    assert engine.calls == [('phase2', 1, 1, True), ('games', 1, world),
                            ('play', 'standard', 'standard', None, False, world),
                            ('play', 'learned', 'learned', 0.5, False, world),
                            ('play', 'learned_online', 'learned_online', 0.5, True, world),
                            ('play', 'conservative', 'conservative', None, False, world),
                            ('play', 'learned', 'learned', pytest.approx(0.7), False, world),    # the sweep
                            ('close', 1)]
    assert rec['phase2']['engine'] == 'recording'
    assert {c: (g['set'], g['engine'], g['complete']) for c, g in rec['games'].items()} == \
        {c: (c, 'recording', True) for c in opts.conditions}
    assert rec['sweep'][1.0]['alpha'] == pytest.approx(0.7) and rec['sweep'][0.0] is rec['games']['learned']
    # a game that fails still frees the subject's games (a kept-alive graph)
    failing = RecordingEngine(fail_at=4)
    with pytest.raises(RuntimeError, match='the game failed'):
        runner.run_subject(failing, 0, subject, opts, ['standard', 'learned'], runner.Progress(1, io.StringIO()))
    assert failing.calls[-1] == ('close', 0) and len(failing.calls) == 5
    # without a first-passage condition Phase II needs no first-passage fit
    assert failing.calls[0] == ('phase2', 0, 1, False)


def test_each_engine_is_chosen_by_its_name_and_says_what_it_plays():
    from supersafe_ros.study.engines import ENGINES, check_conditions, engine_named
    engines = {name: engine_named(name) for name in ENGINES}
    assert {name: e.name for name, e in engines.items()} == {'core': 'core', 'graph': 'graph'}
    assert engines['core'].parallel_subjects and not engines['graph'].parallel_subjects
    assert set(engines['core'].conditions) - set(engines['graph'].conditions) == {'learned_online'}
    check_conditions(engines['core'], ('standard', 'learned_online'))
    with pytest.raises(ValueError, match='learned_online does not run on the graph engine'):
        check_conditions(engines['graph'], ('standard', 'learned_online'))
    with pytest.raises(ValueError, match="engine 'ros' is not one of"):
        engine_named('ros')
