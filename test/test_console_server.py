"""The console's web server without ROS: access rules (token, Host, Origin), the click
limiter, connections (cap, idle ones), the WebSocket protocol, in a real headless
Chromium (test/console_support.py) and with a plain aiohttp client.

The state is fed by a thread standing in for the ROS callbacks; a click removes the
obstacle from that state, as the world's next /obstacle_markers would.
"""
import asyncio
from concurrent.futures import Future
import json
import math
import threading
import time

import pytest
from aiohttp import web

from supersafe_ros.console.access import HostRules
from supersafe_ros.console.limits import InterventionLimiter
from supersafe_ros.console.server import ConsoleServer, is_loopback
from supersafe_ros.console.state import (ClientMessageError, ConsoleState, Field,
                                         parse_client_message)
from console_support import Browser, free_port, http_status, wait_until

OBSTACLES = {i: (-10.0 + 2.5 * i, (-1) ** i * 4.0, 1.8) for i in range(10)}


def test_parse_client_message():
    assert parse_client_message('{"type": "intervene", "obstacle": 3}') == {
        'type': 'intervene', 'obstacle': 3, 'ref': None}
    for bad in ('{not json', '[1, 2]', '{"type": 7}', '{"type": "intervene"}',
                '{"type": "intervene", "obstacle": -1}', '{"type": "intervene", "obstacle": true}',
                '{"type": "intervene", "obstacle": "3"}', '{"type": "launch"}', b'{}', 'x' * 5000,
                '[' * 4000, '{"a":' * 1000):
        with pytest.raises(ClientMessageError):
            parse_client_message(bad)
    with pytest.raises(ClientMessageError, match='nested too deeply'):
        parse_client_message('[' * 4000)      # the decoder's RecursionError is a reply, not a crash


def test_host_and_origin_rules_admit_only_the_consoles_own_names():
    loop = HostRules('127.0.0.1')
    for host in ('127.0.0.1:8765', 'localhost:8765', 'LOCALHOST', '[::1]:8765', 'localhost.:80'):
        assert loop.host_ok(host), host
    # DNS rebinding: a name the attacker controls, resolving to 127.0.0.1
    for host in ('evil.example:8765', 'evil.example', '127.0.0.1.evil.example', '10.0.0.5:8765', '', None,
                 '[::1', 'localhost:99999'):
        assert not loop.host_ok(host), host
    assert loop.origin_ok(None, '127.0.0.1:8765')                    # not a browser
    assert loop.origin_ok('http://127.0.0.1:8765', '127.0.0.1:8765')
    assert loop.origin_ok('http://localhost:8765', 'localhost:8765')
    for origin in ('http://evil.example:8765', 'null', 'http://localhost:9999', 'file://', 'ftp://127.0.0.1:8765',
                   'http://127.0.0.1'):
        assert not loop.origin_ok(origin, '127.0.0.1:8765'), origin
    bound = HostRules('10.0.0.5')
    assert bound.host_ok('10.0.0.5:8765') and bound.host_ok('localhost') and not bound.host_ok('10.0.0.6')
    wildcard = HostRules('0.0.0.0')          # any address literal (cannot be rebound), no other name
    assert wildcard.host_ok('192.168.1.20:8765') and wildcard.host_ok('[fe80::1]:8765')
    assert not wildcard.host_ok('evil.example:8765')


