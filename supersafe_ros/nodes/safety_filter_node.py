"""safety_filter_node: the minimally invasive safety filter of one robot, or of a fleet: one node.

Its robots are ``robots`` (default ``['']``: one robot, in the node's own namespace; a fleet lists
its robots' namespaces, resolved as topic names are). Each robot's own topics (``per_robot_topics``;
types as ``pose_type``, ``detections_type``, ``cmd_vel_stamped`` say, docs/topics.md): in
``pose``, ``detections`` (none with ``require_detections`` false), ``cmd_vel_nav``; out
``cmd_vel``, ``safety_filter/state`` (what was decided and why, named by the robot's namespace),
``safety_filter/ready`` (latched, once the robot's filter can judge), ``safety_filter/level_set``;
their endpoints belong to the helper node ``<name>_io`` (``filter_topics``). The batched topics of
every robot at once (``batched_topics``, ``filter_batched``): fleet/poses, fleet/detections,
fleet/cmd_vel_nav -> fleet/cmd_vel, fleet/safety_filter/state. And /safe_set/value_function in
(``filter_wiring``), /diagnostics out (a status per robot, 1 Hz). fleet_safety_filter_node is this
node named fleet_safety_filter; ``ManagedSafetyFilterNode`` the managed one (``managed``).

Each input is read by its Source (``filter_sources``: checked, or refused with the fault named: the
robot then fails safe and the node complains) and taken into the robot's filter
(``filter.inputs.RobotFilter``); a decision (``filter.decide.decide_many``, nothing written) goes
out one way: the lockstep policy (``runtime.lockstep``) says whether it goes out now; then the
robots' cmd_vel (they wait for it), the record of what was sent (``filter.sent.record_decisions``,
the one writer), the story in the log and the states that are due (docs/filter_learner.md, "How a
decision is made").

When robots are decided (``decide_on``, ``filter_parameters.decision_mode``):

* input (one robot on its own topics, by default): at once on each planner command and range
  sensor's message (each pose with ``publish_on_pose``), that robot alone, plus a watchdog on the
  steady clock deciding a robot nothing went out to for half of 1/rate, so a robot never starves,
  even with its planner dead. Inputs and watchdog are served by a thread of their own
  (``direct_take``, ``ros_io.direct_take``), or by the executor;
* tick (a fleet, or with batched topics): every robot at once, ``rate`` times a second, on the
  newest message of each input (taken then, ``ros_io.take``: no callback per message), and on each
  fleet/poses message; the timer stands in once the batched poses pause (1.5 periods).

``lockstep`` (simulated robots under sim_clock_node, ``supersafe team``): a robot acknowledges its
step on the first command after its pose, and the clock then advances. So the filter answers each
pose once, on that pose; a planner command only updates what the next pose's answer judges; the
watchdog speaks only after ``lockstep_silence`` steady seconds without a pose; a pose the clock has
passed is skipped, and with ``cluster_hold_timeout`` > 0 the answer to a pose near a cluster whose
union value is being solved is held (docs/graph_safety.md).

A robot fails safe before its first valid detections and whenever they are stale (a detections
message means "the sensor has looked"); one without an obstacle sensor opts out with
``require_detections`` false. Ages are on the filter's time base (``runtime.timebase``): sim time
while /clock advances, the steady clock otherwise.
"""
from __future__ import annotations

from functools import partial
import threading
import time

from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticStatus

from ..filter import FAIL_SAFE
from ..filter.decide import decide_many
from ..filter.sent import record_decisions
from ..runtime.lockstep import GIVE_UP, LockstepAnswers
from ..ros_io import rosmsg
from ..ros_io.direct_take import DirectTake, helper_node
from ..ros_io.take import take, take_all
from .common import run_node
from .filter_diagnostics import FilterDiagnostics, status_copy
from .filter_parameters import INPUT, MAP_SENSORS, FilterParameters
from .filter_sources import NO_DETECTIONS, CommandSource, DiscSource, PoseHistory, PoseSource, SensorMap
from .filter_state import HoldSummary, StateThrottle, Status, Story
from .filter_batched import FleetTopics
from .filter_topics import RobotTopics, robot_topic
from .filter_wiring import VALUE_FUNCTION_TOPIC, FilterWiring  # noqa: F401  (the topic, re-exported for tests)
from .managed import ManagedFilter
from .markers import LevelSetMarkerPublisher


