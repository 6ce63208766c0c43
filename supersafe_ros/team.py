"""The ROS 2 node graph of a robot team, every node a process: its layout and its runner.

The same graph as launch/team.launch.py, for machines without `ros2 launch`:
sim_clock, world, N x (dubins_robot, planner, safety_filter) in /robot_<i>,
learner and supervisor, each a child process with the shared ROS_DOMAIN_ID and
loopback-only discovery, parameters from config/*.yaml (ament index share
directory, else the source tree) plus per-process ``-p`` overrides.

``team_processes(...)`` returns the argv of every process so the study can start
the same graph its own way; ``run_team(...)`` starts them, prints /world/stats as
they come, stops at ``duration`` sim seconds (the clock stops there) or on
Ctrl-C/SIGTERM (SIGINT to every child, a grace period, then SIGKILL), and
returns the last stats. The command line, `supersafe team`, is ``team_cli``; running
the team across hosts is ``hosts.placement``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

PACKAGE = 'supersafe_ros'
CONFIG_FILES = {
    'sim_clock': 'clock.yaml', 'world': 'world.yaml', 'dubins_robot': 'robot.yaml',
    'planner': 'planner.yaml', 'safety_filter': 'safety_filter.yaml',
    'learner': 'learner.yaml', 'supervisor': 'supervisor.yaml',
    'supervisor_console': 'console.yaml',
}
NODE_MODULES = {
    'sim_clock': 'sim_clock_node', 'world': 'world_node', 'dubins_robot': 'dubins_robot_node',
    'planner': 'planner_node', 'safety_filter': 'safety_filter_node',
    'learner': 'learner_node', 'supervisor': 'supervisor_node',
    'supervisor_console': 'supervisor_console_node',
}


def config_dir() -> Path:
    """share/supersafe_ros/config from the ament index, else the source tree's config/."""
    try:
        from ament_index_python.packages import get_package_share_directory
        shared = Path(get_package_share_directory(PACKAGE)) / 'config'
        if (shared / 'world.yaml').is_file():
            return shared
    except Exception:  # not installed in an ament prefix (editable install, plain venv)
        pass
    return Path(__file__).resolve().parent.parent / 'config'


def robot_names(n_robots: int) -> list[str]:
    return [f'robot_{i}' for i in range(n_robots)]


def start_poses(n_robots: int, goal_x: float = 16.0, half_height: float = 12.0) -> list[tuple]:
    """Robots start one metre behind the left goal line, spread in y, heading +x."""
    ys = [0.0] if n_robots == 1 else [
        -0.6 * half_height + 1.2 * half_height * i / (n_robots - 1) for i in range(n_robots)]
    return [(-goal_x - 1.0, y, 0.0) for y in ys]


def _param_value(v) -> str:
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, (list, tuple)):
        return '[' + ','.join(_param_value(x) for x in v) + ']'
    if isinstance(v, float):
        return repr(float(v))
    return str(v)


def node_argv(node: str, namespace: str | None = None, params: dict | None = None,
              remaps: dict | None = None, config: Path | None = None,
              python: str = sys.executable, params_files=()) -> list[str]:
    """argv of one node process: python -m <module> --ros-args --params-file ... -r ... -p ...

    ``params_files``: more YAML files, applied after the config file; the layout's own
    values (``-p``, which rcl applies after every file) still win, as in the launch file."""
    argv = [python, '-m', f'{PACKAGE}.nodes.{NODE_MODULES[node]}', '--ros-args']
    cfg = (config or config_dir()) / CONFIG_FILES[node]
    if cfg.is_file():
        argv += ['--params-file', str(cfg)]
    for extra in params_files:
        argv += ['--params-file', str(extra)]
    if namespace:
        argv += ['-r', f'__ns:=/{namespace.strip("/")}']
    for src, dst in (remaps or {}).items():
        argv += ['-r', f'{src}:={dst}']
    for k, v in (params or {}).items():
        argv += ['-p', f'{k}:={_param_value(v)}']
    return argv


@dataclass(frozen=True)
class NodeSpec:
    """One node of the team: its kind (key of NODE_MODULES), namespace, parameters
    (beyond its config file) and remappings. The launch file and ``team_processes``
    both build the graph from these, so the two cannot drift apart."""

    kind: str
    namespace: str | None
    params: dict
    remaps: dict

    @property
    def executable(self) -> str:
        return NODE_MODULES[self.kind]


