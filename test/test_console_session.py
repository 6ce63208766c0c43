"""`supersafe session`: the participant protocol's bookkeeping, and Phase II with a
scripted person in a real headless Chromium, through to the fit."""
import io
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from supersafe_ros.console import session as S
from console_support import Browser, free_port, wait_for_server, wait_until


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
    with pytest.raises(ValueError):
        S.check_participant_id('../x')


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
        S.check_answers({'trust': 8})
    full = {k: 4 for k, _ in S.LIKERT_ITEMS}
    assert S.check_answers(full) == full


def test_human_and_simulated_subjects_go_through_the_study_analysis(tmp_path):
    from supersafe_ros.reach.library import load_or_build_library
    from supersafe_ros.study.protocol import reference_sets
    from supersafe_ros.study.summary import summarize
    lib = load_or_build_library()
    standard, conservative = reference_sets()
    games = {c: {'false_positives': fp, 'interventions': fp + 2, 'crashes': 0, 'trips': 9}
             for c, fp in zip(S.CONDITIONS, (6, 4, 2))}
    human = {'participant': 'h1', 'order': list(S.LATIN_ORDERS[0]),
             'scenes': [{'y0': 0.0, 'intervened': True, 'state': [-4.0, 0.0, 0.0], 'frames': []},
                        {'y0': 1.0, 'intervened': True, 'state': [-3.5, 1.0, 0.0], 'frames': []},
                        {'y0': 2.25, 'intervened': False, 'state': None, 'frames': []}],
             'fit': {'paper': {'omega_max': 0.75, 'mu': 0.4, 'sigma': 0.2, 'alpha': 0.4}},
             'games': games, 'answers': [{'after_game': 2, 'values': {'trust': 5}}]}
    S.write_subject(tmp_path / 'h1', S.subject_record(human, lib.entry(0.75)))
    simulated = {'subject': {'index': 0, 'omega_max': 0.5, 'mu': 0.3, 'sigma': 0.2, 'seed': 1},
                 'fit': {'omega_max': 0.5, 'mu': 0.3, 'sigma': 0.2}, 'states': [[-4.5, 0.2, 0.0]],
                 'learned_vf': lib.entry(0.5), 'games': games, 'sweep': {}}
    S.write_subject(tmp_path / 's0', simulated)
    records = [S.load_subject(tmp_path / 'h1'), S.load_subject(tmp_path / 's0')]
    assert records[0]['subject']['kind'] == 'human' and records[0]['answers'][0]['values'] == {'trust': 5}
    assert records[0]['learned_vf'].values.shape == lib.entry(0.75).values.shape
    summary = summarize(records, standard, conservative)
    assert summary['conditions']['standard']['false_positives'] == [6, 6]
    assert summary['table1']['standard']['total'] == 3      # 2 human + 1 simulated intervention
    # the command does the same from the files
    from supersafe_ros.console.session_runner import analyse
    out = io.StringIO()
    assert analyse([tmp_path], tmp_path / 'summary.json', out=out) == 0
    assert out.getvalue().startswith('2 subjects (1 human, 1 simulated)')
    assert json.loads((tmp_path / 'summary.json').read_text())['answers']['h1'][0]['values'] == {'trust': 5}


