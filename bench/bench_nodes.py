"""Figures for the safety filter and the learner nodes (prints them; no assertions).

    .venv/bin/python bench/bench_nodes.py            # every section
    .venv/bin/python bench/bench_nodes.py --only latency core

Sections:
  vfmsg    the value-function message at the library's 65 x 65 x 42 (710 KB of float32):
           conversion times, one-way delivery to another process over Fast DDS (late
           joiner included), exactness on arrival.
  latency  pose -> cmd_vel through a safety_filter_node process (publish_on_pose), and
           pose -> planner_node -> cmd_vel_nav -> filter -> cmd_vel (the team's chain).
  core     robots one process can filter at 50 Hz, compute only: step_many per robot for
           fleets of 10 to 2,000, clusters off / on with the fallback / on with union values.
  nodes    M SafetyFilterNode instances in ONE process (one executor), each fed pose and
           planner command at 50 Hz: output rate per robot and the process's CPU.
  fleet    fleet_safety_filter_node with M robots on per-robot topics (<ns>/pose, ...), in ONE
           process pinned to one core: decisions per robot per second, the process's CPU.
  batched  fleet_safety_filter_node with N robots on the batched topics (fleet/poses ->
           fleet/cmd_vel), pinned to one core: replies per second, pose -> reply latency.
  learner  intervention published -> new fit (/safe_set/fit) and value function received,
           with the paper's library (65 x 65 x 42, 13 entries).

Every process runs with loopback-only discovery in the bench's own ROS_DOMAIN_ID.
Times between processes use CLOCK_MONOTONIC (time.monotonic_ns), shared by all
processes of the machine.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from supersafe_ros.rosenv import ensure_local_ros_env  # noqa: E402

OBSTACLE = (3.0, -1.0)


def ms(values):
    v = np.asarray(values, dtype=float) * 1e3
    return (f'median {np.median(v):.2f} ms, p99 {np.percentile(v, 99):.2f} ms, max {v.max():.2f} ms '
            f'(n={len(v)})')


def child_env():
    env = dict(os.environ)
    ensure_local_ros_env(env)
    return env


def start(args, log_name):
    log = open(os.path.join(tempfile.gettempdir(), f'bench_nodes_{log_name}.log'), 'w')
    return subprocess.Popen([sys.executable] + args, env=child_env(), stdout=log, stderr=subprocess.STDOUT)


def stop(procs):
    for p in procs:
        if p.poll() is None:
            p.send_signal(2)   # SIGINT: the nodes shut down cleanly
    for p in procs:
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def node_cmd(module, ns=None, **params):
    cmd = ['-m', f'supersafe_ros.nodes.{module}', '--ros-args']
    if ns:
        cmd += ['-r', f'__ns:={ns}']
    for k, v in params.items():
        if isinstance(v, bool):
            v = 'true' if v else 'false'
        cmd += ['-p', f'{k}:={v}']
    return cmd


class Driver:
    """The bench's own node, spun by hand."""

    def __init__(self, name='bench_driver'):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        self.node = rclpy.create_node(name)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def spin_until(self, cond, timeout, what):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if cond():
                return True
            self.executor.spin_once(timeout_sec=0.005)
        if cond():
            return True
        raise TimeoutError(f'timed out after {timeout} s waiting for {what}')

    def spin_for(self, seconds):
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.002)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()