# steady seconds a lockstepped filter may hold a step for a cluster's union value
# (holds of up to 7.3 s were measured with 4 robots at load 10 on 2 cores); the
# filter's clock_stall_timeout stays longer, or it would count the held /clock as stopped
CLUSTER_HOLD_TIMEOUT = 15.0


# sensors 'scan': what the robots, planners and filters are told (beside their config files)
SENSOR_MODE = {
    'world': {'radii': [0.8, 1.8, 2.6]},        # obstacles of three sizes
    'dubins_robot': {'sensors': 'scan', 'cmd_vel_stamped': True, 'follow_speed': True, 'timeout_behavior': 'stop'},
    'planner': {'pose_type': 'odometry', 'cmd_vel_stamped': True, 'slow_radius': 6.0, 'goal_tolerance': 1.0,
                'goal_wait': 1.0},
    'safety_filter': {'pose_type': 'odometry', 'detections_type': 'laser_scan', 'cmd_vel_stamped': True,
                      'robot_radius': 0.1, 'fail_safe_command': 'stop',
                      # the scans kept in a local map as wide as the sensor's reach and the value's window
                      # (3 m/s robots: a 1.5 s horizon is 4.5 m), judged by its one avoid value
                      # (bench_collisions.py scan: trials.ScanSensor's settings)
                      'obstacle_depth': 5.2,          # the largest obstacle's diameter: its far side
                      'inf_is_valid': True,           # the simulated laser's +inf: nothing within range
                      'map_cell': 0.2, 'map_size': 30.0, 'value_cell': 0.25, 'value_headings': 38,
                      'value_horizon': 1.5, 'value_reach': 3.0, 'value_period': 0.4,
                      # between solves the speed is cut so that each command's path meets no cell
                      # within 0.5 s (filter.approach)
                      'time_before_collision': 0.5, 'lookahead': 0.5},
}


