"""The study's Phase II conductor: an rclpy node inside the study runner.

It plays the authors' Phase II protocol on the running graph (one robot, world with
``respawn`` false and no obstacles, supervisor, learner). First it waits until every
``/interventions`` reader (world, learner, itself) is in the graph, until every learner
named in ``learners`` says on its ``~/inputs`` that each of its inputs has matched every
publisher this node sees (an intervention, pose or obstacle set sent before that match
would be lost to it: on a loaded machine the pairwise matches come seconds after the
graph's counts), plus one settling wall second; the robot stays parked meanwhile. Then,
for every lateral offset y0, a scene:

  A. ``/world/set_obstacles`` with no obstacle; ``robot_0/initialpose`` 6 m behind the
     start line (outside the supervisor's grid); wait for a pose there;
  A2. wait until the supervisor has judged that pose (``/supervisor/step_done``): it lags
     the robot by up to two steps and would judge the old poses against the new obstacle;
  B. ``/world/set_obstacles`` with one disc at the origin; wait for its marker (a new
     obstacle id, hence a new encounter for the supervisor);
  C. ``initialpose`` one step behind (x0, y0, 0), so the first pose of the scene is at
     x0; wait for it;
  D. drive: the scene's frames are recorded from here; it ends at the supervisor's
     intervention on this obstacle (``/interventions``, frame obstacle_<id>), or
  E. once the robot is past the obstacle (x > x_end) and the supervisor has judged
     that pose (an intervention on those last poses still counts).

The conductor is also the robot's controller: it answers the newest pose with a zero
Twist on ``robot_0/cmd_vel`` (u = 0; the lockstep robot acknowledges its step when a
command arrives, so from the first reply on the robot steps only when answered). The
requests use reliable transient-local publishers (compatible with volatile and
transient-local readers).
"""
from __future__ import annotations

import math
import threading
import time


ROBOT = 'robot_0'
POSE_TOL = 0.05
READERS = 3       # world, learner, this conductor (the study's Phase II adds its first-passage learner)
SETTLE_S = 1.0
LEAD_IN = 6.0     # m behind the start line where the robot waits while a scene is set


