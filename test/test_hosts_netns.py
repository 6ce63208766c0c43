"""The private host network of `supersafe team --hosts` (root only; CI runs as root).

Asserts what the namespaces look like, that nothing outside them changes, that every
namespace and link goes away on exit, on an exception, on SIGINT/SIGTERM of the CLI, and
that namespaces of a killed run are removed by the next one; and that without
CAP_NET_ADMIN the CLI says so and exits non-zero.
"""
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import time

import pytest

from supersafe_ros.hosts import netns
from supersafe_ros.hosts.netns import HostNetwork, our_namespaces

needs_root = pytest.mark.skipif(not netns.has_net_admin() or shutil.which('ip') is None,
                                reason='needs root (CAP_NET_ADMIN) and iproute2')
REPO = Path(__file__).resolve().parents[1]


def root_view():
    """Interfaces, addresses and routes of the test process's own namespace."""
    return [subprocess.run(['ip', '-o', *a], capture_output=True, text=True).stdout
            for a in (('link', 'show'), ('addr', 'show'), ('route', 'show'))]


@pytest.mark.root
@needs_root
def test_hosts_are_isolated_and_removed_on_exit():
    before = root_view()
    with HostNetwork(3) as net:
        assert sorted(our_namespaces(os.getpid())) == sorted(net.hosts + [net.bridge_ns])
        for i in range(3):
            assert net.interfaces(i) == ['lo', 'eth0']
            routes = subprocess.run(net.exec_prefix(i) + ['ip', 'route', 'show'],
                                    capture_output=True, text=True).stdout
            # on-link /24 and multicast only: no default route, nothing else reachable
            assert 'default' not in routes
            assert sorted(r.split()[0] for r in routes.splitlines()) == ['10.213.0.0/24', '224.0.0.0/4']
            addrs = subprocess.run(net.exec_prefix(i) + ['ip', '-o', '-4', 'addr', 'show'],
                                   capture_output=True, text=True).stdout
            assert f'inet {net.address(i)}/24' in addrs and 'inet 127.0.0.1/8' in addrs
        # the caller's namespace gained nothing
        assert root_view() == before
        # the thread can visit a host and come back
        with net.entered(1):
            assert netns.current_namespace_is(net.hosts[1])
        assert not netns.current_namespace_is(net.hosts[1])
        # a link fault and its repair
        with net.link_down(2):
            assert not net.link_is_up(2)
        assert net.link_is_up(2)
    assert our_namespaces(os.getpid()) == []
    assert root_view() == before


@pytest.mark.root
@needs_root
def test_hosts_removed_after_an_exception_inside():
    with pytest.raises(RuntimeError):
        with HostNetwork(2) as net:
            sleeper = subprocess.Popen(net.exec_prefix(1) + ['sleep', '60'])
            raise RuntimeError('boom')
    # the process inside was stopped and the namespaces are gone
    assert sleeper.wait(timeout=10) != 0
    assert our_namespaces(os.getpid()) == []


LATE_ENTRANT = r"""
import os, sys, time
from supersafe_ros.hosts.netns import _setns
path = sys.argv[1]
fd = os.open(path, os.O_RDONLY)          # as `ip netns exec` does, before it enters
print('ready', flush=True)
while os.path.exists(path):
    time.sleep(0.005)
_setns(fd)                               # enter the deleted namespace
print('entered', flush=True)
time.sleep(60)
"""


@pytest.mark.root
@needs_root
def test_a_process_entering_while_its_host_is_removed_is_killed_too():
    """`ip netns exec` opens the namespace, then enters it: a process started just before
    the network closes can enter after its pids were listed (in CI a sleeper outlived the
    test above so). The close kills such late entrants too."""
    net = HostNetwork(1).create()
    try:
        late = subprocess.Popen([sys.executable, '-c', LATE_ENTRANT, str(netns.NETNS_DIR / net.hosts[0])],
                                stdout=subprocess.PIPE, text=True)
        assert late.stdout.readline().strip() == 'ready'
    finally:
        net.close()
    try:
        assert late.wait(timeout=10) == -signal.SIGKILL
    finally:
        if late.poll() is None:
            late.kill()
    assert our_namespaces(os.getpid()) == []


@pytest.mark.root
@needs_root
def test_stale_namespaces_of_dead_runs_are_removed():
    dead = subprocess.Popen(['true'])
    dead.wait()                        # a pid that no longer runs
    leftover = HostNetwork(2, pid=dead.pid)
    leftover.create()                  # as if its run had been killed with SIGKILL
    assert len(our_namespaces(dead.pid)) == 3
    sleeper = subprocess.Popen(['sleep', '60'])
    live = HostNetwork(2, pid=sleeper.pid)   # a run whose process is alive
    try:
        live.create()                  # the next run removes the dead run's namespaces
        assert our_namespaces(dead.pid) == []
        assert set(leftover.hosts + [leftover.bridge_ns]) == set(live.stale_removed)
        with HostNetwork(2):           # and leaves a live run's alone
            assert len(our_namespaces(sleeper.pid)) == 3
    finally:
        live.close()
        leftover.close()
        sleeper.kill()
        sleeper.wait()
    assert our_namespaces(sleeper.pid) == []


def cli(*args):
    return [sys.executable, '-m', 'supersafe_ros.cli', 'team', *args]