def team_layout(n_robots: int = 2, rate_factor: float = 10.0, seed: int = 0,
                duration: float = 0.0, overrides: dict | None = None, step: float | None = None,
                with_filter: bool = True, with_learner: bool = True,
                with_supervisor: bool = True,
                learner_store: str | Path | None = None,
                use_sim_time: bool = True,
                console_port: int | None = None, sensors: str = 'none') -> list[NodeSpec]:
    """Every node of a team, in start order (the sim clock last).

    ``overrides``: {node kind: {param: value}} applied to every node of that kind
    (e.g. {'supervisor': {'mu': 1.0}, 'sim_clock': {'step': 0.1}}).
    ``with_filter=False``: the planner publishes straight into cmd_vel (test wiring only).
    ``learner_store``: the learner's intervention file; give each run its own (the
    learner reloads whatever the file holds), None = the learner's default.
    ``step``: sim seconds per clock step = 1 / robot rate (None: the override
    sim_clock.step, else 0.05). 0.1 halves the CPU per sim second; the robots then
    move 0.3 m between control decisions instead of 0.15 m.
    ``use_sim_time``: every node but the clock follows /clock. The config files of the
    robot, planner, world, supervisor, filters and RViz node default to the wall clock
    (what a real fleet runs; config/learner.yaml and config/console.yaml set sim time);
    the simulation sets it here, for every node it starts, the filters and the learner
    included.
    ``console_port``: also run the supervisor console (web page) on this port.
    ``sensors``: 'none' (the study's robots: PoseStamped pose, PoseArray detections, Twist,
    constant speed) or 'scan': robots that publish only what a real one does (``odom``
    Odometry, ``scan`` LaserScan, TwistStamped cmd_vel, driving at the commanded speed) in a
    world of obstacles of three sizes, a planner that slows near its goal and stops there a
    moment, and filters that read odometry, the scan and TwistStamped (SENSOR_MODE); the
    world, learner, supervisor and console as in 'none'.
    """
    if sensors not in ('none', 'scan'):
        raise ValueError(f"sensors must be 'none' or 'scan', got {sensors!r}")
    scan = sensors == 'scan'
    if n_robots < 1:
        raise ValueError('a team needs at least one robot')
    overrides = overrides or {}
    unknown = set(overrides) - set(NODE_MODULES)
    if unknown:
        raise ValueError(f'overrides for unknown nodes {sorted(unknown)}')
    robots = robot_names(n_robots)
    sim = {'use_sim_time': bool(use_sim_time)}
    layout = []

    def add(kind, namespace=None, base=None, remaps=None):
        params = dict(base or {})
        params.update(overrides.get(kind, {}))
        layout.append(NodeSpec(kind, namespace, params, dict(remaps or {})))

    # world, planner, supervisor and learner take event times from message stamps and
    # read the clock only for timeouts and statistics: they follow /clock_coarse and
    # are spared a /clock callback every step
    coarse = {'/clock': '/clock_coarse'}
    add('world', None, {**sim, 'robots': robots, 'seed': seed, **(SENSOR_MODE['world'] if scan else {})},
        coarse)
    # one step of the clock = one robot step (lockstep acknowledges every step)
    if step is None:
        step = float(overrides.get('sim_clock', {}).get('step', 0.05))
    if not (math.isfinite(step) and step > 0):
        raise ValueError(f'step must be positive, got {step}')
    for i, (name, pose) in enumerate(zip(robots, start_poses(n_robots))):
        add('dubins_robot', name, {
            **sim, 'initial_x': pose[0], 'initial_y': pose[1], 'initial_theta': pose[2],
            'seed': seed * 1000 + i + 1, 'rate': 1.0 / step, **(SENSOR_MODE['dubins_robot'] if scan else {})})
        planner_remaps = {**coarse, **({'pose': 'odom'} if scan else {})}
        add('planner', name, {**sim, **(SENSOR_MODE['planner'] if scan else {})},
            planner_remaps if with_filter else {**planner_remaps, 'cmd_vel_nav': 'cmd_vel'})
        if with_filter:
            # lockstep: the filter answers each pose once, on that pose (the robot's step
            # acknowledgement), so each command holds exactly one step: the look-ahead is
            # max(the step, the config's lookahead of 0.1 s), the shortest hold that keeps the
            # promise (docs/filter_learner.md, "How far from alpha"). It holds that answer while
            # a cluster's union value is being solved: sim time waits for the solve instead of a
            # fallback (docs/graph_safety.md). A lockstepped robot does not move while /clock
            # waits (a busy machine, a slow rate factor), so the filter counts a stopped /clock
            # as lost only after 20 s (docs/filter_node.md).
            # its robot is the constant-speed Dubins robot: the fail safe is the stop-turn (a
            # --sensors scan robot follows its commanded speed and can stop: SENSOR_MODE)
            add('safety_filter', name, {**sim, 'control_period': step, 'fail_safe_command': 'stop_turn',
                                        'clock_stall_timeout': CLUSTER_HOLD_TIMEOUT + 5.0,
                                        'lockstep': True, 'lockstep_silence': CLUSTER_HOLD_TIMEOUT + 5.0,
                                        'cluster_hold_timeout': CLUSTER_HOLD_TIMEOUT,
                                        **(SENSOR_MODE['safety_filter'] if scan else {})},
                {'pose': 'odom', 'detections': 'scan'} if scan else None)
    if with_learner:
        add('learner', None, {**sim, 'robots': robots,
                              **({'store_path': str(learner_store)} if learner_store else {})},
            coarse)
    if with_supervisor:
        # its first step waits until the world (and the learner) read its /interventions:
        # a reader discovered late (seconds, across hosts) would miss the first ones
        add('supervisor', None, {**sim, 'robots': robots, 'seed': seed * 1000 + 999,
                                 'interventions_readers': 1 + int(with_learner)}, coarse)
    if console_port is not None:
        add('supervisor_console', None, {**sim, 'robots': robots, 'port': int(console_port)}, coarse)
    # the clock starts sim time only once the whole graph is up (the supervisor and the
    # filters may spend seconds loading value functions)
    publishers = ['/obstacle_markers=1'] + [f'/{r}/cmd_vel=1' for r in robots]
    if with_filter:
        publishers += [f'/{r}/cmd_vel_nav=1' for r in robots]
        # and every filter has its robot's detections (the robot knows the world and has
        # looked): the first pose is judged on them, never on "no obstacle" by default
        publishers += [f'/{r}/safety_filter/ready=1' for r in robots]
    if with_supervisor:
        publishers.append('/interventions=1')
    if with_learner:
        publishers.append('/safe_set/value_function=1')
    pose_readers = 2 + int(with_filter) + int(with_supervisor)   # world, planner, filter, supervisor
    odom_readers = 0
    if scan:     # planner and filter read odom instead
        pose_readers, odom_readers = pose_readers - 1 - int(with_filter), 1 + int(with_filter)
    observers = ['/world/step_done'] + (['/supervisor/step_done'] if with_supervisor else [])
    add('sim_clock', None, {
        'use_sim_time': False, 'robots': robots, 'observers': observers,
        'rate_factor': float(rate_factor),
        # a filter holding its answer for a cluster solve is waited for, not skipped
        **({'ack_timeout': CLUSTER_HOLD_TIMEOUT + 5.0} if with_filter else {}),
        'duration': float(duration), 'step': step, 'wait_for_publishers': publishers,
        # every robot's and filter's /clock reader, so that no one misses the first steps
        'wait_for_subscriptions': [f'/{r}/pose={pose_readers}' for r in robots]
        + [f'/{r}/odom={odom_readers}' for r in robots if odom_readers]
        + [f'/clock={len(robots) * (1 + int(with_filter))}']})
    return layout


