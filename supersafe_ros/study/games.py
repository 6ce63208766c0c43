"""Phase III on one kept-alive graph per subject: every condition's game without new processes.

The graph is the team of `supersafe team` (world, 2 x (robot, planner, safety filter),
supervisor; no learner, so interventions cannot refit the set in force) started once per
subject. The sim clock is not a process here: for each game a ``SimClockNode`` runs inside
this process, on a context whose DDS participant the graph discovered once, with
``start_time`` = where the last game stopped and ``duration`` = the game's length. Between
games, with the clock stopped, the runner resets everything a game depends on and waits for
each node to confirm:

1. the condition's safe set (``set_message``): one latched message on
   ``/safe_set/value_function`` (the filters run with ``use_learned`` true and
   ``alpha_offset`` 0). Standard is marked ``source: standard`` (each filter puts its own
   standard set back in force); Conservative (the radius-3.6 value function) and Learned
   sets carry their ``alpha`` (0; mu + k sigma) explicitly. Confirmed by each filter's
   "... set in force" log;
2. ``/world/reset`` (seed: the subject's world seed, the same for every condition):
   counts, H2 measures, layout (ids from 0) and goals afresh. Confirmed by
   ``resets`` in ``/world/stats``;
3. ``/supervisor/reset`` (the subject's w_max, mu, sigma and noise seed): every encounter
   forgotten. Confirmed by its "supervisor reset" log;
4. ``<robot>/initialpose`` to the team's start poses. Confirmed by each robot's
   "teleported" log.

The robots' first step of a game integrates from where the last game's clock stopped, so
it runs one step of the command in force then (the filter's last decision); the rest of
the game is the same closed loop as a fresh graph.
"""
from __future__ import annotations

import threading
import time
from pathlib import Path

from ..team import Team, TeamMonitor, node_argv, robot_names, start_poses, team_layout
from .protocol import ConditionSet, condition_set

N_ROBOTS = 2
RESEND_S = 15.0       # wall seconds before a reset request is sent again


def game_message(vf, alpha: float | None, label: str, **meta):
    """The value-function message of one condition. Standard: ``source: standard``, which
    puts each filter's own standard set back in force (the filters trust no received copy
    of it). Any other set (Conservative; Learned at mu + k sigma) is sent with its level,
    ``alpha`` None = 0 (the study's standard level), and each filter checks it against its
    standard set before using it."""
    from ..ros_io.vfmsg import value_function_to_msg
    if label == 'standard':
        return value_function_to_msg(vf, source='standard', condition=label, **meta)
    level = 0.0 if alpha is None else float(alpha)
    return value_function_to_msg(vf, source='learned' if alpha is not None else label, condition=label,
                                 alpha=level, mu=None, sigma=None, **meta)


def set_message(chosen: ConditionSet):
    """The value-function message of a condition's set (``protocol.condition_set``): a
    learned set with its level and its fit's mu, sigma and w_max; Standard and Conservative
    with none (``game_message``)."""
    if chosen.alpha is None:
        return game_message(chosen.value_function, None, chosen.ran)
    fit = chosen.fit
    return game_message(chosen.value_function, chosen.alpha, chosen.ran, fit_mu=fit['mu'],
                        fit_sigma=fit['sigma'], omega_max=fit['omega_max'])


def condition_message(condition: str, learned: dict, alpha_offset: float = 0.0):
    """(message, alpha or None, what ran) of one condition; ``learned``: condition ->
    (value function, fit) of the subject's learned sets. A learned condition without a
    fit runs the Standard set (and is counted so)."""
    chosen = condition_set(condition, learned, alpha_offset)
    return set_message(chosen), chosen.alpha, chosen.ran


def graph_argvs(world_seed: int, supervisor: dict, step: float, rate_factor: float) -> tuple:
    """(argv of every process but the clock, the clock's parameters) for a kept-alive graph."""
    overrides = {'safety_filter': {'use_learned': True, 'alpha_offset': 0.0},
                 'supervisor': dict(supervisor)}
    layout = team_layout(N_ROBOTS, rate_factor, seed=world_seed, step=step, with_learner=False,
                         overrides=overrides)
    argvs, clock = [], None
    for spec in layout:
        if spec.kind == 'sim_clock':
            clock = dict(spec.params)
            continue
        argvs.append(node_argv(spec.kind, spec.namespace, spec.params, spec.remaps))
    return argvs, clock


