"""A robot's sensors -> cmd_vel through a safety_filter_node process, checkouts side by side (prints
figures; no assertions).

    .venv/bin/python bench/bench_sensors.py                                  # this checkout
    .venv/bin/python bench/bench_sensors.py --checkout /work/base . --samples 200
    .venv/bin/python bench/bench_sensors.py --only scan360 --skip-drive

Three parts, each run for every checkout (the filter process with PYTHONPATH = that checkout: its
supersafe_ros; the checkouts alternate input by input so that the machine's load falls on both):

* **latency**: per input a filter process (``publish_on_pose``, the default ``direct_take``), fed by
  this process at ``--rate``: a detections message (the sensor's), then at once a pose. Printed:
  the time from the detections message's publish to the first cmd_vel after it (a filter that
  decides on each sensor message answers the message itself; one that does not answers the pose:
  today's figure either way), median and p99; the filter process's CPU time (/proc/<pid>/stat) per
  sample and per decision (a cmd_vel), the local map value's background solves apart (its thread,
  ``map_value``, read from /proc/<pid>/task). Inputs: ``pose_array`` (5 centres), ``markers`` (5 discs of
  three sizes), ``scan360`` and ``scan1440`` (a LaserScan ray-cast against the same discs from the
  pose, range 10 m), ``cloud100k`` (a PointCloud2 of 100,000 float32 points: the discs' surfaces and
  scattered points, 16-byte points).
* **drive**: the filter as config/nav2_safety_filter.yaml sets it (a managed node, configured and
  activated through its lifecycle services), a robot driving at 0.5 m/s through the discs: odometry
  at 50 Hz, a 360-beam scan at 10 Hz, TwistStamped at 20 Hz, for ``--drive-seconds``; then
  deactivated, the same feed. Printed: the filter's CPU share of a core while active (its map value's
  solves said apart: its thread, or its worker process, a child counted in) and while inactive, and
  its cmd_vel per second.
* **value**: the local map's value of the nav2 robot (speed 0.5, w_max 1, clearance 0.25, 10 m map at
  5 cm, value grid 0.1 m x 32 headings, horizon 3 s) solved in this process: a first solve and a
  re-solve after a scan moved the robot 0.1 m (``filter.sensing.map_value.solve_map_value``), with the
  checkout's own modules; a checkout without them says so.

Times between processes on CLOCK_MONOTONIC; /proc/loadavg on every line.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import time

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from bench_nodes import Driver, ms, node_cmd, stop  # noqa: E402
from supersafe_ros.rosenv import ensure_local_ros_env  # noqa: E402

DISCS = np.array([(4.0, 1.0, 1.8), (6.0, -3.0, 0.8), (8.0, 4.0, 2.6), (-5.0, 2.0, 1.8), (1.0, -6.0, 0.8)])
POSE = (0.0, 0.0, 0.0)
INPUTS = ('pose_array', 'markers', 'scan360', 'scan1440', 'cloud100k')
DRIVEN = ('scan360', 'scan1440', 'cloud100k')       # the inputs driven through the nav2 filter


def load() -> str:
    with open('/proc/loadavg') as f:
        return 'load ' + ' '.join(f.read().split()[:3])


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process (/proc/<pid>/stat, fields 14 and 15)."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def thread_cpu_seconds(pid: int, name: str) -> float:
    """User + system CPU seconds of the process's threads named ``name`` (/proc/<pid>/task/*/comm)."""
    total = 0.0
    for tid in os.listdir(f'/proc/{pid}/task'):
        try:
            with open(f'/proc/{pid}/task/{tid}/comm') as f:
                if f.read().strip() != name:
                    continue
            with open(f'/proc/{pid}/task/{tid}/stat') as f:
                fields = f.read().rsplit(')', 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
        except OSError:        # (a thread that ended)
            continue
    return total


def children_cpu_seconds(pid: int) -> float:
    """CPU seconds of the process's children (the map value's solver process, the cluster solver's)."""
    total = 0.0
    for task in os.listdir(f'/proc/{pid}/task'):
        try:
            with open(f'/proc/{pid}/task/{task}/children') as f:
                kids = [int(k) for k in f.read().split()]
        except OSError:
            continue
        for kid in kids:
            try:
                total += cpu_seconds(kid)
            except OSError:
                continue
    return total


def commit_of(checkout: Path) -> str:
    out = subprocess.run(['git', '-C', str(checkout), 'rev-parse', '--short', 'HEAD'], capture_output=True, text=True)
    dirty = subprocess.run(['git', '-C', str(checkout), 'status', '--porcelain', '--untracked-files=no'],
                           capture_output=True, text=True).stdout.strip()
    return (out.stdout.strip() or checkout.name) + ('+' if dirty else '')


def start_filter(checkout: Path, args_list, log_name):
    env = dict(os.environ, PYTHONPATH=str(checkout))
    ensure_local_ros_env(env)
    log = open(os.path.join('/tmp', f'bench_sensors_{log_name}.log'), 'w')
    return subprocess.Popen([sys.executable] + args_list, env=env, stdout=log, stderr=subprocess.STDOUT,
                            cwd=str(checkout))


def scan_message(beams, pose, stamp, discs=DISCS):
    from sensor_msgs.msg import LaserScan
    from supersafe_ros.sim.laser import beam_angles, ray_cast
    angles = beam_angles(beams)
    m = LaserScan()
    m.header.frame_id, m.header.stamp = 'laser', stamp
    m.angle_min, m.angle_increment, m.angle_max = float(angles[0]), float(angles[1] - angles[0]), float(angles[-1])
    m.range_min, m.range_max = 0.05, 10.0
    m.ranges = ray_cast(pose, angles, discs[:, :2], discs[:, 2], 10.0).tolist()
    return m


def detections_message(kind, stamp):
    """(message class, filter detections_type, a message) of the input ``kind``."""
    from geometry_msgs.msg import PoseArray
    from sensor_msgs.msg import LaserScan
    from visualization_msgs.msg import MarkerArray
    from supersafe_ros.nodes.markers import obstacles_to_markers
    from supersafe_ros.ros_io import rosmsg
    if kind == 'pose_array':
        return PoseArray, 'pose_array', rosmsg.xy_to_posearray(DISCS[:, :2], stamp)
    if kind == 'markers':
        out = MarkerArray()
        for i, (x, y, r) in enumerate(DISCS):
            out.markers.append(obstacles_to_markers([i], [(x, y)], r, stamp).markers[1])
        return MarkerArray, 'marker_array', out
    if kind.startswith('scan'):
        return LaserScan, 'laser_scan', scan_message(int(kind[4:]), POSE, stamp)
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


def bench_latency(kind, checkout, label, args):
    from geometry_msgs.msg import PoseStamped, Twist
    from rclpy.qos import qos_profile_sensor_data
    from supersafe_ros.ros_io import rosmsg
    ns = f'/bench_{kind}'
    d = Driver(f'bench_sensors_{kind}')
    msg_type, dtype, det = detections_message(kind, d.node.get_clock().now().to_msg())
    proc = start_filter(checkout, node_cmd('safety_filter_node', ns, publish_on_pose=True, rate=1.0,
                                           detections_type=dtype, cmd_timeout=30.0, pose_timeout=30.0,
                                           detections_timeout=30.0, hold_timeout=30.0, level_set_markers=False,
                                           time_before_collision=0.5), f'latency_{kind}')
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
        lat, cpu0, made, outputs = [], None, 0, 0
        for i in range(args.samples + args.warm):
            if i == args.warm:
                cpu0, outputs, solver0 = cpu_seconds(proc.pid), 0, thread_cpu_seconds(proc.pid, 'map_value')
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
            outputs += len(got)
        solver = thread_cpu_seconds(proc.pid, 'map_value') - solver0
        cpu = cpu_seconds(proc.pid) - cpu0 - solver
        print(f'{kind:10s} {label:12s} detections -> cmd_vel {ms(lat)}; filter CPU {cpu / max(1, made) * 1e3:.2f} ms '
              f'a sample, {cpu / max(1, outputs) * 1e3:.2f} ms a decision ({outputs / max(1, made):.2f} decisions a '
              f'sample), the map value\'s background solves {solver / max(1, made) * 1e3:.2f} ms a sample  '
              f'[{load()}]', flush=True)
    finally:
        d.close()
        stop([proc])


def cloud_message(pose, stamp, world_xy):
    """A PointCloud2 in the sensor's frame of the world-fixed points ``world_xy`` seen from ``pose``."""
    from std_msgs.msg import Header
    from sensor_msgs.msg import PointCloud2, PointField
    x, y, th = pose
    c, s = np.cos(th), np.sin(th)
    dx, dy = world_xy[:, 0] - x, world_xy[:, 1] - y
    n = len(world_xy)
    points = np.zeros(n, dtype=[('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('i', '<f4')])
    points['x'], points['y'] = c * dx + s * dy, -s * dx + c * dy
    m = PointCloud2(header=Header(frame_id='lidar', stamp=stamp), height=1, width=n, is_bigendian=False,
                    point_step=16, row_step=16 * n, is_dense=True, data=points.tobytes())
    m.fields = [PointField(name=c, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, c in enumerate('xyz')]
    return m


def cloud_points(n=100_000):
    """The discs' surfaces and scattered points, world-fixed (the cloud100k input's)."""
    rng = np.random.default_rng(0)
    k = rng.integers(0, len(DISCS), n)
    a = rng.uniform(-np.pi, np.pi, n)
    xy = DISCS[k, :2] + DISCS[k, 2:3] * np.column_stack([np.cos(a), np.sin(a)])
    xy[: n // 10] = rng.uniform(-10, 10, (n // 10, 2))
    return xy


def bench_drive(kind, checkout, label, args):
    """The nav2 filter (managed), a robot driving at 0.5 m/s past the discs: each sensor message -> the first
    cmd_vel after it, the CPU per decision, the CPU while active (its map value's solves apart) and inactive."""
    from geometry_msgs.msg import TwistStamped
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import LaserScan, PointCloud2
    from supersafe_ros.ros_io import rosmsg
    d = Driver(f'bench_sensors_drive_{kind}')
    cloud = kind == 'cloud100k'
    # the root namespace: the nav2 file's parameters are those of a node named safety_filter there
    proc = start_filter(checkout, ['-c', 'from supersafe_ros.nodes.safety_filter_node import main_managed; '
                                         'raise SystemExit(main_managed())', '--ros-args',
                                   '--params-file', str(checkout / 'config' / 'nav2_safety_filter.yaml'),
                                   '-r', 'pose:=odom', '-r', f'detections:={"cloud" if cloud else "scan"}']
                        + (['-p', 'detections_type:=point_cloud2', '-p', 'max_sensor_points:=200000'] if cloud else []),
                        f'drive_{kind}')
    world = cloud_points() if cloud else None
    try:
        odom = d.node.create_publisher(Odometry, 'odom', rosmsg.QOS_STREAM)
        sensor = d.node.create_publisher(PointCloud2 if cloud else LaserScan, 'cloud' if cloud else 'scan',
                                         qos_profile_sensor_data)
        cmd = d.node.create_publisher(TwistStamped, 'cmd_vel_nav', rosmsg.QOS_STREAM)
        got = []
        sub = d.node.create_subscription(TwistStamped, 'cmd_vel', lambda m: got.append(time.monotonic_ns()),
                                         rosmsg.QOS_STREAM)
        change = d.node.create_client(ChangeState, '/safety_filter/change_state')
        d.spin_until(lambda: change.service_is_ready(), 120.0, 'the managed filter')

        def transition(tid):
            future = change.call_async(ChangeState.Request(transition=Transition(id=tid)))
            d.spin_until(lambda: future.done(), 60.0, f'transition {tid}')
            return future.result().success
        if not (transition(Transition.TRANSITION_CONFIGURE) and transition(Transition.TRANSITION_ACTIVATE)):
            print(f'{kind:10s} {label:12s} the managed filter did not configure and activate', flush=True)
            return
        d.spin_until(lambda: odom.get_subscription_count() and sensor.get_subscription_count()
                     and cmd.get_subscription_count() and sub.get_publisher_count(), 60.0, 'drive: matched')
        beams = 0 if cloud else int(kind[4:])
        latencies = []

        def feed(seconds, measure):
            t_start, k, pending = time.monotonic(), 0, None
            while time.monotonic() - t_start < seconds:
                now = time.monotonic()
                x = -6.0 + (0.5 * (now - t_start)) % 12.0
                pose = (x, -1.5, 0.0)
                stamp = d.node.get_clock().now().to_msg()
                m = Odometry()
                m.header.frame_id, m.header.stamp, m.child_frame_id = 'odom', stamp, 'base_link'
                m.pose.pose = rosmsg.state_to_pose(pose).pose
                m.twist.twist.linear.x = 0.5
                odom.publish(m)
                if k % 2 == 0:
                    c = TwistStamped()
                    c.header.frame_id, c.header.stamp = 'base_link', stamp
                    c.twist.linear.x = 0.5
                    cmd.publish(c)
                if k % 5 == 0:          # the sensor, stamped as this odometry (built before the clock starts)
                    msg = (cloud_message((x + 0.1, -1.5, 0.0), stamp, world) if cloud
                           else scan_message(beams, (x + 0.1, -1.5, 0.0), stamp))
                    before = len(got)
                    sent = time.monotonic_ns()
                    sensor.publish(msg)
                    pending = (before, sent)
                k += 1
                while time.monotonic() < t_start + k * 0.02:
                    d.executor.spin_once(timeout_sec=0.001)
                    if pending is not None and len(got) > pending[0]:
                        if measure:
                            latencies.append((got[pending[0]] - pending[1]) * 1e-9)
                        pending = None
        feed(3.0, False)                   # warm-up: the first value solved
        got.clear()
        c0, s0, k0, t0 = (cpu_seconds(proc.pid), thread_cpu_seconds(proc.pid, 'map_value'),
                          children_cpu_seconds(proc.pid), time.monotonic())
        feed(args.drive_seconds, True)
        active_t, decisions = time.monotonic() - t0, len(got)
        # the value's solves: its thread in the filter's process, or its worker process (a child)
        kids = children_cpu_seconds(proc.pid) - k0
        solver = thread_cpu_seconds(proc.pid, 'map_value') - s0 + kids
        active_cpu = cpu_seconds(proc.pid) - c0 + kids
        transition(Transition.TRANSITION_DEACTIVATE)
        got.clear()
        c0, k0, t0 = cpu_seconds(proc.pid), children_cpu_seconds(proc.pid), time.monotonic()
        feed(args.drive_seconds, False)
        idle_cpu = cpu_seconds(proc.pid) - c0 + children_cpu_seconds(proc.pid) - k0
        idle_t = time.monotonic() - t0
        print(f'{kind:10s} {label:12s} sensor message -> cmd_vel {ms(latencies)}; CPU per decision '
              f'{(active_cpu - solver) / max(1, decisions) * 1e3:.2f} ms ({decisions / active_t:.0f} a second); '
              f'active {100 * active_cpu / active_t:.1f} % of a core (the map value\'s solves '
              f'{100 * solver / active_t:.1f} %), inactive {100 * idle_cpu / idle_t:.1f} % ({len(got)} cmd_vel)  '
              f'[{load()}]', flush=True)
    finally:
        d.close()
        stop([proc])


def bench_value(checkout, label):
    """The nav2 robot's map value, solved in a process of the checkout."""
    code = r'''
import json, time, numpy as np
try:
    from supersafe_ros.filter.sensing.local_map import LocalMap, MapSettings
    from supersafe_ros.filter.sensing.map_value import MapValueSettings, solve_map_value
    from supersafe_ros.filter.sensing.readings import scan_rays
except ImportError as exc:
    print(json.dumps({'none': str(exc)})); raise SystemExit(0)
from supersafe_ros.sim.laser import beam_angles, ray_cast
discs = np.array(%s)
a = beam_angles(360)
m = LocalMap(MapSettings(cell=0.05, size=10.0))
def scan(x):
    r = ray_cast((x, 0.0, 0.0), a, discs[:, :2], discs[:, 2], 10.0)
    m.follow(x, 0.0)
    m.integrate_rays((x, 0.0, 0.0), scan_rays(r, float(a[0]), float(a[-1]), float(a[1] - a[0]), 0.05, 10.0))
s = MapValueSettings(cell=0.1, headings=32, horizon=3.0)
times = {'first': [], 'again': []}
for k in range(5):
    scan(0.0)
    t0 = time.perf_counter(); v = solve_map_value(m.snapshot(), (0.0, 0.0), 0.5, 1.0, 0.25, s)
    times['first'].append(time.perf_counter() - t0)
    for j in range(1, 6):
        scan(0.1 * j)
        t0 = time.perf_counter(); v = solve_map_value(m.snapshot(), (0.1 * j, 0.0), 0.5, 1.0, 0.25, s, previous=v)
        times['again'].append(time.perf_counter() - t0)
    m = LocalMap(MapSettings(cell=0.05, size=10.0))
figures = {k: [float(np.median(t)), float(max(t))] for k, t in times.items()}
print(json.dumps(figures | {'shape': list(v.vf.grid.shape)}))
''' % DISCS.tolist()
    out = subprocess.run([sys.executable, '-c', code], env=dict(os.environ, PYTHONPATH=str(checkout)),
                         capture_output=True, text=True, cwd=str(checkout))
    line = out.stdout.strip().splitlines()[-1] if out.stdout.strip() else json.dumps({'none': out.stderr[-300:]})
    r = json.loads(line)
    if 'none' in r:
        print(f'value      {label:12s} no local map value in this checkout  [{load()}]', flush=True)
        return
    print(f'value      {label:12s} nav2 map value (grid {tuple(r["shape"])}): first solve median '
          f'{r["first"][0] * 1e3:.1f} '
          f'ms (max {r["first"][1] * 1e3:.1f}), re-solve after 0.1 m median {r["again"][0] * 1e3:.1f} ms '
          f'(max {r["again"][1] * 1e3:.1f})  [{load()}]', flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--checkout', nargs='+', default=[str(HERE.parent)], help='checkouts, side by side')
    parser.add_argument('--only', nargs='+', choices=INPUTS, default=list(INPUTS))
    parser.add_argument('--samples', type=int, default=300)
    parser.add_argument('--warm', type=int, default=20, help='samples not counted (the first messages)')
    parser.add_argument('--rate', type=float, default=20.0, help='messages per second [Hz]')
    parser.add_argument('--drive-seconds', type=float, default=20.0)
    parser.add_argument('--skip-drive', action='store_true')
    parser.add_argument('--skip-latency', action='store_true')
    args = parser.parse_args(argv)
    ensure_local_ros_env()
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 80))
    checkouts = [Path(c).resolve() for c in args.checkout]
    labels = {c: commit_of(c) for c in checkouts}
    import rclpy
    rclpy.init()
    print(f"bench_sensors: ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}, {os.cpu_count()} cores, checkouts "
          + ', '.join(f'{labels[c]} ({c})' for c in checkouts) + f'  [{load()}]', flush=True)
    try:
        order = list(checkouts)
        for c in order:
            bench_value(c, labels[c])
        if not args.skip_latency:
            for kind in args.only:
                for c in order:
                    bench_latency(kind, c, labels[c], args)
                order.reverse()              # the next input in the other order: the load falls on both
        if not args.skip_drive:
            for kind in [k for k in args.only if k in DRIVEN]:
                for c in order:
                    bench_drive(kind, c, labels[c], args)
                order.reverse()
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