def team_processes(*args, config: Path | None = None, python: str = sys.executable,
                   params_files=(), **kwargs) -> list[list[str]]:
    """argv of every process of a team, in start order; arguments as ``team_layout``,
    ``params_files`` as ``node_argv``."""
    return [node_argv(n.kind, n.namespace, n.params, n.remaps, config, python, params_files)
            for n in team_layout(*args, **kwargs)]


def process_name(argv: list[str]) -> str:
    """A short label for a process argv: 'robot_0/planner', 'world', ... (a renamed node,
    ``-r __node:=NAME``, by its name: two learners get two logs)"""
    module = next(a for a in argv if a.startswith(f'{PACKAGE}.nodes.'))
    kind = module.rsplit('.', 1)[1].removesuffix('_node')
    kind = next((a.split(':=', 1)[1] for a in argv if a.startswith('__node:=')), kind)
    ns = next((a.split(':=', 1)[1].strip('/') for a in argv if a.startswith('__ns:=')), '')
    return f'{ns}/{kind}' if ns else kind


def team_env(domain_id: int | None = None, base: dict | None = None) -> dict:
    """Environment of the children: loopback discovery and one shared ROS_DOMAIN_ID."""
    from .rosenv import ensure_local_ros_env
    env = dict(os.environ if base is None else base)
    ensure_local_ros_env(env)
    if domain_id is not None:
        env['ROS_DOMAIN_ID'] = str(int(domain_id))
    elif 'ROS_DOMAIN_ID' not in env:
        env['ROS_DOMAIN_ID'] = str(100 + os.getpid() % 100)
    env.setdefault('ROS_LOG_DIR', os.path.join(os.environ.get('TMPDIR', '/tmp'), 'supersafe-ros-log'))
    env['PYTHONUNBUFFERED'] = '1'
    # the children write to log files: no colour escape codes in them
    env.setdefault('RCUTILS_COLORIZED_OUTPUT', '0')
    return env


def _die_with_parent():
    """In the child before exec (Linux): SIGTERM it if the runner dies without stopping it
    (e.g. SIGKILL), so no orphaned node keeps a sim clock or DDS traffic going."""
    try:
        import ctypes
        libc = ctypes.CDLL('libc.so.6', use_errno=True)
        libc.prctl(1, signal.SIGTERM)          # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


@dataclass
class Team:
    """Running child processes of a team."""

    argvs: list
    env: dict
    log_dir: Path
    procs: list = field(default_factory=list)
    logs: list = field(default_factory=list)

    def start(self):
        self.log_dir.mkdir(parents=True, exist_ok=True)
        for argv in self.argvs:
            name = process_name(argv)
            log = open(self.log_dir / (name.replace('/', '.') + '.log'), 'w')
            self.logs.append(log)
            # own session: a terminal Ctrl-C reaches the runner only, which then
            # stops the children in order
            self.procs.append(subprocess.Popen(argv, env=self.env, stdout=log,
                                               stderr=subprocess.STDOUT, start_new_session=True,
                                               preexec_fn=_die_with_parent))
        # who is who, for anyone who has to clean up after a crashed runner
        (self.log_dir / 'pids.txt').write_text(''.join(
            f'{p.pid} {process_name(a)}\n' for a, p in zip(self.argvs, self.procs)))
        return self

    def dead(self) -> list[str]:
        return [process_name(a) for a, p in zip(self.argvs, self.procs) if p.poll() is not None]

    def cpu_seconds(self) -> dict:
        """User + system CPU seconds used so far by each child (Linux /proc; {} elsewhere)."""
        out = {}
        tick = os.sysconf('SC_CLK_TCK') if hasattr(os, 'sysconf') else 100
        for argv, p in zip(self.argvs, self.procs):
            try:
                with open(f'/proc/{p.pid}/stat') as f:
                    fields = f.read().rsplit(')', 1)[1].split()
                out[process_name(argv)] = (int(fields[11]) + int(fields[12])) / tick
            except (OSError, IndexError, ValueError):
                pass
        return out

    def stop(self, grace: float = 5.0) -> dict:
        """SIGINT every child, wait up to ``grace`` s, SIGKILL the rest; returns exit codes."""
        for p in self.procs:
            if p.poll() is None:
                try:
                    p.send_signal(signal.SIGINT)
                except ProcessLookupError:
                    pass
        deadline = time.monotonic() + grace
        for p in self.procs:
            try:
                p.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        for log in self.logs:
            log.close()
        return {process_name(a): p.returncode for a, p in zip(self.argvs, self.procs)}