class SafetyFilter:
    """The filter of a node's robots (``self``: a Node or a LifecycleNode); ``build()`` makes it
    (the plain node in its constructor, the managed one on configure). It decides only while
    ``active``."""

    active = True

    def build(self):
        # every callback that reads or changes the filters holds this lock (the inputs may be
        # taken by a thread of their own; parameters change under it too)
        self.lock = threading.RLock()
        self.params = p = FilterParameters(self)
        v = p.values
        self.namespaces = p.robots
        self.n = len(self.namespaces)
        self.wiring = w = FilterWiring(self, p, self.namespaces, on_rate=self._set_rate, lock=self.lock)
        self.filters = w.filters
        self.mode, self.lockstep = p.mode, p.lockstep
        self.publish_on_pose = v['publish_on_pose']
        w.live.add('publish_on_pose', lambda value: setattr(self, 'publish_on_pose', bool(value)))
        self.require_detections = v['require_detections']
        self.pose_source = PoseSource(v['pose_type'], w.frame)
        self.command_source = CommandSource(v['cmd_vel_stamped'])
        self.disc_source = self.sensors = None
        self.io = helper_node(self)     # the robots' endpoints (filter_topics), off the executor
        self.direct = self.timer = None
        if self.require_detections and v['detections_type'] in MAP_SENSORS:
            # a range sensor or a costmap: each robot's local map and its value
            self.sensors = [SensorMap(v, PoseHistory(), w.config, p.standard_horizon, w.frame, inline=self.lockstep)
                            for _ in range(self.n)]
            self.sensors[0].say_settings(v, w.config, self.get_logger())
        elif self.require_detections:
            self.disc_source = DiscSource(v['detections_type'], w.frame)
        self.topics = []
        if p.per_robot_topics:
            self.topics = [RobotTopics(self, self.io, ns, v['cmd_vel_stamped'], v['level_set_markers'])
                           for ns in self.namespaces]
        self.fleet = (FleetTopics(self, self.io, self.n, self.on_fleet_poses, self.require_detections)
                      if p.batched_topics else None)
        if self.topics and v['level_set_markers']:
            self.level_set = LevelSetMarkerPublisher(
                self, [(topics.level_set_pub, partial(self._level_set_snapshot, i))
                       for i, topics in enumerate(self.topics)], v['level_set_rate'])
        # each robot's run time: what went out, the lockstep's answers, the story
        now = time.monotonic()
        self.last = [None] * self.n               # (Decisions, row) of each robot's last decision sent
        self.last_state = [None] * self.n         # its last state message
        self.last_publish = [-1e18] * self.n      # steady s
        self.answers = [LockstepAnswers(v['cluster_hold_timeout'], v['lockstep_silence'], now)
                        for _ in range(self.n)]
        self.throttle = StateThrottle(self.n, now, w.state_period)
        self.story = Story(self.get_logger(), self.namespaces)
        self.holds = HoldSummary(self.get_logger())
        self.ready_due = set() if self.require_detections else set(range(self.n))    # say safety_filter/ready
        self.clipped, self.dropped = [], []       # robots whose command was clipped, detections cut
        self.decisions = self.ticks = self.failing_safe = 0    # (counts: tests, benches)
        self.decided = [0] * self.n               # decisions sent, per robot
        inputs = self._subscribe(v)
        self._set_rate(w.rate)
        if self.direct is not None:
            self.direct.start()         # (its wait set sized, the watchdog's period set)
        self.diagnostics = FilterDiagnostics(self, self._statuses, inputs, w.complain)
        self._say_ready()
        self._say_start()

    # -- making it ---------------------------------------------------------------------------------
    def _sources(self):
        """(Source, what takes it, what an input-mode callback does) of each robot input, in the order
        taken: pose, detections, command (ready together, a command is judged on the detections that
        came with it)."""
        out = [(self.pose_source, self.take_pose, self.on_pose)]
        if self.sensors is not None:
            out.append((self.sensors[0], self.take_sensor, self.on_sensor))
        elif self.disc_source is not None:
            out.append((self.disc_source, self.take_detections, self.on_detections))
        out.append((self.command_source, self.take_command, self.on_command))
        return out

    def _subscribe(self, v) -> list:
        """Each robot's inputs subscribed as ``mode`` takes them; [(topic, message class)] of every input
        (the graph watch's)."""
        inputs, noop = [], lambda msg: None
        if self.mode == INPUT and v['direct_take'] and not self.lockstep:
            self.direct = DirectTake(self, self.lock, path=self.params.take_path, io=self.io)
        self.subs = [[] for _ in self.namespaces]     # (tick) each robot's (subscription, taker, every message)
        try:
            for i, ns in enumerate(self.namespaces if self.topics else ()):
                for source, taker, on_message in self._sources():
                    topic = robot_topic(self, ns, source.topic)
                    inputs.append((topic, source.msg_type))
                    if self.direct is not None:     # a thread of their own (the executor keeps the rest)
                        self.direct.add(source.msg_type, topic, partial(on_message, i), source.qos, raw=source.raw)
                    elif self.mode == INPUT:
                        # the executor's (lockstep: it reads /clock before a pose that waits with it, so a pose
                        # the clock has passed is known as such, _clock_passed; a thread of its own would not)
                        self.create_subscription(source.msg_type, topic, self._locked(partial(on_message, i)),
                                                 source.qos, raw=source.raw)
                    else:       # taken by the tick, never an executor: each scan (it adds to the map), else the newest
                        every = taker == self.take_sensor
                        self.subs[i].append((self.io.create_subscription(
                            source.msg_type, topic, noop, source.qos if every else rosmsg.QOS_NEWEST, raw=source.raw),
                            taker, every))
        except BaseException:
            if self.direct is not None:
                self.direct.close()
            raise
        if self.fleet is not None:
            inputs += self.fleet.inputs()
        return inputs

    def _say_start(self):
        w = self.wiring
        if self.mode == INPUT and self.n == 1:
            what = 'filtering cmd_vel_nav -> cmd_vel'
        else:
            shown = ', '.join(self.namespaces[:5]) + (', ...' if self.n > 5 else '')
            what = (f'filtering {self.n} robot(s) ({shown}), '
                    + ('each on its own inputs' if self.mode == INPUT else f'all at once {w.rate:g} times a second')
                    + f'; per-robot topics {"on" if self.topics else "off"}, batched topics '
                    + ('on' if self.fleet is not None else 'off'))
        if self.require_detections:
            self.get_logger().info(f'{what}; waiting for the first pose and detections (failing safe until then)')
        else:
            self.get_logger().info(f'{what}; require_detections false: no obstacle sensor, every pose is judged '
                                   'with no obstacle; waiting for the first pose')

    def _set_rate(self, rate):
        self.period = 1.0 / rate
        if self.direct is not None:          # the inputs' thread serves the watchdog (under the lock)
            self.direct.tick(self.period, self.on_watchdog)
            return
        if self.timer is not None:
            self.destroy_timer(self.timer)
        on_timer = self.on_watchdog if self.mode == INPUT else self.on_tick
        self.timer = self.create_timer(self.period, self._locked(on_timer), clock=self.wiring.steady)

    def _locked(self, callback):
        def locked(*args):
            with self.lock:
                return callback(*args)
        return locked

    # -- inputs: read by their Sources, taken into a robot's filter ---------------------------------------
    def take_pose(self, i, data, t):
        """A serialized pose (``pose_type``; ``PoseSource``) as robot i's; the header's stamp (None if
        unreadable). A pose refused fails the robot safe and is said."""
        w, f = self.wiring, self.filters[i]
        stamp = None
        try:
            state, stamp = self.pose_source.read(data)
            tau = w.stamp(stamp, t)
            f.update_pose(state, t, stamp=tau)
        except ValueError as exc:   # MessageError is a ValueError
            f.reject_pose(str(exc), t)
            self._complain(i, 'pose', f'pose rejected: {exc}; failing safe', level='error')
            return stamp
        if self.sensors is not None:     # (the poses a local map places its returns with)
            self.sensors[i].history.add(t if tau is None else tau, state)
        if not self.require_detections:
            f.update_detections(NO_DETECTIONS, t)
        return stamp

    def take_detections(self, i, data, t):
        """A serialized PoseArray or a MarkerArray (``DiscSource``): robot i's detections, at most
        ``max_detections`` of them (the nearest; the state and a log line say which were dropped)."""
        f = self.filters[i]
        try:
            f.update_detections(self.disc_source.read(data), t, self.wiring.safe_set)
        except ValueError as exc:
            f.reject_detections(str(exc), t)
            self._complain(i, 'detections', f'detections rejected: {exc}; failing safe', level='error')
            return
        self.ready_due.add(i)
        if f.detections.dropped:
            self.dropped.append(i)

    def take_sensor(self, i, msg, t) -> bool:
        """A LaserScan, PointCloud2 or OccupancyGrid into robot i's local map (``SensorMap.take_into``),
        the map's value asked for again; False if it could not be placed yet (no pose: starting)."""
        sensor = self.sensors[i]
        placed, learned = sensor.take_into(self.filters[i], msg, t, self.wiring, partial(self._complain, i))
        if learned:
            self.ready_due.add(i)
        if placed and self.active:     # (inactive: no decision reads the value; solved again once active)
            sensor.ask_value(self.wiring, partial(self._complain, i))
        return placed

    def take_command(self, i, data, t):
        """A serialized Twist or TwistStamped (``CommandSource``) as robot i's planner command; its
        header is that of the cmd_vel judged from it. A command not finite or unreadable stops a robot
        that can stop until a valid one comes."""
        f = self.filters[i]
        if not self.command_source.take(f, data, t, self.topics[i].sink):
            self._complain(i, 'cmd', f'cmd_vel_nav rejected: {f.command.note}')
        elif f.command.note:
            self.clipped.append(i)

    def _complain(self, i, kind, text, level='warn'):
        """A throttled log line about robot i (named in a fleet)."""
        if self.n == 1:
            self.wiring.complain(kind, text, level=level)
        else:
            self.wiring.complain(f'{kind} {self.namespaces[i]}', f'{self.namespaces[i]}: {text}', level=level)

    # -- decide_on input: each message decides its robot -----------------------------------------------
    def on_pose(self, i, data):
        t = self.wiring.now()
        stamp = self.take_pose(i, data, t)
        if self.lockstep:
            self.answers[i].new_pose(time.monotonic())
            if stamp is not None and self._clock_passed(i, stamp):
                return
            self.decide((i,), t, answers_pose=True)
        elif self.publish_on_pose:
            self.decide((i,), t)

    def on_detections(self, i, data):
        self.take_detections(i, data, self.wiring.now())

    def on_sensor(self, i, msg):
        t = self.wiring.now()
        if self.take_sensor(i, msg, t) and not self.lockstep:
            self.decide((i,), t)

    def on_command(self, i, data):
        t = self.wiring.now()
        self.take_command(i, data, t)
        if not self.lockstep:       # in lockstep the next pose's answer judges it
            self.decide((i,), t)

    def _clock_passed(self, i, stamp) -> bool:
        """Lockstep with sim time: True (and said) if /clock is already past this pose, which the robot
        has acknowledged without this answer (``LockstepAnswers.clock_passed``). Answering it would
        acknowledge the newer step with a decision on the older pose, and the filter would stay a step
        behind from then on (seen at start-up: up to 5 steps, 1 s, for seconds). Skipping it lets the
        next, current pose be answered."""
        answers = self.answers[i]
        clock_ns = self.get_clock().now().nanoseconds if self.wiring.time.sim else None
        if not answers.clock_passed(stamp.sec * 1_000_000_000 + stamp.nanosec, clock_ns):
            return False
        self._complain(i, 'lockstep', f'skipped a pose the clock has already passed ({answers.poses_skipped} so '
                       'far): its step went on without this answer; answering the current pose', level='info')
        return True

    def on_watchdog(self):
        """Every period: each robot whose last command went out half a period ago or more is decided
        again (not starved: its planner may be dead); in lockstep, a held answer once the cluster value
        is in force (or timed out), and nothing while poses come (a pose's answer is the robot's step)."""
        self._say_ready()
        now = time.monotonic()
        if not self.lockstep:
            # half a period, not a whole one: the last output went out a little after the previous
            # tick, so a whole period would skip every other tick (rate / 2)
            due = [i for i, last in enumerate(self.last_publish) if now - last >= self.period * 0.5]
            if due:
                self.decide(due)
            return
        for i, answers in enumerate(self.answers):
            held = answers.held_pose_time
            if held is not None:
                self.decide((i,), held)       # a held answer: out once the cluster value is in force
            elif answers.quiet(now):
                # the pose's answer is the robot's command (and its step's ack); the state topic still
                # reports the set in force (a new learned set) while no pose comes
                last = self.last[i]
                if last is not None and self.throttle.due(now, (i,), (last[0].action[last[1]],),
                                                          self.wiring.set_update, self.wiring.state_period):
                    self._say_states([i], [last[0][last[1]]])
            elif now - self.last_publish[i] >= self.period * 0.5:
                self.decide((i,))

    # -- decide_on tick: every robot at once ------------------------------------------------------------
    def on_tick(self):
        if not self.topics and self.fleet.flowing(time.monotonic(), self.period):
            return      # the batched poses are ticking (each decides)
        self.decide_all()

    def decide_all(self, t=None):
        """Every robot's inputs that wait taken (the batched ones first, unless a fleet/poses message has
        just done so, ``t``), then every robot decided."""
        w = self.wiring
        if t is None:
            self._take_batched()
            t = w.now()
        if self.topics:
            for i, subs in enumerate(self.subs):
                for sub, taker, every in subs:
                    if every:
                        for msg in take_all(sub):
                            taker(i, msg, t)
                    else:
                        data = take(sub)
                        if data is not None:
                            taker(i, data, t)
        self.ticks += 1
        self._say_ready()
        return self.decide(None, t)

    # -- batched topics ----------------------------------------------------------------------------------
    def on_fleet_poses(self, data):
        """A serialized fleet/poses (``FleetTopics``): every robot's pose, then a tick of every robot. Poses
        that came while the filter was deciding are superseded by the newest: it decides once, on the
        newest (deciding on each in turn would answer ever older poses)."""
        with self.lock:
            fleet = self.fleet
            data = fleet.newest_poses(data, self.wiring.complain)
            self._take_batched()       # the detections and commands sent before these poses
            t = self.wiring.now()
            fleet.take_poses(data, self.filters, self.wiring, t, self._complain)
            self.decide_all(t)
            fleet.last_poses = time.monotonic()
            self.timer.reset()      # the timer decides only when the poses pause (on_tick)

    def _take_batched(self):
        """Every fleet/detections and fleet/cmd_vel_nav message waiting (``FleetTopics.take_waiting``)."""
        if self.fleet is not None:
            beyond, ready = self.fleet.take_waiting(self.filters, self.wiring, self._complain)
            if ready:
                self.ready_due.update(range(self.n))
            self._tell_excess(beyond, [], 'fleet/cmd_vel_nav')

    # -- the decision, one direction -------------------------------------------------------------------
    def decide(self, rows=None, t=None, answers_pose=False):
        """Decide robots ``rows`` (None: every robot) at filter time ``t`` and send what the lockstep
        policy lets go out: their commands first (the robots wait for them), then the record of what was
        sent, the story and the states due. ``answers_pose``: the answer to robot rows[0]'s lockstepped
        pose, which may be held (then the watchdog decides again, and None is returned)."""
        if not self.active:
            return None            # a managed node, inactive: no cmd_vel (managed.py)
        w = self.wiring
        t = w.now() if t is None else t
        filters = self.filters if rows is None else [self.filters[i] for i in rows]
        rows = range(self.n) if rows is None else rows
        decisions = decide_many(filters, w.safe_set, t)
        verdict = None
        if self.lockstep:       # (one robot at a time)
            verdict = self.answers[rows[0]].judge(t, time.monotonic(), decisions.clusters_solving(0), answers_pose)
            if not verdict.publish:
                return None     # held: not sent, so not recorded as sent
        self._send(rows, filters, decisions, t)
        record_decisions(filters, decisions)
        if verdict is not None and verdict.action == GIVE_UP:
            self._complain(rows[0], 'cluster_hold', f'{verdict.why}: answering with the fallback until it lands',
                           level='warn')
        elif verdict is not None and verdict.held_for is not None:
            self.holds.held(verdict.held_for)
        self._after(rows, filters, decisions, t)
        return decisions

    def _send(self, rows, filters, decisions, t):
        """The commands out: each robot's cmd_vel (serialized, ``CommandSink``), and fleet/cmd_vel when
        every robot was decided."""
        if self.topics:
            topics, clock = self.topics, self._clock_ns
            for i, f, action, linear, omega in zip(rows, filters, decisions.action, decisions.linear,
                                                   decisions.omega):
                topics[i].send(f, t, action, linear, omega, clock)
        if self.fleet is not None and len(rows) == self.n:
            self.fleet.send(decisions)

    def _after(self, rows, filters, decisions, t):
        """What follows the commands: each robot's last decision kept, the story told, what was
        clipped or cut said, the states that are due sent."""
        now = time.monotonic()
        last, last_publish, decided = self.last, self.last_publish, self.decided
        for k, i in enumerate(rows):
            last[i] = (decisions, k)
            last_publish[i] = now
            decided[i] += 1
        self.decisions += 1
        if len(rows) == self.n:
            self.failing_safe = decisions.action.count(FAIL_SAFE)
        self.story.tell(rows, decisions, filters, t)
        if self.clipped or self.dropped:
            self._tell_excess(self.clipped, self.dropped, 'cmd_vel_nav')
            self.clipped, self.dropped = [], []
        w = self.wiring
        due = self.throttle.due(now, rows, decisions.action, w.set_update, w.state_period)
        if due:
            self._say_states([rows[k] for k in due], [decisions[k] for k in due], every=len(rows) == self.n)

    def _say_states(self, robots, outs, every=False):
        """The state messages of ``robots`` (their outputs ``outs``), each built once, on their own topics
        and, for a tick of ``every`` robot, fleet/safety_filter/state."""
        w = self.wiring
        shared = w.shared_state_values()
        sensors = self.sensors
        states = []
        for i, out in zip(robots, outs):
            extra = None if sensors is None else sensors[i].state_values(self.filters[i].detections)
            state = w.state_message(self.namespaces[i], out, extra, shared)
            self.last_state[i] = state
            states.append(state)
        if self.topics:
            for i, state in zip(robots, states):
                self.topics[i].say_state(state)
        if every and self.fleet is not None:
            self.fleet.say_states(states)

    def _tell_excess(self, clipped, dropped, commands):
        """One throttled line for the robots whose new commands were beyond their limits (the first one's
        raw values), one for those whose detections were cut to max_detections."""
        if clipped:         # (a kind per topic: one does not silence the other)
            f = self.filters[clipped[0]]
            self.wiring.complain(f'{commands} clipped', f'{commands} beyond the robot\'s limits'
                                 f'{self.story.who(clipped)}: {self._named(clipped[0])}{f.command.note}')
        if dropped:
            shown = next((i for i in dropped if not self.filters[i].detections.dropped_safely), dropped[0])
            d = self.filters[shown].detections
            self.wiring.complain('detections dropped', f'detections cut{self.story.who(dropped)}: '
                                 f'{self._named(shown)}{d.note}', level='warn' if d.dropped_safely else 'error')

    def _named(self, i) -> str:
        return '' if self.n == 1 else f'{self.namespaces[i]}: '

    def _say_ready(self):
        """Each robot's latched safety_filter/ready once its filter can judge (from the watchdog's or the
        tick's thread: a publisher made off the control path)."""
        if self.ready_due and self.topics:
            for i in sorted(self.ready_due):
                self.topics[i].say_ready()
        self.ready_due.clear()

    def _clock_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    # -- what it says ----------------------------------------------------------------------------------
    def _level_set_snapshot(self, i):
        f = self.filters[i]
        with self.lock:
            return self.wiring.safe_set, f.pose.value, f.detections.value

    def _statuses(self) -> list:
        """Each robot's status on /diagnostics: its last state message (at most 1/state_rate old, and
        every change of action at once: not built again for /diagnostics, which a fleet of thousands
        would pay for each second), with what its sensor's last message says of itself."""
        w, node = self.wiring, self.get_fully_qualified_name()
        out, shared = [], None
        with self.lock:     # (the states are refilled by decide, on the inputs' thread too)
            for i, ns in enumerate(self.namespaces):
                name, last = f'{node}: {ns}', self.last[i]
                if last is None:
                    out.append(Status(DiagnosticStatus.ERROR[0], name, 'no decision yet' if self.active else
                                      'inactive: no cmd_vel', ns))
                    continue
                state = self.last_state[i]
                if state is None:       # (none published yet)
                    shared = shared or w.shared_state_values()
                    state = w.state_message(ns, last[0][last[1]], shared=shared)
                status = status_copy(state, name, ns, None if self.active else
                                     f'inactive (lifecycle): no cmd_vel; last: {state.message}')
                note = self.sensors[i].problem(self.filters[i].detections) if self.sensors is not None else ''
                if note:        # what the sensor's last message says of itself (every beam NaN, ...)
                    status.level = max(status.level, DiagnosticStatus.WARN[0])
                    status.message = f'{status.message}; {note}'
                out.append(status)
        return out

    def send_zero_twist(self) -> list:
        """One zero twist on every robot's cmd_vel (and fleet/cmd_vel): a managed node going quiet
        (managed.py), the bases must not keep the last commands; the publishers it went out on. Under
        the lock: after a decision under way on the inputs' thread, never before it."""
        with self.lock:
            for topics in self.topics:
                topics.send_zero(self._clock_ns)
            if self.fleet is not None:
                self.fleet.send_zero()
        return [topics.cmd_pub for topics in self.topics] + ([self.fleet.cmd_pub] if self.fleet is not None else [])

    def close(self):
        """Close what build() made, also when it failed half way (a managed node's failed configure)."""
        direct = getattr(self, 'direct', None)
        if direct is not None:
            direct.close()
        for sensor in getattr(self, 'sensors', None) or ():
            sensor.close()
        holds = getattr(self, 'holds', None)
        if holds is not None:
            holds.flush()
        wiring = getattr(self, 'wiring', None)
        if wiring is not None:
            wiring.close()
            wiring.live.close()
        io = getattr(self, 'io', None)
        if io is not None:
            self.io = None
            io.destroy_node()

    def destroy_node(self):
        if getattr(self, 'direct', None) is not None:
            self.direct.close()          # its thread stops before the handles it waits on go
        if getattr(self, 'wiring', None) is not None:
            self.wiring.sets.close()
        return super().destroy_node()


class SafetyFilterNode(SafetyFilter, Node):
    """The SafetyFilter as a plain node: built and deciding from construction."""

    def __init__(self, node_name='safety_filter', **kwargs):
        Node.__init__(self, node_name, **kwargs)
        self.build()


class ManagedSafetyFilterNode(ManagedFilter, SafetyFilter, LifecycleNode):
    """The SafetyFilter as a managed (lifecycle) node: built on configure, deciding while active
    (nodes/managed.py)."""

    def __init__(self, node_name='safety_filter', **kwargs):
        LifecycleNode.__init__(self, node_name, **kwargs)
        self.start_lifecycle()


def main(args=None):
    return run_node(SafetyFilterNode, args)


def main_managed(args=None):
    return run_node(ManagedSafetyFilterNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
