"""The filter's two take paths side by side: ``take_path`` private against public (prints
figures; no assertions).

    .venv/bin/python bench/bench_take.py                  # 3 pairs at rest, 3 beside 2 burners
    .venv/bin/python bench/bench_take.py --pairs 5 --samples 600 --only rest

``private``: the inputs waited on by an rcl wait set of their own (rclpy's private
``_rclpy.WaitSet``) and the value function copied by rcl through ctypes without the GIL
(``ros_io.gil_free_take``). ``public``: the helper nodes spun by a SingleThreadedExecutor
of their own in their own thread, every message taken by rclpy (``ros_io.direct_take``).

Each run starts a safety_filter_node process (``publish_on_pose``, watchdog at 1 Hz, no
timeouts in reach) with one path and feeds it from this process:

* latency: ``--samples`` poses at 50 Hz, alternately far from and near an obstacle, each
  answered by a cmd_vel: pose -> cmd_vel median and p99, and the filter process's CPU
  (user + system, /proc) per cmd_vel it published meanwhile;
* 50 MB: poses at 50 Hz while another process publishes a 50 MB message on
  /safe_set/value_function (12.5 M float32 without a layout: the filter takes all of it,
  then refuses it at decoding, so the take is what is measured): the longest gap between
  two cmd_vel, from 0.5 s before the message is published until the filter's state counts
  it rejected.

Then the take alone, apart from the filter (``stall``): in this process a DirectTake
with one raw subscription to /safe_set/value_function and a thread sleeping 1 ms at a
time; its longest stall while 50 MB arrive, for the private wait set with the take
without the GIL (``gil_free_take``), the private wait set with rclpy's take, and the
public executor (which of the two private pieces the gap comes from).

The two paths run in pairs, the order alternating from pair to pair, at rest and then
beside two CPU burners (``yes > /dev/null``, started and ended by this bench). Every
process runs with loopback-only discovery in this shell's ROS_DOMAIN_ID.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from bench_nodes import OBSTACLE, Driver, cpu_seconds, node_cmd, start, stop  # noqa: E402
from supersafe_ros.rosenv import ensure_local_ros_env  # noqa: E402

NS = '/bench_take'
VF_FLOATS = 12_500_000          # 50 MB of float32
PATHS = ('private', 'public')


def serve_big_value_function():
    """Child: publish one 50 MB message on /safe_set/value_function once the filter listens;
    print the time it was published (CLOCK_MONOTONIC ns); stay until stdin closes."""
    import rclpy
    from std_msgs.msg import Float32MultiArray
    from supersafe_ros.ros_io import rosmsg
    ensure_local_ros_env()
    rclpy.init()
    node = rclpy.create_node('bench_take_vf')
    pub = node.create_publisher(Float32MultiArray, '/safe_set/value_function', rosmsg.QOS_LATCHED)
    # a serialized Float32MultiArray: CDR header, no dims, data_offset 0, n floats
    data = (b'\x00\x01\x00\x00' + np.array([0, 0, VF_FLOATS], dtype='<u4').tobytes()
            + np.ones(VF_FLOATS, dtype='<f4').tobytes())
    deadline = time.monotonic() + 60
    while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    t = time.monotonic_ns()
    pub.publish(data)
    print(f'published {t}', flush=True)
    sys.stdin.read()
    node.destroy_node()
    rclpy.try_shutdown()


def percentile_ms(values, q):
    return float(np.percentile(np.asarray(values) * 1e3, q))


def run(path, samples):
    """One filter process on ``path``: its latency, CPU per decision and 50 MB gap."""
    from diagnostic_msgs.msg import DiagnosticStatus
    from geometry_msgs.msg import PoseArray, PoseStamped, Twist
    from supersafe_ros.ros_io import rosmsg
    proc = start(node_cmd('safety_filter_node', NS, publish_on_pose=True, rate=1.0, cmd_timeout=30.0,
                          pose_timeout=30.0, detections_timeout=30.0, hold_timeout=30.0, level_set_markers=False,
                          take_path=path), f'take_{path}')
    d = Driver('bench_take')
    vf = None
    try:
        pose_pub = d.node.create_publisher(PoseStamped, f'{NS}/pose', rosmsg.QOS_STREAM)
        det_pub = d.node.create_publisher(PoseArray, f'{NS}/detections', rosmsg.QOS_STREAM)
        cmd_pub = d.node.create_publisher(Twist, f'{NS}/cmd_vel_nav', rosmsg.QOS_STREAM)
        got = []
        sub = d.node.create_subscription(Twist, f'{NS}/cmd_vel', lambda m: got.append(time.monotonic_ns()),
                                         rosmsg.QOS_STREAM)
        rejected = []
        d.node.create_subscription(
            DiagnosticStatus, f'{NS}/safety_filter/state',
            lambda m: rejected.append(int(rosmsg.diagnostic_values(m).get('sets_rejected', '0'))),
            rosmsg.QOS_STREAM)
        needed = (pose_pub, det_pub, cmd_pub)
        d.spin_until(lambda: proc.poll() is not None or (all(p.get_subscription_count() for p in needed)
                                                         and sub.get_publisher_count()),
                     120.0, 'the filter to match (it loads the standard set first)')
        if proc.poll() is not None:
            raise RuntimeError(f'the filter ended (exit {proc.returncode}); see its log in /tmp')
        cmd_pub.publish(rosmsg.turn_rate_to_twist(0.2, 3.0))
        det_pub.publish(rosmsg.xy_to_posearray([OBSTACLE]))
        d.spin_for(0.5)
        poses = [rosmsg.state_to_pose((OBSTACLE[0] - 7.5, OBSTACLE[1] + 7.0, 0.0)),
                 rosmsg.state_to_pose((OBSTACLE[0] - 3.0, OBSTACLE[1] + 0.6, 0.0))]
        # latency and CPU per decision
        latency, lost = [], 0
        got.clear()
        cpu0 = cpu_seconds(proc.pid)
        for i in range(samples):
            t0 = time.monotonic_ns()
            before = len(got)
            pose_pub.publish(poses[i % 2])
            try:
                d.spin_until(lambda: len(got) > before, 2.0, 'cmd_vel')
                latency.append((got[before] - t0) * 1e-9)
            except TimeoutError:
                lost += 1
            d.spin_for(max(0.0, 0.02 - (time.monotonic_ns() - t0) * 1e-9))   # 50 Hz
        cpu = cpu_seconds(proc.pid) - cpu0
        decisions = len(got)
        # the longest cmd_vel gap while 50 MB arrive
        got.clear()
        vf = subprocess.Popen([sys.executable, os.path.abspath(__file__), '--serve-vf'], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env=dict(os.environ))
        published = None
        sent = []
        deadline = time.monotonic() + 120
        i = 0
        os.set_blocking(vf.stdout.fileno(), False)
        while (not rejected or rejected[-1] < 1) and time.monotonic() < deadline:
            t0 = time.monotonic_ns()
            pose_pub.publish(poses[i % 2])
            sent.append(t0)
            i += 1
            if published is None:
                line = vf.stdout.readline()
                if line.startswith('published'):
                    published = int(line.split()[1])
            d.spin_for(max(0.0, 0.02 - (time.monotonic_ns() - t0) * 1e-9))
        arrived = rejected and rejected[-1] >= 1
        if published is None:
            raise RuntimeError('the 50 MB message was not published')
        window = [t for t in got if t >= published - 500_000_000]
        gap = max(np.diff(window)) * 1e-9 if len(window) > 1 else float('nan')
        sent_window = [t for t in sent if t >= published - 500_000_000]
        send_gap = max(np.diff(sent_window)) * 1e-9 if len(sent_window) > 1 else float('nan')
        return dict(path=path, median=percentile_ms(latency, 50), p99=percentile_ms(latency, 99),
                    n=len(latency), lost=lost, cpu_ms=cpu / max(decisions, 1) * 1e3, decisions=decisions,
                    gap_ms=gap * 1e3, send_gap_ms=send_gap * 1e3, arrived=bool(arrived),
                    load=os.getloadavg()[0])
    finally:
        if vf is not None:
            vf.stdin.close()
            try:
                vf.wait(10)
            except subprocess.TimeoutExpired:
                vf.kill()
                vf.wait()
        d.close()
        stop([proc])


def stall(variant, rounds):
    """In this process: a DirectTake with one raw subscription to /safe_set/value_function
    (``variant``: private + gil_free, private with rclpy's take, public) while another process
    publishes 50 MB on it, and a thread that sleeps 1 ms at a time: its longest stall from
    publication to the message's arrival. The take alone, apart from the filter."""
    import threading
    from rclpy.node import Node
    from std_msgs.msg import Float32MultiArray
    from supersafe_ros.ros_io import rosmsg
    from supersafe_ros.ros_io.direct_take import DirectTake
    path, gil_free = {'private': ('private', True), 'private_rclpy_take': ('private', False),
                      'public': ('public', False)}[variant]
    out = []
    for _ in range(rounds):
        owner = Node('bench_take_stall')
        arrived = threading.Event()
        direct = DirectTake(owner, threading.Lock(), suffix='_sets', path=path)
        direct.add(Float32MultiArray, '/safe_set/value_function', lambda data: arrived.set(), rosmsg.QOS_LATCHED,
                   raw=True, gil_free=gil_free)
        direct.start()
        ticks, stop = [], threading.Event()

        def tick():
            while not stop.is_set():
                ticks.append(time.monotonic_ns())
                time.sleep(0.001)
        ticker = threading.Thread(target=tick, daemon=True)
        ticker.start()
        vf = subprocess.Popen([sys.executable, os.path.abspath(__file__), '--serve-vf'], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env=dict(os.environ))
        try:
            published = int(vf.stdout.readline().split()[1])
            if not arrived.wait(60):
                raise RuntimeError('the 50 MB message did not arrive')
            stop.set()
            ticker.join()
            window = [t for t in ticks if t >= published]
            out.append(max(np.diff(window)) * 1e-6 if len(window) > 1 else float('nan'))
        finally:
            stop.set()
            vf.stdin.close()
            vf.wait(10)
            direct.close()
            owner.destroy_node()
    return out


def stalls(name, rounds):
    print(f'[{name}] the take alone: longest stall of a 1 ms ticker while 50 MB arrive, {rounds} rounds '
          f'each, variants alternating (load {os.getloadavg()[0]:.1f})', flush=True)
    got = {v: [] for v in ('private', 'private_rclpy_take', 'public')}
    for k in range(rounds):
        for v in (list(got) if k % 2 == 0 else list(got)[::-1]):
            got[v] += stall(v, 1)
    for v, ms in got.items():
        what = {'private': 'private wait set, taken without the GIL (gil_free_take)',
                'private_rclpy_take': 'private wait set, taken by rclpy (GIL held)',
                'public': 'public executor, taken by rclpy (GIL held)'}[v]
        print(f"[{name}]   {what}: {', '.join(f'{x:.0f}' for x in ms)} ms", flush=True)
    print(f'[{name}] load {os.getloadavg()[0]:.1f} at the end', flush=True)


def say(r):
    print(f"  {r['path']:7s} CPU/decision {r['cpu_ms']:.2f} ms ({r['decisions']} cmd_vel); pose -> cmd_vel "
          f"median {r['median']:.2f} ms, p99 {r['p99']:.2f} ms (n={r['n']}, {r['lost']} unanswered); "
          f"50 MB: longest cmd_vel gap {r['gap_ms']:.0f} ms (poses sent at most {r['send_gap_ms']:.0f} ms "
          f"apart{'' if r['arrived'] else '; NOT counted rejected in time'}); load {r['load']:.1f}", flush=True)


def condition(name, pairs, samples):
    print(f'[{name}] {pairs} pairs, load {os.getloadavg()[0]:.1f} at the start', flush=True)
    runs = []
    for k in range(pairs):
        order = PATHS if k % 2 == 0 else PATHS[::-1]
        print(f'[{name}] pair {k + 1}', flush=True)
        pair = {}
        for path in order:
            pair[path] = run(path, samples)
            say(pair[path])
        runs.append(pair)
    wins = {key: sum(p['private'][key] < p['public'][key] for p in runs) for key in ('cpu_ms', 'p99', 'gap_ms')}
    for path in PATHS:
        rs = [p[path] for p in runs]

        def span(key, fmt='.2f'):
            vals = [r[key] for r in rs]
            return f'{min(vals):{fmt}}-{max(vals):{fmt}}'
        print(f"[{name}] {path}: CPU/decision {span('cpu_ms')} ms, median {span('median')} ms, p99 "
              f"{span('p99')} ms, 50 MB gap {span('gap_ms', '.0f')} ms", flush=True)
    print(f"[{name}] private lower in {wins['cpu_ms']}/{pairs} pairs (CPU/decision), {wins['p99']}/{pairs} "
          f"(p99), {wins['gap_ms']}/{pairs} (50 MB gap)", flush=True)
    return runs


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--pairs', type=int, default=3, help='pairs (private, public) per condition')
    parser.add_argument('--samples', type=int, default=400, help='latency samples per run')
    parser.add_argument('--only', choices=('rest', 'burners'), help='one condition only')
    parser.add_argument('--stall-rounds', type=int, default=4, help='rounds of the take-alone stall per variant')
    parser.add_argument('--no-filter', action='store_true', help='only the take-alone stalls')
    parser.add_argument('--serve-vf', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.serve_vf:
        serve_big_value_function()
        return
    ensure_local_ros_env()
    import rclpy
    rclpy.init()
    try:
        if args.only in (None, 'rest'):
            if not args.no_filter:
                condition('rest', args.pairs, args.samples)
            stalls('rest', args.stall_rounds)
        if args.only in (None, 'burners'):
            burners = [subprocess.Popen(['yes'], stdout=subprocess.DEVNULL) for _ in range(2)]
            try:
                if not args.no_filter:
                    condition('2 burners', args.pairs, args.samples)
                stalls('2 burners', args.stall_rounds)
            finally:
                for b in burners:      # only the burners this bench started
                    b.kill()
                    b.wait()
    finally:
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