class TeamMonitor:
    """A small rclpy node in the runner: collects /world/stats and /sim/clock_status."""

    def __init__(self, env: dict):
        from .ros_io.background_node import BackgroundNode
        from diagnostic_msgs.msg import DiagnosticStatus
        from .ros_io import rosmsg
        self.ros = BackgroundNode('team_monitor', env['ROS_DOMAIN_ID'])
        self.node = self.ros.node
        self.stats = {}
        self.clock = {}
        self.interventions = []
        self.events = []
        self.lock = threading.Lock()
        self.node.create_subscription(DiagnosticStatus, '/world/stats',
                                      lambda m: self._set('stats', rosmsg.diagnostic_values(m)),
                                      rosmsg.QOS_LATCHED)
        self.node.create_subscription(DiagnosticStatus, '/sim/clock_status',
                                      lambda m: self._set('clock', rosmsg.diagnostic_values(m)),
                                      rosmsg.QOS_LATCHED)
        self.node.create_subscription(
            DiagnosticStatus, '/world/events',
            lambda m: self.events.append({'event': m.name, **rosmsg.diagnostic_values(m)}),
            rosmsg.QOS_LOG)
        self.node.create_subscription(DiagnosticStatus, '/world/intervention_log',
                                      lambda m: self.interventions.append(rosmsg.diagnostic_values(m)),
                                      rosmsg.QOS_LOG)
        self.ros.start()

    def _set(self, attr, values):
        with self.lock:
            setattr(self, attr, values)

    def snapshot(self):
        with self.lock:
            return dict(self.stats), dict(self.clock)

    def close(self):
        self.ros.close()


def format_stats(stats: dict, clock: dict) -> str:
    keys = ('trips', 'crashes', 'interventions', 'false_positives', 'score')
    parts = [f'sim {clock.get("sim_time", "?")} s', f'x{clock.get("rate_factor_achieved", "?")}',
             f'counted to {stats.get("sim_time", "?")} s']
    parts += [f'{k} {stats[k]}' for k in keys if k in stats]
    return '  '.join(parts)


def gate_clock_on_recorder(argvs: list[list[str]]) -> tuple[list[list[str]], list[str]]:
    """With a recorder: the sim clock also waits for its ready publisher, which it creates once
    it has subscribed to /clock and every topic the clock waits for (so that the bag holds
    the run from its first step). Returns (argvs, those topics)."""
    from .ros_io.bag_recorder import READY_TOPIC
    out, topics = [], ['/clock']
    for argv in argvs:
        argv = list(argv)
        if process_name(argv) == 'sim_clock':
            for i, a in enumerate(argv):
                key, sep, value = a.partition(':=')
                if argv[i - 1] == '-p' and key in ('wait_for_publishers', 'wait_for_subscriptions'):
                    topics += [t.split('=')[0] for t in value.strip('[]').split(',') if t]
                    if key == 'wait_for_publishers':
                        entries = [t for t in value.strip('[]').split(',') if t] + [f'{READY_TOPIC}=1']
                        argv[i] = f'{key}:=[{",".join(entries)}]'
        out.append(argv)
    return out, sorted(set(topics))


