"""The supervisor console in a real headless Chromium: click latency, page update rate,
and the console's CPU share.

Part 1, a real team (2 robots, 10 obstacles, no simulated supervisor, real time):
  * page updates per second (frames the page drew from server messages) and server
    messages per second, over --window wall seconds;
  * the console process's CPU share (user + system CPU / wall time, one core = 100%);
  * --clicks clicks on obstacles: click -> the world's /world/intervention_log record
    ("removed in the world", received here) and click -> the obstacle's element leaving
    the page (measured in the page). Median and p99.
  * the console's CPU with --idle (50) idle WebSockets open beside the page (connected,
    never asking for updates), and with as many watching sockets that read every update
    (for comparison); then --attempts (1000) connection attempts against the cap
    (max_connections 8 by default: the rest are refused).
Part 2, 50 robots: a feed in this process publishes 50 robots' poses at 20 Hz, ten
obstacle markers and stats (the console cannot tell it from a team); page updates per
second and the console's CPU.

    .venv/bin/python bench/bench_console.py [--window 10] [--clicks 20] [--robots-many 50]
                                            [--idle 50] [--attempts 1000] [--parts team,many]
"""
import argparse
import asyncio
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'test'))
from console_support import Browser, free_port, wait_for_server, wait_until  # noqa: E402

from supersafe_ros import team  # noqa: E402


def proc_cpu(pid) -> float:
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def page_counters(driver):
    return driver.execute_script('const p = window.supersafeConsole; return [p.messages, p.renders];')


def measure_rates(driver, pid, window):
    m0, r0 = page_counters(driver)
    c0, t0 = proc_cpu(pid), time.monotonic()
    time.sleep(window)
    m1, r1 = page_counters(driver)
    c1, t1 = proc_cpu(pid), time.monotonic()
    wall = t1 - t0
    return (r1 - r0) / wall, (m1 - m0) / wall, 100.0 * (c1 - c0) / wall


def pct(values):
    a = np.asarray(values, dtype=float)
    return f'median {np.median(a):.1f} ms  p99 {np.percentile(a, 99):.1f} ms  max {a.max():.1f} ms (n={len(a)})'


def part_team(args, env):
    port = free_port()
    argvs = team.team_processes(2, rate_factor=1.0, seed=5, step=0.05, with_learner=False,
                                with_supervisor=False, console_port=port,
                                overrides={'supervisor_console': {'max_connections': min(1000, args.idle + 8)}})
    running = team.Team(argvs, env, Path(tempfile.mkdtemp(prefix='bench-console-'))).start()
    monitor = browser = None
    try:
        names = [team.process_name(a) for a in argvs]
        pid = running.procs[names.index('supervisor_console')].pid
        monitor = team.TeamMonitor(env)
        received = {}
        lock = threading.Lock()
        from diagnostic_msgs.msg import DiagnosticStatus
        from supersafe_ros.ros_io import rosmsg

        def on_log(msg):
            t = time.time() * 1000.0
            with lock:
                received.setdefault(rosmsg.diagnostic_values(msg).get('obstacle'), t)
        monitor.node.create_subscription(DiagnosticStatus, '/world/intervention_log', on_log,
                                         rosmsg.QOS_LOG)
        wait_for_server(f'http://127.0.0.1:{port}/', timeout=120)
        browser = Browser()
        d = browser.driver
        d.get(f'http://127.0.0.1:{port}/')
        wait_until(lambda: d.execute_script(
            'return document.querySelectorAll("[data-robot][data-x]").length') == 2,
            120, 'two robots on the page')
        time.sleep(2.0)   # past the start
        renders, messages, cpu = measure_rates(d, pid, args.window)
        clock = monitor.snapshot()[1]
        print(f'2 robots / 10 obstacles (real team, real time): page updates {renders:.1f}/s '
              f'(server messages {messages:.1f}/s); console CPU {cpu:.1f}% of a core; the team ran at '
              f'{clock.get("rate_factor_achieved", "?")}x real time', flush=True)

        clicked = []
        for _ in range(args.clicks):
            oid = d.execute_script(
                'const e = document.querySelector("[data-obstacle-id]"); '
                'return e ? e.dataset.obstacleId : null;')
            d.find_element('css selector', f'[data-obstacle-id="{oid}"]').click()
            clicked.append(oid)
            wait_until(lambda: d.execute_script(f'return window.supersafeConsole.removals[{oid}] !== undefined'),
                       30, f'obstacle {oid} to leave the page')
            wait_until(lambda: oid in received, 30, f'the world to log obstacle {oid}')
            time.sleep(args.click_gap)
        clicks = d.execute_script('return window.supersafeConsole.clicks')
        removals = d.execute_script('return window.supersafeConsole.removals')
        world = [received[o] - clicks[o] for o in clicked]
        page = [removals[o] for o in clicked]
        print(f'click -> removed in the world: {pct(world)}')
        print(f'click -> removed on the page:  {pct(page)}', flush=True)
        connections(args, port, pid)
        return renders, cpu
    finally:
        if browser:
            browser.close()
        if monitor:
            monitor.close()
        running.stop()


