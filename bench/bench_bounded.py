"""The filter's work against the number of detections (issue 22): prints figures, no assertions.

    .venv/bin/python bench/bench_bounded.py                  # both sections
    .venv/bin/python bench/bench_bounded.py --only core      # compute only, in this process

Sections:
  core  per decision, against 1 / 10 / 100 / 1,000 / 10,000 / 100,000 detections: a robot's
        own filter (RobotFilter.step) and a fleet of ``--fleet`` robots sharing one array
        (step_many, per robot); the first decision after a new array (its k-d tree is built
        then) and the steady ones; and the arrival of a message (validation and, beyond
        max_detections, keeping the nearest). Detections: a few near the robots (a cluster
        and a lone disc), the rest uniform over 4 x 4 km. With the shipped max_detections
        (10,000) and with none in force (``max_detections`` 200,000).
  node  the reviewer's run: safety_filter_node as a process with the shipped config, pose and
        planner command at 50 Hz, detections of N entries re-sent every 0.25 s for
        ``--seconds``: the gaps between cmd_vel (median, p99, longest), the filter's RSS, and
        how many decisions named the near obstacle. N = 1,000 / 3,000 / 100,000.

Every line prints the load average (2 shared cores: the figures follow the load).
"""
from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from supersafe_ros.rosenv import ensure_local_ros_env  # noqa: E402

SIZES = (1, 10, 100, 1_000, 10_000, 100_000)
NEAR = np.array([[0.0, 0.0], [4.5, 0.0], [2.0, -7.0]])       # a pair 4.5 m apart (a cluster), a lone disc


def load():
    return f'load {os.getloadavg()[0]:.1f}'


def detections(n, rng):
    """``n`` centres: up to three near the origin, the rest uniform over 4 x 4 km."""
    near = NEAR[:min(n, len(NEAR))]
    return np.concatenate([near, rng.uniform(-2000.0, 2000.0, (n - len(near), 2))])


def us(seconds):
    return f'{seconds * 1e6:9.0f} us'