# -- vfmsg -------------------------------------------------------------------------------------
def serve_vf_echo():
    """Child: receive value functions, reply with the arrival time and whether they are exact."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from std_msgs.msg import Float32MultiArray
    from supersafe_ros.ros_io import rosmsg
    from supersafe_ros.reach.library import LibrarySpec, load_or_build_library
    from supersafe_ros.ros_io.vfmsg import msg_to_value_function
    ensure_local_ros_env()
    rclpy.init()
    reference = load_or_build_library(LibrarySpec()).entry(1.0).values
    node = rclpy.create_node('bench_vf_echo')
    reply = node.create_publisher(DiagnosticStatus, '/bench/vf_echo', rosmsg.QOS_EVENTS)

    def on_vf(msg):
        t_recv = time.monotonic_ns()
        vf = msg_to_value_function(msg)
        t_conv = time.monotonic_ns()
        exact = bool(np.array_equal(vf.values.view(np.uint32), reference.view(np.uint32)))
        reply.publish(rosmsg.make_diagnostic('echo', {'sent': vf.meta.get('sent_ns'), 'recv': t_recv,
                                                      'conv': t_conv, 'exact': exact}))
    node.create_subscription(Float32MultiArray, '/bench/vf', on_vf, rosmsg.QOS_LATCHED)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, Exception):
        pass
    finally:
        rclpy.try_shutdown()


def bench_vfmsg(args):
    from diagnostic_msgs.msg import DiagnosticStatus
    from std_msgs.msg import Float32MultiArray
    from supersafe_ros.ros_io import rosmsg
    from supersafe_ros.reach.library import LibrarySpec, load_or_build_library
    from supersafe_ros.ros_io.vfmsg import msg_to_value_function, value_function_to_msg
    vf = load_or_build_library(LibrarySpec()).entry(1.0)
    n_bytes = vf.values.nbytes
    to_t, from_t = [], []
    for _ in range(20):
        t0 = time.perf_counter()
        msg = value_function_to_msg(vf, source='learned', mu=0.3, sigma=0.1)
        t1 = time.perf_counter()
        msg_to_value_function(msg)
        t2 = time.perf_counter()
        to_t.append(t1 - t0)
        from_t.append(t2 - t1)
    print(f'[vfmsg] {vf.grid.shape} = {vf.values.size} float32 = {n_bytes / 1024:.0f} KiB '
          f'(+{len(msg.layout.dim[3].label)} B JSON metadata)')
    print(f'[vfmsg] value_function_to_msg {ms(to_t)}; msg_to_value_function (validated) {ms(from_t)}')

    d = Driver('bench_vf_pub')
    pub = d.node.create_publisher(Float32MultiArray, '/bench/vf', rosmsg.QOS_LATCHED)
    echoes = []
    sub = d.node.create_subscription(DiagnosticStatus, '/bench/vf_echo',
                                     lambda m: echoes.append(rosmsg.diagnostic_values(m)), rosmsg.QOS_EVENTS)
    # late joiner: publish before the subscriber process exists
    pub.publish(value_function_to_msg(vf, sent_ns=time.monotonic_ns()))
    child = start([os.path.abspath(__file__), '--serve-vf-echo'], 'vf_echo')
    try:
        d.spin_until(lambda: echoes, 60.0, 'the late joiner to receive the latched value function')
        late = echoes[-1]
        print(f"[vfmsg] late joiner received the latched message: exact={late['exact']}")
        d.spin_until(lambda: sub.get_publisher_count() and pub.get_subscription_count(), 10, 'matching')
        echoes.clear()
        for i in range(args.vf_repeats):
            pub.publish(value_function_to_msg(vf, sent_ns=time.monotonic_ns()))
            d.spin_until(lambda: len(echoes) > i, 10.0, 'an echo')
        one_way = [(int(e['recv']) - int(e['sent'])) * 1e-9 for e in echoes]
        convert = [(int(e['conv']) - int(e['recv'])) * 1e-9 for e in echoes]
        exact = all(e['exact'] == 'True' for e in echoes)
        print(f'[vfmsg] publish (incl. to_msg) -> subscriber callback in another process: {ms(one_way)}')
        print(f'[vfmsg] + msg_to_value_function in the subscriber: {ms(convert)}; all exact: {exact}')
    finally:
        stop([child])
        d.close()


# -- latency ---------------------------------------------------------------------------------
def bench_latency(args):
    from geometry_msgs.msg import PoseArray, PoseStamped, Twist
    from supersafe_ros.ros_io import rosmsg
    results = {}
    for chain in ('filter', 'planner+filter'):
        ns = '/bench_robot'
        procs = [start(node_cmd('safety_filter_node', ns, publish_on_pose=(chain == 'filter'), rate=1.0,
                                cmd_timeout=30.0, pose_timeout=30.0, detections_timeout=30.0,
                                hold_timeout=30.0, direct_take=not args.no_direct_take), 'latency_filter')]
        if chain != 'filter':
            procs.append(start(node_cmd('planner_node', ns), 'latency_planner'))
        d = Driver('bench_latency')
        try:
            pose_pub = d.node.create_publisher(PoseStamped, f'{ns}/pose', rosmsg.QOS_STREAM)
            det_pub = d.node.create_publisher(PoseArray, f'{ns}/detections', rosmsg.QOS_STREAM)
            got = []
            sub = d.node.create_subscription(Twist, f'{ns}/cmd_vel', lambda m: got.append(time.monotonic_ns()),
                                             rosmsg.QOS_STREAM)
            needed = [pose_pub, det_pub]
            if chain == 'filter':
                cmd_pub = d.node.create_publisher(Twist, f'{ns}/cmd_vel_nav', rosmsg.QOS_STREAM)
                needed.append(cmd_pub)
            else:
                goal_pub = d.node.create_publisher(PoseStamped, f'{ns}/goal', rosmsg.QOS_LATCHED)
                goal_pub.publish(rosmsg.state_to_pose((20.0, 0.0, 0.0)))
                needed.append(goal_pub)
            d.spin_until(lambda: all(p.get_subscription_count() for p in needed) and sub.get_publisher_count(),
                         60.0, f'{chain} to match (the filter loads the standard set first)')
            if chain == 'filter':
                cmd_pub.publish(rosmsg.turn_rate_to_twist(0.2, 3.0))
            det_pub.publish(rosmsg.xy_to_posearray([OBSTACLE]))
            d.spin_for(0.5)
            lat = {'pass': [], 'override': []}
            poses = {'pass': (OBSTACLE[0] - 7.5, OBSTACLE[1] + 7.0, 0.0),
                     'override': (OBSTACLE[0] - 3.0, OBSTACLE[1] + 0.6, 0.0)}
            for i in range(args.samples):
                kind = 'pass' if i % 2 else 'override'
                got.clear()
                t0 = time.monotonic_ns()
                pose_pub.publish(rosmsg.state_to_pose(poses[kind]))
                try:
                    d.spin_until(lambda: got, 2.0, 'cmd_vel')
                except TimeoutError:
                    continue
                lat[kind].append((got[0] - t0) * 1e-9)
                d.spin_for(max(0.0, 0.02 - (time.monotonic_ns() - t0) * 1e-9))   # 50 Hz
            results[chain] = lat
            both = lat['pass'] + lat['override']
            taker = 'the executor' if args.no_direct_take else 'their own thread'
            print(f'[latency] pose -> cmd_vel, {chain} (pose taken by {taker}): {ms(both)} '
                  f'(load {os.getloadavg()[0]:.1f})')
            print(f"[latency]    pass: {ms(lat['pass'])}; override: {ms(lat['override'])}")
        finally:
            d.close()
            stop(procs)
    return results


# -- core ---------------------------------------------------------------------------------------
def _core_fleet(n, rng, field, shared, **cfg):
    from supersafe_ros.filter import FilterConfig, RobotFilter
    config = FilterConfig(**cfg)
    filters = []
    for i in range(n):
        f = RobotFilter(config)
        f.update_pose((rng.uniform(-15, 15), rng.uniform(-10, 10), rng.uniform(-np.pi, np.pi)), 0.0)
        f.update_detections(field if shared else field[rng.choice(len(field), 3, replace=False)], 0.0)
        f.update_command(0.1, 0.0)
        filters.append(f)
    return filters


def _tick_times(step, filters, reps):
    """Median wall and CPU (process_time) seconds of one tick, and the load around it."""
    step(filters, 0.0)          # warm: cluster frames, first solves requested
    wall, cpu = [], []
    for r in range(reps):
        t = 0.02 * (r + 1)
        for f in filters:       # a new pose each tick (50 Hz), as in the fleet
            f.update_pose(f.pose.value, t)
        w0, c0 = time.perf_counter(), time.process_time()
        step(filters, t)
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return float(np.median(wall)), float(np.median(cpu)), os.getloadavg()[0]


def bench_core(args):
    """step_many per robot, compute only (no messages): clusters off, clusters on with the
    loiter fallback in force (union values not yet solved), clusters on with the union values
    in force (every robot sees the same 10 obstacles, as the batched fleet/detections give)."""
    from supersafe_ros.filter.clusters.geometry import ClusterSettings
    from supersafe_ros.filter.clusters.store import ClusterStore
    from supersafe_ros.filter import SafeSet, step_many
    from supersafe_ros.reach.grid import Grid
    from supersafe_ros.reach.library import load_or_solve
    vf = load_or_solve(Grid((-8, -8), (8, 8), (65, 65, 42)), 3.0, 1.0, 1.8, 3.0)
    safe = SafeSet(vf, 0.0)
    rng = np.random.default_rng(0)
    field = np.stack([rng.uniform(-12, 12, 10), rng.uniform(-8, 8, 10)], axis=1)   # ten obstacles
    budget = 1.0 / 50.0
    fallback = ClusterStore(ClusterSettings(), fallback_only=True)
    solved = ClusterStore(ClusterSettings(), background=False)    # inline solves (disk-cached)
    t0 = time.perf_counter()
    step_many(_core_fleet(1, rng, field, True), safe, 0.0, solved)
    print(f'[core] union values of the shared field solved or loaded in {time.perf_counter() - t0:.1f} s')
    print(f'[core] one process, one core of {os.cpu_count()} shared (load average {os.getloadavg()[0]:.1f}); '
          f'budget {budget * 1e3:.0f} ms per 50 Hz tick; wall (CPU) per tick, median')
    variants = [('clusters off', dict(clusters=False), False, None),
                ('clusters, fallback', {}, False, fallback),
                ('clusters, union', {}, True, solved)]
    best = {}
    for n in args.core_sizes:
        line = []
        for name, cfg, shared, store in variants:
            filters = _core_fleet(n, rng, field, shared, **cfg)
            wall, cpu, load = _tick_times(lambda fs, t: step_many(fs, safe, t, store), filters,
                                          max(3, min(30, int(3000 / n))))
            if cpu <= budget:
                best[name] = max(best.get(name, 0), n)
            line.append(f'{name} {wall / n * 1e6:5.1f} ({cpu / n * 1e6:5.1f}) us/robot')
        print(f'[core] step_many {n:5d} robots: ' + '; '.join(line) + f' (load {load:.1f})')
    print('[core] largest tested fleet within the 50 Hz budget (CPU): '
          + ', '.join(f'{k} {v}' for k, v in best.items()) + f' (load {os.getloadavg()[0]:.1f})')


# -- nodes --------------------------------------------------------------------------------------
def serve_filters(m):
    """Child: M safety_filter nodes (/bench_<i>) in one process and one executor."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from supersafe_ros.nodes.safety_filter_node import SafetyFilterNode
    ensure_local_ros_env()
    rclpy.init()
    ex = SingleThreadedExecutor()
    nodes = []
    from diagnostic_msgs.msg import DiagnosticStatus
    from supersafe_ros.ros_io import rosmsg
    reporter = rclpy.create_node('bench_filters_report')
    report = reporter.create_publisher(DiagnosticStatus, '/bench/decisions', rosmsg.QOS_EVENTS)
    reporter.create_timer(0.25, lambda: report.publish(rosmsg.make_diagnostic(
        'decisions', {'t': time.monotonic_ns(), 'decisions': ','.join(str(n.decisions) for n in nodes)})))
    ex.add_node(reporter)
    for i in range(m):
        n = SafetyFilterNode(namespace=f'/bench_{i}',
                             parameter_overrides=[Parameter('state_rate', value=2.0),
                                                  Parameter('rate', value=10.0)])
        nodes.append(n)
        ex.add_node(n)
    try:
        ex.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()


