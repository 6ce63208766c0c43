"""`supersafe session` without ROS: the participant protocol's bookkeeping, the fit screen's
words, and the researcher's --analyse (listing, descriptive table, tests only when
meaningful, the CSV export). The scripted participants in Chromium are in
test_session_participant.py."""
import csv
import io
import json
import re
import subprocess
import sys
import warnings

import numpy as np
import pytest

from supersafe_ros.session import protocol as S
from supersafe_ros.session.analysis import analyse, find_participants
from supersafe_ros.session.fit_view import fit_view, turn_x
from supersafe_ros.study.design import paper_plan, short_plan
from supersafe_ros.study.subjective import TEAM_ITEMS


def test_latin_square_is_balanced_and_fixed_by_the_participant():
    orders = S.LATIN_ORDERS
    assert sorted(orders) == sorted(set(orders)) and len(orders) == 6
    for pos in range(3):       # each condition equally often first, second, third
        assert {c: sum(o[pos] == c for o in orders) for c in S.CONDITIONS} == dict.fromkeys(S.CONDITIONS, 2)
    follows = {}
    for o in orders:           # and each ordered pair of neighbours equally often
        for a, b in zip(o, o[1:]):
            follows[(a, b)] = follows.get((a, b), 0) + 1
    assert len(follows) == 6 and set(follows.values()) == {2}
    assert S.condition_order('7') == orders[7 % 6] and S.condition_order('P-07') == S.condition_order('P-07')
    offsets = S.phase2_offsets('7')
    assert len(offsets) == 42 and min(offsets) == -2.25 and max(offsets) == 2.25
    assert sorted(offsets) == pytest.approx(np.linspace(-2.25, 2.25, 42))
    assert offsets != sorted(offsets) and offsets == S.phase2_offsets('7') != S.phase2_offsets('8')
    for bad in ('../x', 'a\n', 'a b', '', '.hidden', 'x' * 65, None):
        with pytest.raises(ValueError):
            S.check_participant_id(bad)      # 'a\n' passed match() with '$' and made a folder 'a\n'
    assert S.check_participant_id('P-07.b_2') == 'P-07.b_2'


def test_store_resumes_and_never_overwrites_a_complete_participant(tmp_path):
    store = S.SessionStore(tmp_path, 'p1', n_offsets=5)
    assert not store.resumed and len(store.remaining_offsets()) == 5
    store.add_scene({'y0': store.data['offsets'][0], 'intervened': True, 'state': [-3.0, 0.5, 0.0],
                     'frames': [[-8.0, 0.5, 0.0], [-3.0, 0.5, 0.0]]})
    again = S.SessionStore(tmp_path, 'p1', n_offsets=5)      # Ctrl-C, then the same command
    assert again.resumed and again.remaining_offsets() == store.data['offsets'][1:]
    again.data['complete'] = True
    again.save()
    before = again.path.read_text()
    with pytest.raises(S.ParticipantExists):
        S.SessionStore(tmp_path, 'p1')
    assert again.path.read_text() == before
    (tmp_path / 'other').mkdir()
    (tmp_path / 'other' / 'notes.txt').write_text('x')
    with pytest.raises(S.ParticipantExists):
        S.SessionStore(tmp_path, 'other')
    with pytest.raises(ValueError):
        S.check_answers({'trust': [8, 1]})
    full = dict({k: [4, 5] for k, _ in TEAM_ITEMS}, preference=4)
    assert S.check_answers(full) == full


def test_the_plan_is_fixed_when_a_participant_is_created_and_kept_on_resume(tmp_path):
    store = S.SessionStore(tmp_path, '8', n_offsets=2)           # the paper's form by default
    assert store.data['plan'] == paper_plan(8) and store.data['plays'] == [] and len(store.data['order']) == 6
    again = S.SessionStore(tmp_path, '8', n_offsets=2, phase3='short')
    assert again.data['plan']['form'] == 'paper'                 # a resumed participant keeps its form
    from supersafe_ros.session.analysis import phase_reached
    data = dict(store.data, scenes=[{}, {}], fit={'paper': None}, plays=[{}, {}], answers=[{}])
    assert phase_reached(data) == 'Phase III, 2 of 6 games, 1 of 3 questionnaires'
    short = S.SessionStore(tmp_path, '9', n_offsets=2, phase3='short')
    assert short.data['plan']['form'] == 'short' and short.data['order'] == list(S.LATIN_ORDERS[9 % 6])
    # a session.json from before the plan (games keyed by condition) resumes in the short form
    old = {'participant': 'o1', 'order': list(S.LATIN_ORDERS[3]), 'offsets': [0.0], 'phase1': None,
           'scenes': [], 'fit': None, 'answers': [], 'complete': False,
           'games': {S.LATIN_ORDERS[3][0]: {'false_positives': 2}}}
    (tmp_path / 'o1').mkdir()
    (tmp_path / 'o1' / 'session.json').write_text(json.dumps(old))
    resumed = S.SessionStore(tmp_path, 'o1')
    assert resumed.data['plan']['form'] == 'short'
    assert [g['treatment'] for g in resumed.data['plan']['games']] == list(S.LATIN_ORDERS[3])
    assert resumed.data['plays'] == [dict(resumed.data['plan']['games'][0], false_positives=2)]


