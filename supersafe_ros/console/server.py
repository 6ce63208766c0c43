"""The console's web server: aiohttp (HTTP and WebSocket in one asyncio library).

It runs its own asyncio loop on a thread of its own; the ROS side never blocks it.
Hand-off between the two threads:
  ROS -> web: callbacks write into ``ConsoleState`` (one lock) and call ``notify``,
              which wakes the loop with ``call_soon_threadsafe`` at most once per
              pending batch (a flag, not one wake-up per pose).
  web -> ROS: a click calls ``intervene(obstacle_id)`` (publishing from this thread is
              thread-safe in rclpy), which returns at once: a dict (nothing published,
              and why) or a Future of the world's answer, awaited here without holding
              up the page's other messages.
Updates are batched: at most ``update_rate`` state messages per second, each with every
robot's newest pose; a change of the obstacles or a crash goes out at once.

Connections: at most ``max_connections`` WebSockets (more get 503). A page receives state
updates only after it asks (``{"type": "watch"}``, which the console's pages send), so a
connection that only holds a socket open costs nothing but its heartbeat; a watcher that
does not read (its send buffer is backed up) is skipped until it drains, then gets a
full snapshot. A message of ``push`` (the session's screen) is never skipped silently: a
page that cannot take it (backed up, or the send fails or takes over 2 s) is closed, so
it reconnects and its hello carries what it missed (``hello_extra``).

Access (``access.py``): the Host header must name the console (DNS rebinding), a
browser's Origin must be a page of the console, and a non-loopback bind needs the token
(``?token=``, the cookie the page sets, or ``Authorization: Bearer``), else 403.

Bounds on what a client holds: a connection whose request headers are not complete
within ``header_timeout`` s is closed (aiohttp's keep-alive timer, which runs from the
moment a connection opens and while it waits for a request), and at most
``max_unfinished`` connections may be without a complete request at once (``limits``:
when one more opens, the oldest is closed; a page's request completes at once, so it
gets through while slow ones are held). A WebSocket message over ``MAX_FRAME_BYTES`` gets an
error reply, then the socket is closed (code 1009, message too big); one over
``state.MAX_MESSAGE_CHARS`` characters gets the error reply and the socket stays open.
"""
from __future__ import annotations

import asyncio
from concurrent.futures import Future
import hmac
import json
from pathlib import Path
import secrets
import threading
import time

from aiohttp import WSCloseCode, WSMsgType, web

from .access import HostRules, is_loopback
from .limits import UnfinishedRequests
from .state import MAX_MESSAGE_CHARS, ClientMessageError, ConsoleState, parse_client_message

__all__ = ['ConsoleServer', 'is_loopback', 'new_token', 'static_dir']

TOKEN_COOKIE = 'supersafe_console_token'
BACKLOG_BYTES = 16 * 1024     # a watcher with more than this unsent is skipped until it drains
CLOSE_TIMEOUT = 0.5           # s a page gets to answer the close frame at shutdown
MAX_FRAME_BYTES = MAX_MESSAGE_CHARS * 4      # a WebSocket message longer than this closes the socket


def new_token() -> str:
    return secrets.token_urlsafe(18)


def static_dir() -> Path:
    """share/supersafe_ros/console/static from the ament index, else beside this module."""
    try:
        from ament_index_python.packages import get_package_share_directory
        shared = Path(get_package_share_directory('supersafe_ros')) / 'console' / 'static'
        if (shared / 'index.html').is_file():
            return shared
    except Exception:  # not installed in an ament prefix (editable install, plain venv)
        pass
    return Path(__file__).resolve().parent / 'static'