def cpu_seconds(pid):
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def bench_nodes(args):
    from geometry_msgs.msg import PoseArray, PoseStamped, Twist
    from supersafe_ros.ros_io import rosmsg
    print('[nodes] M filter nodes in one process; the bench feeds each pose + planner command at 50 Hz '
          'and detections at 10 Hz, for %.0f s; decisions counted inside the filter process' % args.window)
    for m in args.node_counts:
        child = start([os.path.abspath(__file__), '--serve-filters', str(m)], f'filters_{m}')
        d = Driver('bench_nodes')
        try:
            pubs, reports = [], []
            from diagnostic_msgs.msg import DiagnosticStatus
            d.node.create_subscription(DiagnosticStatus, '/bench/decisions',
                                       lambda msg: reports.append(rosmsg.diagnostic_values(msg)),
                                       rosmsg.QOS_EVENTS)
            for i in range(m):
                ns = f'/bench_{i}'
                pubs.append((d.node.create_publisher(PoseStamped, f'{ns}/pose', rosmsg.QOS_STREAM),
                             d.node.create_publisher(PoseArray, f'{ns}/detections', rosmsg.QOS_STREAM),
                             d.node.create_publisher(Twist, f'{ns}/cmd_vel_nav', rosmsg.QOS_STREAM)))
            d.spin_until(lambda: all(p.get_subscription_count() for trio in pubs for p in trio),
                         120.0, f'{m} filters to match')
            rng = np.random.default_rng(1)
            poses = [rosmsg.state_to_pose((OBSTACLE[0] + rng.uniform(-6, 6), OBSTACLE[1] + rng.uniform(-6, 6),
                                           rng.uniform(-3, 3))) for _ in range(m)]
            dets = rosmsg.xy_to_posearray([OBSTACLE, (OBSTACLE[0] + 6, OBSTACLE[1])])
            cmd = rosmsg.turn_rate_to_twist(0.1, 3.0)
            ticks = 0
            for trio in pubs:
                trio[1].publish(dets)
            d.spin_for(0.3)
            d.spin_until(lambda: reports, 5.0, 'a decision report')
            cpu0, t0 = cpu_seconds(child.pid), time.monotonic()
            me0 = time.process_time()
            next_tick = t0
            while time.monotonic() - t0 < args.window:
                for i, (pose_pub, det_pub, cmd_pub) in enumerate(pubs):
                    pose_pub.publish(poses[i])
                    if ticks % 5 == 0:
                        det_pub.publish(dets)
                    cmd_pub.publish(cmd)
                ticks += 1
                next_tick += 0.02
                d.spin_for(max(0.0, next_tick - time.monotonic()))
            elapsed = time.monotonic() - t0
            cpu = cpu_seconds(child.pid) - cpu0
            feeder = time.process_time() - me0
            d.spin_for(0.3)
            t0_ns, t1_ns = int(t0 * 1e9), int((t0 + elapsed) * 1e9)
            window = [r for r in reports if t0_ns <= int(r['t']) <= t1_ns]   # reports inside the window
            first, last = window[0], window[-1]
            rate_in = ticks / elapsed
            span = (int(last['t']) - int(first['t'])) * 1e-9
            decided = (np.array(last['decisions'].split(','), dtype=float)
                       - np.array(first['decisions'].split(','), dtype=float)) / span
            print(f'[nodes] M={m:3d}: fed at {rate_in:5.1f} Hz per robot; decisions per robot (filter side) '
                  f'median {np.median(decided):5.1f} Hz, min {decided.min():5.1f} Hz; filter process CPU '
                  f'{100 * cpu / elapsed:5.1f} % of one core; bench (feeder) CPU {100 * feeder / elapsed:5.1f} %')
            per = cpu / max(1.0, decided.sum() * elapsed)
            print(f'[nodes]        filter CPU per decision (with its pose, detections, command and output '
                  f'messages) {per * 1e3:.2f} ms -> one core would serve ~{1.0 / (per * 50.0):.0f} robots at 50 Hz')
        finally:
            d.close()
            stop([child])


