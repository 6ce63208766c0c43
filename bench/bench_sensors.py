"""Scan / cloud -> cmd_vel through a safety_filter_node process (prints figures; no assertions).

    .venv/bin/python bench/bench_sensors.py                 # every input
    .venv/bin/python bench/bench_sensors.py --only scan360 --samples 200

For each input the filter runs in its own process (``publish_on_pose``, the default
``direct_take``), fed by this process: a detections message (the sensor's), then at once a
pose; the filter takes them in that order and answers the pose with cmd_vel. Printed:

* latency: detections message published -> cmd_vel received (so it holds the sensor
  message's transport, its returns made covering discs, and the decision), median and p99;
* CPU per decision: the filter process's CPU time (user + system, /proc/<pid>/stat) over the
  samples, divided by the decisions (each one taking one sensor message and one pose).

Inputs: ``pose_array`` (today's: 5 centres, the PoseArray figures of bench_nodes.py), ``markers``
(5 discs of three sizes), ``scan360`` and ``scan1440`` (a LaserScan ray-cast against the same
discs from the pose, range 10 m), ``cloud100k`` (a PointCloud2 of 100,000 float32 points: the
discs' surfaces and scattered points, 16-byte points). Times between processes on
CLOCK_MONOTONIC.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

from bench_nodes import Driver, ms, node_cmd, start, stop  # noqa: E402
from supersafe_ros.rosenv import ensure_local_ros_env  # noqa: E402

DISCS = np.array([(4.0, 1.0, 1.8), (6.0, -3.0, 0.8), (8.0, 4.0, 2.6), (-5.0, 2.0, 1.8), (1.0, -6.0, 0.8)])
POSE = (0.0, 0.0, 0.0)
INPUTS = ('pose_array', 'markers', 'scan360', 'scan1440', 'cloud100k')


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process (/proc/<pid>/stat, fields 14 and 15)."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def detections_message(kind, stamp):
    """(message class, filter detections_type, a message) of the input ``kind``."""
    from geometry_msgs.msg import PoseArray
    from sensor_msgs.msg import LaserScan
    from visualization_msgs.msg import MarkerArray
    from supersafe_ros.nodes.markers import obstacles_to_markers
    from supersafe_ros.ros_io import rosmsg
    from supersafe_ros.sim.laser import beam_angles, ray_cast
    if kind == 'pose_array':
        return PoseArray, 'pose_array', rosmsg.xy_to_posearray(DISCS[:, :2], stamp)
    if kind == 'markers':
        out = MarkerArray()
        for i, (x, y, r) in enumerate(DISCS):
            m = obstacles_to_markers([i], [(x, y)], r, stamp).markers[1]
            out.markers.append(m)
        return MarkerArray, 'marker_array', out
    if kind.startswith('scan'):
        beams = int(kind[4:])
        angles = beam_angles(beams)
        m = LaserScan()
        m.header.frame_id, m.header.stamp = 'laser', stamp
        m.angle_min, m.angle_increment, m.angle_max = float(angles[0]), float(angles[1] - angles[0]), float(angles[-1])
        m.range_min, m.range_max = 0.05, 10.0
        m.ranges = ray_cast(POSE, angles, DISCS[:, :2], DISCS[:, 2], 10.0).tolist()
        return LaserScan, 'laser_scan', m
    from std_msgs.msg import Header
    from sensor_msgs.msg import PointCloud2, PointField
    rng = np.random.default_rng(0)
    n = 100_000
    k = rng.integers(0, len(DISCS), n)
    a = rng.uniform(-np.pi, np.pi, n)
    xy = DISCS[k, :2] + DISCS[k, 2:3] * np.column_stack([np.cos(a), np.sin(a)])
    xy[: n // 10] = rng.uniform(-10, 10, (n // 10, 2))      # scattered returns
    points = np.zeros(n, dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('i', '<f4')])
    points['x'], points['y'] = xy[:, 0], xy[:, 1]
    m = PointCloud2(header=Header(frame_id='lidar', stamp=stamp), height=1, width=n, is_bigendian=False,
                    point_step=16, row_step=16 * n, is_dense=True, data=points.tobytes())
    m.fields = [PointField(name=c, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, c in enumerate('xyz')]
    return PointCloud2, 'point_cloud2', m


def bench_input(kind, args):
    from geometry_msgs.msg import PoseStamped, Twist
    from rclpy.qos import qos_profile_sensor_data
    from supersafe_ros.ros_io import rosmsg
    ns = f'/bench_{kind}'
    d = Driver(f'bench_sensors_{kind}')
    msg_type, dtype, det = detections_message(kind, d.node.get_clock().now().to_msg())
    proc = start(node_cmd('safety_filter_node', ns, publish_on_pose=True, rate=1.0, detections_type=dtype,
                          cmd_timeout=30.0, pose_timeout=30.0, detections_timeout=30.0, hold_timeout=30.0,
                          level_set_markers=False, obstacle_depth=args.obstacle_depth,
                          time_before_collision=args.time_before_collision), f'sensors_{kind}')
    try:
        qos = qos_profile_sensor_data if dtype in ('laser_scan', 'point_cloud2') else rosmsg.QOS_STREAM
        det_pub = d.node.create_publisher(msg_type, f'{ns}/detections', qos)
        pose_pub = d.node.create_publisher(PoseStamped, f'{ns}/pose', rosmsg.QOS_STREAM)
        cmd_pub = d.node.create_publisher(Twist, f'{ns}/cmd_vel_nav', rosmsg.QOS_STREAM)
        got = []
        sub = d.node.create_subscription(Twist, f'{ns}/cmd_vel', lambda m: got.append(time.monotonic_ns()),
                                         rosmsg.QOS_STREAM)
        d.spin_until(lambda: all(p.get_subscription_count() for p in (det_pub, pose_pub, cmd_pub))
                     and sub.get_publisher_count(), 120.0, f'{kind}: the filter to match')
        cmd_pub.publish(rosmsg.turn_rate_to_twist(0.2, 3.0))
        lat, cpu0, made = [], None, 0
        for i in range(args.samples + args.warm):
            if i == args.warm:
                cpu0 = cpu_seconds(proc.pid)
            stamp = d.node.get_clock().now().to_msg()
            for header in ([m.header for m in det.markers] if kind == 'markers' else [det.header]):
                header.stamp = stamp          # (the same message, stamped anew: building 100k points is not timed)
            pose = rosmsg.state_to_pose(POSE, stamp)
            got.clear()
            t0 = time.monotonic_ns()
            det_pub.publish(det)
            pose_pub.publish(pose)
            try:
                d.spin_until(lambda: got, 5.0, 'cmd_vel')
            except TimeoutError:
                continue
            if i >= args.warm:
                lat.append((got[0] - t0) * 1e-9)
                made += 1
            d.spin_for(max(0.0, 1.0 / args.rate - (time.monotonic_ns() - t0) * 1e-9))
        cpu = (cpu_seconds(proc.pid) - cpu0) / max(1, made)
        print(f'[{kind}, obstacle_depth {args.obstacle_depth:g}, time_before_collision '
              f'{args.time_before_collision:g}] detections -> cmd_vel: {ms(lat)}; filter CPU per '
              f'decision {cpu * 1e3:.2f} ms '
              f'(load {os.getloadavg()[0]:.1f})', flush=True)
        return lat, cpu
    finally:
        d.close()
        stop([proc])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--only', nargs='+', choices=INPUTS, default=list(INPUTS))
    parser.add_argument('--samples', type=int, default=300)
    parser.add_argument('--warm', type=int, default=20, help='samples not counted (the first messages)')
    parser.add_argument('--rate', type=float, default=20.0, help='messages per second [Hz]')
    parser.add_argument('--obstacle-depth', type=float, default=0.0,
                        help='the filter\'s obstacle_depth: each return stands for its beam this far behind it [m]')
    parser.add_argument('--time-before-collision', type=float, default=0.0,
                        help='the filter\'s time_before_collision: > 0 cuts each command\'s speed so that its '
                        'path enters no disc (filter/approach.py) [s]')
    args = parser.parse_args(argv)
    ensure_local_ros_env()
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 80))
    import rclpy
    rclpy.init()
    print(f"bench_sensors: ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}, {os.cpu_count()} cores, "
          f'load average {os.getloadavg()[0]:.1f}', flush=True)
    try:
        for kind in args.only:
            bench_input(kind, args)
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