def yaw_of(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class Phase2Conductor:
    def __init__(self, env: dict, offsets, x0: float = -8.0, x_end: float = 2.5,
                 step_length: float = 0.6, readers: int = READERS, learners=()):
        from ..ros_io.background_node import BackgroundNode
        from rclpy.qos import QoSProfile, DurabilityPolicy, HistoryPolicy, ReliabilityPolicy
        from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped, Twist
        from std_msgs.msg import Float32MultiArray
        from visualization_msgs.msg import MarkerArray
        from ..ros_io import rosmsg
        self.msgs = {'PoseArray': PoseArray, 'PoseWithCovarianceStamped': PoseWithCovarianceStamped,
                     'Twist': Twist}
        self.offsets = [float(v) for v in offsets]
        self.readers = int(readers)     # /interventions readers to wait for before the first scene
        self.learner_inputs = {name: None for name in learners}   # node name: newest ~/inputs values
        self.x0, self.x_end = float(x0), float(x_end)
        # a teleported, commanded robot moves one step before its next pose: teleport that
        # much behind x0 so that the scene's first pose is at x0
        self.step_length = float(step_length)
        self.scenes = []
        self.scene_index = -1
        self.stage = 'idle'
        self.obstacle_id = None
        self.marker_ids = None          # ids of the latest marker set
        self.sim_time = 0.0
        self.frames = []
        self.done = threading.Event()
        self.settle_until = None
        self.received = []             # every intervention on a scene's obstacle, as sent
        self.lock = threading.Lock()
        self.vf_msgs = []
        self.fit_event = threading.Condition()

        self.ros = BackgroundNode('study_conductor', env['ROS_DOMAIN_ID'])
        self.node = self.ros.node
        # transient local + reliable is compatible with volatile and transient-local readers
        request_qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                                 reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.obstacles_pub = self.node.create_publisher(PoseArray, '/world/set_obstacles', request_qos)
        self.pose_pub = self.node.create_publisher(PoseWithCovarianceStamped, f'/{ROBOT}/initialpose',
                                                   request_qos)
        self.cmd_pub = self.node.create_publisher(Twist, f'/{ROBOT}/cmd_vel', rosmsg.QOS_STREAM)
        # only the newest pose: each reply acknowledges the robot's current lockstep step,
        # so replies to a backlog of old poses (a conductor slowed by a loaded machine
        # while sim time ran free before the first command) would let the robot drive
        # on unseen, past the scene's checkpoints. In step the robot waits for every
        # reply, so no pose of a scene is dropped.
        newest_only = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                                 reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.VOLATILE)
        self.node.create_subscription(PoseStamped, f'/{ROBOT}/pose', self.on_pose, newest_only)
        self.node.create_subscription(PoseStamped, '/interventions', self.on_intervention,
                                      rosmsg.QOS_EVENTS)
        self.node.create_subscription(MarkerArray, '/obstacle_markers', self.on_markers,
                                      rosmsg.QOS_LATCHED)
        self.node.create_subscription(Float32MultiArray, '/safe_set/value_function', self.on_vf,
                                      rosmsg.QOS_LATCHED)
        from diagnostic_msgs.msg import DiagnosticStatus
        for name in self.learner_inputs:
            self.node.create_subscription(
                DiagnosticStatus, f'/{name}/inputs',
                lambda m, name=name: self.learner_inputs.__setitem__(name, rosmsg.diagnostic_values(m)),
                rosmsg.QOS_LATCHED)
        from rosgraph_msgs.msg import Clock
        self.judged = -1.0            # newest sim time whose poses the supervisor has judged
        self.node.create_subscription(Clock, '/supervisor/step_done', self.on_judged, rosmsg.QOS_ACK)
        self.ros.start()

    # -- requests -----------------------------------------------------------------------
    def _set_obstacles(self, centres):
        msg = self.msgs['PoseArray']()
        msg.header.frame_id = 'map'
        for cx, cy in centres:
            from geometry_msgs.msg import Pose
            p = Pose()
            p.position.x, p.position.y = float(cx), float(cy)
            p.orientation.w = 1.0
            msg.poses.append(p)
        self.obstacles_pub.publish(msg)

    def _teleport(self, x, y, theta=0.0):
        msg = self.msgs['PoseWithCovarianceStamped']()
        msg.header.frame_id = 'map'
        msg.pose.pose.position.x, msg.pose.pose.position.y = float(x), float(y)
        msg.pose.pose.orientation.z = math.sin(theta / 2)
        msg.pose.pose.orientation.w = math.cos(theta / 2)
        self.pose_pub.publish(msg)

    def _start_scene(self, k):
        self.scene_index = k
        if k >= len(self.offsets):
            self.stage = 'finished'
            self._set_obstacles([])
            self.done.set()
            return
        self.stage = 'A'
        self.previous_id = self.obstacle_id
        self._set_obstacles([])
        # park the robot far behind the start (outside the supervisor's grid) while the
        # obstacle is set: it drives on a few steps meanwhile
        self._teleport(self.x0 - LEAD_IN - self.step_length, self.offsets[k])

    def _at(self, x, y, target_x):
        return (target_x - self.step_length - POSE_TOL <= x <= target_x + POSE_TOL
                and abs(y - self.offsets[self.scene_index]) < POSE_TOL)

    def _parked(self, x, y):
        """The robot is on the scene's line, well behind the start: teleported. Any pose
        there counts (the robot drives on, and the first poses after the first reply may
        be dropped: the newest-only subscription)."""
        return (x <= self.x0 - 0.5 * LEAD_IN
                and abs(y - self.offsets[self.scene_index]) < POSE_TOL)

    # -- callbacks ----------------------------------------------------------------------
    def on_pose(self, msg):
        x, y = msg.pose.position.x, msg.pose.position.y
        th = yaw_of(msg.pose.orientation)
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        with self.lock:
            self.sim_time = t
            if self.stage == 'idle':
                # every /interventions reader (world, learner, this node) visible, then a
                # settling second of wall time: the graph's counts come before the pairwise
                # matches, and an intervention sent before the learner's match is lost
                if self.node.count_subscribers('/interventions') >= self.readers and self._learners_hear():
                    if self.settle_until is None:
                        self.settle_until = time.monotonic() + SETTLE_S
                    elif time.monotonic() >= self.settle_until:
                        self._start_scene(0)
            elif self.stage == 'A' and self._parked(x, y):
                self.stage = 'A2'
                self.wait_until = t
            elif self.stage == 'A2' and self.judged >= self.wait_until - 1e-9:
                # the supervisor lags the robot by up to two steps: place the obstacle only
                # once it has judged the teleported pose, or it would judge the old ones
                # against the new obstacle
                self.stage = 'B'
                self._set_obstacles([(0.0, 0.0)])
            elif self.stage == 'B' and self.marker_ids and len(self.marker_ids) == 1 and \
                    self.marker_ids[0] != self.previous_id:
                self.obstacle_id = self.marker_ids[0]
                self.stage = 'C'
                self._teleport(self.x0 - self.step_length, self.offsets[self.scene_index])
            elif self.stage == 'C' and self._at(x, y, self.x0):
                self.stage = 'D'
                self.scene_start = t
                self.frames = [(x, y, th)]
            elif self.stage == 'D':
                self.frames.append((x, y, th))
                if x > self.x_end:
                    self.stage = 'E'          # past the obstacle: let the supervisor catch up
                    self.wait_until = t
            elif self.stage == 'E' and self.judged >= self.wait_until - 1e-9:
                self._end_scene(None)
        if self.stage != 'idle':
            self.cmd_pub.publish(self.msgs['Twist']())   # u = 0; also the lockstep's answer

    def _learners_hear(self) -> bool:
        """Every watched learner has matched, on each of its inputs, at least the publishers
        of that topic in this node's view of the graph (and at least one)."""
        seen = {'interventions': self.node.count_publishers('/interventions'),
                'obstacle_markers': self.node.count_publishers('/obstacle_markers'),
                'poses': self.node.count_publishers(f'/{ROBOT}/pose')}
        for heard in self.learner_inputs.values():
            if heard is None:
                return False
            for key, value in heard.items():
                if key in seen and int(value) < max(1, seen[key]):
                    return False
        return True

    def _end_scene(self, state):
        self.scenes.append({'y0': self.offsets[self.scene_index], 'intervened': state is not None,
                            'state': list(state) if state is not None else None,
                            'obstacle': self.obstacle_id, 'start_time': self.scene_start,
                            'end_time': self.sim_time,
                            'frames': list(self.frames) + ([tuple(state)] if state is not None else [])})
        self._start_scene(self.scene_index + 1)

    def on_intervention(self, msg):
        frame = msg.header.frame_id
        with self.lock:
            # C: an eager supervisor may intervene on poses just before the teleport back
            # (at the start line too); E: on the last poses before the end of the scene
            if self.stage not in ('C', 'D', 'E') or frame != f'obstacle_{self.obstacle_id}':
                return
            self.received.append(msg)
            if self.stage == 'C':
                self.scene_start = self.sim_time
                self.frames = []
            p = msg.pose
            self._end_scene((p.position.x, p.position.y, yaw_of(p.orientation)))

    def on_markers(self, msg):
        ids = [m.id for m in msg.markers if m.action == m.ADD]
        with self.lock:
            self.marker_ids = ids

    def on_judged(self, msg):
        with self.lock:
            self.judged = msg.clock.sec + msg.clock.nanosec * 1e-9

    def on_vf(self, msg):
        with self.fit_event:
            self.vf_msgs.append(msg)
            self.fit_event.notify_all()

    def wait_for_fit(self, n_interventions: int, timeout: float = 15.0):
        """The learner's newest value-function message once it is fitted on
        ``n_interventions`` (or the newest one at the timeout; None if none came)."""
        from ..ros_io.vfmsg import msg_metadata
        deadline = time.monotonic() + timeout
        with self.fit_event:
            while True:
                if self.vf_msgs:
                    meta = msg_metadata(self.vf_msgs[-1])
                    if meta.get('source') == 'learned' and int(meta.get('interventions') or 0) >= n_interventions:
                        return self.vf_msgs[-1]
                left = deadline - time.monotonic()
                if left <= 0:
                    learned = [m for m in self.vf_msgs if msg_metadata(m).get('source') == 'learned']
                    return learned[-1] if learned else None
                self.fit_event.wait(left)

    def resend(self, frames_stored: set) -> int:
        """Send again the scenes' interventions whose frame the learner has not stored
        (the world rejects them: those obstacles are gone). Returns how many."""
        pub = getattr(self, 'resend_pub', None)
        if pub is None:
            from geometry_msgs.msg import PoseStamped
            from ..ros_io import rosmsg
            pub = self.resend_pub = self.node.create_publisher(PoseStamped, '/interventions',
                                                               rosmsg.QOS_EVENTS)
            deadline = time.monotonic() + 3.0
            while pub.get_subscription_count() < 2 and time.monotonic() < deadline:
                time.sleep(0.05)
        missing = [m for m in self.received if m.header.frame_id not in frames_stored]
        for m in missing:
            pub.publish(m)
        return len(missing)

    def watch_learner(self, vf_topic: str, fit_topic: str) -> 'LearnerWatch':
        """Follow a (remapped) learner's latched value function and fit status."""
        return LearnerWatch(self.node, vf_topic, fit_topic)

    def close(self):
        self.ros.close()