def test_limiter_lets_one_click_per_obstacle_and_a_few_per_second_through():
    now = [0.0]
    lim = InterventionLimiter(per_second=3, confirm_timeout=3.0, clock=lambda: now[0])
    assert lim.admit(1) is None
    assert 'being removed' in lim.admit(1)          # sent, not answered yet
    lim.removed(1)
    assert 'already gone' in lim.admit(1)           # the world removed it
    assert lim.admit(2) is None and lim.admit(3) is None
    assert 'Too many' in lim.admit(4)               # a fourth within the same second
    now[0] = 1.0
    assert lim.admit(4) is None
    now[0] = 4.5                                    # no answer for 2 within confirm_timeout: again
    assert lim.admit(2) is None
    assert 'being removed' in lim.admit(2)
    lim.forget(2)                                   # never published after all: clickable again
    assert lim.admit(2) is None
    # the flood: 817 clicks/s for 5 s over ten obstacles, the world answering each
    # intervention 50 ms later
    lim = InterventionLimiter(per_second=3, confirm_timeout=3.0, clock=lambda: now[0])
    admitted, answers, next_id, alive = [], [], 10, list(range(10))
    for k in range(817 * 5):
        now[0] = 100.0 + k / 817
        while answers and answers[0][0] <= now[0]:
            _, oid = answers.pop(0)
            lim.removed(oid)
        oid = alive[k % len(alive)]
        if lim.admit(oid) is None:
            admitted.append((now[0], oid))
            answers.append((now[0] + 0.05, oid))
            alive[alive.index(oid)] = next_id       # the world's replacement
            next_id += 1
    assert 10 <= len(admitted) <= 3 * 6
    assert len({oid for _, oid in admitted}) == len(admitted)      # never the same obstacle twice
    for t, _ in admitted:
        assert sum(1 for u, _ in admitted if t <= u < t + 1.0) <= 3


def test_intervention_is_the_nearest_robots_state_relative_to_the_obstacle():
    state = ConsoleState(['robot_0', 'robot_1'])
    state.set_obstacles({4: (1.0, 2.0, 1.8)})
    with pytest.raises(LookupError):
        state.intervention(4)
    state.set_pose('robot_0', -10.0, 0.0, 0.0, 5)
    state.set_pose('robot_1', 3.0, 1.0, 0.5, 7)
    req = state.intervention(4)
    assert req.robot == 'robot_1' and req.stamp_ns == 7
    assert req.rel_state == pytest.approx((2.0, -1.0, 0.5))
    with pytest.raises(KeyError):
        state.intervention(5)
    with pytest.raises(ValueError):
        state.set_pose('robot_9', 0.0, 0.0, 0.0, 0)
    with pytest.raises(ValueError):
        state.set_pose('robot_0', math.nan, 0.0, 0.0, 0)
    assert is_loopback('127.0.0.1') and is_loopback('::1') and is_loopback('localhost')
    assert not is_loopback('0.0.0.0') and not is_loopback('10.1.2.3')


class FedServer:
    """A ConsoleServer whose state a thread moves (two robots circling, ten obstacles).
    With ``world_delay`` a click is answered as the bridge does: through the limiter, by a
    Future that a stand-in for the world completes that many seconds later."""

    def __init__(self, host, max_connections=8, world_delay=None, clock=time.monotonic):
        self.state = ConsoleState(['robot_0', 'robot_1'], Field())
        self.state.set_obstacles(OBSTACLES)
        self.clicked = []
        self.world_delay = world_delay
        self.limiter = InterventionLimiter(per_second=3, clock=clock)
        self.server = ConsoleServer(self.state, self.intervene if world_delay is None else self.intervene_later,
                                    host=host, port=free_port(), update_rate=30.0, log=lambda *a: None,
                                    max_connections=max_connections)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.feed, daemon=True)

    def intervene_later(self, oid):
        if not self.state.has_obstacle(oid):
            return {'ok': False, 'message': 'That obstacle is already gone.'}
        refused = self.limiter.admit(oid)
        if refused:
            return {'ok': False, 'message': refused, 'limited': True}
        future = Future()

        def world():
            self.intervene(oid)
            self.limiter.removed(oid)
            future.set_result({'ok': True, 'robot': 'robot_1', 'message': 'removed'})
        threading.Timer(self.world_delay, world).start()
        return future

    def intervene(self, oid):
        try:
            self.state.intervention(oid)
        except KeyError:
            return {'ok': False, 'message': f'obstacle {oid} is already gone'}
        self.clicked.append(oid)
        self.state.set_obstacles({k: v for k, v in OBSTACLES.items() if k not in self.clicked})
        return {'ok': True, 'robot': 'robot_0', 'message': 'sent'}

    def feed(self):
        k = 0
        while not self.stop.wait(0.02):
            k += 1
            for i, r in enumerate(self.state.robots):
                a = 0.05 * k + i * math.pi
                self.state.set_pose(r, 12 * math.cos(a), 8 * math.sin(a), a + math.pi / 2, k)

    def __enter__(self):
        self.server.start()
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join()
        self.server.stop()


