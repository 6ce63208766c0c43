"""A team on K hosts, driven from Python: for the tests and bench/bench_hosts.py (test-only,
so here and not in the package; the benches take support modules from test/ as bench_console does).

``HostsTeam(argvs, n_hosts)`` places ``team_processes(...)`` over a HostNetwork (or,
with ``n_hosts=1``, runs them on loopback as `supersafe team` does), starts the
discovery server if asked, the processes, and a watcher process (hosts.probe) on host 0
for the world's stats, events and interventions, the clock and the graph; more
watchers can be started on any host.
Everything stops and every namespace goes away on ``close()``/``__exit__``.
"""
from __future__ import annotations

import contextlib
from pathlib import Path
import json
import signal
import subprocess
import sys
import threading
import time

from supersafe_ros.hosts.netns import HostNetwork
from supersafe_ros.hosts.placement import (discovery_server, discovery_server_argv, env_argv, host_ros_env,
                                           place)
from supersafe_ros.team import Team, _die_with_parent, process_name, team_env


class Probe:
    """A running hosts.probe process and what it has printed so far."""

    def __init__(self, argv: list[str], env: dict, log_path: Path):
        self.records: list[dict] = []
        self.lock = threading.Lock()
        self.stderr = open(log_path, 'w')
        self.proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=self.stderr,
                                     text=True, start_new_session=True,
                                     preexec_fn=_die_with_parent)
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        for line in self.proc.stdout:
            try:
                record = json.loads(line)
            except ValueError:
                continue
            with self.lock:
                self.records.append(record)

    def of(self, topic: str) -> list[dict]:
        with self.lock:
            return [r for r in self.records if r.get('topic') == topic]

    def latest(self, topic: str) -> dict:
        found = self.of(topic)
        return found[-1].get('values', found[-1]) if found else {}

    def graphs(self) -> list[dict]:
        with self.lock:
            return [r for r in self.records if 'graph' in r]

    def close(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.thread.join(timeout=5)
        self.stderr.close()


MONITOR_WATCHES = ['/world/stats=diag:latched', '/sim/clock_status=diag:latched',
                   '/world/events=diag:log', '/world/intervention_log=diag:log']


class HostsTeam:
    def __init__(self, argvs: list[list[str]], n_hosts: int, log_dir, domain_id: int | None = None,
                 discovery_server: bool = False):
        self.n_hosts = int(n_hosts)
        self.ds = bool(discovery_server)
        self.log_dir = Path(log_dir)
        self.net = HostNetwork(self.n_hosts) if self.n_hosts > 1 else None
        self.env = team_env(domain_id)
        self.domain_id = int(self.env['ROS_DOMAIN_ID'])
        if self.net:
            self.placed = place(argvs, self.net, self.ds)
        else:
            self.placed = [(0, list(a)) for a in argvs]
        self.names = [process_name(a) for _, a in self.placed]
        self.hosts = {name: h for name, (h, _) in zip(self.names, self.placed)}
        self.team: Team | None = None
        self.monitor: Probe | None = None
        self.probes: list[Probe] = []
        self._stack = contextlib.ExitStack()
        self.t_start = None

    # -- life cycle --------------------------------------------------------------
    def __enter__(self):
        try:
            return self.start()
        except BaseException:
            self.close()
            raise

    def __exit__(self, *exc):
        self.close()

    def start(self) -> 'HostsTeam':
        self.log_dir.mkdir(parents=True, exist_ok=True)
        if self.net:
            self._stack.enter_context(self.net)
            if self.ds:
                self._stack.enter_context(discovery_server(discovery_server_argv(self.net),
                                                           self.log_dir))
        self.t_start = time.monotonic()
        self.team = Team([a for _, a in self.placed], self.env, self.log_dir).start()
        self._stack.callback(self.team.stop)
        self.monitor = self.watch(0, MONITOR_WATCHES, graph=0.25)
        return self

    def close(self):
        for probe in self.probes:
            probe.close()
        self.probes.clear()
        self._stack.close()

    def watch(self, host: int, watches: list[str], graph: float = 0.0) -> Probe:
        """A hosts.probe process on ``host``: TOPIC=diag|pose[:QOS] watches, graph counts
        every ``graph`` seconds. On host 0 with a discovery server it is a super client
        (it sees every endpoint, as the sim clock must)."""
        argv = [sys.executable, '-m', 'supersafe_ros.hosts.probe',
                *(['--graph', str(graph)] if graph > 0 else []), *watches]
        if self.net:
            env = host_ros_env(self.net, host, self.ds, super_client=(host == 0))
            argv = self.net.exec_prefix(host) + env_argv(env) + argv
        probe = Probe(argv, self.env, self.log_dir / f'probe_h{host}_{len(self.probes)}.log')
        self.probes.append(probe)
        return probe

    # -- observation ---------------------------------------------------------------
    def sim_time(self) -> float:
        return float(self.monitor.latest('/sim/clock_status').get('sim_time', 0.0))

    def stats(self) -> dict:
        return self.monitor.latest('/world/stats')

    def interventions(self) -> list[dict]:
        return [r['values'] for r in self.monitor.of('/world/intervention_log')]

    def events(self) -> list[dict]:
        return [{'event': r['name'], **r['values']} for r in self.monitor.of('/world/events')]

    def graph_complete_at(self, expected: dict) -> float | None:
        """Seconds from the start until the host-0 watcher first saw every topic of
        ``expected`` with at least its counts (None: not yet)."""
        for r in self.monitor.graphs():
            if not missing_from(expected, r['graph']):
                return r['t'] - self.t_start
        return None

    def wait(self, predicate, timeout: float, what: str, poll: float = 0.1):
        deadline = time.monotonic() + timeout
        while not predicate():
            dead = self.team.dead() + (['probe'] if self.monitor.proc.poll() is not None else [])
            if dead:
                raise RuntimeError(f'processes exited while waiting for {what}: {dead} '
                                   f'(logs in {self.log_dir})')
            if time.monotonic() > deadline:
                raise TimeoutError(f'no {what} within {timeout} s (logs in {self.log_dir})')
            time.sleep(poll)

    def wait_sim(self, t: float, timeout: float):
        """Until the clock and the world's counts both reached sim time ``t``."""
        self.wait(lambda: self.sim_time() >= t - 1e-6
                  and float(self.stats().get('sim_time', 0.0)) >= t - 1e-6, timeout, f'sim time {t}')

    def proc(self, name: str) -> subprocess.Popen:
        return self.team.procs[self.names.index(name)]

    def kill9(self, name: str) -> int:
        p = self.proc(name)
        p.send_signal(signal.SIGKILL)
        return p.wait(timeout=30)

    def restart(self, name: str) -> subprocess.Popen:
        """Start process ``name`` again (same host, argv, environment and log, appended)."""
        i = self.names.index(name)
        argv = self.placed[i][1]
        log = open(self.log_dir / (name.replace('/', '.') + '.log'), 'a')
        self.team.logs.append(log)
        p = subprocess.Popen(argv, env=self.env, stdout=log, stderr=subprocess.STDOUT,
                             start_new_session=True, preexec_fn=_die_with_parent)
        self.team.procs[i] = p
        return p


def missing_from(expected: dict, seen: dict) -> dict:
    """Topics of ``expected`` whose counts ``seen`` does not reach yet."""
    return {t: (seen.get(t, (0, 0)), c) for t, c in expected.items()
            if seen.get(t, (0, 0))[0] < c[0] or seen.get(t, (0, 0))[1] < c[1]}


def team_graph(graph: dict) -> dict:
    """The team's own topics of a graph count (the watchers' and monitors' left out)."""
    return {t: tuple(c) for t, c in graph.items() if not t.startswith('/hosts_probe')}
