"""The console's web server: aiohttp (HTTP and WebSocket in one asyncio library).

It runs its own asyncio loop on a thread of its own; the ROS side never blocks it.
Hand-off between the two threads:
  ROS -> web: callbacks write into ``ConsoleState`` (one lock) and call ``notify``,
              which wakes the loop with ``call_soon_threadsafe`` at most once per
              pending batch (a flag, not one wake-up per pose).
  web -> ROS: a click calls ``intervene(obstacle_id)`` (publishing from this thread is
              thread-safe in rclpy), which returns at once.
Updates are batched: at most ``update_rate`` state messages per second, each with every
robot's newest pose; a change of the obstacles goes out at once (a click's result).

Access: bound to a loopback address, no token is needed. Bound to any other address,
every request (page, static files, WebSocket) must carry the token (``?token=``, the
cookie the page sets, or ``Authorization: Bearer``), else 403. A WebSocket whose Origin
is another site is refused too, so a web page elsewhere cannot drive the console.
"""
from __future__ import annotations

import asyncio
import hmac
import ipaddress
import json
from pathlib import Path
import secrets
import threading
import time
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web

from .state import ClientMessageError, ConsoleState, parse_client_message

TOKEN_COOKIE = 'supersafe_console_token'


def is_loopback(host: str) -> bool:
    if host == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


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


class ConsoleServer:
    """Serves the page and one WebSocket per open page.

    ``intervene(obstacle_id) -> dict`` is called for a click; its dict ({'ok': bool,
    'message': str, ...}) is sent back to that page. ``extra_handlers``: {type: fn(msg)
    -> dict} for other page messages (the participant session uses this)."""

    def __init__(self, state: ConsoleState, intervene, host: str = '127.0.0.1', port: int = 8765,
                 token: str = '', update_rate: float = 30.0, log=print, extra_handlers=None,
                 static: Path | None = None, page_config: dict | None = None):
        if not (update_rate > 0):
            raise ValueError('update_rate must be positive')
        self.state = state
        self.intervene = intervene
        self.host = host
        self.port = int(port)
        self.loopback = is_loopback(host)
        # a non-loopback bind always needs a token: make one if none was given
        self.token = token or ('' if self.loopback else new_token())
        self.min_interval = 1.0 / float(update_rate)
        self.log = log
        self.extra_handlers = dict(extra_handlers or {})
        self.static = Path(static or static_dir())
        self.page_config = dict(page_config or {})
        self.index_page = 'index.html'      # the participant session serves session.html
        self.files_dir = None               # /files/<name> serves from here when set (figures)
        self.hello_extra = None             # fn() -> dict merged into each page's hello
        self.clients: set = set()
        self.sent_updates = 0
        self._loop = None
        self._thread = None
        self._runner = None
        self._ready = threading.Event()
        self._error = None
        self._wake = None
        self._urgent = False
        self._pending = False
        self._pending_lock = threading.Lock()
        self._sent_versions = (-1, -1, -1)
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
                asyncio.run_coroutine_threadsafe(self._broadcast(json.dumps(message)), loop)
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

    def stop(self) -> None:
        loop = self._loop
        if loop is None:
            return
        fut = asyncio.run_coroutine_threadsafe(self._shutdown(), loop)
        try:
            fut.result(timeout=5.0)
        except Exception:
            pass
        loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(timeout=5.0)

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
        self._ready.set()
        self._sender = loop.create_task(self._send_loop())
        try:
            loop.run_forever()
        finally:
            self._loop = None
            loop.close()

    async def _serve(self):
        app = web.Application(middlewares=[self._auth])
        app.router.add_get('/', self._index)
        app.router.add_get('/ws', self._ws)
        app.router.add_get('/files/{name}', self._file)
        app.router.add_static('/static/', self.static, follow_symlinks=False)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.host, self.port)
        await site.start()
        self.port = site._server.sockets[0].getsockname()[1]

    async def _shutdown(self):
        for ws in list(self.clients):
            await ws.close()
        if self._runner is not None:
            await self._runner.cleanup()

    # ----- HTTP -----------------------------------------------------------------------------
    def _token_ok(self, request) -> bool:
        if not self.token:
            return True
        auth = request.headers.get('Authorization', '')
        given = (request.query.get('token') or request.cookies.get(TOKEN_COOKIE)
                 or (auth[7:] if auth.startswith('Bearer ') else ''))
        return hmac.compare_digest(given.encode(), self.token.encode())

    @web.middleware
    async def _auth(self, request, handler):
        if not self._token_ok(request):
            return web.Response(status=403, text='403: this console needs its token (?token=...)\n')
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

    def _origin_ok(self, request) -> bool:
        origin = request.headers.get('Origin')
        if not origin:
            return True            # not a browser page (scripts, tests)
        return urlsplit(origin).netloc == request.host

    # ----- WebSocket ------------------------------------------------------------------------
    def hello(self) -> dict:
        snap = self.state.snapshot()
        out = {'type': 'hello', 'field': self.state.field.as_dict(),
               'robots': self.state.robots, 'config': self.page_config, 'state': snap}
        if self.hello_extra is not None:
            out.update(self.hello_extra())
        return out

    async def _ws(self, request):
        if not self._origin_ok(request):
            return web.Response(status=403, text='403: cross-origin WebSocket refused\n')
        ws = web.WebSocketResponse(heartbeat=20.0, max_msg_size=64 * 1024)
        await ws.prepare(request)
        await ws.send_str(json.dumps(self.hello()))
        self.clients.add(ws)
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    reply = self._handle(msg.data)
                elif msg.type == WSMsgType.BINARY:
                    reply = {'type': 'error', 'message': 'binary messages are not understood; send JSON text'}
                else:
                    break
                if reply is not None:
                    await ws.send_str(json.dumps(reply))
        finally:
            self.clients.discard(ws)
        return ws

    def _handle(self, text) -> dict | None:
        try:
            msg = parse_client_message(text, extra_types=tuple(self.extra_handlers))
        except ClientMessageError as exc:
            return {'type': 'error', 'message': str(exc)}
        if msg['type'] == 'ping':
            return {'type': 'pong', 'ref': msg['ref'], 'time': time.time()}
        if msg['type'] in self.extra_handlers:
            try:
                out = self.extra_handlers[msg['type']](msg)
            except Exception as exc:   # keep serving whatever a handler does
                self.log(f'console: handler for {msg["type"]} failed: {exc!r}')
                return {'type': 'error', 'message': f'{msg["type"]} failed: {exc}'}
            return out
        try:
            result = self.intervene(msg['obstacle'])
        except Exception as exc:
            self.log(f'console: intervention on {msg["obstacle"]} failed: {exc!r}')
            result = {'ok': False, 'message': f'intervention failed: {exc}'}
        return {'type': 'intervention', 'obstacle': msg['obstacle'], 'ref': msg['ref'], **result}

    async def _broadcast(self, text: str):
        dead = []
        for ws in list(self.clients):
            try:
                await asyncio.wait_for(ws.send_str(text), timeout=2.0)
            except Exception:     # closed or hopelessly slow page: drop it
                dead.append(ws)
        for ws in dead:
            self.clients.discard(ws)

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
            if versions == self._sent_versions:
                continue
            snap = self.state.snapshot(with_obstacles=versions[1] != self._sent_versions[1],
                                       with_stats=versions[2] != self._sent_versions[2])
            self._sent_versions = versions
            last = loop.time()
            if self.clients:
                await self._broadcast(json.dumps(snap, separators=(',', ':')))
                self.sent_updates += 1