@pytest.fixture(scope='module')
def browser():
    b = Browser()
    yield b.driver
    b.close()


def page_counts(driver):
    return driver.execute_script(
        'const p = window.supersafeConsole; return p && [p.connected, p.messages, p.renders, '
        'document.querySelectorAll("[data-obstacle-id]").length, p.errors.slice()];')


@pytest.mark.browser
def test_non_loopback_bind_refuses_requests_without_the_token(browser):
    # the rule is about the bind address: bound to every interface, reached over loopback
    with FedServer('0.0.0.0') as fed:
        server = fed.server
        assert server.token, 'a non-loopback bind must generate a token'
        base = f'http://127.0.0.1:{server.port}'
        for path in ('/', '/static/console.js', '/ws', '/?token=wrong'):
            assert http_status(base + path) == 403, path
        assert http_status(f'{base}/?token={server.token}') == 200
        assert http_status(f'{base}/static/console.js?token={server.token}') == 200

        browser.get(base + '/')
        assert '403' in browser.find_element('tag name', 'body').text
        assert not browser.find_elements('css selector', '[data-obstacle-id]')
        # with the token the page, its scripts (cookie) and the WebSocket all work
        browser.get(f'{base}/?token={server.token}')
        wait_until(lambda: (page_counts(browser) or [0])[0] and page_counts(browser)[3] == 10,
                   30, 'the page to connect with the token and draw ten obstacles')
    with FedServer('127.0.0.1') as fed:
        assert not fed.server.token
        assert http_status(f'http://127.0.0.1:{fed.server.port}/') == 200


@pytest.mark.browser
def test_malformed_websocket_message_gets_an_error_and_the_server_keeps_serving(browser):
    with FedServer('127.0.0.1') as fed:
        browser.get(f'http://127.0.0.1:{fed.server.port}/')
        wait_until(lambda: (page_counts(browser) or [0])[0], 30, 'the page to connect')
        browser.execute_script("""
            const ws = window.supersafeConsole.ws;
            ws.send('{not json');
            ws.send(JSON.stringify({type: 'intervene', obstacle: 'three'}));
            ws.send(JSON.stringify({type: 'format_disk'}));
            ws.send(new Uint8Array([1, 2, 3]));""")
        errors = wait_until(lambda: len(page_counts(browser)[4]) >= 4 and page_counts(browser)[4],
                            30, 'four error replies')
        assert 'not JSON' in errors[0] and 'obstacle' in errors[1]
        assert 'unknown message type' in errors[2] and 'binary' in errors[3]
        # still serving: state keeps arriving on the same socket, and a click still works
        before = page_counts(browser)[1]
        wait_until(lambda: page_counts(browser)[1] > before + 10, 30, 'more state updates')
        browser.find_element('css selector', '[data-obstacle-id="4"]').click()
        wait_until(lambda: page_counts(browser)[3] == 9, 30, 'obstacle 4 to leave the page')
        assert fed.clicked == [4]
        # an obstacle already gone gets a message on the page, and nothing breaks
        browser.execute_script("window.supersafeSend({type: 'intervene', obstacle: 4});")
        wait_until(lambda: 'already gone' in browser.find_element('id', 'message').text, 30,
                   'the page to say the obstacle is already gone')
        assert page_counts(browser)[0] and fed.clicked == [4]

        # a plain client sees the same protocol; a page from another origin is refused
        async def raw():
            import aiohttp
            url = f'http://127.0.0.1:{fed.server.port}/ws'
            async with aiohttp.ClientSession() as session:
                async with session.ws_connect(url) as ws:
                    hello = json.loads((await ws.receive()).data)
                    assert hello['type'] == 'hello' and len(hello['state']['obstacles']) == 9
                    await ws.send_str('{"type": "intervene"}')
                    while True:
                        reply = json.loads((await ws.receive(timeout=10)).data)
                        if reply['type'] != 'state':
                            break
                    assert reply['type'] == 'error'
                    await ws.send_str('{"type": "ping", "ref": 1}')
                    while True:
                        reply = json.loads((await ws.receive(timeout=10)).data)
                        if reply['type'] != 'state':
                            break
                    assert reply == {'type': 'pong', 'ref': 1, 'time': reply['time']}
                with pytest.raises(aiohttp.WSServerHandshakeError) as exc:
                    async with session.ws_connect(url, headers={'Origin': 'http://evil.example'}):
                        pass
                assert exc.value.status == 403
        asyncio.run(raw())


