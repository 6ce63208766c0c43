"""The console's web server without ROS: access rules, WebSocket protocol, in a real
headless Chromium (test/console_support.py) and with a plain aiohttp client.

The state is fed by a thread standing in for the ROS callbacks; a click removes the
obstacle from that state, as the world's next /obstacle_markers would.
"""
import asyncio
import json
import math
import threading

import pytest

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
                '{"type": "intervene", "obstacle": "3"}', '{"type": "launch"}', b'{}', 'x' * 5000):
        with pytest.raises(ClientMessageError):
            parse_client_message(bad)


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
    """A ConsoleServer whose state a thread moves (two robots circling, ten obstacles)."""

    def __init__(self, host):
        self.state = ConsoleState(['robot_0', 'robot_1'], Field())
        self.state.set_obstacles(OBSTACLES)
        self.clicked = []
        self.server = ConsoleServer(self.state, self.intervene, host=host, port=free_port(),
                                    update_rate=30.0, log=lambda *a: None)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.feed, daemon=True)

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