def run_team(argvs: list[list[str]], duration: float = 0.0, timeout: float = 0.0,
             domain_id: int | None = None, log_dir: Path | None = None,
             print_period: float = 5.0, out=sys.stdout, record: Path | None = None) -> dict:
    """Run a team until ``duration`` sim seconds pass (0: until interrupted) or ``timeout``
    wall seconds; returns {'stats', 'clock', 'interventions', 'events' (trips and crashes),
    'exit_codes', 'dead', 'reason', 'cpu_seconds', 'cpu_seconds_at_start'}, plus 'bag'
    (a recording.bag.BagInfo) when ``record`` names a new bag folder: every topic is
    recorded there (supersafe_ros.ros_io.bag_recorder)."""
    env = team_env(domain_id)
    log_dir = Path(log_dir or default_log_dir())
    stop = threading.Event()
    reason = ['interrupted']

    def on_signal(signum, frame):
        reason[0] = f'signal {signal.Signals(signum).name}'
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)} \
        if threading.current_thread() is threading.main_thread() else {}
    team = Team(argvs, env, log_dir)
    monitor = None
    recorder = None
    print(f'team: {len(argvs)} processes, ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]}, logs in {log_dir}',
          file=out, flush=True)
    try:
        if record is not None:   # first, so that it joins every topic as it appears
            from .ros_io.bag_recorder import start_recorder
            argvs, ready_after = gate_clock_on_recorder(argvs)
            team.argvs = argvs
            recorder = start_recorder(record, env['ROS_DOMAIN_ID'], ready_after=ready_after)
            print(f'recording every topic to {record}', file=out, flush=True)
        team.start()
        monitor = TeamMonitor(env)
        wall0 = time.monotonic()
        next_print = wall0 + print_period
        cpu_at_start = None
        while not stop.wait(0.2):
            stats, clock = monitor.snapshot()
            if cpu_at_start is None and clock:
                cpu_at_start = team.cpu_seconds()   # the graph is up: start-up CPU ends here
            if time.monotonic() >= next_print:
                print(format_stats(stats, clock), file=out, flush=True)
                next_print += print_period
            dead = team.dead()
            if dead:
                reason[0] = f'processes exited: {dead}'
                break
            if duration > 0 and float(clock.get('sim_time', 0.0)) >= duration - 1e-6:
                reason[0] = 'duration reached'
                # the world's final counts: stats whose sim_time is the last step
                deadline = time.monotonic() + 10.0
                while (float(monitor.snapshot()[0].get('sim_time', 0.0)) < duration - 1e-6
                       and time.monotonic() < deadline and not stop.is_set()):
                    time.sleep(0.05)
                break
            if timeout > 0 and time.monotonic() - wall0 > timeout:
                reason[0] = 'wall-clock timeout'
                break
    finally:
        dead = team.dead()
        cpu = team.cpu_seconds()
        codes = team.stop()
        stats, clock = monitor.snapshot() if monitor else ({}, {})
        interventions = list(monitor.interventions) if monitor else []
        events = list(monitor.events) if monitor else []
        if monitor:
            monitor.close()
        bag = recorder.stop() if recorder else None
        for s, h in old.items():
            signal.signal(s, h)
    print(f'team stopped ({reason[0]}): {format_stats(stats, clock)}', file=out, flush=True)
    if bag is not None:
        print(f'recorded {bag.message_count} messages on {len(bag.topics)} topics: {bag.path}',
              file=out, flush=True)
    return {'stats': stats, 'clock': clock, 'interventions': interventions, 'events': events,
            'exit_codes': codes, 'dead': dead, 'reason': reason[0], 'cpu_seconds': cpu,
            'cpu_seconds_at_start': cpu_at_start or {}, 'bag': bag}


def exit_status(result: dict, log_dir) -> int:
    """The command's exit status after ``run_team``: 1 if a process died while the team ran,
    else 0; the processes that did not exit cleanly are named (with their logs' folder)."""
    unclean = {n: c for n, c in result['exit_codes'].items() if c != 0}
    if unclean:
        print(f'processes that did not exit cleanly (exit codes): {unclean}; logs in {log_dir}')
    if result['dead'] and result['reason'].startswith('processes exited'):
        return 1
    return 0


def parse_overrides(items) -> dict:
    """['supervisor.mu=1.0', ...] -> {'supervisor': {'mu': 1.0}} (values parsed as YAML)."""
    import yaml
    out: dict = {}
    for item in items or []:
        key, sep, value = item.partition('=')
        node, dot, param = key.partition('.')
        if not sep or not dot or node not in NODE_MODULES:
            raise ValueError(f"override '{item}' is not <node>.<param>=<value> with node in "
                             f'{sorted(NODE_MODULES)}')
        out.setdefault(node, {})[param] = yaml.safe_load(value)
    return out


def default_log_dir() -> Path:
    return Path(os.environ.get('TMPDIR', '/tmp')) / f'supersafe-team-{os.getpid()}'