def test_complete_participant_is_refused_by_the_command(tmp_path):
    store = S.SessionStore(tmp_path, 'done1', n_offsets=2)
    store.data['complete'] = True
    store.save()
    r = subprocess.run([sys.executable, '-m', 'supersafe_ros.cli', 'session', '--participant', 'done1',
                        '--out', str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and 'never overwritten' in r.stderr
    r = subprocess.run([sys.executable, '-m', 'supersafe_ros.cli', 'session', '--participant', 'a\n',
                        '--out', str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and 'participant ID' in r.stderr and not (tmp_path / 'a\n').exists()


GAMES = {c: {'false_positives': fp, 'interventions': fp + 2, 'crashes': 0, 'trips': 9, 'played': c,
             'alpha': None, 'sim_time': 120.0}
         for c, fp in zip(S.CONDITIONS, (6, 4, 2))}
FP_SECOND = {'standard': 8, 'learned': 2, 'conservative': 2}     # the paper form's second game


def human_session(pid, row=0, form='paper', trust=(3, 5)):
    """A complete human participant's session data (three Phase II scenes, every game and
    questionnaire of its plan; trust: the (Standard, Learned) ratings)."""
    design = paper_plan(row) if form == 'paper' else short_plan(row)
    plays, seen = [], set()
    for g in design['games']:
        t = g['treatment']
        play = dict(GAMES[t], **g, world_seed=900000 + (g['version'] or 0))
        if t in seen:
            play.update(false_positives=FP_SECOND[t], interventions=FP_SECOND[t] + 2)
        seen.add(t)
        plays.append(play)
    answers = []
    for q in design['questionnaires']:
        a, b = q['games']
        treatments = [design['games'][a - 1]['treatment'], design['games'][b - 1]['treatment']]
        rate = {'standard': trust[0], 'learned': trust[1], 'conservative': 4}
        answers.append({'after_game': q['after_game'], 'comparison': q['comparison'], 'games': [a, b],
                        'labels': [f'Game {a}', f'Game {b}'], 'treatments': treatments,
                        'values': dict({k: [rate[treatments[0]], rate[treatments[1]]] for k, _ in TEAM_ITEMS},
                                       preference=6)})
    return {'participant': pid, 'plan': design, 'order': [g['treatment'] for g in design['games']],
            'phase1': {'seconds': 60.0, 'path_columns': ['t', 'x', 'y', 'theta', 'u'],
                       'path': [[0.05, -17.0, 0.0, 0.0, 1.0], [0.1, -16.85, 0.0, 0.05, 1.0]]},
            'scenes': [{'y0': 0.0, 'intervened': True, 'state': [-4.0, 0.0, 0.0], 'frames': []},
                       {'y0': 1.0, 'intervened': True, 'state': [-3.5, 1.0, 0.0], 'frames': []},
                       {'y0': 2.25, 'intervened': False, 'state': None, 'frames': []}],
            'fit': {'paper': {'omega_max': 0.75, 'mu': 0.4, 'sigma': 0.2, 'alpha': 0.4}},
            'plays': plays, 'answers': answers}


def write_human(root, pid, lib, row=0, form='paper', trust=(3, 5)):
    data = human_session(pid, row, form, trust)
    S.write_subject(root / pid, S.subject_record(data, lib.entry(0.75)))
    (root / pid / 'session.json').write_text(json.dumps({**data, 'complete': True}))


def test_analyse_lists_every_participant_and_says_no_test_is_meaningful_below_three(tmp_path):
    from supersafe_ros.reach.library import load_or_build_library
    lib = load_or_build_library()
    write_human(tmp_path, 'h1', lib)
    simulated = {'subject': {'index': 0, 'omega_max': 0.5, 'mu': 0.3, 'sigma': 0.2, 'seed': 1},
                 'fit': {'omega_max': 0.5, 'mu': 0.3, 'sigma': 0.2}, 'states': [[-4.5, 0.2, 0.0]],
                 'learned_vf': lib.entry(0.5), 'games': GAMES, 'sweep': {}}
    S.write_subject(tmp_path / 'study' / 's00', simulated)
    # an interrupted participant: Phase II, 5 of 42 scenes
    store = S.SessionStore(tmp_path, 'p9')
    for y0 in store.data['offsets'][:5]:
        store.add_scene({'y0': y0, 'intervened': False, 'state': None, 'frames': []})
    record = S.load_subject(tmp_path / 'h1')
    assert record['phase1']['path'][1] == [0.1, -16.85, 0.0, 0.05, 1.0]     # the Phase I path is kept
    assert record['design'] == {'form': 'paper', 'row': 0} and len(record['plays']) == 6
    assert record['games']['standard']['false_positives'] == (6 + 8) / 2      # the mean of its two games
    assert record['games']['standard']['totals']['false_positives'] == 14

    out = io.StringIO()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        assert analyse([tmp_path], json_path=tmp_path / 'a.json', csv_path=tmp_path / 'a.csv', out=out) == 0
    text = out.getvalue()
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)], [str(w.message) for w in caught]
    assert text.startswith('3 participants:')
    lines = {line.split()[0]: line for line in text.splitlines() if line.startswith('  ')}
    assert 'complete' in lines['h1'] and 'human' in lines['h1']
    assert 'incomplete: Phase II, 5 of 42 scenes' in lines['p9']
    assert 'complete' in lines['s00'] and 'simulated' in lines['s00']
    assert '2 complete (1 human, 1 simulated)' in text
    assert 'no statistical test is meaningful' in text and 'ANOVA' not in text and 'F(' not in text
    table = text[text.index('condition'):].splitlines()
    # Standard: the human's mean of 6 and 8, the simulated subject's 6
    assert table[1].split()[:2] == ['standard', '6.50'] and table[3].split()[:2] == ['conservative', '2.00']
    assert 'questionnaires: 1 of 2 subjects answered' in text
    assert '1 simulated subject: a simulated supervisor answers no questionnaire' in text
    assert 'Standard vs Learned (1 participant answered)' in text and 'no test (fewer than 3)' in text
    doc = json.loads((tmp_path / 'a.json').read_text())
    assert doc['tests_meaningful'] is False and doc['anova'] is None and doc['answered'] == 1
    assert doc['subjective']['standard-learned']['items']['trust']['learned'] == 5
    assert len(doc['answers']['h1']) == 3
    # the CSV: one row per participant and game
    rows = list(csv.DictReader(open(tmp_path / 'a.csv')))
    h1 = [r for r in rows if r['participant'] == 'h1']
    assert len(rows) == 6 + 3 and len(h1) == 6
    plan = paper_plan(0)['games']
    assert [(r['game'], r['treatment'], r['comparison'], r['position_in_pair'], r['version']) for r in h1] == [
        (str(g['game']), g['treatment'], g['comparison'], str(g['position_in_pair']), str(g['version']))
        for g in plan]
    assert {r['form'] for r in h1} == {'paper'}
    sim = [r for r in rows if r['participant'] == '0']
    assert {r['treatment'] for r in sim} == set(S.CONDITIONS) and {r['form'] for r in sim} == {'same-world'}
    assert [r['false_positives'] for r in h1 if r['treatment'] == 'standard'] == ['6', '8']
    # and the answers: one row per participant, comparison and item
    answers = list(csv.DictReader(open(tmp_path / 'a_answers.csv')))
    assert len(answers) == 3 * 6
    sl = {r['item']: r for r in answers if r['comparison'] == 'standard-learned'}
    first = plan[0]['treatment']
    assert sl['trust']['first_treatment'] == first
    assert sl['trust']['first_rating'] == ('3' if first == 'standard' else '5')
    assert sl['preference']['preference'] == '6'
    assert sl['preference']['towards_second_named'] == ('6' if plan[1]['treatment'] == 'learned' else '2')


def test_analyse_tests_from_three_subjects_and_lists_a_folder_without_complete_ones(tmp_path):
    from supersafe_ros.reach.library import load_or_build_library
    lib = load_or_build_library()
    for k, trust in enumerate(((3, 5), (2, 6), (4, 4))):
        write_human(tmp_path, f'h{k}', lib, row=k, trust=trust)
    write_human(tmp_path, 'h3', lib, row=1, form='short')
    out = io.StringIO()
    assert analyse([tmp_path], out=out) == 0
    text = out.getvalue()
    assert '4 complete (4 human, 0 simulated)' in text and 'Phase III forms: paper, short' in text
    assert 'repeated-measures ANOVA (false positives, 4 subjects): F(2, 6)' in text
    assert 'paired post-hoc (' in text and 'p(Holm) = ' in text
    assert 'no statistical test' not in text
    # the paper's subjective test: the three paper participants' trust in Standard and Learned
    # (the short-form participant of row 1 did not compare them)
    assert 'Standard vs Learned (3 participants answered)' in text
    trust = next(line for line in text.splitlines() if line.strip().startswith('trust') and 'F(1, 2)' in line)
    assert 'Standard 3.00  Learned 5.00' in trust
    only = tmp_path / 'only'
    S.SessionStore(only, 'q1')
    out = io.StringIO()
    assert analyse([only], out=out) == 0
    assert 'incomplete: Phase I' in out.getvalue() and 'nothing to analyse' in out.getvalue()
    assert analyse([tmp_path / 'empty'], out=io.StringIO()) == 2
    assert [e['participant'] for e in find_participants([tmp_path])] == ['h0', 'h1', 'h2', 'h3', 'q1']


def test_fit_screen_says_earlier_or_later_in_words_and_keeps_the_numbers_for_the_researcher():
    from supersafe_ros.study.protocol import reference_sets
    standard, conservative = reference_sets()
    scenes = [{'intervened': True, 'state': [-5.0, 0.5, 0.0]}, {'intervened': False, 'state': None}]
    head_on = turn_x(standard, 0.0)
    assert -6.0 < head_on < -2.0            # the standard set turns a head-on robot a few metres out
    for fit_vf, mu, word in ((conservative, 0.0, 'earlier'), (standard, -0.5, 'later'),
                             (standard, 0.05, 'same')):
        page, researcher = fit_view(scenes, {'mu': mu, 'omega_max': 1.0, 'sigma': 0.1}, fit_vf, standard)
        assert page['change'] == researcher['change'] == word
        assert f' {word} than before' in page['sentence'] or (word == 'same' and 'same point' in page['sentence'])
        assert researcher['turn_distance_standard'] == pytest.approx(-head_on)
        assert page['summary'] == 'You stopped the robot in 1 of 2 scenes.'
        # the participant's words hold no fit numbers (mu, sigma, w_max, distances)
        words = page['summary'] + page['sentence']
        assert not any(t in words for t in ('mu', 'sigma', 'w_max', 'alpha', '.0', ' m '))
        assert page['drawing']['stops'] == [[-5.0, 0.5]] and page['drawing']['before'] and page['drawing']['now']
    page, researcher = fit_view([{'intervened': False, 'state': None}], None, None, standard)
    assert page['change'] == 'none' and 'nothing to learn' in page['sentence']
    assert page['drawing']['now'] == page['drawing']['before']


async def start_for_another_screen(port):
    """A Start meant for another screen (a late double click) starts nothing."""
    import aiohttp
    async with aiohttp.ClientSession() as session:
        async with session.ws_connect(f'http://127.0.0.1:{port}/ws') as ws:
            hello = json.loads((await ws.receive(timeout=30)).data)
            assert hello['session']['phase'] == 'phase1' and hello['session']['waiting']
            await ws.send_str(json.dumps({'type': 'start', 'phase': 'phase2'}))
            reply = json.loads((await ws.receive(timeout=30)).data)
            assert reply == {'type': 'error', 'message': 'nothing to start now'}


def test_sigint_and_sigterm_before_any_phase_end_the_session_cleanly(tmp_path):
    """Waiting for the participant's Start (no graph yet): either signal ends the command
    at once, says how to resume, leaves no traceback and no empty bag."""
    import asyncio
    import signal
    from console_support import dump_stacks, free_port, wait_for_server
    for sig in (signal.SIGINT, signal.SIGTERM):
        stacks = ''
        port = free_port()
        proc = subprocess.Popen([sys.executable, '-m', 'supersafe_ros.cli', 'session', '--participant', 's1',
                                 '--out', str(tmp_path), '--port', str(port)],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
        try:
            wait_for_server(f'http://127.0.0.1:{port}/', timeout=60)
            if sig == signal.SIGINT:
                asyncio.run(start_for_another_screen(port))
            else:       # every thread's stack (a test's evidence of a hang); the session goes on
                stacks = dump_stacks(proc)
            proc.send_signal(sig)
            out = stacks + proc.communicate(timeout=60)[0]
        finally:
            if proc.poll() is None:
                proc.kill()
        assert proc.returncode == 128 + sig, out
        if sig == signal.SIGTERM:
            # the main thread (in the session's run) and the web server's thread
            assert len(re.findall(r'^(Current thread|Thread) 0x[0-9a-f]+', stacks, re.M)) >= 2, stacks
            assert 'session/runner.py' in stacks and 'server.py' in stacks, stacks
        assert 'interrupted: resume with the same command' in out and 'Traceback' not in out, out
        assert 'Task was destroyed' not in out, out
        assert json.loads((tmp_path / 's1' / 'session.json').read_text())['scenes'] == []
        assert not list((tmp_path / 's1').glob('recording-*'))


def test_a_port_in_use_is_said_plainly(tmp_path):
    import socket
    with socket.socket() as taken:
        taken.bind(('127.0.0.1', 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = subprocess.run([sys.executable, '-m', 'supersafe_ros.cli', 'session', '--participant', 'p2',
                            '--out', str(tmp_path), '--port', str(port)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and f'cannot serve the console on port {port}' in r.stderr, r
    assert 'Traceback' not in r.stderr + r.stdout


class ScriptedSession:
    """Session.protocol's order of events, with every screen and phase recorded instead of run."""

    def __init__(self, store, phase3='paper'):
        import argparse
        from supersafe_ros.session.runner import Session
        self.protocol = Session.protocol.__get__(self)
        self.store, self.events = store, []
        self.args = argparse.Namespace(phase1_seconds=0, stop_after=None, estimator='paper', game_seconds=5.0,
                                       phase3=phase3)

    def wait_for_start(self, phase, **fields):
        self.events.append(('start', phase, fields.get('game')))

    def show(self, phase, **fields):
        self.events.append(('show', phase))

    def say(self, text):
        pass

    def learned_vf(self, estimator=None):
        return None

    def game(self, g):
        self.events.append(('game', g['game']))
        self.store.data['plays'].append(dict(g, false_positives=g['game'], interventions=g['game'],
                                             crashes=0, trips=1))
        self.store.save()
        if g['game'] == self.stop_at:
            raise KeyboardInterrupt

    def ask(self, q):
        self.events.append(('ask', tuple(q['games'])))
        self.store.data['answers'].append({'comparison': q['comparison'], 'games': q['games']})
        self.store.save()


def test_the_protocol_runs_the_plan_and_resumes_at_the_game_or_questionnaire_where_it_stopped(tmp_path,
                                                                                              monkeypatch):
    import time
    monkeypatch.setattr(time, 'sleep', lambda s: None)       # the protocol's last pause for the page
    store = S.SessionStore(tmp_path, '3', n_offsets=1)
    store.data.update(scenes=[{'y0': 0.0, 'intervened': False, 'state': None, 'frames': []}],
                      fit={'paper': None, 'first_passage': None}, fit_seen=True)
    store.save()
    run = ScriptedSession(store)
    run.stop_at = 4                      # Ctrl-C in game 4: its record is lost, games 1-3 stay
    with pytest.raises(KeyboardInterrupt):
        run.protocol()
    assert [e for e in run.events if e[0] != 'show'] == [
        ('start', 'game', 'Game 1'), ('game', 1), ('start', 'game', 'Game 2'), ('game', 2), ('ask', (1, 2)),
        ('start', 'game', 'Game 3'), ('game', 3), ('start', 'game', 'Game 4'), ('game', 4)]
    data = json.loads(store.path.read_text())
    data['plays'] = data['plays'][:3]           # game 4 did not end
    store.path.write_text(json.dumps(data))
    again = ScriptedSession(S.SessionStore(tmp_path, '3'))
    again.stop_at = None
    assert again.protocol() == 0
    assert [e for e in again.events if e[0] != 'show'] == [
        ('start', 'game', 'Game 4'), ('game', 4), ('ask', (3, 4)),
        ('start', 'game', 'Game 5'), ('game', 5), ('start', 'game', 'Game 6'), ('game', 6), ('ask', (5, 6))]
    done = json.loads(again.store.path.read_text())
    assert done['complete'] and [p['game'] for p in done['plays']] == [1, 2, 3, 4, 5, 6]
    subject = json.loads((tmp_path / '3' / 'subject.json').read_text())
    assert len(subject['plays']) == 6 and len(subject['answers']) == 3
    # a questionnaire left open: the resumed session asks it before the next game
    store = S.SessionStore(tmp_path, '4', n_offsets=1)
    store.data.update(scenes=[{}], fit={'paper': None}, fit_seen=True,
                      plays=[dict(g) for g in store.data['plan']['games'][:2]])
    store.save()
    run = ScriptedSession(S.SessionStore(tmp_path, '4'))
    run.stop_at = 3
    with pytest.raises(KeyboardInterrupt):
        run.protocol()
    assert [e for e in run.events if e[0] != 'show'][:2] == [('ask', (1, 2)), ('start', 'game', 'Game 3')]