# -- core ------------------------------------------------------------------------------------------
def core(args):
    from supersafe_ros.filter import FilterConfig, RobotFilter, step_many, update_detections_all
    from supersafe_ros.filter.clusters.geometry import ClusterSettings
    from supersafe_ros.filter.clusters.store import ClusterStore
    from supersafe_ros.reach.library import LibrarySpec, load_or_build_library
    from supersafe_ros.filter import SafeSet
    library = load_or_build_library(LibrarySpec())
    safe = SafeSet(library.entry(1.0), 0.0)
    store = ClusterStore(ClusterSettings(), fallback_only=True)     # the fallback: no solve in the timing
    rng = np.random.default_rng(0)
    print(f'[core] per decision: steady (median of {args.repeat}) | first after a new array | arrival of '
          f'the message; one robot, and a fleet of {args.fleet} sharing one array ({load()})')
    for limit in (10_000, 200_000):
        config = FilterConfig(max_detections=limit)
        print(f'[core] max_detections {limit:,}' + (' (shipped)' if limit == 10_000 else ' (none in force)'))
        for n in SIZES:
            det = detections(n, rng)
            # one robot, near the pair, steering into it
            f = RobotFilter(config, 'robot')
            t = 0.0
            f.update_pose((-3.0, 0.6, 0.0), t)
            f.update_command(-0.4, t)
            t0 = time.perf_counter()
            f.update_detections(det, t, safe)
            arrival = time.perf_counter() - t0
            t0 = time.perf_counter()
            out = f.step(safe, t + 0.001, store)
            first = time.perf_counter() - t0
            steady = []
            for k in range(args.repeat):
                t = 0.002 + 0.001 * k
                f.update_pose((-3.0, 0.6, 0.0), t)
                t0 = time.perf_counter()
                f.step(safe, t, store)
                steady.append(time.perf_counter() - t0)
            print(f'[core]   {n:>7,} detections, one robot: {us(np.median(steady))} | {us(first)} | {us(arrival)}'
                  f'  ({out.action}, obstacle {out.obstacle_index}; {f.detections.dropped:,} dropped)')
            # a fleet sharing the array, spread over 2 x 2 km with a few near the pair
            m = args.fleet
            fleet = [RobotFilter(config, f'r{i}') for i in range(m)]
            xy = np.concatenate([[(-3.0, 0.6)] * min(4, m), rng.uniform(-1000, 1000, (max(0, m - 4), 2))])
            for r, p in zip(fleet, xy):
                r.update_pose((p[0], p[1], 0.0), 0.0)
                r.update_command(-0.4, 0.0)
            t0 = time.perf_counter()
            update_detections_all(fleet, det, 0.0, safe)
            arrival = time.perf_counter() - t0
            t0 = time.perf_counter()
            step_many(fleet, safe, 0.001, store)
            first = time.perf_counter() - t0
            steady = []
            for k in range(max(3, args.repeat // 10)):
                t = 0.002 + 0.001 * k
                for r, p in zip(fleet, xy):
                    r.update_pose((p[0], p[1], 0.0), t)
                t0 = time.perf_counter()
                step_many(fleet, safe, t, store)
                steady.append(time.perf_counter() - t0)
            print(f'[core]   {n:>7,} detections, fleet of {m}, per robot: {us(np.median(steady) / m)} | '
                  f'{us(first / m)} | {us(arrival / m)}  (a tick: {np.median(steady) * 1e3:.1f} ms)')
    print(f'[core] done ({load()})')


# -- node ------------------------------------------------------------------------------------------
def rss_mb(pid):
    try:
        with open(f'/proc/{pid}/status') as fh:
            for line in fh:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return math.nan


def node(args):
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from geometry_msgs.msg import PoseArray, PoseStamped, Twist
    from supersafe_ros.ros_io import cdr, rosmsg
    env = dict(os.environ)
    ensure_local_ros_env(env)
    ensure_local_ros_env()
    rclpy.init()
    config = os.path.join(os.path.dirname(HERE), 'config', 'safety_filter.yaml')
    obstacle = (4.0, -2.0)
    into = (obstacle[0] - 3.0, obstacle[1] + 0.6, 0.0)
    rng = np.random.default_rng(1)
    try:
        for n in args.node_sizes:
            ns = '/bench_bounded'
            log = open(os.path.join(tempfile.gettempdir(), f'bench_bounded_{n}.log'), 'w')
            proc = subprocess.Popen([sys.executable, '-m', 'supersafe_ros.nodes.safety_filter_node', '--ros-args',
                                     '-r', f'__ns:={ns}', '--params-file', config], env=env, stdout=log,
                                    stderr=subprocess.STDOUT)
            d = rclpy.create_node('bench_bounded_driver')
            try:
                pose = d.create_publisher(PoseStamped, f'{ns}/pose', rosmsg.QOS_STREAM)
                det = d.create_publisher(PoseArray, f'{ns}/detections', rosmsg.QOS_STREAM)
                cmd = d.create_publisher(Twist, f'{ns}/cmd_vel_nav', rosmsg.QOS_STREAM)
                out, states = [], []
                sub = d.create_subscription(Twist, f'{ns}/cmd_vel', lambda m: out.append(time.monotonic()),
                                            rosmsg.QOS_STREAM)
                ssub = d.create_subscription(DiagnosticStatus, f'{ns}/safety_filter/state',
                                             lambda m: states.append(rosmsg.diagnostic_values(m)), rosmsg.QOS_STREAM)
                deadline = time.monotonic() + 120
                while not (pose.get_subscription_count() and det.get_subscription_count()
                           and cmd.get_subscription_count() and sub.get_publisher_count()
                           and ssub.get_publisher_count()):
                    rclpy.spin_once(d, timeout_sec=0.05)
                    if time.monotonic() > deadline:
                        raise TimeoutError('the filter process did not match')
                far = rng.uniform(-2000.0, 2000.0, (n - 1, 2)) + obstacle
                far = far[np.hypot(*(far - obstacle).T) > 60.0]
                far = np.concatenate([far, rng.uniform(-2000.0, 2000.0, (n - 1 - len(far), 2)) + [5000.0, 0.0]])
                data = cdr.pose_array_bytes(np.concatenate([far[:n // 2], [obstacle], far[n // 2:]]))
                close = str(n // 2)
                rss0 = rss_mb(proc.pid)
                # warm: a small message, then the run
                det.publish(rosmsg.xy_to_posearray([obstacle]))
                start = time.monotonic()
                next_tick, next_det, sent, rss = start, start, 0, [rss0]
                while time.monotonic() - start < 2.0 + args.seconds:
                    now = time.monotonic()
                    if now >= next_det and now - start >= 2.0:
                        det.publish(data)
                        next_det += 0.25
                        rss.append(rss_mb(proc.pid))
                    if now >= next_tick:
                        pose.publish(rosmsg.state_to_pose(into, stamp=d.get_clock().now().to_msg()))
                        cmd.publish(rosmsg.turn_rate_to_twist(-0.4, 3.0))
                        sent += 1
                        next_tick += 0.02
                    rclpy.spin_once(d, timeout_sec=max(0.0, min(next_tick, next_det) - time.monotonic()))
                times = np.array([t for t in out if t >= start + 2.0])
                gaps = np.diff(times) if len(times) > 1 else np.array([math.inf])
                named = sum(s.get('obstacle_index') == close for s in states)
                print(f'[node] {n:>7,} detections every 0.25 s, pose + command at 50 Hz, {args.seconds:g} s: '
                      f'{len(times)} cmd_vel, gaps median {np.median(gaps) * 1e3:.1f} ms, p99 '
                      f'{np.percentile(gaps, 99) * 1e3:.1f} ms, longest {gaps.max() * 1e3:.0f} ms; RSS '
                      f'{rss0:.0f} -> {max(rss):.0f} MB; {named} of {len(states)} states name obstacle {close}'
                      f'{" (" + states[-1].get("detections_dropped", "") + " dropped)" if states else ""}; '
                      f'alive: {proc.poll() is None} ({load()})', flush=True)
            finally:
                d.destroy_node()
                if proc.poll() is None:
                    proc.send_signal(2)
                try:
                    proc.wait(15)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
    finally:
        rclpy.shutdown()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--only', nargs='*', choices=('core', 'node'), default=None)
    ap.add_argument('--repeat', type=int, default=200, help='steady decisions timed per size (one robot)')
    ap.add_argument('--fleet', type=int, default=100, help='robots of the fleet sharing one array')
    ap.add_argument('--seconds', type=float, default=10.0, help='node: seconds of 50 Hz commands per size')
    ap.add_argument('--node-sizes', type=int, nargs='*', default=[1_000, 3_000, 100_000])
    args = ap.parse_args(argv)
    only = set(args.only or ('core', 'node'))
    print(f'bench_bounded at {time.strftime("%Y-%m-%d %H:%M")}, {os.cpu_count()} cores, {load()}')
    if 'core' in only:
        core(args)
    if 'node' in only:
        node(args)


if __name__ == '__main__':
    main()
