#!/usr/bin/env python3
"""The console's web server under connections that never finish their request (issue 29).

A ConsoleServer (the node's defaults: header_timeout 10 s, max_unfinished 64, or as given)
runs in a child process; this process opens ``--connections`` TCP connections to it on
loopback, each sending a request line and one header and then nothing. Printed: the
server's open file descriptors before, at the peak and after; how many connections the
server closed at once (over the cap) and after how long the rest were closed; whether a
whole request is served while they are held; and /proc/loadavg.

    .venv/bin/python bench/bench_console_limits.py [--connections 1000] [--header-timeout 10] [--cap 64]
"""
from __future__ import annotations

import argparse
import asyncio
import os
from pathlib import Path
import subprocess
import sys

ROOT = Path(__file__).resolve().parent.parent

SERVER = '''
import sys, time
from supersafe_ros.console.server import ConsoleServer
from supersafe_ros.console.state import ConsoleState, Field
kwargs = {} if sys.argv[1] == 'default' else dict(header_timeout=float(sys.argv[1]), max_unfinished=int(sys.argv[2]))
try:
    server = ConsoleServer(ConsoleState(['robot_0'], Field()), lambda oid: {'ok': False}, port=0,
                           log=lambda *a: None, **kwargs)
except TypeError:        # a server without these bounds (before issue 29)
    server = ConsoleServer(ConsoleState(['robot_0'], Field()), lambda oid: {'ok': False}, port=0,
                           log=lambda *a: None)
print(server.start(), flush=True)
sys.stdin.read()
server.stop()
'''


def load():
    with open('/proc/loadavg') as f:
        return ' '.join(f.read().split()[:3])


def fds(pid):
    return len(os.listdir(f'/proc/{pid}/fd'))


async def run(pid, port, n, limit_s):
    base = fds(pid)
    loop = asyncio.get_running_loop()

    async def closed(reader, opened):
        try:
            await asyncio.wait_for(reader.read(), limit_s)
        except ConnectionError:
            pass
        except asyncio.TimeoutError:
            return None
        return loop.time() - opened
    conns, waits = [], []
    for _ in range(n):
        reader, writer = await asyncio.open_connection('127.0.0.1', port)
        writer.write(b'GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ')
        conns.append(writer)
        waits.append(loop.create_task(closed(reader, loop.time())))
    await asyncio.sleep(0.5)
    peak = fds(pid)
    t0 = loop.time()
    reader, writer = await asyncio.open_connection('127.0.0.1', port)
    writer.write(f'GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n'.encode())
    try:
        status = (await asyncio.wait_for(reader.readline(), 5.0)).decode().strip() or 'closed'
        status += f' in {(loop.time() - t0) * 1e3:.0f} ms'
    except (asyncio.TimeoutError, ConnectionError) as exc:
        status = f'no answer ({type(exc).__name__})'
    writer.close()
    lived = await asyncio.gather(*waits)
    for w in conns:
        w.close()
    await asyncio.sleep(0.5)
    return base, peak, fds(pid), lived, status


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--connections', type=int, default=1000)
    ap.add_argument('--header-timeout', default='default', help='seconds, or "default" (the node\'s)')
    ap.add_argument('--cap', type=int, default=64)
    ap.add_argument('--limit', type=float, default=60.0, help='give up waiting for a close after this')
    args = ap.parse_args()
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    child = subprocess.Popen([sys.executable, '-c', SERVER, str(args.header_timeout), str(args.cap)],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env, cwd=str(ROOT))
    try:
        port = int(child.stdout.readline())
        base, peak, after, lived, status = asyncio.run(run(child.pid, port, args.connections, args.limit))
        times = sorted(t for t in lived if t is not None)
        quick = [t for t in times if t < 1.0]
        late = [t for t in times if t >= 1.0]
        print(f'{args.connections} unfinished requests (header_timeout {args.header_timeout}, cap {args.cap}): '
              f'server fds {base} -> {peak} at the peak -> {after} after; {len(quick)} closed within 1 s of '
              f'opening, {len(late)} later ({min(late, default=0):.1f} to {max(late, default=0):.1f} s after '
              f'opening), {len(lived) - len(times)} still open after {args.limit:g} s; a whole request '
              f'meanwhile: {status}; load {load()}', flush=True)
    finally:
        child.stdin.close()
        child.wait(timeout=10)


if __name__ == '__main__':
    main()
