"""The console's web server at its limits (issue 29), a real aiohttp server on loopback:

* a WebSocket message over 16 KB gets an error reply, then the socket closes (1009);
  one over 4,096 characters gets the reply and the socket stays;
* ``ping``'s and ``intervene``'s ``ref`` is an integer or a string: ``Infinity`` and
  ``NaN`` (which Python's reader accepts) are answered with an error, and every reply is
  strict JSON;
* unfinished HTTP requests: connections whose headers never end are closed after
  ``header_timeout``, and beyond ``max_unfinished`` at once a new one is closed as it
  opens; a page opened before keeps working, and so does a request after the flood.
"""
import asyncio
import json

import pytest

from supersafe_ros.console.server import MAX_FRAME_BYTES, ConsoleServer
from supersafe_ros.console.state import MAX_MESSAGE_CHARS, ConsoleState, Field
from console_support import closed_by_server, free_port

OBSTACLES = {i: (-10.0 + 2.5 * i, 4.0, 1.8) for i in range(3)}


def strict_json(text):
    def refuse(name):
        raise ValueError(f'{name} is not JSON')
    return json.loads(text, parse_constant=refuse)


class Console:
    def __init__(self, **kwargs):
        self.state = ConsoleState(['robot_0'], Field())
        self.state.set_obstacles(OBSTACLES)
        self.state.set_pose('robot_0', 0.0, 0.0, 0.0, 1)
        self.server = ConsoleServer(self.state, lambda oid: {'ok': True, 'message': 'sent'}, port=free_port(),
                                    log=lambda *a: None, **kwargs)

    def __enter__(self):
        self.server.start()
        return self

    def __exit__(self, *exc):
        self.server.stop()

    @property
    def url(self):
        return f'http://127.0.0.1:{self.server.port}'


async def reply(ws, timeout=10.0):
    msg = await ws.receive(timeout=timeout)
    return msg


def test_an_oversized_message_is_answered_before_the_socket_closes():
    import aiohttp
    with Console() as console:
        async def run():
            async with aiohttp.ClientSession() as session:
                async with session.ws_connect(console.url + '/ws') as ws:
                    assert strict_json((await reply(ws)).data)['type'] == 'hello'
                    await ws.send_str('x' * (MAX_MESSAGE_CHARS + 10))          # long: answered, kept
                    answer = strict_json((await reply(ws)).data)
                    assert answer['type'] == 'error' and 'too long' in answer['message']
                    await ws.send_str('{"type": "ping", "ref": 1}')
                    assert strict_json((await reply(ws)).data)['type'] == 'pong'
                    await ws.send_str('{"type": "ping", "ref": "' + 'y' * MAX_FRAME_BYTES + '"}')   # over 16 KB
                    answer = await reply(ws)
                    assert answer.type == aiohttp.WSMsgType.TEXT, answer
                    error = strict_json(answer.data)
                    assert error['type'] == 'error' and 'over 16 KB' in error['message']
                    closing = await reply(ws)
                    assert closing.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED), closing
                    assert ws.close_code == 1009
        asyncio.run(run())


@pytest.mark.parametrize('ref', ['Infinity', '-Infinity', 'NaN', '1e400', '1.5', 'true', '[1]', '{"a": 1}'])
def test_a_ref_that_is_not_an_integer_or_a_string_is_refused(ref):
    import aiohttp
    with Console() as console:
        async def run():
            async with aiohttp.ClientSession() as session:
                async with session.ws_connect(console.url + '/ws') as ws:
                    strict_json((await reply(ws)).data)
                    for kind in ('"ping"', '"intervene", "obstacle": 1'):
                        await ws.send_str(f'{{"type": {kind}, "ref": {ref}}}')
                        answer = strict_json((await reply(ws)).data)     # strict JSON, never Infinity
                        assert answer['type'] == 'error' and '"ref"' in answer['message'], answer
                    for good, echoed in (('7', 7), ('"abc"', 'abc'), ('null', None)):
                        await ws.send_str(f'{{"type": "ping", "ref": {good}}}')
                        assert strict_json((await reply(ws)).data)['ref'] == echoed
        asyncio.run(run())


def test_unfinished_requests_are_timed_out_and_capped():
    import aiohttp
    cap, slow = 5, 40
    with Console(header_timeout=1.0, max_unfinished=cap) as console:
        server = console.server
        port = server.port

        async def run():
            async with aiohttp.ClientSession() as session:
                page = await session.ws_connect(console.url + '/ws')       # a page open before
                assert strict_json((await reply(page)).data)['type'] == 'hello'
                conns = []
                for _ in range(slow):       # headers that never end
                    reader, writer = await asyncio.open_connection('127.0.0.1', port)
                    writer.write(f'GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Slow: '.encode())
                    conns.append((reader, writer))
                # the oldest are closed as newer ones open: the first 35 go while the last 5 are held
                for reader, _ in conns[:slow - cap]:
                    assert await closed_by_server(reader)
                assert server.unfinished.evicted == slow - cap and len(server.unfinished) == cap
                # a whole request gets through meanwhile (the oldest slow one makes room)
                async with session.get(console.url + '/') as r:
                    assert r.status == 200
                for reader, _ in conns[slow - cap:]:      # the rest: at the header timeout
                    assert await closed_by_server(reader)
                for _, writer in conns:
                    writer.close()
                assert server.unfinished.abandoned == slow and len(server.unfinished) == 0
                # the page still answers
                await page.send_str('{"type": "ping", "ref": 3}')
                pong = strict_json((await reply(page)).data)
                assert pong['type'] == 'pong' and pong['ref'] == 3
                await page.close()
        asyncio.run(run())
        assert server.unfinished.peak == cap + 1