class ConsoleSocket(web.WebSocketResponse):
    """aiohttp's WebSocket, which says why before it closes on a message that is too big.

    aiohttp closes the socket as soon as it reads a message over ``max_msg_size`` (from
    ``receive``, before the handler sees anything); the page is told first."""

    async def close(self, *, code: int = WSCloseCode.OK, message: bytes = b'', drain: bool = True) -> bool:
        if code == WSCloseCode.MESSAGE_TOO_BIG and not self.closed:
            try:
                await self.send_str(json.dumps({
                    'type': 'error', 'message': f'message too long: over {MAX_FRAME_BYTES // 1024} KB; '
                    'the console closes the connection (the page reconnects)'}))
            except Exception:       # the page is gone already: nothing to tell
                pass
            message = message or b'message too big'
        return await super().close(code=code, message=message, drain=drain)


class Client:
    """One open WebSocket: whether it asked for updates, and whether it missed some."""

    __slots__ = ('ws', 'transport', 'watching', 'needs_full')

    def __init__(self, ws, transport):
        self.ws, self.transport = ws, transport
        self.watching = False
        self.needs_full = True

    def backed_up(self) -> bool:
        t = self.transport
        return t is None or t.is_closing() or t.get_write_buffer_size() > BACKLOG_BYTES