def cpu_over(pid, window) -> float:
    c0, t0 = proc_cpu(pid), time.monotonic()
    time.sleep(window)
    return 100.0 * (proc_cpu(pid) - c0) / (time.monotonic() - t0)


def connections(args, port, pid):
    """The console's CPU with idle sockets, with reading watchers, and under a connection storm."""
    import aiohttp
    url = f'http://127.0.0.1:{port}/ws'
    result = {}

    async def hold(n, watch):
        async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0)) as session:
            sockets = [await session.ws_connect(url) for _ in range(n)]
            readers = []
            for ws in sockets:
                await ws.receive()                          # hello
                if watch:
                    await ws.send_str(json.dumps({'type': 'watch'}))

                    async def read(ws=ws):
                        async for _ in ws:
                            pass
                    readers.append(asyncio.ensure_future(read()))
            await asyncio.sleep(1.0)
            result['cpu'] = await asyncio.get_running_loop().run_in_executor(None, cpu_over, pid, args.window)
            for r in readers:
                r.cancel()
            for ws in sockets:
                await ws.close()

    base = cpu_over(pid, args.window)
    asyncio.run(hold(args.idle, watch=False))
    idle = result['cpu']
    asyncio.run(hold(args.idle, watch=True))
    watching = result['cpu']
    again = cpu_over(pid, args.window)       # the baseline once more: how much is noise
    print(f'console CPU, 2 robots and one page: {base:.1f}% (again after: {again:.1f}%); with {args.idle} idle '
          f'sockets as well: {idle:.1f}%; with {args.idle} sockets reading every update instead: {watching:.1f}% '
          'of a core', flush=True)
    return base, idle, watching


def storm(args):
    """--attempts WebSocket connections against a console with the default cap (no team)."""
    import aiohttp
    from supersafe_ros.console.server import ConsoleServer
    from supersafe_ros.console.state import ConsoleState
    server = ConsoleServer(ConsoleState(['robot_0']), lambda oid: {'ok': False}, port=free_port(),
                           log=lambda *a: None)
    server.start()

    async def attack():
        async with aiohttp.ClientSession() as session:
            held, refused = [], 0
            for _ in range(args.attempts):
                try:
                    held.append(await session.ws_connect(f'http://127.0.0.1:{server.port}/ws'))
                except aiohttp.WSServerHandshakeError:
                    refused += 1
            c0, t0 = time.process_time(), time.monotonic()
            await asyncio.sleep(args.window)
            cpu = 100.0 * (time.process_time() - c0) / (time.monotonic() - t0)
            for ws in held:
                await ws.close()
            return len(held), refused, cpu
    try:
        held, refused, cpu = asyncio.run(attack())
    finally:
        server.stop()
    print(f'{args.attempts} connection attempts against max_connections {server.max_connections}: {held} open, '
          f'{refused} refused (503); this process (client and server) then used {cpu:.1f}% of a core', flush=True)