# -- fleet node ----------------------------------------------------------------------------------
def superseded(node) -> int:
    """fleet/poses superseded so far (the node's count in any checkout's form)."""
    fleet = getattr(node, 'fleet', None)
    return getattr(node, 'superseded_poses', None) or getattr(fleet, 'superseded', 0)


def serve_fleet(m, batched, core, profile=''):
    """Child: one fleet_safety_filter_node for /bench_0 .. /bench_<m-1>, on ``core`` if not None."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from diagnostic_msgs.msg import DiagnosticStatus
    from supersafe_ros.nodes.common import freeze_startup_objects
    from supersafe_ros.nodes.fleet_safety_filter_node import FleetSafetyFilterNode
    from supersafe_ros.ros_io import rosmsg
    if core is not None:
        _pin_threads({core})     # the threads so far (numpy's); later ones inherit it
    ensure_local_ros_env()
    rclpy.init()
    node = FleetSafetyFilterNode(parameter_overrides=[
        Parameter('robots', value=[f'bench_{i}' for i in range(m)]),
        Parameter('per_robot_topics', value=not batched), Parameter('batched_topics', value=batched),
        Parameter('state_rate', value=1.0), Parameter('rate', value=50.0),
        Parameter('pose_timeout', value=1.0), Parameter('detections_timeout', value=2.0)])
    report = node.create_publisher(DiagnosticStatus, '/bench/decisions', rosmsg.QOS_EVENTS)
    node.create_timer(0.25, lambda: report.publish(rosmsg.make_diagnostic('decisions', {
        't': time.monotonic_ns(), 'ticks': node.ticks, 'fail_safe': node.failing_safe,
        'superseded': superseded(node),
        'decisions': ','.join(str(int(v)) for v in getattr(node, 'decided', node.decisions))})),
        clock=node.wiring.steady)
    freeze_startup_objects()    # as run_node does
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    profiler = None
    if profile:
        import cProfile
        profiler = cProfile.Profile()
        profiler.enable()
    try:
        ex.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if profiler is not None:
            profiler.disable()
            profiler.dump_stats(profile)
        node.close()
        rclpy.try_shutdown()


CORES = sorted(os.sched_getaffinity(0))     # the cores this process was given, before any pinning


def node_core():
    """The core a pinned fleet child runs on (the last one given to the driver)."""
    return CORES[-1]


def _pin_threads(cores, previous=None):
    """Every thread of this process onto ``cores`` (``sched_setaffinity(0, ...)`` moves only
    the calling thread; DDS and rclpy threads run beside it); with ``previous`` (what an
    earlier call returned), each thread back where it was (new threads onto ``cores``).
    Returns each thread's affinity before."""
    before = {}
    for name in os.listdir('/proc/self/task'):
        tid = int(name)
        try:
            before[tid] = os.sched_getaffinity(tid)
            os.sched_setaffinity(tid, previous.get(tid, cores) if previous is not None else cores)
        except OSError:     # the thread ended meanwhile
            pass
    return before


