"""Private test networks of Linux network namespaces: one namespace per "host".

ROS-free plumbing for `supersafe team --hosts K`. ``HostNetwork(k)`` is a context
manager that makes

* one bridge namespace ``<prefix>-<pid>-br`` holding a Linux bridge ``br0``;
* ``k`` host namespaces ``<prefix>-<pid>-h<i>``, each with loopback up and one veth
  ``eth0`` (address 10.213.0.<i+1>/24) whose peer ``h<i>`` is a port of the bridge.

Every link is created inside those namespaces, never in the caller's: the caller's
namespace gains no interface, address or route. The host namespaces have no default
route and no NAT, only the on-link /24 and a multicast route on ``eth0`` (DDS
discovery multicasts), so their traffic cannot reach any other address. Deleting the
namespaces deletes their links. On entry, namespaces left behind by runs whose process
is gone (SIGKILL) are removed; on exit (normal, exception, Ctrl-C) every namespace this
run made is removed after the processes still inside it are killed.

Needs CAP_NET_ADMIN (root): ``require_net_admin()`` raises ``NetworkPermissionError``
with a message saying so.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
from pathlib import Path
import re
import shutil
import signal
import subprocess
import time

PREFIX = 'supersafe'
SUBNET = '10.213.0'            # /24, private (RFC 1918), only ever inside our namespaces
PREFIX_LEN = 24
HOST_IF = 'eth0'
BRIDGE_IF = 'br0'
NETNS_DIR = Path('/run/netns')
CAP_NET_ADMIN = 12
CLONE_NEWNET = 0x40000000
_NAME_RE = re.compile(rf'^{PREFIX}-(\d+)-(br|h\d+)$')


class NetworkError(RuntimeError):
    """A namespace or link operation failed (the message holds the command and its error)."""


class NetworkPermissionError(NetworkError):
    """The process may not create network namespaces (no root / CAP_NET_ADMIN)."""


def has_net_admin() -> bool:
    """True if this process holds CAP_NET_ADMIN in its effective set (Linux /proc)."""
    try:
        for line in Path('/proc/self/status').read_text().splitlines():
            if line.startswith('CapEff:'):
                return bool(int(line.split()[1], 16) >> CAP_NET_ADMIN & 1)
    except OSError:
        pass
    return False


def require_net_admin() -> None:
    """Raise NetworkPermissionError unless namespaces can be made here (root, `ip`)."""
    if not has_net_admin():
        raise NetworkPermissionError(
            'supersafe --hosts creates network namespaces and veth links, which needs root '
            '(CAP_NET_ADMIN); run it as root, e.g. sudo -E .venv/bin/supersafe team --hosts 3')
    if shutil.which('ip') is None:
        raise NetworkError("supersafe --hosts needs the 'ip' tool (Debian: apt-get install iproute2)")


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    proc = subprocess.run(['ip', *args], capture_output=True, text=True)
    if check and proc.returncode != 0:
        raise NetworkError(f"ip {' '.join(args)}: {proc.stderr.strip() or proc.returncode}")
    return proc


def list_namespaces() -> list[str]:
    """Names of every named network namespace (`ip netns list`)."""
    out = _ip('netns', 'list', check=False).stdout
    return [line.split()[0] for line in out.splitlines() if line.strip()]


def our_namespaces(pid: int | None = None) -> list[str]:
    """Namespaces made by this module (by any run, or by the run of ``pid``)."""
    names = []
    for name in list_namespaces():
        m = _NAME_RE.match(name)
        if m and (pid is None or int(m.group(1)) == pid):
            names.append(name)
    return names


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def namespace_pids(name: str) -> list[int]:
    """Processes living in a namespace (`ip netns pids`)."""
    out = _ip('netns', 'pids', name, check=False).stdout
    return [int(p) for p in out.split() if p.isdigit()]


def _pids_in_netns(ident: tuple) -> list[int]:
    """Processes whose network namespace is the one with this (device, inode) (what `ip
    netns pids` compares, without the namespace's name, which is gone after a delete)."""
    pids = []
    for entry in os.listdir('/proc'):
        if entry.isdigit():
            try:
                st = os.stat(f'/proc/{entry}/ns/net')
                if (st.st_dev, st.st_ino) == ident:
                    pids.append(int(entry))
            except OSError:
                pass
    return pids


def _signal_all(pids, sig) -> None:
    for pid in pids:
        if pid != os.getpid():
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass


def delete_namespace(name: str, grace: float = 2.0, settle: float = 0.5) -> None:
    """Kill what still runs inside ``name`` (SIGTERM, then SIGKILL), then delete it.

    A namespace stays alive while a process is in it, and its veth with it. A process
    started with ``ip netns exec`` just before may not have entered yet when the pids are
    listed (it holds the namespace's file open and enters after): for ``settle`` seconds
    after the delete, late entrants are found by the namespace's identity and killed.
    Processes are listed by that identity throughout (as `ip netns pids` does, without a
    process per poll); by name only if the namespace's file cannot be read."""
    try:
        st = (NETNS_DIR / name).stat()
        ident = (st.st_dev, st.st_ino)
    except OSError:
        ident = None
    inside = (lambda: _pids_in_netns(ident)) if ident is not None else (lambda: namespace_pids(name))
    pids = inside()
    for sig in (signal.SIGTERM, signal.SIGKILL):
        _signal_all(pids, sig)
        deadline = time.monotonic() + grace
        while pids and time.monotonic() < deadline:
            still = set(inside())
            pids = [p for p in pids if _pid_alive(p) and p in still]
            if pids:
                time.sleep(0.05)
        if not pids:
            break
    _ip('netns', 'delete', name, check=False)
    if ident is None:
        return
    deadline = time.monotonic() + settle
    while True:
        _signal_all(_pids_in_netns(ident), signal.SIGKILL)
        if time.monotonic() >= deadline:
            break
        time.sleep(0.05)


def remove_stale(alive=_pid_alive) -> list[str]:
    """Delete namespaces of earlier runs whose process no longer exists; returns their names."""
    removed = []
    for name in our_namespaces():
        pid = int(_NAME_RE.match(name).group(1))
        if pid != os.getpid() and not alive(pid):
            delete_namespace(name)
            removed.append(name)
    return removed


def _libc():
    return ctypes.CDLL('libc.so.6', use_errno=True)


def _setns(fd: int) -> None:
    if _libc().setns(fd, CLONE_NEWNET) != 0:
        err = ctypes.get_errno()
        raise NetworkError(f'setns: {os.strerror(err)}')


class HostNetwork:
    """``k`` host namespaces on one private bridge; see the module docstring."""

    def __init__(self, n_hosts: int, pid: int | None = None):
        if n_hosts < 1:
            raise ValueError('a host network needs at least one host')
        if n_hosts > 250:
            raise ValueError('at most 250 hosts fit the /24 test subnet')
        self.n_hosts = int(n_hosts)
        self.pid = os.getpid() if pid is None else int(pid)
        self.bridge_ns = f'{PREFIX}-{self.pid}-br'
        self.hosts = [f'{PREFIX}-{self.pid}-h{i}' for i in range(self.n_hosts)]
        self.created: list[str] = []
        self.stale_removed: list[str] = []

    @staticmethod
    def address(host: int) -> str:
        """The IPv4 address of host ``host`` on the test subnet."""
        return f'{SUBNET}.{host + 1}'

    def exec_prefix(self, host: int) -> list[str]:
        """argv prefix that runs a command inside host ``host``'s namespace."""
        return ['ip', 'netns', 'exec', self.hosts[host]]

    # -- life cycle ------------------------------------------------------------
    def create(self) -> 'HostNetwork':
        require_net_admin()
        self.stale_removed = remove_stale()
        try:
            self._add_ns(self.bridge_ns)
            br = ('-n', self.bridge_ns)
            _ip(*br, 'link', 'add', BRIDGE_IF, 'type', 'bridge')
            # no IGMP snooping: the bridge floods DDS multicast to every port
            _ip(*br, 'link', 'set', BRIDGE_IF, 'type', 'bridge', 'mcast_snooping', '0')
            _ip(*br, 'link', 'set', BRIDGE_IF, 'up')
            for i, name in enumerate(self.hosts):
                self._add_ns(name)
                host = ('-n', name)
                _ip(*host, 'link', 'set', 'lo', 'up')
                # both ends made inside our namespaces: the caller's namespace never sees them
                _ip(*br, 'link', 'add', f'h{i}', 'type', 'veth', 'peer', 'name', HOST_IF,
                    'netns', name)
                _ip(*br, 'link', 'set', f'h{i}', 'master', BRIDGE_IF)
                _ip(*br, 'link', 'set', f'h{i}', 'up')
                _ip(*host, 'addr', 'add', f'{self.address(i)}/{PREFIX_LEN}', 'dev', HOST_IF)
                _ip(*host, 'link', 'set', HOST_IF, 'up')
                # multicast (DDS discovery) leaves through the test link only
                _ip(*host, 'route', 'add', '224.0.0.0/4', 'dev', HOST_IF)
        except BaseException:
            self.close()
            raise
        return self

    def _add_ns(self, name: str) -> None:
        _ip('netns', 'add', name)
        self.created.append(name)

    def close(self) -> None:
        """Delete every namespace this run made (hosts first, then the bridge)."""
        for name in reversed(self.created):
            delete_namespace(name)
        self.created = [n for n in self.created if n in list_namespaces()]

    def __enter__(self) -> 'HostNetwork':
        return self.create()

    def __exit__(self, *exc) -> None:
        self.close()

    # -- link faults -------------------------------------------------------------
    def set_link(self, host: int, up: bool) -> None:
        """Bring host ``host``'s only link (eth0) down or up, as a pulled cable would."""
        _ip('-n', self.hosts[host], 'link', 'set', HOST_IF, 'up' if up else 'down')

    def link_is_up(self, host: int) -> bool:
        out = _ip('-n', self.hosts[host], '-o', 'link', 'show', HOST_IF).stdout
        return 'state UP' in out or ',UP' in out.split('>')[0]

    @contextlib.contextmanager
    def link_down(self, host: int):
        """Host ``host`` cut off for the duration of the block; the link comes back after."""
        self.set_link(host, False)
        try:
            yield
        finally:
            self.set_link(host, True)

    # -- entering a host -----------------------------------------------------------
    @contextlib.contextmanager
    def entered(self, host: int):
        """Move the calling thread into host ``host``'s namespace for the block.

        Sockets and threads made inside the block belong to that host (a DDS participant
        made there talks on the test link); the thread returns to its own namespace
        after. Threads started before the block stay where they are."""
        own = os.open('/proc/thread-self/ns/net', os.O_RDONLY)
        try:
            target = os.open(str(NETNS_DIR / self.hosts[host]), os.O_RDONLY)
            try:
                _setns(target)
            finally:
                os.close(target)
            try:
                yield self.hosts[host]
            finally:
                _setns(own)
        finally:
            os.close(own)

    def interfaces(self, host: int) -> list[str]:
        """Interface names in host ``host`` (for checks: 'lo' and 'eth0')."""
        out = _ip('-n', self.hosts[host], '-o', 'link', 'show').stdout
        return [line.split(':')[1].strip().split('@')[0] for line in out.splitlines() if line]


def current_namespace_is(name: str) -> bool:
    """True if the calling thread lives in the named namespace ``name`` (/run/netns/name)."""
    try:
        here = os.stat('/proc/thread-self/ns/net')
        there = os.stat(NETNS_DIR / name)
    except OSError:
        return False
    return (here.st_dev, here.st_ino) == (there.st_dev, there.st_ino)
