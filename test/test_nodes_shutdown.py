"""Every node executable stops quietly: SIGINT (Ctrl-C) or SIGTERM -> exit 0, nothing on stderr.

Log lines go to stdout here (RCUTILS_LOGGING_USE_STDOUT), so stderr holds only what
is not a log line: tracebacks, rcl's "Failed to publish log message to rosout", and
any print to stderr. Each node is a real process started from its installed config,
as `supersafe team` starts it, in a process group of its own with what it spawns (the
filter's cluster worker and multiprocessing's resource tracker): the signal goes to the
group, as a terminal's Ctrl-C does, and then again to the node until it has exited, as
`ros2 launch` does after the terminal (there is no ros2cli here).
"""
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from supersafe_ros import team

# small value-function grids: start-up is the point, not the numerics
SMALL = {
    'supervisor': {'grid_nxy': 17, 'grid_ntheta': 8},
    'safety_filter': {'standard_shape': [17, 17, 8]},
    'learner': {'library_shape': [17, 17, 8], 'library_omegas': [0.5, 1.0]},
}
# the even ones are signalled as soon as they log (often still in their constructor), the odd
# ones once they answer a service call (spinning), the filter once its cluster worker is up
NODES = [('sim_clock', None), ('world', None), ('dubins_robot', 'robot_0'), ('planner', 'robot_0'),
         ('supervisor', None), ('safety_filter', 'robot_0'), ('learner', None)]


class NodeProcess:
    def __init__(self, kind, namespace, tmp_path):
        params = dict(SMALL.get(kind, {}))
        if kind == 'learner':
            params['store_path'] = str(tmp_path / 'interventions.jsonl')
        if kind == 'sim_clock':
            params['start_timeout'] = 0.5       # starts stepping, with or without a graph
        env = dict(os.environ, RCUTILS_LOGGING_USE_STDOUT='1', RCUTILS_COLORIZED_OUTPUT='0',
                   PYTHONUNBUFFERED='1')
        self.kind = kind
        self.name = f'/{namespace}/{kind}' if namespace else f'/{kind}'
        self.proc = subprocess.Popen(team.node_argv(kind, namespace, params), env=env,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     start_new_session=True)
        self.stdout, self.stderr = [], []
        self.readers = [threading.Thread(target=self._read, args=(s, out), daemon=True)
                        for s, out in ((self.proc.stdout, self.stdout), (self.proc.stderr, self.stderr))]
        for r in self.readers:
            r.start()

    @staticmethod
    def _read(stream, out):
        for line in stream:
            out.append(line)

    def logged(self) -> bool:
        """A log line of this node ('[sim_clock]', '[robot_0.planner]', ...)."""
        return any(f'[{self.kind}]' in line or f'.{self.kind}]' in line for line in self.stdout)

    def children(self) -> list:
        """Pids of the processes this node started (its cluster worker, the resource tracker)."""
        return [pid for pid, ppid in processes() if ppid == self.proc.pid]

    def finish(self, timeout):
        try:
            code = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()
            code = 'hung'
        for r in self.readers:
            r.join(timeout=5)
        return code


def processes():
    """(pid, parent pid) of every process (Linux /proc)."""
    out = []
    for d in os.listdir('/proc'):
        if d.isdigit():
            try:
                with open(f'/proc/{d}/stat') as f:
                    fields = f.read().rsplit(')', 1)[1].split()
            except OSError:
                continue
            if fields[0] != 'Z':
                out.append((int(d), int(fields[1])))
    return out


def running(pids) -> list:
    alive = {pid for pid, _ in processes()}
    return [p for p in pids if p in alive]


def spinning(client, spin, name, deadline) -> bool:
    """True once the node ``name`` answers a get_parameters call (its executor spins)."""
    from rcl_interfaces.srv import GetParameters
    cli = client.create_client(GetParameters, f'{name}/get_parameters')
    try:
        while time.monotonic() < deadline:
            if cli.service_is_ready():
                future = cli.call_async(GetParameters.Request(names=['use_sim_time']))
                spin.until(lambda: future.done() or time.monotonic() > deadline, 120.0, f'{name} to answer')
                if future.done():
                    return True
            spin.spin_for(0.05)
        return False
    finally:
        client.destroy_client(cli)


def signal_until_stopped(procs, sig_of, deadline):
    """Signal each node again every 50 ms until it has exited (``ros2 launch`` signals every
    node it started once the terminal's Ctrl-C has reached the whole group)."""
    while time.monotonic() < deadline and any(p.proc.poll() is None for p in procs):
        for p in procs:
            if p.proc.poll() is None:
                try:
                    p.proc.send_signal(sig_of[p.kind])
                except ProcessLookupError:
                    pass
        time.sleep(0.05)