class LearnerWatch:
    """A learner's value-function messages and /safe_set/fit statuses (remapped topics).

    Under first-passage the value function's metadata is not the thing to wait on: it is
    sent only when the chosen entry or level changes, so its counts can lag the data. The
    fit status comes after every refit with the counts the fit used
    (``fitted_interventions``, ``fitted_encounters``) and which set is in force
    (``published_index``, ``published_alpha``)."""

    def __init__(self, node, vf_topic: str, fit_topic: str):
        from diagnostic_msgs.msg import DiagnosticStatus
        from std_msgs.msg import Float32MultiArray
        from ..ros_io import rosmsg
        self.vf_msgs, self.statuses = [], []
        self.cond = threading.Condition()
        node.create_subscription(Float32MultiArray, vf_topic, self._on_vf, rosmsg.QOS_LATCHED)
        node.create_subscription(DiagnosticStatus, fit_topic,
                                 lambda m: self._on_status(rosmsg.diagnostic_values(m)), rosmsg.QOS_LATCHED)

    def _on_vf(self, msg):
        with self.cond:
            self.vf_msgs.append(msg)
            self.cond.notify_all()

    def _on_status(self, values: dict):
        with self.cond:
            self.statuses.append(values)
            self.cond.notify_all()

    def _in_force(self):
        """(value-function message, status) when the newest status's set in force is the
        newest learned message's, else None."""
        from ..ros_io.vfmsg import msg_metadata
        if not self.statuses or not self.vf_msgs:
            return None
        status, msg = self.statuses[-1], self.vf_msgs[-1]
        meta = msg_metadata(msg)
        try:
            same = (meta.get('source') == 'learned'
                    and int(status.get('published_index', -1)) == int(meta.get('index', -2))
                    and math.isclose(float(status.get('published_alpha', 'nan')), float(meta.get('alpha')),
                                     rel_tol=1e-6, abs_tol=1e-9))
        except (TypeError, ValueError):
            return None
        return (msg, status) if same else None

    def wait_for_counts(self, interventions: int, encounters: int, timeout: float = 15.0):
        """(value-function message, status) once the learner's fit used at least
        ``interventions`` interventions in ``encounters`` encounters and its message is the
        set in force; at the timeout the newest such pair, or (None, newest status or None)."""
        deadline = time.monotonic() + timeout
        with self.cond:
            while True:
                pair = self._in_force()
                if pair is not None:
                    st = pair[1]
                    if (int(st.get('fitted_interventions', 0)) >= interventions
                            and int(st.get('fitted_encounters', 0)) >= encounters):
                        return pair
                left = deadline - time.monotonic()
                if left <= 0:
                    return pair if pair is not None else (None, self.statuses[-1] if self.statuses else None)
                self.cond.wait(left)