class ConsoleServer:
    """Serves the page and one WebSocket per open page.

    ``intervene(obstacle_id)`` is called for a click: a dict ({'ok': bool, 'message': str,
    ...}) is sent back to that page at once; a Future is awaited for at most
    ``confirm_timeout`` s, then ``unanswered(obstacle_id, future) -> dict`` gives the
    reply. ``extra_handlers``: {type: fn(msg) -> dict} for other page messages (the
    participant session uses this)."""

    def __init__(self, state: ConsoleState, intervene, host: str = '127.0.0.1', port: int = 8765,
                 token: str = '', update_rate: float = 30.0, log=print, extra_handlers=None,
                 static: Path | None = None, page_config: dict | None = None,
                 max_connections: int = 8, confirm_timeout: float = 3.0, unanswered=None,
                 header_timeout: float = 10.0, max_unfinished: int = 64):
        if not (update_rate > 0):
            raise ValueError('update_rate must be positive')
        if int(max_connections) < 1:
            raise ValueError('max_connections must be at least 1')
        if not (0 < header_timeout < float('inf')):
            raise ValueError('header_timeout must be a positive number of seconds')
        self.header_timeout = float(header_timeout)
        self.unfinished = UnfinishedRequests(max_unfinished)
        self.state = state
        self.intervene = intervene
        self.unanswered = unanswered or (lambda oid, fut: {
            'ok': False, 'message': 'The robots did not confirm the removal; try again.'})
        self.confirm_timeout = float(confirm_timeout)
        self.host = host
        self.port = int(port)
        self.loopback = is_loopback(host)
        self.rules = HostRules(host)
        # a non-loopback bind always needs a token: make one if none was given
        self.token = token or ('' if self.loopback else new_token())
        self.min_interval = 1.0 / float(update_rate)
        self.max_connections = int(max_connections)
        self.log = log
        self.extra_handlers = dict(extra_handlers or {})
        self.static = Path(static or static_dir())
        self.page_config = dict(page_config or {})
        self.index_page = 'index.html'      # the participant session serves session.html
        self.files_dir = None               # /files/<name> serves from here when set
        self.hello_extra = None             # fn() -> dict merged into each page's hello
        self.clients: dict = {}             # ws -> Client
        self.watchers: dict = {}            # the clients that asked for updates (an update visits only these)
        self.sent_updates = 0
        self.refused = {'host': 0, 'origin': 0, 'token': 0, 'full': 0}
        self._loop = None
        self._thread = None
        self._runner = None
        self._sender = None
        self._tasks: set = set()
        self._ready = threading.Event()
        self._error = None
        self._wake = None
        self._urgent = False
        self._pending = False
        self._pending_lock = threading.Lock()
        self._sent_versions = None
        state.changed = self.notify

    # ----- thread hand-off --------------------------------------------------------------
    def notify(self, kind: str = 'pose') -> None:
        """From any thread: something in the state changed."""
        loop = self._loop
        if loop is None:
            return
        with self._pending_lock:
            if kind == 'obstacles':
                self._urgent = True
            if self._pending and kind != 'obstacles':
                return
            self._pending = True
        try:
            loop.call_soon_threadsafe(self._wake.set)
        except RuntimeError:   # loop closed during shutdown
            pass

    def push(self, message: dict) -> None:
        """From any thread: send ``message`` to every open page."""
        loop = self._loop
        if loop is not None:
            try:
                asyncio.run_coroutine_threadsafe(self._send_all(json.dumps(message)), loop)
            except RuntimeError:
                pass

    # ----- life cycle ---------------------------------------------------------------------
    def start(self, timeout: float = 30.0) -> int:
        """Start the loop thread, bind, and return the bound port (raises if binding failed)."""
        self._thread = threading.Thread(target=self._run, name='console-web', daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError('the console web server did not start')
        if self._error is not None:
            raise self._error
        return self.port

    def url(self, host: str | None = None) -> str:
        h = host or self.host
        if ':' in h:
            h = f'[{h}]'
        suffix = f'?token={self.token}' if self.token else ''
        return f'http://{h}:{self.port}/{suffix}'

    def stop(self, timeout: float = 1.5) -> None:
        """Close every page's socket and the listener; returns within about ``timeout`` s."""
        loop = self._loop
        if loop is None:
            return
        fut = asyncio.run_coroutine_threadsafe(self._shutdown(), loop)
        try:
            fut.result(timeout=timeout)
        except Exception:
            pass
        try:
            loop.call_soon_threadsafe(loop.stop)
        except RuntimeError:
            pass
        if self._thread is not None:
            self._thread.join(timeout=timeout)

    def _run(self):
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self._wake = asyncio.Event()
        try:
            loop.run_until_complete(self._serve())
        except Exception as exc:   # binding failed: report it to start()
            self._error = exc
            self._ready.set()
            loop.close()
            return
        self._loop = loop
        self._sender = loop.create_task(self._send_loop())
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            self._loop = None
            loop.close()

    async def _serve(self):
        app = web.Application(middlewares=[self._access])
        app.router.add_get('/', self._index)
        app.router.add_get('/ws', self._ws)
        app.router.add_get('/files/{name}', self._file)
        app.router.add_static('/static/', self.static, follow_symlinks=False)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=0.5,
                                     keepalive_timeout=self.header_timeout)
        await self._runner.setup()
        self._count_unfinished(self._runner.server)
        site = web.TCPSite(self._runner, self.host, self.port)
        await site.start()
        self.port = site._server.sockets[0].getsockname()[1]

    async def _shutdown(self):
        for task in [self._sender, *self._tasks]:
            if task is not None:
                task.cancel()
        await asyncio.gather(*(asyncio.wait_for(ws.close(code=1001, message=b'console stopped'), CLOSE_TIMEOUT)
                               for ws in list(self.clients)), return_exceptions=True)
        if self._sender is not None:
            await asyncio.gather(self._sender, return_exceptions=True)
        if self._runner is not None:
            await self._runner.cleanup()

    def _count_unfinished(self, server):
        """Every connection counts as unfinished from its opening to its first complete
        request (``_access`` sees it); over ``max_unfinished``, the oldest is closed."""
        made, lost = server.connection_made, server.connection_lost

        def connection_made(handler, transport):
            made(handler, transport)
            oldest = self.unfinished.opened(handler)
            if oldest is not None:
                # aiohttp's own way to drop a connection (as its keep-alive timer does), once
                # the handler is set up: closing the transport here would pull it out from under it
                asyncio.get_running_loop().call_soon(oldest.force_close)

        def connection_lost(handler, exc):
            self.unfinished.closed(handler)
            lost(handler, exc)

        server.connection_made, server.connection_lost = connection_made, connection_lost

    # ----- HTTP -----------------------------------------------------------------------------
    def _token_ok(self, request) -> bool:
        if not self.token:
            return True
        auth = request.headers.get('Authorization', '')
        given = (request.query.get('token') or request.cookies.get(TOKEN_COOKIE)
                 or (auth[7:] if auth.startswith('Bearer ') else ''))
        return hmac.compare_digest(given.encode(), self.token.encode())

    def _refuse(self, why: str, text: str):
        self.refused[why] += 1
        return web.Response(status=403, text=text)

    @web.middleware
    async def _access(self, request, handler):
        self.unfinished.finished(request.protocol)
        host = request.headers.get('Host')
        if not self.rules.host_ok(host):
            return self._refuse('host', '403: this console answers only to its own address '
                                '(127.0.0.1, localhost, [::1] or the address it is bound to)\n')
        if not self.rules.origin_ok(request.headers.get('Origin'), host):
            return self._refuse('origin', '403: a page of another site may not use this console\n')
        if not self._token_ok(request):
            return self._refuse('token', '403: this console needs its token (?token=...)\n')
        response = await handler(request)
        if self.token and request.query.get('token') and isinstance(response, web.StreamResponse):
            response.set_cookie(TOKEN_COOKIE, self.token, httponly=True, samesite='Strict')
        return response

    async def _index(self, request):
        return web.FileResponse(self.static / self.index_page,
                                headers={'Cache-Control': 'no-store'})

    async def _file(self, request):
        name = request.match_info['name']
        if self.files_dir is None or '/' in name or name.startswith('.'):
            raise web.HTTPNotFound()
        path = Path(self.files_dir) / name
        if not path.is_file():
            raise web.HTTPNotFound()
        return web.FileResponse(path, headers={'Cache-Control': 'no-store'})

    # ----- WebSocket ------------------------------------------------------------------------
    def hello(self) -> dict:
        snap = self.state.snapshot()
        out = {'type': 'hello', 'field': self.state.field.as_dict(),
               'robots': self.state.robots, 'config': self.page_config, 'state': snap}
        if self.hello_extra is not None:
            out.update(self.hello_extra())
        return out

    async def _ws(self, request):
        if len(self.clients) >= self.max_connections:
            self.refused['full'] += 1
            return web.Response(status=503, text=f'503: {self.max_connections} pages are open already; '
                                'close one (max_connections)\n')
        ws = ConsoleSocket(heartbeat=20.0, max_msg_size=MAX_FRAME_BYTES, compress=False, timeout=CLOSE_TIMEOUT)
        await ws.prepare(request)
        client = Client(ws, request.transport)
        self.clients[ws] = client
        try:
            await ws.send_str(json.dumps(self.hello()))
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    reply = self._handle(client, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    reply = {'type': 'error', 'message': 'binary messages are not understood; send JSON text'}
                else:
                    break
                if isinstance(reply, tuple):      # (message, Future): answered when the world is
                    task = asyncio.get_running_loop().create_task(self._answer(ws, *reply))
                    self._tasks.add(task)
                    task.add_done_callback(self._tasks.discard)
                elif reply is not None:
                    await ws.send_str(json.dumps(reply))
        except (ConnectionError, RuntimeError):
            pass            # the page went away, or the server is stopping
        finally:
            self.clients.pop(ws, None)
            self.watchers.pop(ws, None)
        return ws

    def _handle(self, client: Client, text):
        try:
            msg = parse_client_message(text, extra_types=tuple(self.extra_handlers))
        except ClientMessageError as exc:
            return {'type': 'error', 'message': str(exc)}
        except Exception as exc:     # whatever a message does, the page gets an answer
            self.log(f'console: message not understood: {exc!r}')
            return {'type': 'error', 'message': 'message not understood'}
        if msg['type'] == 'ping':
            return {'type': 'pong', 'ref': msg['ref'], 'time': time.time()}
        if msg['type'] == 'watch':
            client.watching = client.needs_full = True
            self.watchers[client.ws] = client
            self.notify('obstacles')
            return None
        if msg['type'] in self.extra_handlers:
            try:
                return self.extra_handlers[msg['type']](msg)
            except Exception as exc:   # keep serving whatever a handler does
                self.log(f'console: handler for {msg["type"]} failed: {exc!r}')
                return {'type': 'error', 'message': f'{msg["type"]} failed: {exc}'}
        try:
            result = self.intervene(msg['obstacle'])
        except Exception as exc:
            self.log(f'console: intervention on {msg["obstacle"]} failed: {exc!r}')
            result = {'ok': False, 'message': f'intervention failed: {exc}'}
        if isinstance(result, Future):
            return (msg, result)
        return {'type': 'intervention', 'obstacle': msg['obstacle'], 'ref': msg['ref'], **result}

    async def _answer(self, ws, msg, future):
        try:
            result = await asyncio.wait_for(asyncio.wrap_future(future), self.confirm_timeout)
        except asyncio.TimeoutError:
            result = self.unanswered(msg['obstacle'], future)
        try:
            await ws.send_str(json.dumps({'type': 'intervention', 'obstacle': msg['obstacle'],
                                          'ref': msg['ref'], **result}))
        except (ConnectionError, RuntimeError):
            pass

    async def _send_all(self, text: str):
        """A session message to every page (watching or not), with a bound on slow ones: a
        page that does not get it is closed (it reconnects, and its hello has the screen)."""
        for ws, client in list(self.clients.items()):
            if not client.backed_up():
                try:
                    await asyncio.wait_for(ws.send_str(text), timeout=2.0)
                    continue
                except Exception:     # closed or hopelessly slow page
                    pass
            self._drop(ws)

    def _drop(self, ws):
        """Forget a page that missed a message, and close its socket: left open, the page
        would wait, connected, for messages that never come."""
        client = self.clients.pop(ws, None)
        self.watchers.pop(ws, None)
        if not ws.closed:
            task = asyncio.get_running_loop().create_task(
                self._close_quietly(ws, client.transport if client is not None else None))
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    @staticmethod
    async def _close_quietly(ws, transport):
        try:
            await asyncio.wait_for(ws.close(code=WSCloseCode.TRY_AGAIN_LATER, message=b'missed a message'),
                                   CLOSE_TIMEOUT)
        except Exception:     # it does not answer the close: cut the connection
            if transport is not None:
                transport.abort()

    async def _broadcast(self, delta: dict, full_snapshot):
        texts = {}
        for ws, client in list(self.watchers.items()):
            if client.backed_up():      # not reading: skip it, it gets everything once it drains
                client.needs_full = True
                continue
            kind = 'full' if client.needs_full else 'delta'
            if kind not in texts:
                texts[kind] = json.dumps(full_snapshot() if kind == 'full' else delta, separators=(',', ':'))
            client.needs_full = False
            try:
                await ws.send_str(texts[kind])
            except Exception:
                self._drop(ws)

    async def _send_loop(self):
        last = 0.0
        loop = asyncio.get_running_loop()
        while True:
            await self._wake.wait()
            self._wake.clear()
            with self._pending_lock:
                urgent = self._urgent
            if not urgent:
                # batch: wait out the rest of the update interval (poses keep arriving)
                delay = last + self.min_interval - loop.time()
                if delay > 0:
                    try:
                        await asyncio.wait_for(self._wake.wait(), timeout=delay)
                        self._wake.clear()
                    except asyncio.TimeoutError:
                        pass
            with self._pending_lock:
                self._pending = False
                self._urgent = False
            versions = self.state.versions()
            watchers = list(self.watchers.values())
            if versions == self._sent_versions and not any(c.needs_full for c in watchers):
                continue
            sent = self._sent_versions or (-1,) * len(versions)
            delta = self.state.snapshot(with_obstacles=versions[1] != sent[1], with_stats=versions[2] != sent[2],
                                        with_events=versions[3] != sent[3])
            self._sent_versions = versions
            last = loop.time()
            if watchers:
                await self._broadcast(delta, self.state.snapshot)
                self.sent_updates += 1