@contextlib.contextmanager
def driver_off_node_core(args):
    """While a section runs, this process (the driver, all its threads) stays off the core of
    the pinned fleet child, so that the child has its core to itself: the driver's own work
    (serializing a thousand poses 50 times a second) had sometimes run there and counted as
    the child's slowness. Yields a description for the section's header."""
    others = set(CORES) - {node_core()}
    if args.all_cores or not others:
        yield 'the bench driver on any core'
        return
    before = _pin_threads(others)
    try:
        yield f'the bench driver on core(s) {sorted(others)}, the child alone on core {node_core()}'
    finally:
        _pin_threads(set(CORES), before)


def start_fleet(args, m, batched):
    """The child serving ``m`` robots on the batched or the per-robot topics."""
    return start([os.path.abspath(__file__), '--serve-fleet', str(m)] + (['--serve-batched'] if batched else [])
                 + ([] if args.all_cores else ['--serve-core', str(node_core())])
                 + (['--profile', f'{args.profile}.{m}'] if args.profile else []),
                 f'{"batched" if batched else "fleet"}_{m}')


def _window_rates(reports, t0, t1):
    """Decisions per robot per second between the reports around [t0, t1] (the child's view)."""
    before = [r for r in reports if int(r['t']) <= int(t0 * 1e9)]
    after = [r for r in reports if int(r['t']) >= int(t1 * 1e9)]
    first = before[-1] if before else (reports[0] if reports else None)
    last = after[0] if after else (reports[-1] if reports else None)
    if first is None or last is first:
        return np.zeros(1), -1
    span = (int(last['t']) - int(first['t'])) * 1e-9
    decided = (np.array(last['decisions'].split(','), dtype=float)
               - np.array(first['decisions'].split(','), dtype=float)) / span
    # the child's ticks at the span's rate over the window itself (the driver's CPU figure is
    # the window's; the span reaches up to a report period beyond it on each side)
    _window_rates.ticks = (int(last['ticks']) - int(first['ticks'])) * (t1 - t0) / span
    _window_rates.superseded = int(last.get('superseded', 0)) - int(first.get('superseded', 0))
    # failing safe once fed (from half a second into the window: a section without warm-up
    # starts its window with the first inputs, which take a moment to come)
    fed = [r for r in reports if int((t0 + 0.5) * 1e9) <= int(r['t']) <= int(t1 * 1e9)]
    return decided, max((int(r['fail_safe']) for r in fed), default=-1)


def _capacity(tag, m, cpu, ticks):
    """CPU per tick in the filter process, and what that means for a core at 50 Hz (CPU time
    is what a loaded machine inflates least)."""
    if ticks <= 0:
        print(f'[{tag}]          no ticks measured')
        return
    per_tick = cpu / ticks
    print(f'[{tag}]          filter CPU per tick of {m} robots (inputs taken, one step_many, outputs '
          f'published) {per_tick * 1e3:.1f} ms ({per_tick / m * 1e6:.0f} us per robot) -> one core would '
          f'serve ~{m * 0.02 / per_tick:.0f} robots at 50 Hz (load {os.getloadavg()[0]:.1f})')


