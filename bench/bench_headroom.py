"""The filter nodes' headroom, checkouts side by side in one run (prints figures; no assertions).

    .venv/bin/python bench/bench_headroom.py --checkout /work/d61 .
    .venv/bin/python bench/bench_headroom.py --only fleet --fleet-sizes 60 120

Every node runs the code of a checkout (its ``supersafe_ros`` first on sys.path); the driver and
this script are this checkout's. Sections, each run for every checkout in turn:

* **fleet**: fleet_safety_filter_node with M robots on per-robot topics (the node's defaults, as a
  user runs it: ``<ns>/pose``, ``<ns>/detections``, ``<ns>/cmd_vel_nav``), pinned to one core, the
  driver on the other; each robot fed a pose and a command at 50 Hz, detections at 10 Hz, for
  ``--window`` s. Printed: the node's ticks per second; its CPU share of the core; CPU per
  robot-decision; the share of its decisions' time spent on state messages (building and
  publishing ``<ns>/safety_filter/state``: the node's own state builder and publishers timed from
  inside, every call); the slowest robot's decisions per second.
* **batched**: the same node on the batched topics alone (``fleet/poses`` -> ``fleet/cmd_vel``),
  N robots: ticks per second, CPU share, CPU per robot-decision, state share.
* **latency**: one robot's pose -> cmd_vel through a safety_filter_node (``publish_on_pose``, the
  default ``direct_take``), a process per checkout running at the same time on its own namespace,
  the samples alternating between them (the load falls on both alike): median, p99.

Times between processes on CLOCK_MONOTONIC; /proc/loadavg on every line.
"""
from __future__ import annotations

import argparse
from functools import partial
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = Path(__file__).resolve().parent
OBSTACLE = (3.0, -1.0)      # bench_nodes'
bench_nodes = None          # imported by main() once supersafe_ros is that of the right checkout


def import_from(root: str):
    """supersafe_ros of ``root`` (its submodules follow the package's path), then bench_nodes (the
    driver's parts: Driver, cpu_seconds, pinning), which imports it."""
    global bench_nodes
    sys.path.insert(0, root)
    import supersafe_ros  # noqa: F401
    sys.path.insert(0, str(HERE))
    import bench_nodes as module
    bench_nodes = module
    # bench_nodes puts this checkout first on sys.path: the checkout's own goes first again, or a
    # process the node spawns (its cluster and map workers) imports this checkout's package
    sys.path.insert(0, root)


def ensure_local_ros_env(env=None):
    from supersafe_ros.rosenv import ensure_local_ros_env as ensure
    return ensure(env)


def load():
    return '[load ' + ' '.join(open('/proc/loadavg').read().split()[:3]) + ']'


def label(checkout: Path) -> str:
    head = subprocess.run(['git', '-C', str(checkout), 'rev-parse', '--short', 'HEAD'], capture_output=True,
                          text=True).stdout.strip() or '?'
    dirty = subprocess.run(['git', '-C', str(checkout), 'status', '--porcelain', '--', 'supersafe_ros'],
                           capture_output=True, text=True).stdout.strip()
    return head + ('+' if dirty else '')


def child_env(checkout: Path) -> dict:
    env = dict(os.environ)
    ensure_local_ros_env(env)
    env['PYTHONPATH'] = str(checkout)
    return env


# -- the fleet node's child ----------------------------------------------------------------------
class Timed:
    """Seconds spent in the wrapped calls (perf_counter; a few hundred ns a call)."""

    def __init__(self):
        self.seconds = 0.0

    def wrap(self, fn):
        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - t0
        return timed