class GameGraph:
    """One subject's Phase III graph; ``play`` runs one game and returns the world's counts."""

    def __init__(self, env: dict, world_seed: int, supervisor: dict, step: float,
                 rate_factor: float, log_dir: Path, start_timeout: float = 120.0):
        from ..ros_io import rosmsg
        from diagnostic_msgs.msg import DiagnosticStatus
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from rcl_interfaces.msg import Log
        from rclpy.qos import QoSProfile, DurabilityPolicy, HistoryPolicy, ReliabilityPolicy
        from std_msgs.msg import Float32MultiArray
        self.env, self.step, self.supervisor = env, float(step), dict(supervisor)
        self.robots = robot_names(N_ROBOTS)
        self.sim_time = 0.0
        self.games = 0
        self.Pose = PoseWithCovarianceStamped
        argvs, self.clock_params = graph_argvs(world_seed, supervisor, step, rate_factor)
        self.clock_params['start_timeout'] = float(start_timeout)
        self.cond = threading.Condition()
        self.logs = {}                  # (node name, message prefix) -> count
        self.rejected = None            # a filter's rejection of a set: that game cannot run
        # the monitor (stats, intervention log, events) and this runner's endpoints share
        # one context: the graph discovers it once, so each game's clock is matched at once
        self.monitor = TeamMonitor(env)
        self.ros = self.monitor.ros
        node = self.node = self.monitor.node
        rosout_qos = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST,
                                reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(Log, '/rosout', self.on_log, rosout_qos)
        self.vf_pub = node.create_publisher(Float32MultiArray, '/safe_set/value_function',
                                            rosmsg.QOS_LATCHED)
        self.world_reset = node.create_publisher(DiagnosticStatus, '/world/reset', rosmsg.QOS_EVENTS)
        self.sup_reset = node.create_publisher(DiagnosticStatus, '/supervisor/reset', rosmsg.QOS_EVENTS)
        self.pose_pubs = {r: node.create_publisher(PoseWithCovarianceStamped, f'/{r}/initialpose',
                                                   rosmsg.QOS_EVENTS) for r in self.robots}
        self.team = Team(argvs, env, Path(log_dir)).start()
        self.rosmsg = rosmsg

    # -- confirmations ------------------------------------------------------------------
    # the filter confirms a learned set ("learned set in force: ...") and the standard set
    # ("... the local standard set is in force ...") in different words
    KEYS = (('safety_filter', (' set in force', ' set is in force')), ('supervisor', ('supervisor reset',)),
            ('dubins_robot', ('teleported to',)))

    def on_log(self, log):
        if (log.name.endswith('safety_filter') and ' rejected' in log.msg
                and (' set ' in log.msg or 'value function' in log.msg)):
            with self.cond:        # the set this game needs will not come into force
                self.rejected = f'{log.name}: {log.msg}'
                self.cond.notify_all()
        for kind, markers in self.KEYS:
            if log.name.endswith(kind) and any(m in log.msg for m in markers):
                with self.cond:
                    key = (log.name, kind)
                    self.logs[key] = self.logs.get(key, 0) + 1
                    self.cond.notify_all()

    def _counts(self, kind):
        with self.cond:
            return {k[0]: v for k, v in self.logs.items() if k[1] == kind}

    def _wait(self, what: str, done, deadline: float):
        while not done():
            if self.rejected:
                raise RuntimeError(f'game {self.games}: a filter rejected the set: {self.rejected}')
            dead = self.team.dead()
            if dead:
                raise RuntimeError(f'graph processes exited: {dead} (logs in {self.team.log_dir})')
            if time.monotonic() > deadline:
                raise RuntimeError(f'game {self.games}: no confirmation of {what} in time '
                                   f'(logs in {self.team.log_dir})')
            with self.cond:
                self.cond.wait(0.05)

    def _logged(self, kind: str, before: dict, n: int):
        """A check: ``n`` nodes of ``kind`` have logged their confirmation since ``before``."""
        def done():
            now = self._counts(kind)
            return sum(1 for name, c in now.items() if c > before[kind].get(name, 0)) >= n
        return done

    def _confirm(self, what: str, send, done, deadline: float, every: float = RESEND_S) -> int:
        """send(), then wait for done(), sending again every ``every`` wall seconds;
        returns how many times it was sent again."""
        send()
        resends = 0
        next_send = time.monotonic() + every
        while not done():
            if time.monotonic() > next_send:
                send()
                resends += 1
                next_send = time.monotonic() + every
            self._wait(what, lambda: done() or time.monotonic() > next_send, deadline)
        return resends

    def _wait_matched(self, deadline: float):
        """Every reset reader is in the graph (the filters and robots may load for seconds)."""
        pubs = [(self.vf_pub, N_ROBOTS), (self.world_reset, 1), (self.sup_reset, 1)] + \
            [(p, 1) for p in self.pose_pubs.values()]
        self._wait('the graph coming up', lambda: all(p.get_subscription_count() >= n for p, n in pubs),
                   deadline)

    # -- one game -----------------------------------------------------------------------
    def play(self, vf_msg, world_seed: int, supervisor_seed: int, game_seconds: float,
             timeout: float) -> dict:
        """Reset the graph for a game, run ``game_seconds`` of sim time, return the counts
        (``/world/stats`` values at the game's end), its intervention log and wall time."""
        t0 = time.monotonic()
        deadline = t0 + timeout
        self._wait_matched(deadline)
        stats_before = self.monitor.snapshot()[0]
        resets = int(float(stats_before.get('resets', 0) or 0))
        n_log = len(self.monitor.interventions)
        before = {k: self._counts(k) for k, _ in self.KEYS}
        sup = dict(self.supervisor, seed=int(supervisor_seed))

        def teleport():
            for r, pose in zip(self.robots, start_poses(N_ROBOTS)):
                msg = self.Pose()
                msg.header.frame_id = self.rosmsg.MAP_FRAME
                msg.pose.pose = self.rosmsg.state_to_pose(pose).pose
                self.pose_pubs[r].publish(msg)
        # every request is idempotent while the clock is stopped, so a confirmation that
        # does not come (a /rosout message lost on a loaded machine) is asked for again
        resends = 0
        resends += self._confirm('the set in force', lambda: self.vf_pub.publish(vf_msg),
                                 self._logged('safety_filter', before, N_ROBOTS), deadline)
        resends += self._confirm(
            'the world reset',
            lambda: self.world_reset.publish(self.rosmsg.make_diagnostic('reset', {'seed': int(world_seed)})),
            lambda: int(float(self.monitor.snapshot()[0].get('resets', 0) or 0)) > resets, deadline)
        resends += self._confirm(
            'the supervisor reset',
            lambda: self.sup_reset.publish(self.rosmsg.make_diagnostic('reset', sup)),
            self._logged('supervisor', before, 1), deadline)
        resends += self._confirm('the robots at their start', teleport,
                                 self._logged('dubins_robot', before, N_ROBOTS), deadline)
        cpu0 = self.team.cpu_seconds()
        start = self.sim_time
        end = start + float(game_seconds)
        clock = self._start_clock(start, float(game_seconds))
        wall_run = time.monotonic()
        try:
            self._wait('the end of the game',
                       lambda: float(self.monitor.snapshot()[0].get('sim_time', 0) or 0) >= end - 1e-6,
                       deadline)
        finally:
            self._stop_clock(clock)
        stats = self.monitor.snapshot()[0]
        cpu = self.team.cpu_seconds()
        self.sim_time = end
        self.games += 1
        return {'stats': dict(stats, sim_time=f'{end - start:.3f}'),
                'interventions': list(self.monitor.interventions[n_log:]),
                'wall': time.monotonic() - t0, 'wall_running': time.monotonic() - wall_run,
                # CPU of the graph's processes while the game ran (the clock runs in here)
                'resends': resends,
                'cpu_s': sum(cpu.get(k, 0.0) - cpu0.get(k, 0.0) for k in cpu),
                'cpu_by_process': {k: round(cpu[k] - cpu0.get(k, 0.0), 2) for k in cpu}}

    def _start_clock(self, start: float, duration: float):
        from rclpy.logging import LoggingSeverity
        from rclpy.parameter import Parameter
        from ..nodes.sim_clock_node import SimClockNode
        params = dict(self.clock_params, start_time=start, duration=duration)
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        clock = SimClockNode(context=self.ros.context, parameter_overrides=overrides)
        # its per-game start/stop lines would interleave with the study's progress lines
        clock.get_logger().set_level(LoggingSeverity.WARN)
        self.ros._executor.add_node(clock)
        return clock

    def _stop_clock(self, clock):
        clock.close()
        self.ros._executor.remove_node(clock)
        clock.destroy_node()

    def close(self):
        try:
            self.team.stop()
        finally:
            self.monitor.close()
