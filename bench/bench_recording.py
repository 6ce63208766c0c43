"""Figures for recording and the level-set markers (prints them; no assertions).

    .venv/bin/python bench/bench_recording.py [--messages N] [--rate HZ]

Sections:
  writer     the ROS-free BagWriter: PoseStamped CDR messages written per second (zstd chunks).
  recorder   start_recorder in this process, a publisher in another process sending N poses
             at a given rate (0: as fast as it can; keep last 200 reliable, as the robots):
             how many reach the bag, and the recorder's CPU share of a core while it records.
             Bursts beyond what one Python thread takes (a few thousand per second) overflow
             the queues (the recorder's 1000, the publisher's 200) and lose messages.
  contour    runtime.contours.level_set_contour on the standard set (65 x 65 x 42): ms per call.

Runs in its own ROS_DOMAIN_ID with loopback-only discovery. Say the load (printed).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

PUBLISHER = textwrap.dedent('''
    import sys, time
    import rclpy
    from rclpy.duration import Duration
    from geometry_msgs.msg import PoseStamped
    from supersafe_ros.ros_io import rosmsg
    n, rate = int(sys.argv[1]), float(sys.argv[2])
    rclpy.init()
    node = rclpy.create_node('bench_pose_publisher')
    pub = node.create_publisher(PoseStamped, '/bench/pose', rosmsg.QOS_EVERY_SAMPLE)
    deadline = time.monotonic() + 60
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    t0 = time.monotonic()
    for i in range(n):
        pub.publish(rosmsg.state_to_pose((0.01 * i, 0.0, 0.0)))
        if rate > 0:
            time.sleep(max(0.0, t0 + (i + 1) / rate - time.monotonic()))
    pub.wait_for_all_acked(Duration(seconds=30))
    print(f'{time.monotonic() - t0:.3f}', flush=True)
''')


def load() -> str:
    return open('/proc/loadavg').read().split(' ')[0]


def bench_writer(n: int):
    from rclpy.serialization import serialize_message
    from supersafe_ros.recording.bag import BagWriter
    from supersafe_ros.ros_io import rosmsg
    data = serialize_message(rosmsg.state_to_pose((1.0, 2.0, 0.3)))
    with tempfile.TemporaryDirectory() as d:
        bag = BagWriter(Path(d) / 'b')
        bag.add_topic('/pose', 'geometry_msgs/msg/PoseStamped')
        t0 = time.perf_counter()
        for i in range(n):
            bag.write('/pose', data, i)
        bag.close()
        dt = time.perf_counter() - t0
        size = (Path(d) / 'b' / 'b.mcap').stat().st_size
    print(f'writer: {n} PoseStamped in {dt:.3f} s = {n / dt:,.0f} msg/s; file {size / n:.1f} B/msg '
          f'(load {load()})')


def cpu_seconds() -> float:
    t = os.times()
    return t.user + t.system


def bench_recorder(n: int, rate: float):
    from supersafe_ros.ros_io.bag_recorder import start_recorder
    with tempfile.TemporaryDirectory() as d:
        rec = start_recorder(Path(d) / 'b', poll_period=0.1)
        proc = subprocess.Popen([sys.executable, '-c', PUBLISHER, str(n), str(rate)],
                                stdout=subprocess.PIPE, text=True, env=os.environ.copy())
        c0, w0 = cpu_seconds(), time.monotonic()
        out, _ = proc.communicate(timeout=300)
        # until every message is in, or none came for a second (the rest were lost)
        last, last_t = -1, time.monotonic()
        while rec.message_count('/bench/pose') < n and time.monotonic() - last_t < 1.0:
            if rec.message_count('/bench/pose') != last:
                last, last_t = rec.message_count('/bench/pose'), time.monotonic()
            time.sleep(0.01)
        wall, cpu = last_t - w0, cpu_seconds() - c0
        got = rec.message_count('/bench/pose')
        rec.stop()
    print(f'recorder: {got}/{n} poses recorded; publisher sent them in {float(out.strip() or "nan"):.2f} s '
          f'(rate {"max" if rate <= 0 else f"{rate:g} Hz"}); recorder process CPU {cpu / wall:.0%} of a core '
          f'(load {load()})')


def bench_contour(repeat: int = 20):
    from supersafe_ros.runtime.contours import level_set_contour
    from supersafe_ros.nodes.filter_wiring import standard_value_function
    vf = standard_value_function([-8.0, -8.0], [8.0, 8.0], [65, 65, 42], 3.0, 1.0, 1.8, 3.0)
    times = []
    for i in range(repeat):
        t0 = time.perf_counter()
        level_set_contour(vf, -3.0 + 6.0 * i / repeat, 0.0)
        times.append(time.perf_counter() - t0)
    print(f'contour: level_set_contour on 65 x 65 x 42 (refine 2): median {np.median(times) * 1e3:.1f} ms, '
          f'max {max(times) * 1e3:.1f} ms over {repeat} headings (load {load()})')


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--messages', type=int, default=5000)
    ap.add_argument('--rate', type=float, default=0.0, help='publisher rate [Hz] (0: as fast as it can)')
    ap.add_argument('--only', nargs='*', default=['writer', 'recorder', 'contour'])
    args = ap.parse_args()
    from supersafe_ros.rosenv import ensure_local_ros_env
    ensure_local_ros_env()
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 40))
    if 'writer' in args.only:
        bench_writer(20 * args.messages)
    if 'recorder' in args.only:
        bench_recorder(args.messages, args.rate)
    if 'contour' in args.only:
        bench_contour()


if __name__ == '__main__':
    main()