class RobotFeed:
    """Every robot's own topics fed as a stack would (``/bench_<i>``): a pose (about the obstacles) and a
    command at 50 Hz, detections (two obstacles 6 m apart) at 10 Hz. ``pubs``: each robot's three
    publishers (to wait for matches); ``run(seconds)``: feed for that long, on a 50 Hz schedule; the
    ticks fed so far in ``ticks``."""

    def __init__(self, d, m):
        from geometry_msgs.msg import PoseArray, PoseStamped, Twist
        from supersafe_ros.ros_io import rosmsg
        self.d = d
        self.pubs = [(d.node.create_publisher(PoseStamped, f'/bench_{i}/pose', rosmsg.QOS_STREAM),
                      d.node.create_publisher(PoseArray, f'/bench_{i}/detections', rosmsg.QOS_STREAM),
                      d.node.create_publisher(Twist, f'/bench_{i}/cmd_vel_nav', rosmsg.QOS_STREAM)) for i in range(m)]
        rng = np.random.default_rng(1)
        self.poses = [rosmsg.state_to_pose((OBSTACLE[0] + rng.uniform(-6, 6), OBSTACLE[1] + rng.uniform(-6, 6),
                                            rng.uniform(-3, 3))) for _ in range(m)]
        self.dets = rosmsg.xy_to_posearray([OBSTACLE, (OBSTACLE[0] + 6, OBSTACLE[1])])
        self.cmd = rosmsg.turn_rate_to_twist(0.1, 3.0)
        self.ticks = 0

    def matched(self) -> bool:
        return all(p.get_subscription_count() for trio in self.pubs for p in trio)

    def run(self, seconds):
        d, start = self.d, time.monotonic()
        next_tick = start
        while time.monotonic() - start < seconds:
            stamp = d.node.get_clock().now().to_msg()
            for pose, (pose_pub, det_pub, cmd_pub) in zip(self.poses, self.pubs):
                pose.header.stamp = stamp
                pose_pub.publish(pose)
                if self.ticks % 5 == 0:
                    det_pub.publish(self.dets)
                cmd_pub.publish(self.cmd)
            self.ticks += 1
            next_tick += 0.02
            d.spin_for(max(0.0, next_tick - time.monotonic()))


class BatchedFeed:
    """The batched topics fed as a fleet manager would: ``send()`` one tick's fleet/cmd_vel_nav and
    fleet/poses (n robots scattered over 80 m; every fifth tick fleet/detections first, 30 obstacles);
    ``run(seconds)`` one tick every 20 ms for that long."""

    def __init__(self, d, n):
        from geometry_msgs.msg import PoseArray
        from std_msgs.msg import Float64MultiArray
        from supersafe_ros.ros_io import fleetmsg, rosmsg
        self.d = d
        self.pose_pub = d.node.create_publisher(PoseArray, '/fleet/poses', rosmsg.QOS_STREAM)
        self.det_pub = d.node.create_publisher(PoseArray, '/fleet/detections', rosmsg.QOS_STREAM)
        self.cmd_pub = d.node.create_publisher(Float64MultiArray, '/fleet/cmd_vel_nav', rosmsg.QOS_STREAM)
        rng = np.random.default_rng(2)
        field = np.stack([rng.uniform(-40, 40, 30), rng.uniform(-40, 40, 30)], axis=1)
        states = np.stack([rng.uniform(-40, 40, n), rng.uniform(-40, 40, n), rng.uniform(-3, 3, n)], axis=1)
        self.poses = rosmsg.xy_to_posearray(states[:, :2])
        for pose, th in zip(self.poses.poses, states[:, 2]):
            pose.orientation = rosmsg.yaw_to_quaternion(float(th))
        self.dets = rosmsg.xy_to_posearray(field)
        self.cmds = fleetmsg.commands_to_msg(np.tile([3.0, 0.1], (n, 1)))
        self.ticks = 0

    def matched(self) -> bool:
        return all(p.get_subscription_count() for p in (self.pose_pub, self.det_pub, self.cmd_pub))

    def send(self) -> int:
        """One tick's messages; the monotonic ns just before the poses went out."""
        if self.ticks % 5 == 0:
            self.det_pub.publish(self.dets)
        self.cmd_pub.publish(self.cmds)
        self.poses.header.stamp = self.d.node.get_clock().now().to_msg()
        sent = time.monotonic_ns()
        self.pose_pub.publish(self.poses)
        self.ticks += 1
        return sent

    def run(self, seconds):
        next_tick = start = time.monotonic()
        while time.monotonic() - start < seconds:
            self.send()
            next_tick += 0.02
            self.d.spin_for(max(0.0, next_tick - time.monotonic()))


def bench_fleet(args):
    with driver_off_node_core(args) as where:
        _bench_fleet(args, where)


def _bench_fleet(args, where):
    from diagnostic_msgs.msg import DiagnosticStatus
    from supersafe_ros.ros_io import rosmsg
    print('[fleet] fleet_safety_filter_node, per-robot topics, one process pinned to one core; the bench '
          f'feeds each robot pose + command at 50 Hz and detections at 10 Hz for {args.window:.0f} s; '
          f'{where}')
    for m in args.fleet_sizes:
        child = start_fleet(args, m, batched=False)
        d = Driver('bench_fleet')
        try:
            reports = []
            d.node.create_subscription(DiagnosticStatus, '/bench/decisions',
                                       lambda msg: reports.append(rosmsg.diagnostic_values(msg)), rosmsg.QOS_EVENTS)
            feed = RobotFeed(d, m)
            d.spin_until(lambda: feed.matched() and reports, 180.0, f'the fleet node of {m} robots to match')
            t0 = time.monotonic()
            cpu0, me0 = cpu_seconds(child.pid), time.process_time()
            feed.run(args.window)
            ticks = feed.ticks
            t1 = time.monotonic()
            cpu, feeder = cpu_seconds(child.pid) - cpu0, time.process_time() - me0
            d.spin_until(lambda: reports and int(reports[-1]['t']) >= int(t1 * 1e9), 30.0, 'a report after the window')
            decided, fail = _window_rates(reports, t0, t1)
            print(f'[fleet] M={m:4d}: fed at {ticks / (t1 - t0):5.1f} Hz per robot; decisions per robot median '
                  f'{np.median(decided):5.1f}/s, min {decided.min():5.1f}/s; '
                  f'robots failing safe at most {fail} once fed; '
                  f'fleet process CPU {100 * cpu / (t1 - t0):5.1f} % of its one core; feeder CPU '
                  f'{100 * feeder / (t1 - t0):5.1f} % (load {os.getloadavg()[0]:.1f})')
            _capacity('fleet', m, cpu, _window_rates.ticks)
        finally:
            d.close()
            stop([child])