@pytest.mark.root
@pytest.mark.ros
@needs_root
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_cli_removes_its_namespaces_on_a_signal(tmp_path, sig):
    # no robots' processes needed to see the plumbing: a team whose nodes start slowly
    # is interrupted as soon as its namespaces exist
    proc = subprocess.Popen(cli('--hosts', '3', '--robots', '2', '--duration', '600',
                                '--log-dir', str(tmp_path)),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    deadline = time.monotonic() + 60
    while len(our_namespaces(proc.pid)) < 4 and time.monotonic() < deadline:
        assert proc.poll() is None, proc.stdout.read()
        time.sleep(0.1)
    assert len(our_namespaces(proc.pid)) == 4
    while not (tmp_path / 'pids.txt').exists() and time.monotonic() < deadline:
        time.sleep(0.1)                # the nodes are started
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=60)
    assert our_namespaces(proc.pid) == [], out
    pids = [int(line.split()[0]) for line in (tmp_path / 'pids.txt').read_text().splitlines()]
    alive = [p for p in pids if Path(f'/proc/{p}').exists()
             and 'supersafe_ros' in Path(f'/proc/{p}/cmdline').read_text(errors='replace')]
    assert alive == [], out


def test_print_argv_places_shared_nodes_on_host_zero_and_deals_robots():
    out = subprocess.run(cli('--hosts', '3', '--robots', '4', '--print-argv', '--discovery-server'),
                         capture_output=True, text=True, check=True).stdout
    placed = {}
    for line in out.splitlines():
        if line.startswith('host '):
            host = int(line.split()[1])
            name = line.split('] ', 1)[1].split(':', 1)[0]
            placed[name] = host
            assert ' ip netns exec supersafe-' in line
            if name != 'discovery_server':
                assert 'ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET' in line
                assert 'ROS_DISCOVERY_SERVER=10.213.0.1:11811' in line
                assert ('ROS_SUPER_CLIENT=TRUE' in line) == (name == 'sim_clock')
            if name.endswith('/safety_filter'):
                # a robot host's filter counts a still /clock as a lost link after 1 s
                stall = [a for a in line.split() if a.startswith('clock_stall_timeout:=')]
                assert stall == ['clock_stall_timeout:=1.0'], line
    for shared in ('world', 'learner', 'supervisor', 'sim_clock', 'discovery_server'):
        assert placed[shared] == 0
    for i in range(4):
        for kind in ('dubins_robot', 'planner', 'safety_filter'):
            assert placed[f'robot_{i}/{kind}'] == 1 + i % 2


NOBODY = ['setpriv', '--reuid=65534', '--regid=65534', '--clear-groups', '--inh-caps=-all', '--bounding-set=-all']


@pytest.fixture
def readable_package():
    """This checkout's package and config, copied to a folder every user can read: the clone
    may sit in a folder uid 65534 cannot enter (a 0700 temp folder), where it found no
    supersafe_ros (or, through an editable install, another checkout's)."""
    import stat
    import tempfile
    base = '/tmp' if os.path.isdir('/tmp') and os.stat('/tmp').st_mode & stat.S_ISVTX else None
    root = Path(tempfile.mkdtemp(prefix='supersafe-nobody-', dir=base))
    try:
        ignore = shutil.ignore_patterns('__pycache__', '*.pyc')
        for name in ('supersafe_ros', 'config'):
            shutil.copytree(REPO / name, root / name, ignore=ignore)
        for folder in [root, *(p for p in root.rglob('*') if p.is_dir())]:
            folder.chmod(0o755)
        for f in root.rglob('*'):
            if f.is_file():
                f.chmod(0o644)
        yield root
    finally:
        shutil.rmtree(root, ignore_errors=True)


@pytest.mark.root
@pytest.mark.skipif(shutil.which('setpriv') is None, reason='needs setpriv (util-linux)')
def test_without_net_admin_it_says_so_and_exits_nonzero(tmp_path, readable_package):
    # drop CAP_NET_ADMIN (and run as nobody when root): the plumbing must refuse clearly
    env = {**os.environ, 'HOME': str(readable_package), 'PYTHONPATH': str(readable_package)}
    reach = subprocess.run([*NOBODY, sys.executable, '-c', 'import numpy, yaml'], capture_output=True,
                           text=True, timeout=120, env=env, cwd=readable_package)
    if reach.returncode != 0:
        pytest.skip(f'uid 65534 cannot run this interpreter and its packages ({sys.executable}): '
                    f'{reach.stderr.strip()[-200:]}')
    proc = subprocess.run([*NOBODY, *cli('--hosts', '2', '--duration', '1', '--log-dir',
                                         str(readable_package / 'logs'))],
                          capture_output=True, text=True, timeout=120, env=env, cwd=readable_package)
    assert proc.returncode != 0
    assert 'CAP_NET_ADMIN' in proc.stderr and 'root' in proc.stderr, proc.stderr
    assert 'Traceback' not in proc.stderr


@pytest.mark.root
@needs_root
def test_subnet_discovery_is_kept_only_inside_the_named_namespace():
    from supersafe_ros.rosenv import ensure_local_ros_env
    with HostNetwork(2) as net:
        def ranged(name):
            return ensure_local_ros_env({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
                                         'SUPERSAFE_NETNS': name})['ROS_AUTOMATIC_DISCOVERY_RANGE']
        assert ranged(net.hosts[1]) == 'LOCALHOST'          # named, but this thread is not in it
        with net.entered(1):
            assert ranged(net.hosts[1]) == 'SUBNET'
            assert ranged(net.hosts[0]) == 'LOCALHOST'      # another host's name
            assert ranged('') == 'LOCALHOST'
        assert ranged(net.hosts[1]) == 'LOCALHOST'