def serve(checkout: str, m: int, batched: bool, core: int | None):
    """Child: one fleet_safety_filter_node of ``checkout`` for /bench_0 .. /bench_<m-1>."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from diagnostic_msgs.msg import DiagnosticStatus
    from supersafe_ros.nodes.fleet_safety_filter_node import FleetSafetyFilterNode
    from supersafe_ros.ros_io import rosmsg
    if core is not None:
        bench_nodes._pin_threads({core})
    ensure_local_ros_env()
    rclpy.init()
    node = FleetSafetyFilterNode(parameter_overrides=[
        Parameter('robots', value=[f'bench_{i}' for i in range(m)]),
        Parameter('per_robot_topics', value=not batched), Parameter('batched_topics', value=batched),
        Parameter('rate', value=50.0), Parameter('pose_timeout', value=1.0),
        Parameter('detections_timeout', value=2.0)])
    states, decisions = Timed(), Timed()
    # the state's builder and publishers (whatever form the checkout gives them), and each decision
    w = node.wiring
    for name in ('state_message', 'shared_state_values'):
        if hasattr(w, name):
            setattr(w, name, states.wrap(getattr(w, name)))
    import importlib
    for module, name in (('supersafe_ros.ros_io.cdr', 'diagnostic_status_bytes'),
                         ('supersafe_ros.nodes.fleet_safety_filter_node', 'array_bytes'),
                         ('supersafe_ros.nodes.filter_topics', 'array_bytes')):
        try:
            module = importlib.import_module(module)
        except ImportError:             # a checkout without that module
            continue
        if hasattr(module, name):       # a checkout that serializes its states itself
            setattr(module, name, states.wrap(getattr(module, name)))
    for topics in getattr(node, 'topics', []):
        topics.state_pub.publish = states.wrap(topics.state_pub.publish)
    if batched:     # (the batched states' publisher: the node's, or its FleetTopics')
        fleet_states = getattr(node, 'fleet_state_pub', None) or node.fleet.state_pub
        fleet_states.publish = states.wrap(fleet_states.publish)
    node.decide = decisions.wrap(node.decide)
    report = node.create_publisher(DiagnosticStatus, '/bench/decisions', rosmsg.QOS_EVENTS)
    node.create_timer(0.25, lambda: report.publish(rosmsg.make_diagnostic('decisions', {
        't': time.monotonic_ns(), 'ticks': node.ticks, 'fail_safe': node.failing_safe,
        'superseded': bench_nodes.superseded(node), 'state_s': f'{states.seconds:.9f}',
        'decide_s': f'{decisions.seconds:.9f}',
        'decisions': ','.join(str(int(v)) for v in getattr(node, 'decided', node.decisions))})), clock=w.steady)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    try:
        ex.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.close()
        rclpy.try_shutdown()


def start_child(args, checkout: Path, m: int, batched: bool):
    core = None if args.all_cores else bench_nodes.node_core()
    cmd = [sys.executable, str(Path(__file__).resolve()), '--serve', str(checkout), '--robots', str(m)]
    cmd += (['--batched'] if batched else []) + ([] if core is None else ['--core', str(core)])
    log = open(os.path.join(tempfile.gettempdir(), f'bench_headroom_{"batched" if batched else "fleet"}_{m}.log'),
               'w')
    return subprocess.Popen(cmd, env=child_env(checkout), stdout=log, stderr=subprocess.STDOUT)


def window_figures(reports, t0, t1):
    """(ticks/s, decisions per robot per second (array), state s, decide s) between the reports
    around [t0, t1], the child's view."""
    before = [r for r in reports if int(r['t']) <= int(t0 * 1e9)]
    after = [r for r in reports if int(r['t']) >= int(t1 * 1e9)]
    first, last = (before[-1] if before else reports[0]), (after[0] if after else reports[-1])
    span = (int(last['t']) - int(first['t'])) * 1e-9
    decided = (np.array(last['decisions'].split(','), float) - np.array(first['decisions'].split(','), float))
    return ((int(last['ticks']) - int(first['ticks'])) / span, decided / span,
            float(last['state_s']) - float(first['state_s']), float(last['decide_s']) - float(first['decide_s']))