def bench_batched(args):
    with driver_off_node_core(args) as where:
        _bench_batched(args, where)


def _bench_batched(args, where):
    from diagnostic_msgs.msg import DiagnosticStatus
    from std_msgs.msg import Float64MultiArray
    from supersafe_ros.ros_io import rosmsg
    print('[batched] fleet_safety_filter_node, batched topics only, pinned to one core; the bench sends '
          f'fleet/poses + fleet/cmd_vel_nav at 50 Hz (fleet/detections at 10 Hz) for {args.window:.0f} s; '
          f'{where}')
    for n in args.batched_sizes:
        child = start_fleet(args, n, batched=True)
        d = Driver('bench_batched')
        try:
            reports, replies = [], []
            d.node.create_subscription(DiagnosticStatus, '/bench/decisions',
                                       lambda msg: reports.append(rosmsg.diagnostic_values(msg)), rosmsg.QOS_EVENTS)
            d.node.create_subscription(Float64MultiArray, '/fleet/cmd_vel',
                                       lambda msg: replies.append(time.monotonic_ns()), rosmsg.QOS_STREAM)
            batched = BatchedFeed(d, n)
            d.spin_until(lambda: batched.matched() and reports, 180.0, f'the fleet node of {n} robots to match')

            def feed(seconds):
                """Poses and commands at 50 Hz (detections at 10 Hz) for ``seconds``: (ticks, the
                latencies of the replies that came within their tick, the send times)."""
                latency, sends, ticks = [], [], 0
                next_tick = start = time.monotonic()
                while time.monotonic() - start < seconds:
                    replies.clear()
                    sent = batched.send()
                    sends.append(sent)
                    ticks += 1
                    next_tick += 0.02
                    while time.monotonic() < next_tick:
                        d.executor.spin_once(timeout_sec=0.001)
                        if replies and replies[0] >= sent and len(latency) < ticks:
                            latency.append((replies[0] - sent) * 1e-9)
                return ticks, latency, sends

            # a second of warm-up first: the first detections start the cluster solves (a background
            # thread on the child's core) and the first ticks build their caches
            feed(1.0)
            t0 = time.monotonic()
            cpu0 = cpu_seconds(child.pid)
            ticks, latency, sends = feed(args.window)
            t1 = time.monotonic()
            cpu = cpu_seconds(child.pid) - cpu0
            feed(0.5)       # still fed while the child's report after the window comes (every 0.25 s)
            d.spin_until(lambda: reports and int(reports[-1]['t']) >= int(t1 * 1e9), 30.0, 'a report after the window')
            decided, fail = _window_rates(reports, t0, t1)
            print(f'[batched] N={n:5d}: fed at {ticks / (t1 - t0):5.1f} Hz; decisions per robot median '
                  f'{np.median(decided):5.1f}/s, min {decided.min():5.1f}/s; '
                  f'robots failing safe at most {fail} once fed; '
                  f'process CPU {100 * cpu / (t1 - t0):5.1f} % of its one core (load {os.getloadavg()[0]:.1f})')
            _capacity('batched', n, cpu, _window_rates.ticks)
            if latency:
                print(f'[batched]          fleet/poses -> fleet/cmd_vel (replies within the tick, '
                      f'{len(latency)} of {ticks}): {ms(latency)} (load {os.getloadavg()[0]:.1f})')
            # the driver's own hiccups: poses sent less than half a period after the previous ones
            # (after a late send) can only be superseded, however fast the filter
            gaps = np.diff(np.array(sends)) * 1e-9
            print(f'[batched]          the driver sent {np.sum(gaps < 0.01)} of {len(gaps)} poses less than 10 ms '
                  f'after the previous ones (largest gap {1e3 * gaps.max():.1f} ms); the filter superseded '
                  f'{_window_rates.superseded} in the window (a newer one had come while it decided)')
        finally:
            d.close()
            stop([child])