class ManyRobotFeed:
    """50 robots circling at 20 Hz, ten obstacles and stats, from one node."""

    def __init__(self, env, robots, rate=20.0):
        from supersafe_ros.ros_io.background_node import BackgroundNode
        from geometry_msgs.msg import PoseStamped
        from visualization_msgs.msg import MarkerArray
        from diagnostic_msgs.msg import DiagnosticStatus
        from supersafe_ros.nodes.markers import obstacles_to_markers
        from supersafe_ros.ros_io import rosmsg
        self.rosmsg = rosmsg
        self.robots = robots
        self.ros = BackgroundNode('console_bench_feed', env['ROS_DOMAIN_ID'])
        node = self.ros.node
        self.pubs = [node.create_publisher(PoseStamped, f'/{r}/pose', rosmsg.QOS_STREAM) for r in robots]
        markers = node.create_publisher(MarkerArray, '/obstacle_markers', rosmsg.QOS_LATCHED)
        stats = node.create_publisher(DiagnosticStatus, '/world/stats', rosmsg.QOS_LATCHED)
        xy = np.array([(-10.0 + 2.5 * i, (-1) ** i * 4.0) for i in range(10)])
        markers.publish(obstacles_to_markers(np.arange(10), xy, 1.8))
        stats.publish(rosmsg.make_diagnostic('world', {'trips': 0, 'crashes': 0, 'interventions': 0,
                                                       'score': 0}))
        self.k = 0
        node.create_timer(1.0 / rate, self.tick)
        self.ros.start()

    def tick(self):
        self.k += 1
        stamp = self.ros.node.get_clock().now().to_msg()
        for i, pub in enumerate(self.pubs):
            a = 0.02 * self.k + 2 * math.pi * i / len(self.pubs)
            rad = 6.0 + 5.0 * (i % 3)
            pub.publish(self.rosmsg.state_to_pose((rad * math.cos(a), 0.8 * rad * math.sin(a),
                                                   a + math.pi / 2), stamp))

    def close(self):
        self.ros.close()


def part_many(args, env):
    port = free_port()
    robots = team.robot_names(args.robots_many)
    argv = team.node_argv('supervisor_console', params={'robots': robots, 'port': port,
                                                        'use_sim_time': False})
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    feed = browser = None
    try:
        feed = ManyRobotFeed(env, robots)
        wait_for_server(f'http://127.0.0.1:{port}/', timeout=120)
        browser = Browser()
        d = browser.driver
        d.get(f'http://127.0.0.1:{port}/')
        wait_until(lambda: d.execute_script(
            'return document.querySelectorAll("[data-robot][data-x]").length') == len(robots),
            120, f'{len(robots)} robots on the page')
        time.sleep(2.0)
        renders, messages, cpu = measure_rates(d, proc.pid, args.window)
        print(f'{len(robots)} robots / 10 obstacles (feed at 20 Hz per robot): page updates '
              f'{renders:.1f}/s (server messages {messages:.1f}/s); console CPU {cpu:.1f}% of a core',
              flush=True)
        return renders, cpu
    finally:
        if browser:
            browser.close()
        if feed:
            feed.close()
        proc.send_signal(2)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--window', type=float, default=10.0, help='wall seconds per rate measurement')
    ap.add_argument('--clicks', type=int, default=20)
    ap.add_argument('--click-gap', type=float, default=0.3, help='wall seconds between clicks')
    ap.add_argument('--robots-many', type=int, default=50)
    ap.add_argument('--idle', type=int, default=50, help='idle WebSockets beside the page (part team)')
    ap.add_argument('--attempts', type=int, default=1000, help='connection attempts against the cap')
    ap.add_argument('--parts', default='team,many,storm', help='comma-separated: team, many, storm')
    ap.add_argument('--domain-id', type=int, default=None)
    args = ap.parse_args()
    env = team.team_env(args.domain_id)
    os.environ['ROS_DOMAIN_ID'] = env['ROS_DOMAIN_ID']
    print(f'load before: {open("/proc/loadavg").read().strip()}  cores {os.cpu_count()}', flush=True)
    parts = args.parts.split(',')
    if 'team' in parts:
        part_team(args, env)
    if 'many' in parts:
        part_many(args, env)
    if 'storm' in parts:
        storm(args)
    print(f'load after: {open("/proc/loadavg").read().strip()}')


if __name__ == '__main__':
    main()