def print_figures(section, tag, m, reports, t0, t1, cpu):
    ticks, per_robot, state_s, decide_s = window_figures(reports, t0, t1)
    span = t1 - t0
    robot_decisions = per_robot.sum() * span
    print(f'{section:8s} {tag:10s} {m:5d} robots: {ticks:6.1f} ticks/s, slowest robot {per_robot.min():5.1f} '
          f'decisions/s; CPU {100 * cpu / span:5.1f} % of its core, {1e6 * cpu / max(robot_decisions, 1):6.1f} us '
          f'a robot-decision; state messages {100 * state_s / max(decide_s, 1e-9):4.1f} % of the decisions\' '
          f'time ({1e6 * state_s / max(robot_decisions, 1):5.1f} us a robot-decision)  {load()}', flush=True)


FEEDS = {'fleet': 'per-robot topics, fed pose + command at 50 Hz, detections at 10 Hz',
         'batched': 'fleet/poses + fleet/cmd_vel_nav at 50 Hz, fleet/detections at 10 Hz'}


def bench_rows(section, args, checkouts):
    """The ``section``'s rows (fleet or batched): every size, every checkout in turn."""
    print(f'== {section}: {FEEDS[section]}, {args.window:g} s a row; the node pinned to core '
          f'{bench_nodes.node_core()}, the driver off it', flush=True)
    for size in (args.fleet_sizes if section == 'fleet' else args.batched_sizes):
        for checkout, tag in checkouts:
            row(args, section, checkout, tag, size)


def row(args, section, checkout, tag, size):
    """One row: the fleet node of ``checkout`` (per-robot topics, or ``batched`` ones) of ``size``
    robots, fed (``bench_nodes.RobotFeed`` or ``BatchedFeed``), measured (``measure``)."""
    from diagnostic_msgs.msg import DiagnosticStatus
    from supersafe_ros.ros_io import rosmsg
    batched = section == 'batched'
    child = start_child(args, checkout, size, batched=batched)
    d = bench_nodes.Driver(f'bench_headroom_{section}')
    try:
        reports = []
        d.node.create_subscription(DiagnosticStatus, '/bench/decisions',
                                   lambda msg: reports.append(rosmsg.diagnostic_values(msg)), rosmsg.QOS_EVENTS)
        feed = (bench_nodes.BatchedFeed if batched else bench_nodes.RobotFeed)(d, size)
        d.spin_until(lambda: feed.matched() and reports, 180.0, f'the fleet node of {size} robots to match')
        measure(section, tag, size, feed.run, child, d, reports, args.window)
    finally:
        d.close()
        bench_nodes.stop([child])


def measure(section, tag, size, feed, child, d, reports, window):
    """One row: ``feed`` 1 s (warm-up: the first detections, the first ticks' caches), then the
    window with the node's CPU, then until the node's report covers the window; its figures."""
    feed(1.0)
    t0, cpu0 = time.monotonic(), bench_nodes.cpu_seconds(child.pid)
    feed(window)
    t1, cpu = time.monotonic(), bench_nodes.cpu_seconds(child.pid) - cpu0
    feed(0.5)
    d.spin_until(lambda: reports and int(reports[-1]['t']) >= int(t1 * 1e9), 30.0, 'a report after')
    print_figures(section, tag, size, reports, t0, t1, cpu)