def ws_url(fed):
    return f'http://127.0.0.1:{fed.server.port}/ws'


async def next_reply(ws, timeout=10):
    """The next message that is not a state update."""
    while True:
        msg = json.loads((await ws.receive(timeout=timeout)).data)
        if msg['type'] != 'state':
            return msg


def test_rebinding_hosts_and_foreign_origins_are_refused_and_deep_json_gets_a_reply():
    import aiohttp
    with FedServer('127.0.0.1') as fed:
        port = fed.server.port

        async def run():
            async with aiohttp.ClientSession() as session:
                # DNS rebinding: the request reaches 127.0.0.1 under the attacker's name
                async with session.get(f'http://127.0.0.1:{port}/', headers={'Host': f'evil.example:{port}'}) as r:
                    assert r.status == 403
                async with session.get(f'http://127.0.0.1:{port}/', headers={'Host': f'localhost:{port}'}) as r:
                    assert r.status == 200
                for headers in ({'Host': f'evil.example:{port}', 'Origin': f'http://evil.example:{port}'},
                                {'Origin': f'http://evil.example:{port}'}, {'Origin': 'null'}):
                    with pytest.raises(aiohttp.WSServerHandshakeError) as exc:
                        async with session.ws_connect(ws_url(fed), headers=headers):
                            pass
                    assert exc.value.status == 403, headers
                async with session.ws_connect(ws_url(fed), headers={'Origin': f'http://127.0.0.1:{port}'}) as ws:
                    assert json.loads((await ws.receive()).data)['type'] == 'hello'
                    await ws.send_str('[' * 4000)
                    reply = await next_reply(ws)
                    assert reply['type'] == 'error' and 'nested' in reply['message']
                    await ws.send_str('{"type": "ping", "ref": 2}')     # the same socket still answers
                    assert (await next_reply(ws))['type'] == 'pong'
        asyncio.run(run())
        assert fed.server.refused['host'] == 2 and fed.server.refused['origin'] == 2


def test_connections_are_capped_and_idle_ones_get_no_updates():
    import aiohttp
    with FedServer('127.0.0.1', max_connections=4) as fed:
        async def run():
            async with aiohttp.ClientSession() as session:
                idle = [await session.ws_connect(ws_url(fed)) for _ in range(3)]
                watcher = await session.ws_connect(ws_url(fed))
                with pytest.raises(aiohttp.WSServerHandshakeError) as exc:
                    await session.ws_connect(ws_url(fed))              # the fifth
                assert exc.value.status == 503
                for ws in idle + [watcher]:
                    assert json.loads((await ws.receive()).data)['type'] == 'hello'
                await watcher.send_str('{"type": "watch"}')
                states = 0
                while states < 20:
                    msg = json.loads((await watcher.receive(timeout=10)).data)
                    states += msg['type'] == 'state'
                    if states == 1:       # a watcher's first update is complete
                        assert 'obstacles' in msg and 'stats' in msg and 'events' in msg
                # twenty updates went out meanwhile; the sockets that never asked got none
                for ws in idle:
                    with pytest.raises(asyncio.TimeoutError):
                        await ws.receive(timeout=0.3)
                await idle[0].close()
                again = await session.ws_connect(ws_url(fed))          # a place is free again
                assert json.loads((await again.receive()).data)['type'] == 'hello'
                for ws in idle[1:] + [watcher, again]:
                    await ws.close()
        asyncio.run(run())
        assert fed.server.refused['full'] == 1