# -- learner ----------------------------------------------------------------------------------------
def bench_learner(args):
    from diagnostic_msgs.msg import DiagnosticStatus
    from geometry_msgs.msg import PoseStamped
    from std_msgs.msg import Float32MultiArray
    from supersafe_ros.ros_io import rosmsg
    from supersafe_ros.learning.data import PHASE2_OFFSETS, intervention_states, phase2_encounters
    from supersafe_ros.learning.supervisor import NoisySupervisor
    from supersafe_ros.reach.library import LibrarySpec, load_or_build_library
    t0 = time.perf_counter()
    lib = load_or_build_library(LibrarySpec())
    print(f'[learner] paper library {lib.spec.shape} x {len(lib.entries)} entries loaded in '
          f'{time.perf_counter() - t0:.2f} s (bench process)')
    sup = NoisySupervisor(lib.entry(0.75), 0.5, 0.2, rng=3)
    states = intervention_states(phase2_encounters(sup, np.tile(PHASE2_OFFSETS, 3), rng=3))[:args.interventions]
    store = os.path.join(tempfile.mkdtemp(prefix='bench_learner_'), 'subject.jsonl')
    t_start = time.monotonic()
    child = start(node_cmd('learner_node', None, store_path=store, min_interventions=1), 'learner')
    d = Driver('bench_learner')
    try:
        fits, vfs = [], []
        fit_sub = d.node.create_subscription(DiagnosticStatus, '/safe_set/fit',
                                             lambda m: fits.append((time.monotonic_ns(), m)), rosmsg.QOS_LATCHED)
        vf_sub = d.node.create_subscription(Float32MultiArray, '/safe_set/value_function',
                                            lambda m: vfs.append(time.monotonic_ns()), rosmsg.QOS_LATCHED)
        pub = d.node.create_publisher(PoseStamped, '/interventions', rosmsg.QOS_EVENTS)
        d.spin_until(lambda: pub.get_subscription_count() and fit_sub.get_publisher_count()
                     and vf_sub.get_publisher_count(), 120.0, 'the learner to start')
        print(f'[learner] learner_node up (library from cache) {time.monotonic() - t_start:.2f} s after launch')
        to_fit, to_vf, to_learner, inside = [], [], [], {'store_s': [], 'fit_s': [], 'publish_s': []}
        for i, s in enumerate(states):
            fits.clear()
            vfs.clear()
            msg = rosmsg.state_to_pose(s, frame=rosmsg.obstacle_frame(i))
            msg.header.stamp.sec = 1000 + i
            t0 = time.monotonic_ns()
            pub.publish(msg)
            d.spin_until(lambda: vfs and any(rosmsg.diagnostic_values(m).get('fitted_interventions') == str(i + 1)
                                             for _, m in fits), 10.0, 'the new fit')
            t_fit = min(t for t, m in fits if rosmsg.diagnostic_values(m).get('fitted_interventions') == str(i + 1))
            to_fit.append((t_fit - t0) * 1e-9)
            vals = rosmsg.diagnostic_values(fits[-1][1])
            to_learner.append((int(vals['received_monotonic_ns']) - t0) * 1e-9)
            for k in inside:
                inside[k].append(float(vals.get(k, 'nan')))
            to_vf.append((vfs[0] - t0) * 1e-9)
        print(f'[learner] intervention published -> learner callback: {ms(to_learner)}')
        print('[learner] inside the learner: ' + '; '.join(f'{k[:-2]} {ms(v)}' for k, v in inside.items()))
        last = rosmsg.diagnostic_values(fits[-1][1])
        print(f'[learner] intervention -> /safe_set/fit received: {ms(to_fit)}')
        print(f'[learner] intervention -> /safe_set/value_function (710 KB) received: {ms(to_vf)}')
        print(f"[learner] final fit on {last['interventions']} interventions: omega_max {last['omega_max']}, "
              f"mu {float(last['mu']):.3f}, sigma {float(last['sigma']):.3f} "
              f'(simulated supervisor: omega_max 0.75, mu 0.5, sigma 0.2)')
    finally:
        d.close()
        stop([child])


SECTIONS = {'vfmsg': bench_vfmsg, 'latency': bench_latency, 'core': bench_core, 'nodes': bench_nodes,
            'fleet': bench_fleet, 'batched': bench_batched, 'learner': bench_learner}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--only', nargs='+', choices=list(SECTIONS), default=list(SECTIONS))
    parser.add_argument('--samples', type=int, default=400, help='latency samples per chain')
    parser.add_argument('--vf-repeats', type=int, default=20)
    parser.add_argument('--core-sizes', type=int, nargs='+', default=[10, 100, 1000, 2000])
    parser.add_argument('--node-counts', type=int, nargs='+', default=[1, 5, 10, 20])
    parser.add_argument('--window', type=float, default=5.0, help='seconds per node-count run')
    parser.add_argument('--interventions', type=int, default=40)
    parser.add_argument('--no-direct-take', action='store_true',
                        help='latency: the filter\'s executor takes its inputs (direct_take false)')
    parser.add_argument('--serve-vf-echo', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--fleet-sizes', type=int, nargs='+', default=[50, 100, 150])
    parser.add_argument('--batched-sizes', type=int, nargs='+', default=[500, 1000, 2000])
    parser.add_argument('--all-cores', action='store_true', help='do not pin the fleet node to one core')
    parser.add_argument('--profile', default='', help='fleet and batched: cProfile the fleet node, stats to '
                        'PROFILE.<robots> (profiling inflates the figures printed)')
    parser.add_argument('--serve-filters', type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument('--serve-fleet', type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument('--serve-batched', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--serve-core', type=int, default=None, help=argparse.SUPPRESS)
    args, _ = parser.parse_known_args(argv)
    if args.serve_vf_echo:
        return serve_vf_echo()
    if args.serve_filters:
        return serve_filters(args.serve_filters)
    if args.serve_fleet:
        return serve_fleet(args.serve_fleet, args.serve_batched, args.serve_core, args.profile)
    ensure_local_ros_env()
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 80))
    import rclpy
    rclpy.init()
    print(f"bench_nodes: ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}, {os.environ.get('RMW_IMPLEMENTATION')}, "
          f'{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}')
    try:
        for name in args.only:
            SECTIONS[name](args)
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