def bench_latency(args, checkouts):
    from geometry_msgs.msg import PoseArray, PoseStamped, Twist
    from supersafe_ros.ros_io import rosmsg
    print(f'== latency: one robot\'s pose -> cmd_vel (safety_filter_node, publish_on_pose, direct_take), a '
          f'process per checkout at once, samples alternating, {args.samples} a checkout at 50 Hz', flush=True)
    procs, lanes = [], []
    d = bench_nodes.Driver('bench_headroom_latency')
    try:
        for k, (checkout, tag) in enumerate(checkouts):
            ns = f'/headroom_{k}'
            cmd = [sys.executable] + bench_nodes.node_cmd(
                'safety_filter_node', ns, publish_on_pose=True, rate=1.0, cmd_timeout=30.0, pose_timeout=30.0,
                detections_timeout=30.0, hold_timeout=30.0)
            log = open(os.path.join(tempfile.gettempdir(), f'bench_headroom_latency_{k}.log'), 'w')
            procs.append(subprocess.Popen(cmd, env=child_env(checkout), cwd=str(checkout), stdout=log,
                                          stderr=subprocess.STDOUT))
            got = []
            lane = {'tag': tag, 'got': got, 'lat': [],
                    'pose': d.node.create_publisher(PoseStamped, f'{ns}/pose', rosmsg.QOS_STREAM),
                    'det': d.node.create_publisher(PoseArray, f'{ns}/detections', rosmsg.QOS_STREAM),
                    'cmd': d.node.create_publisher(Twist, f'{ns}/cmd_vel_nav', rosmsg.QOS_STREAM),
                    'sub': d.node.create_subscription(Twist, f'{ns}/cmd_vel',
                                                      lambda m, got=got: got.append(time.monotonic_ns()),
                                                      rosmsg.QOS_STREAM)}
            lanes.append(lane)
        d.spin_until(lambda: all(lane[k].get_subscription_count() for lane in lanes for k in ('pose', 'det', 'cmd'))
                     and all(lane['sub'].get_publisher_count() for lane in lanes), 120.0, 'the filters to match')
        for lane in lanes:
            lane['cmd'].publish(rosmsg.turn_rate_to_twist(0.2, 3.0))
            lane['det'].publish(rosmsg.xy_to_posearray([OBSTACLE]))
        d.spin_for(0.5)
        poses = [(OBSTACLE[0] - 7.5, OBSTACLE[1] + 7.0, 0.0), (OBSTACLE[0] - 3.0, OBSTACLE[1] + 0.6, 0.0)]
        for i in range(args.samples + 20):
            for lane in lanes:
                lane['got'].clear()
                t0 = time.monotonic_ns()
                lane['pose'].publish(rosmsg.state_to_pose(poses[i % 2]))
                try:
                    d.spin_until(lambda: lane['got'], 2.0, 'cmd_vel')
                except TimeoutError:
                    continue
                if i >= 20:
                    lane['lat'].append((lane['got'][0] - t0) * 1e-9)
                d.spin_for(max(0.0, 0.01 - (time.monotonic_ns() - t0) * 1e-9))
        for lane in lanes:
            print(f"latency  {lane['tag']:10s} pose -> cmd_vel {bench_nodes.ms(lane['lat'])}  {load()}", flush=True)
    finally:
        d.close()
        bench_nodes.stop(procs)


SECTIONS = {'latency': bench_latency, 'fleet': partial(bench_rows, 'fleet'), 'batched': partial(bench_rows, 'batched')}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--checkout', nargs='+', default=[str(HERE.parent)], help='checkouts to compare')
    parser.add_argument('--only', nargs='+', choices=list(SECTIONS), default=list(SECTIONS))
    parser.add_argument('--fleet-sizes', type=int, nargs='+', default=[60])
    parser.add_argument('--batched-sizes', type=int, nargs='+', default=[1000, 2000])
    parser.add_argument('--window', type=float, default=8.0, help='seconds a row')
    parser.add_argument('--samples', type=int, default=400, help='latency samples a checkout')
    parser.add_argument('--all-cores', action='store_true', help='do not pin the fleet node to one core')
    parser.add_argument('--serve', default='', help=argparse.SUPPRESS)
    parser.add_argument('--robots', type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument('--batched', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--core', type=int, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    import_from(args.serve or str(HERE.parent))
    if args.serve:
        return serve(args.serve, args.robots, args.batched, args.core)
    ensure_local_ros_env()
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 80))
    checkouts = [(Path(c).resolve(), label(Path(c).resolve())) for c in args.checkout]
    import rclpy
    rclpy.init()
    print(f"bench_headroom: ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}, {os.cpu_count()} cores, checkouts "
          + ', '.join(f'{tag} ({c})' for c, tag in checkouts) + f'  {load()}', flush=True)
    try:
        for name in args.only:
            SECTIONS[name](args, checkouts)
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