def test_a_click_is_answered_with_what_the_world_did_and_a_flood_is_limited():
    """The limiter's clock is the test's: the flood comes within the second of the first click
    however slowly a busy machine serves it."""
    import aiohttp
    now = [0.0]
    with FedServer('127.0.0.1', world_delay=0.1, clock=lambda: now[0]) as fed:
        async def run():
            async with aiohttp.ClientSession() as session:
                async with session.ws_connect(ws_url(fed)) as ws:
                    await ws.receive()
                    await ws.send_str(json.dumps({'type': 'intervene', 'obstacle': 3, 'ref': 'a'}))
                    await ws.send_str(json.dumps({'type': 'intervene', 'obstacle': 3, 'ref': 'b'}))
                    replies = {}
                    while len(replies) < 2:
                        r = await next_reply(ws)
                        replies[r['ref']] = r
                    # the second click on the same obstacle is refused at once; the first gets
                    # the world's answer (the robot it named) once the world has removed it
                    assert replies['b']['ok'] is False and 'being removed' in replies['b']['message']
                    assert replies['a'] == {'type': 'intervention', 'obstacle': 3, 'ref': 'a', 'ok': True,
                                            'robot': 'robot_1', 'message': 'removed'}
                    # a flood: 400 clicks on every obstacle as fast as the socket takes them, half a
                    # second after the first click
                    now[0] = 0.5
                    for k in range(400):
                        await ws.send_str(json.dumps({'type': 'intervene', 'obstacle': k % 10, 'ref': k}))
                    answers = []
                    while len(answers) < 400:
                        r = await next_reply(ws)
                        if r['type'] == 'intervention' and isinstance(r['ref'], int):
                            answers.append(r)
                    return answers
        answers = asyncio.run(run())
        ok = [a['obstacle'] for a in answers if a['ok']]
        assert len(ok) == len(set(ok)) and 1 <= len(ok) <= 9        # nine obstacles left, each once at most
        # only those reached the "world" (the world's stand-ins answer on timers of their own: any order)
        assert fed.clicked[0] == 3 and sorted(fed.clicked[1:]) == sorted(ok)
        reasons = {a['message'] for a in answers if not a['ok']}
        assert reasons <= {'That obstacle is already gone.', 'That obstacle is already being removed.',
                           'Too many clicks: wait a moment, then click again.'}, reasons
        assert 'Too many clicks: wait a moment, then click again.' in reasons


@pytest.mark.browser
def test_page_keeps_keyboard_focus_marks_crashes_answers_empty_clicks_and_shows_a_lost_connection(browser):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys
    fed = FedServer('127.0.0.1').__enter__()
    try:
        browser.get(f'http://127.0.0.1:{fed.server.port}/')
        wait_until(lambda: (page_counts(browser) or [0, 0, 0, 0])[3] == 10, 30, 'ten obstacles')
        assert browser.execute_script('return document.body.dataset.connected') == 'true'
        colours = browser.execute_script(
            'return [...document.querySelectorAll("[data-robot]")].map(r => r.dataset.colour)')
        assert colours == ['blue', 'orange']
        # keyboard: focus an obstacle, Enter removes it, the focus moves to another obstacle
        browser.execute_script('document.querySelector(\'[data-obstacle-id="2"]\').focus()')
        ActionChains(browser).send_keys(Keys.ENTER).perform()
        wait_until(lambda: page_counts(browser)[3] == 9, 30, 'obstacle 2 to leave the page')
        assert browser.execute_script(
            'return document.activeElement && document.activeElement.getAttribute("data-obstacle-id")') == '0'
        ActionChains(browser).send_keys(Keys.ENTER).perform()          # still works from there
        wait_until(lambda: page_counts(browser)[3] == 8, 30, 'obstacle 0 to leave the page')
        assert fed.clicked == [2, 0]
        # a click on the empty ground says what to do instead
        browser.execute_script("document.getElementById('ground').dispatchEvent("
                               "new MouseEvent('click', {bubbles: true}))")
        wait_until(lambda: 'not an obstacle' in browser.find_element('id', 'message').text, 30,
                   'the message line to answer a click on nothing')
        # a crash from the world: a mark on the field where it happened, and the line names the robot
        fed.state.add_crash({'robot': 'robot_1', 'obstacle': '5', 'time': '0.0', 'x': '2.5', 'y': '-4.0'})
        mark = wait_until(lambda: browser.find_elements('css selector', '[data-crash]'), 30, 'a crash mark')
        assert mark[0].get_attribute('transform') == 'translate(2.5 -4)'
        assert browser.find_element('id', 'message').text == 'Crash: the orange robot hit an obstacle.'
        # a robot driven off the field (Phase I) stays in sight at the field's edge, faded
        fed.stop.set()
        fed.thread.join()
        fed.state.set_pose('robot_0', 30.0, -2.0, 0.0, 10 ** 9)
        robot = wait_until(lambda: (r := browser.find_element('css selector', '[data-robot="robot_0"]'))
                           .get_attribute('data-x') == '30' and r, 30, 'the off-field pose')
        assert robot.get_attribute('transform').startswith('translate(19.4 -2)')
        assert 'off-field' in robot.get_attribute('class')
        # the console goes away: a banner that says what happened and what to do
        fed.__exit__(None, None, None)
        banner = wait_until(lambda: (b := browser.find_element('id', 'banner')).is_displayed() and b, 30,
                            'the lost-connection banner')
        assert 'connection' in banner.text and 'researcher' in banner.text
        assert browser.execute_script('return document.body.dataset.connected') == 'false'
    finally:
        fed.stop.set()
        fed.server.stop()