def test_complete_participant_is_refused_by_the_command(tmp_path):
    store = S.SessionStore(tmp_path, 'done1', n_offsets=2)
    store.data['complete'] = True
    store.save()
    r = subprocess.run([sys.executable, '-m', 'supersafe_ros.cli', 'session', '--participant', 'done1',
                        '--out', str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and 'never overwritten' in r.stderr


def page(driver):
    return driver.execute_script("""
        const r = document.querySelector('[data-robot="robot_0"]');
        const o = document.querySelector('[data-obstacle-id]');
        return {phase: document.body.dataset.phase, waiting: document.body.dataset.waiting,
                running: document.body.dataset.running,
                x: r && r.hasAttribute('data-x') ? parseFloat(r.dataset.x) : null,
                obstacle: o ? o.dataset.obstacleId : null,
                fits: [...document.querySelectorAll('#fit-lines li')].map(li => li.textContent),
                figure: document.getElementById('fit-figure').naturalWidth};""")


@pytest.mark.ros
@pytest.mark.browser
def test_scripted_participant_goes_through_phase_two_and_gets_a_fit(tmp_path):
    from selenium.webdriver.common.keys import Keys
    port = free_port()
    n = 3
    proc = subprocess.Popen(
        [sys.executable, '-m', 'supersafe_ros.cli', 'session', '--participant', '12', '--out',
         str(tmp_path), '--port', str(port), '--offsets', str(n), '--phase1-seconds', '0',
         '--stop-after', 'fit', '--rate-factor', '2'],
        env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True)
    browser = None
    try:
        wait_for_server(f'http://127.0.0.1:{port}/', timeout=60)
        browser = Browser()
        d = browser.driver
        d.get(f'http://127.0.0.1:{port}/')
        wait_until(lambda: page(d)['phase'] == 'phase2' and page(d)['waiting'] == 'true', 60,
                   'the Phase II start button')
        d.find_element('id', 'start').click()
        handled = set()

        # intervene on every scene but the last, when the robot is 3-5 m before the obstacle
        def step():
            p = page(d)
            if p['phase'] in ('fitting', 'fit'):
                return True
            if (p['obstacle'] is not None and p['obstacle'] not in handled and len(handled) < n - 1
                    and p['x'] is not None and -6.0 <= p['x'] <= -2.5):
                d.find_element('tag name', 'body').send_keys(Keys.SPACE)
                handled.add(p['obstacle'])
            return False
        wait_until(step, 60 + 30 * n, 'Phase II to end', period=0.03)
        wait_until(lambda: page(d)['phase'] == 'fit' and page(d)['figure'] > 0, 120,
                   'the fit and its figure on the page')
        fits = page(d)['fits']
        assert fits[0].startswith('paper: w_max') and fits[1].startswith('first-passage: w_max'), fits
        data = json.loads((tmp_path / '12' / 'session.json').read_text())
        # the scenes the person intervened in, and one (at least) let pass
        assert {str(s['obstacle']) for s in data['scenes'] if s['intervened']} == handled
        assert len(handled) == n - 1 and len(data['scenes']) == n
        assert sorted(s['y0'] for s in data['scenes']) == pytest.approx(np.linspace(-2.25, 2.25, n))
        for s in data['scenes']:
            if s['intervened']:
                # the intervention state is the robot's state relative to the obstacle
                assert -7.0 <= s['state'][0] <= -1.0 and s['state'][1] == pytest.approx(s['y0'], abs=0.05)
            else:
                assert len(s['frames']) > 10 and s['frames'][-1][0] > 2.0   # the whole pass, recorded
        assert data['fit']['paper']['interventions'] == n - 1
        assert data['fit']['first_passage']['encounters'] == n
        assert data['order'] == list(S.condition_order('12'))
        d.find_element('id', 'start').click()              # "Continue": --stop-after fit ends here
        assert proc.wait(timeout=60) == 0
        # the session's recording holds the person's interventions as the graph carried them
        from bag_support import read_bag
        _, _, _, messages = read_bag(tmp_path / '12' / 'recording-1' / 'recording-1_0.mcap')
        frames = [m.header.frame_id for topic, _, _, m, _ in messages if topic == '/interventions']
        assert sorted(frames) == sorted(f'obstacle_{o}' for o in handled)
    finally:
        if browser:
            browser.close()
        if proc.poll() is None:
            proc.send_signal(2)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
        print(proc.stdout.read())


@pytest.mark.ros
@pytest.mark.browser
@pytest.mark.slow
def test_scripted_participant_completes_the_whole_protocol(tmp_path):
    """Phase I (arrow keys), Phase II (Space), the fit, three games with clicks and both
    Likert screens, to subject.json; then the researcher's --analyse over it."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys
    port = free_port()
    n, game_s = 3, 6.0
    proc = subprocess.Popen(
        [sys.executable, '-m', 'supersafe_ros.cli', 'session', '--participant', 'w1', '--out',
         str(tmp_path), '--port', str(port), '--offsets', str(n), '--phase1-seconds', '4',
         '--game-seconds', str(game_s), '--rate-factor', '2', '--no-record'],
        env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True)
    browser = None
    try:
        wait_for_server(f'http://127.0.0.1:{port}/', timeout=60)
        browser = Browser()
        d = browser.driver
        d.get(f'http://127.0.0.1:{port}/')

        def press_start(phase):
            wait_until(lambda: page(d)['phase'] == phase and page(d)['waiting'] == 'true', 180,
                       lambda: f'the {phase} start button (page: {page(d)})')
            d.find_element('id', 'start').click()
            wait_until(lambda: page(d)['waiting'] != 'true' or page(d)['phase'] != phase, 30,
                       f'{phase} to start')

        press_start('phase1')
        wait_until(lambda: page(d)['running'] == 'true', 60, 'Phase I to run')
        ActionChains(d).key_down(Keys.ARROW_LEFT).perform()
        wait_until(lambda: page(d)['phase'] != 'phase1', 120, 'Phase I to end')
        ActionChains(d).key_up(Keys.ARROW_LEFT).perform()
        press_start('phase2')
        handled = set()

        def phase2_step():
            p = page(d)
            if p['phase'] in ('fitting', 'fit'):
                return True
            if (p['obstacle'] is not None and p['obstacle'] not in handled and len(handled) < n - 1
                    and p['x'] is not None and -6.0 <= p['x'] <= -2.5):
                d.find_element('tag name', 'body').send_keys(Keys.SPACE)
                handled.add(p['obstacle'])
            return False
        wait_until(phase2_step, 60 + 30 * n, 'Phase II to end', period=0.03)
        press_start('fit')
        clicks = 0
        for game in range(3):
            press_start('game')

            def game_step():
                nonlocal clicks
                p = page(d)
                if p['phase'] != 'game' or p['waiting'] == 'true':
                    return True
                if p['obstacle'] is not None and p['running'] == 'true' and clicks < 2 * (game + 1):
                    d.find_element('css selector', '[data-obstacle-id]').click()
                    clicks += 1
                return False
            wait_until(game_step, 180, f'game {game + 1} to end', period=0.5)
            if game >= 1:
                wait_until(lambda: page(d)['phase'] == 'likert', 60, 'the Likert screen')
                fives = d.execute_script("""
                    const seen = new Set(); const out = [];
                    for (const r of document.querySelectorAll('input[data-likert]')) {
                      if (!seen.has(r.name) && r.value === '5') { seen.add(r.name); out.push(r); } }
                    return out;""")
                for radio in fives:
                    radio.click()
                d.find_element('css selector', 'button[data-action="answers"]').click()
        wait_until(lambda: page(d)['phase'] == 'done', 120, 'the end of the session')
        assert proc.wait(timeout=60) == 0
        subject = json.loads((tmp_path / 'w1' / 'subject.json').read_text())
        session = json.loads((tmp_path / 'w1' / 'session.json').read_text())
        assert set(session['games']) == set(S.CONDITIONS)
        for cond, g in session['games'].items():
            assert g['complete'] and g['sim_time'] == pytest.approx(game_s, abs=0.06), (cond, g)
            assert g['trips'] + g['crashes'] + g['interventions'] >= 0
        assert sum(g['interventions'] for g in session['games'].values()) >= 1   # the clicks reached the world
        assert len(session['answers']) == 2 and all(set(a['values'].values()) == {5} for a in session['answers'])
        assert subject['answers'] == session['answers'] or len(subject.get('answers', [])) == 2
        out = io.StringIO()
        from supersafe_ros.console.session_runner import analyse
        assert analyse([tmp_path], out=out) == 0
        assert '1 subjects (1 human' in out.getvalue() or '1 subject' in out.getvalue()
    finally:
        if browser:
            browser.close()
        if proc.poll() is None:
            proc.send_signal(2)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
        print(proc.stdout.read())