@pytest.mark.ros
@pytest.mark.slow
def test_every_node_stops_quietly_on_a_signal(tmp_path, ros_context):
    from rclpy.node import Node
    from graph_support import Spinner
    procs = [NodeProcess(kind, ns, tmp_path) for kind, ns in NODES]
    client = Node('shutdown_test_client', context=ros_context)
    spin = Spinner(ros_context, client)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not all(p.logged() or p.proc.poll() is not None
                                                      for p in procs[::2]):
            time.sleep(0.05)
        for p in procs:
            assert p.proc.poll() is None, f'{p.kind} exited early: {"".join(p.stderr)}'
            assert p.logged() or p in procs[1::2], f'{p.kind} said nothing in 120 s'
        # SIGINT (Ctrl-C, team) and SIGTERM (launch's escalation), each both right after
        # the first log line (often still in the constructor) and once spinning, to the
        # node's process group, then to the node again and again until it has exited
        signals = [signal.SIGINT, signal.SIGTERM]
        sig_of = {}
        for i, p in enumerate(procs[::2]):
            sig_of[p.kind] = signals[i % 2]
            os.killpg(p.proc.pid, sig_of[p.kind])
        spawned = {}
        for i, p in enumerate(procs[1::2]):
            assert spinning(client, spin, p.name, time.monotonic() + 120), f'{p.name} never answered'
            while p.kind == 'safety_filter' and len(p.children()) < 2 and time.monotonic() < deadline + 120:
                time.sleep(0.1)           # its resource tracker and cluster worker
            spawned[p.kind] = p.children()
            sig_of[p.kind] = signals[(i + 1) % 2]
            os.killpg(p.proc.pid, sig_of[p.kind])
        signal_until_stopped(procs, sig_of, time.monotonic() + 30)
        results = {p.kind: (p.finish(30), ''.join(p.stderr)) for p in procs}
        # what they started goes with them (the tracker reads its pipe to the end first)
        deadline = time.monotonic() + 30
        while running(sum(spawned.values(), [])) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = running(sum(spawned.values(), []))
    finally:
        spin.shutdown()
        client.destroy_node()
        for p in procs:
            if p.proc.poll() is None:
                os.killpg(p.proc.pid, signal.SIGKILL)
    assert len(spawned['safety_filter']) == 2, 'the filter had no cluster worker: nothing of it was tested'
    bad = {k: v for k, v in results.items() if v != (0, '')}
    assert not bad, bad
    assert left == [], left


def test_a_stop_swallowed_while_importing_still_stops_the_node(tmp_path):
    """A SIGTERM that lands while a node is still importing raises SystemExit inside
    whatever import is running; a library's bare ``except:`` can swallow it (a killed team
    runner's world node once kept running so, and drove the next test's robots). run_node
    must still stop before it starts rclpy or builds the node."""
    built = tmp_path / 'built'
    script = f'''
import os, signal, sys
import supersafe_ros.nodes as nodes
from supersafe_ros.nodes.common import run_node
try:
    nodes._stop_while_importing(signal.SIGTERM, None)   # as the import-time handler does
except BaseException:
    pass                                                 # ... and an import swallowed it
class Node:
    def __init__(self):
        open({str(built)!r}, 'w').close()
sys.exit(run_node(Node, ['x']))
'''
    proc = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert not built.exists()


@pytest.mark.ros
def test_the_events_executor_spins_a_node_and_stops_it_quietly(tmp_path, ros_context, monkeypatch):
    """SUPERSAFE_EXECUTOR=events (rclpy's experimental EventsExecutor, which takes no guard
    conditions): the filter's watchdog publishes commands (timers and publishers run), then stops on SIGINT with exit 0
    and nothing on stderr (it once crashed at start-up on run_node's stop guard condition)."""
    from geometry_msgs.msg import PoseArray, PoseStamped, Twist
    from rclpy.node import Node
    from supersafe_ros.ros_io import rosmsg
    from graph_support import Spinner, matched
    monkeypatch.setenv('SUPERSAFE_EXECUTOR', 'events')
    p = NodeProcess('safety_filter', 'events_robot', tmp_path)
    driver = Node('events_driver', context=ros_context)
    spin = Spinner(ros_context, driver)
    try:
        got = []
        pose = driver.create_publisher(PoseStamped, '/events_robot/pose', rosmsg.QOS_STREAM)
        det = driver.create_publisher(PoseArray, '/events_robot/detections', rosmsg.QOS_STREAM)
        sub = driver.create_subscription(Twist, '/events_robot/cmd_vel', got.append, rosmsg.QOS_STREAM)
        spin.until(lambda: matched(pose, det, sub) or p.proc.poll() is not None, 60.0, 'the filter to match')
        assert p.proc.poll() is None, ''.join(p.stderr)
        det.publish(rosmsg.xy_to_posearray([(50.0, 50.0)]))
        spin.until(lambda: got or p.proc.poll() is not None, 10.0, 'a command from the filter')
        assert got, ''.join(p.stderr)
        p.proc.send_signal(signal.SIGINT)
        assert p.finish(30) == 0 and ''.join(p.stderr) == ''
    finally:
        spin.shutdown()
        driver.destroy_node()
        if p.proc.poll() is None:
            os.killpg(p.proc.pid, signal.SIGKILL)