class SlowScriptServer(ConsoleServer):
    """The session's page, whose session.js arrives ``delay`` s late (a slow disk or a
    loaded machine): console.js has run long before it."""

    delay = 2.0

    @web.middleware
    async def _access(self, request, handler):
        if request.path == '/static/session.js':
            await asyncio.sleep(self.delay)
        return await super()._access(request, handler)


@pytest.mark.browser
def test_the_first_message_waits_for_the_pages_other_scripts(browser):
    # hello carries the session's screen; session.js, which shows it, must be listening by then
    state = ConsoleState(['robot_0'], Field())
    state.set_obstacles(OBSTACLES)
    server = SlowScriptServer(state, lambda oid: {'ok': False, 'message': 'no'}, port=free_port(),
                              log=lambda *a: None)
    server.index_page = 'session.html'
    server.hello_extra = lambda: {'session': {'type': 'session', 'phase': 'phase1', 'waiting': True,
                                              'seconds': 60}}
    server.start()
    try:
        browser.get(f'http://127.0.0.1:{server.port}/')
        wait_until(lambda: (page_counts(browser) or [0])[0], 30, 'the page to connect')
        wait_until(lambda: browser.execute_script('return window.supersafeConsole.renders') > 0, 30,
                   'the first state to be drawn')
        # one hello per connection, and nothing else names the screen: it was seen or it is lost
        assert browser.execute_script('return document.body.dataset.phase') == 'phase1'
        assert browser.find_element('id', 'phase-title').text.startswith('Part 1 of 3')
        assert browser.find_element('id', 'start').is_displayed()
    finally:
        server.stop()


def test_a_page_that_cannot_take_a_screen_message_is_closed_and_gets_the_screen_on_reconnecting():
    # the session's screens are pushed once each: a page that missed one (its socket backed
    # up) would stay, connected, on the old screen; closed, it reconnects to the current one
    import aiohttp
    with FedServer('127.0.0.1') as fed:
        view = {'type': 'session', 'phase': 'phase1', 'waiting': False}
        fed.server.hello_extra = lambda: {'session': view}

        async def receive(ws):
            msg = await ws.receive(timeout=10)
            return json.loads(msg.data) if msg.type == aiohttp.WSMsgType.TEXT else msg.type

        async def run():
            async with aiohttp.ClientSession() as session:
                async with session.ws_connect(ws_url(fed)) as slow:
                    assert (await receive(slow))['session']['phase'] == 'phase1'
                    # its send buffer is backed up, as if the page had stopped reading
                    (client,) = fed.server.clients.values()
                    client.transport = None
                    async with session.ws_connect(ws_url(fed)) as quick:
                        assert (await receive(quick))['session']['phase'] == 'phase1'
                        view.update(phase='phase2', waiting=True)
                        fed.server.push(view)
                        assert (await receive(quick)) == view
                        assert await receive(slow) in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED)
                # the page reconnects: its hello has the screen it missed
                async with session.ws_connect(ws_url(fed)) as again:
                    assert (await receive(again))['session'] == view
        asyncio.run(run())
