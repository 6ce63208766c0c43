"""learner_node: learns the supervisor's safe set online, from interventions and encounters.

Topics and services:
  sub  /interventions            geometry_msgs/PoseStamped   the intervened robot's pose in the
                                                             removed obstacle's frame (obstacle at the
                                                             origin, axes as map); frame_id
                                                             obstacle_<id>; stamp = intervention time.
                                                             Reliable, a queue of 100,000: none is dropped.
  sub  /<robot>/pose             geometry_msgs/PoseStamped   first-passage only: every robot in `robots`
  sub  /obstacle_markers         visualization_msgs/MarkerArray  first-passage only: obstacle ids, centres
  pub  /safe_set/value_function  std_msgs/Float32MultiArray  latched: the fitted V, exact float32,
                                                             with grid and fit as JSON (ros_io.vfmsg);
                                                             sent when the chosen entry changes, or its
                                                             mu, sigma or alpha by more than
                                                             republish_level_tolerance
  pub  /safe_set/fit             diagnostic_msgs/DiagnosticStatus  latched: one per refit (and after
                                                             rejections): counts, omega_max, mu, sigma,
                                                             alpha, whether the fit is published and why
  pub  ~/inputs                  diagnostic_msgs/DiagnosticStatus  latched, sent when a count changes: how
                                                             many publishers each input has matched
                                                             (interventions, obstacle_markers, and
                                                             poses: the fewest over the robots), so a
                                                             driver can wait until the learner hears
                                                             before it makes events (the study's
                                                             conductor does)
  srv  ~/reset                   std_srvs/Empty              new subject: archive the data files
                                                             (renamed, never deleted), start empty,
                                                             publish the standard set

Flow. A callback only validates and stores: an intervention is checked
(``intervention_input``: frame ``obstacle_<int>`` of sane length, valid stamp, finite
pose; not a duplicate: the same obstacle number and stamp, whatever the frame's spelling)
and appended to the store at once (to the kernel; the refit timer fsyncs every line
appended since the last one before it fits: a group commit). A stored intervention
outside the library's grid, or whose encounter no admissible entry explains
(``learning.encounter_window``), is set aside from the fit: kept in the store, logged and
counted (``set_aside``), so one hasty click cannot stop the learning. Rejections and
set-asides are logged at WARN per reason, at most once a second with the count and the
latest example (``rejections``), and their totals at shutdown.

A steady timer (``refit_period``) refits once on everything received so far, whatever
the number of messages since the last refit, checks the fitted set against the standard
set (``filter.admissibility.check_learned_set``) and publishes it only if it passes and
its entry changed, or its level (mu, sigma or alpha) moved by more than
``republish_level_tolerance`` (0.01 m): a refit on one more encounter moves mu in its
third digit, and resending the 710 KB set for that cost every filter a decode and a check
and the log two lines each. Each encounter's values are computed once, when
it arrives, so a refit only maximises.

Estimators (``estimator``): ``first-passage`` (default) builds encounters from the robots'
poses and the obstacle set (``learning.encounters.EncounterBuilder``), stores each
finished one in ``<store>.encounters.jsonl``, and fits
``learning.estimators.fit_first_passage``; ``paper`` fits the paper's estimator to the
intervention states. Interventions are stored under both.

Store. ``store_path`` '' starts a fresh file for this run under
$XDG_DATA_HOME/supersafe_ros/runs/ (never the last run's data), and the newest ``keep_runs``
run folders stay there: older ones are removed at start (``storage.prune_runs``: never a
running learner's, never a named store). A named file that holds data is resumed, and the
log says so: "resuming N interventions and M encounters from FILE".
"""
from __future__ import annotations

import math
import os
import time

import numpy as np
from rclpy.clock import Clock as RosClock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from std_msgs.msg import Float32MultiArray
from std_srvs.srv import Empty
from visualization_msgs.msg import MarkerArray

from ..ros_io import rosmsg
from ..filter.admissibility import check_learned_set
from ..learning.encounters import EncounterBuilder, EncounterRecord
from ..learning.intervention_store import Intervention, InterventionStore, RecordStore
# imported here, not in the first refit: scipy takes ~1 s to import on a busy machine
from ..learning.estimators import admissible_mask, fit_first_passage_intervals, fit_paper_values
from ..learning.encounter_window import EncounterWindow
from ..reach.library import PAPER_OMEGAS, LibrarySpec, load_or_build_library
from ..ros_io.take import take
from ..ros_io.vfmsg import value_function_to_msg
from ..storage import new_run_store, prune_runs
from .common import LiveParameters, declare, run_node
from .intervention_input import Rejected, parse_intervention, receive_time_ns
from .markers import ObstacleMarkers
from .rejections import RejectionLog

VALUE_FUNCTION_TOPIC = '/safe_set/value_function'
FIT_TOPIC = '/safe_set/fit'
ESTIMATORS = ('first-passage', 'paper')
DEFAULT_OMEGAS = [float(w) for w in PAPER_OMEGAS]
# every pose and every obstacle set, even when a refit holds the learner up (reliable;
# compatible with the robots' stream and the world's latched writers)
QOS_EVERY_POSE = QoSProfile(depth=5000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.VOLATILE)
QOS_EVERY_OBSTACLE_SET = QoSProfile(depth=100, history=HistoryPolicy.KEEP_LAST,
                                    reliability=ReliabilityPolicy.RELIABLE,
                                    durability=DurabilityPolicy.TRANSIENT_LOCAL)
DRAIN_LIMIT = 1000             # messages of a burst taken per callback (see on_interventions)
SET_ASIDE_OUTSIDE = 'outside the library grid'


def default_store_path() -> str:
    """A fresh file for this run: $XDG_DATA_HOME (or ~/.local/share)/supersafe_ros/runs/."""
    return str(new_run_store())


def encounter_store_path(store_path: str) -> str:
    stem = store_path[:-6] if store_path.endswith('.jsonl') else store_path
    return stem + '.encounters.jsonl'


def build_library(speed, radius, horizon, omegas, lo, hi, shape, cache_dir=None):
    """The candidate value functions sorted by omega_max (from the cache, or solved and cached)."""
    spec = LibrarySpec(speed=speed, radius=radius, omegas=tuple(sorted(omegas)),
                       horizon=horizon if horizon > 0 else None, lo=tuple(lo), hi=tuple(hi),
                       shape=tuple(int(n) for n in shape))
    return list(load_or_build_library(spec, cache_dir=cache_dir or None).entries)


class LearnerNode(Node):
    def __init__(self, node_name='learner', **kwargs):
        super().__init__(node_name, **kwargs)
        p = lambda *a, **k: declare(self, *a, **{'read_only': True, **k})  # noqa: E731
        store_path = p('store_path', '', 'JSON-lines file of accepted interventions (encounters go to '
                       '<file>.encounters.jsonl); a file with data is resumed. "" = a fresh file for '
                       'this run under $XDG_DATA_HOME or ~/.local/share, supersafe_ros/runs/')
        keep_runs = p('keep_runs', 20, 'with store_path "": the newest run folders kept in supersafe_ros/runs/ '
                      '(older ones are removed at start, never a running learner\'s); 0 = keep all', 0, 100000)
        self.estimator = p('estimator', 'first-passage', f'estimator, one of {ESTIMATORS}')
        if self.estimator not in ESTIMATORS:
            raise ValueError(f"estimator '{self.estimator}' is not one of {ESTIMATORS}")
        self.robots = [r.strip('/') for r in p('robots', ['robot_0'], 'robot namespaces whose '
                                               '<ns>/pose the first-passage estimator follows')]
        self.alpha_k = p('alpha_k', 0.0, 'alpha = mu + alpha_k sigma (paper: 0)', -5.0, 10.0,
                         read_only=False)
        self.min_interventions = p('min_interventions', 3, 'interventions (first-passage: encounters '
                                   'ending in one) before a fit is published', 1, 100000, read_only=False)
        self.prior = p('conservative_prior', True, 'only entries whose unsafe set contains the true '
                       'one (true_omega_max) are admissible (paper, MAP prior)')
        true_omega = p('true_omega_max', 1.0, 'robots\' true turn-rate bound [rad/s] (prior, standard '
                       'set, reset)', 0.0, 20.0)
        self.standard_alpha = p('standard_alpha', 0.0, 'level of the standard set (true dynamics) a '
                                'learned set must contain to be published', -10.0, 10.0, read_only=False)
        self.frame_prefix = p('obstacle_frame_prefix', rosmsg.OBSTACLE_FRAME_PREFIX,
                              'an intervention frame is this followed by the obstacle id')
        self.refit_period = p('refit_period', 0.05, 'steady seconds between refits (one refit covers '
                              'everything received since the last)', 0.001, 60.0)
        self.level_tolerance = p('republish_level_tolerance', 0.01, 'the value function is republished '
                                 'when the chosen entry changes, or mu, sigma or alpha moves by more than this '
                                 '[value units, m]; 0 = any change', 0.0, 10.0, read_only=False)
        self.fit_window = p('fit_window', 5000, 'newest interventions (paper) or encounters '
                            '(first-passage) fitted; older ones stay stored (bounds the refit time)',
                            1, 10_000_000)
        speed = p('library_speed', 3.0, 'library: robot speed [m/s]', 0.01, 100.0)
        radius = p('library_radius', 1.8, 'library: obstacle radius [m]', 0.01, 100.0)
        horizon = p('library_horizon', 3.0, 'library: avoid horizon [s] (0 = to convergence)', 0.0, 1000.0)
        omegas = p('library_omegas', DEFAULT_OMEGAS, 'library: candidate turn-rate bounds [rad/s]')
        self.lo = p('library_lo', [-8.0, -8.0], 'library grid: (xmin, ymin) [m]')
        self.hi = p('library_hi', [8.0, 8.0], 'library grid: (xmax, ymax) [m]')
        shape = p('library_shape', [65, 65, 42], 'library grid: nodes (nx, ny, ntheta)')
        cache_dir = p('cache_dir', '', 'library cache ("" = $SUPERSAFE_CACHE or ~/.cache/supersafe_ros)')
        builder_args = dict(
            jump_distance=p('jump_distance', 1.0, 'a pose this far (plus speed x dt) from the previous '
                            'one is a jump (teleport, reset): it ends the robot\'s encounters [m]', 0.0, 1e3),
            grace=p('intervention_grace', 2.0, 'an encounter ended without intervention waits this long '
                    '(pose time) for a late intervention before it is final [s]', 0.0, 1e3),
            match_tolerance=p('match_tolerance', 1.0, 'an intervention belongs to the encounter of its '
                              'obstacle passing within this distance of its state [m]', 0.0, 1e3),
            pending_timeout=p('pending_timeout', 5.0, 'after an intervention, no new encounter with that '
                              'obstacle until it is removed or this time passes [s]', 0.0, 1e4),
            max_frames=p('max_encounter_frames', 2000, 'frames after which an encounter is closed '
                         '(bounded memory)', 2, 1_000_000),
            removal_delay=p('removal_delay', 1.0, 'an encounter with a removed obstacle goes on this long '
                            'after the removal\'s stamp (the world stamps with a coarse clock) [s]', 0.0, 100.0),
            reorder=p('reorder_window', 1.0, 'a pose is judged once its robot has poses this much newer '
                      '(pose time), so obstacle sets and interventions read up to this late still apply '
                      'to it (topics are not ordered with each other) [s]', 0.0, 100.0))

        t0 = time.perf_counter()
        self.entries = build_library(speed, radius, horizon, omegas, self.lo, self.hi, shape, cache_dir)
        self.true_vf = self._true_entry(true_omega)
        self.admissible = (admissible_mask(self.entries, self.true_vf) if self.prior
                           else np.ones(len(self.entries), dtype=bool))
        self.get_logger().info(f'{self.estimator} estimator, library of {len(self.entries)} entries '
                               f'{tuple(shape)} ready in {time.perf_counter() - t0:.2f} s')

        live = LiveParameters(self)
        live.add('alpha_k', lambda v: self._set('alpha_k', v))
        live.add('min_interventions', lambda v: self._set('min_interventions', v))
        live.add('standard_alpha', lambda v: self._set('standard_alpha', v))
        live.add('republish_level_tolerance', lambda v: self._set('level_tolerance', v))

        self.vf_pub = self.create_publisher(Float32MultiArray, VALUE_FUNCTION_TOPIC, rosmsg.QOS_LATCHED)
        self.fit_pub = self.create_publisher(DiagnosticStatus, FIT_TOPIC, rosmsg.QOS_LATCHED)
        self.interventions_sub = self.create_subscription(PoseStamped, '/interventions',
                                                          self.on_interventions, rosmsg.QOS_EVERY_EVENT)
        self.inputs_pub = self.create_publisher(DiagnosticStatus, '~/inputs', rosmsg.QOS_LATCHED)
        self.inputs_heard = None
        self.create_service(Empty, '~/reset', self.on_reset)
        self.builder_args = dict(builder_args, speed=speed)
        self.builder = None
        self.markers_sub = None
        self.pose_subs = {}
        if self.estimator == 'first-passage':
            self.obstacles = ObstacleMarkers()
            self.markers_sub = self.create_subscription(MarkerArray, '/obstacle_markers', self.on_markers_msg,
                                                        QOS_EVERY_OBSTACLE_SET)
            for r in self.robots:
                self.pose_subs[r] = self.create_subscription(
                    PoseStamped, f'/{r}/pose', lambda m, r=r: self.on_pose_msg(r, m), QOS_EVERY_POSE)

        self.fit = None
        self.published = None        # (index, alpha, mu, sigma) of the value function in force
        self.counts = {'rejected': 0, 'duplicates': 0, 'set_aside': 0, 'refits': 0, 'published': 0, 'refused': 0}
        warn = self.get_logger().warn
        self.rejections = RejectionLog('intervention', 'rejected', warn)     # duplicates too
        self.set_aside = RejectionLog('intervention', 'set aside from the fit (kept in the store)', warn)
        self.verdict = ''
        self.timing = {}
        if not store_path:
            store_path = default_store_path()
            gone = prune_runs(keep_runs, current=os.path.dirname(store_path))
            if gone:
                self.get_logger().info(f'{len(gone)} old run folders removed from {os.path.dirname(gone[0])} '
                                       f'(keep_runs {keep_runs})')
            self._open_stores(store_path, resumed=False)
        else:
            self._open_stores(store_path, resumed=True)
        self.create_timer(self.refit_period, self.on_timer,
                          clock=RosClock(clock_type=ClockType.STEADY_TIME))

    def _set(self, attr, value):
        setattr(self, attr, value)
        self.dirty = True

    def _true_entry(self, omega):
        """The library entry of the true dynamics (conservative prior, standard set, reset)."""
        for e in self.entries:
            if e.meta.get('omega_max') is not None and abs(float(e.meta['omega_max']) - omega) < 1e-9:
                return e
        raise ValueError(f'true_omega_max {omega} is not among the library omegas '
                         f'{[e.meta.get("omega_max") for e in self.entries]}')

    # -- stores ----------------------------------------------------------------------------
    def _open_stores(self, path, resumed):
        self.store = InterventionStore(path, keep=self.fit_window)
        self.encounter_store = (RecordStore(encounter_store_path(self.store.path), EncounterRecord,
                                            keep=self.fit_window)
                                if self.estimator == 'first-passage' else None)
        self._reset_caches()
        for entry in self.store.entries:                        # values not computed yet
            if self.in_grid(entry):
                self.new_interventions.append(entry)
            else:
                self._set_aside(SET_ASIDE_OUTSIDE, f'stored {entry.frame} at ({entry.x:.3g}, {entry.y:.3g})')
        self.new_encounters = list(self.encounter_store.entries) if self.encounter_store else []
        n, m = len(self.store), len(self.encounter_store or ())
        damage = ''
        for s in (self.store, self.encounter_store):
            if s is not None and (s.torn_bytes or s.skipped_lines):
                damage += (f'; {os.path.basename(s.path)}: cut a torn last line of {s.torn_bytes} bytes, '
                           f'skipped {s.skipped_lines} damaged lines')
        if n or m:
            what = f'{n} interventions' + (f' and {m} encounters' if self.encounter_store is not None else '')
            self.get_logger().info(f'resuming {what} from {self.store.path}{damage}')
        else:
            self.get_logger().info(f'store {self.store.path}: empty, a new subject'
                                   f'{"" if resumed else " (store_path not set: a fresh file for this run)"}'
                                   f'{damage}')
        self.dirty = bool(n or m)

    def _reset_caches(self):
        self.fit = None
        self.published = None
        self.values = np.zeros((len(self.entries), 0))    # paper: V_i at the newest interventions
        self.window = EncounterWindow(self.entries, self.admissible, self.fit_window, self._set_aside)
        self.new_interventions, self.new_encounters = [], []
        if self.estimator == 'first-passage':
            self.builder = EncounterBuilder(self.lo, self.hi, **self.builder_args)
            if getattr(self, 'obstacles', None) is not None and self.obstacles.centres:
                ids, xy = self.obstacles.arrays()
                self.builder.set_obstacles(ids, xy, 0.0, time.monotonic())

    def close(self):
        if self.builder is not None and self.encounter_store is not None:
            self.builder.finish_all()
            self._drain_encounters()
        now = time.monotonic()
        self.rejections.close(now)        # what is pending, and the run's totals per reason
        self.set_aside.close(now)
        self.store.close()
        if self.encounter_store is not None:
            self.encounter_store.close()

    # -- inputs ----------------------------------------------------------------------------
    def parse(self, msg: PoseStamped) -> Intervention:
        """Validated intervention (``intervention_input``); raises Rejected with the reason."""
        return parse_intervention(msg, self.frame_prefix, lambda: receive_time_ns(self.get_clock()))

    def in_grid(self, entry: Intervention) -> bool:
        return self.lo[0] <= entry.x <= self.hi[0] and self.lo[1] <= entry.y <= self.hi[1]

    # The executor hands a callback one message per wait, and a wait costs far more than
    # a take. So each callback also takes what else is waiting (rclpy's own take call, as
    # its executor makes it): obstacle sets and interventions first, then poses one robot
    # at a time, so a burst costs one wait and the topics are read roughly in the order
    # they were sent (stamps order the rest: see learning.encounters).
    def _take(self, sub):
        try:
            return take(sub)
        except Exception as exc:     # a failed take must not lose what was handled already
            self.get_logger().warn(f'{sub.topic_name}: take failed ({exc}); the executor continues',
                                   throttle_duration_sec=5.0)
            return None

    def _take_events(self):
        if self.markers_sub is not None:
            for _ in range(DRAIN_LIMIT):
                m = self._take(self.markers_sub)
                if m is None:
                    break
                self.on_markers(m)
        for _ in range(DRAIN_LIMIT):
            m = self._take(self.interventions_sub)
            if m is None:
                break
            self.on_intervention(m)

    def _take_all(self):
        self._take_events()
        for _ in range(DRAIN_LIMIT):
            took = False
            for robot, sub in self.pose_subs.items():
                m = self._take(sub)
                if m is not None:
                    self.on_pose(robot, m)
                    took = True
            if not took:
                return
            self._take_events()

    def on_interventions(self, msg: PoseStamped):
        self.on_intervention(msg)
        self._take_all()

    def on_markers_msg(self, msg: MarkerArray):
        self.on_markers(msg)
        self._take_all()

    def on_pose_msg(self, robot, msg: PoseStamped):
        self._take_events()
        self.on_pose(robot, msg)
        self._take_all()

    def on_intervention(self, msg: PoseStamped):
        try:
            entry = self.parse(msg)
        except Rejected as exc:
            self.counts['rejected'] += 1
            self._note(self.rejections, exc.reason, str(exc))
            return
        if not self.store.append(entry, sync=False):   # fsynced by the next refit tick
            self.counts['duplicates'] += 1
            self._note(self.rejections, 'duplicate', f'obstacle {entry.obstacle} at stamp {entry.stamp_ns} ns is '
                       f'stored already (this one as {entry.frame!r})')
            return
        self._admit(entry)

    def _admit(self, entry: Intervention):
        """A stored intervention into the fit, or set aside from it with the reason."""
        if not self.in_grid(entry):
            self._set_aside(SET_ASIDE_OUTSIDE, f'{entry.frame} at ({entry.x:.3g}, {entry.y:.3g}), the grid '
                            f'{tuple(self.lo)}..{tuple(self.hi)}: a click on an obstacle far from every robot')
            return
        self.new_interventions.append(entry)
        if self.builder is not None:
            self.builder.intervention(entry.obstacle, entry.stamp_ns * 1e-9, entry.state, time.monotonic())
        self.dirty = True

    def _set_aside(self, reason: str, details: str):
        self.counts['set_aside'] += 1
        self._note(self.set_aside, reason, details)

    def _note(self, log: RejectionLog, reason: str, details: str):
        """Log (per reason, at most once a second) and say on the next status."""
        log.add(reason, details, time.monotonic())
        self.status_note = f'{log.noun} {log.verb}: {log.latest}'
        self.status_dirty = True

    def on_markers(self, msg: MarkerArray):
        try:
            self.obstacles.update(msg)
        except ValueError as exc:
            self.get_logger().error(f'/obstacle_markers rejected: {exc}', throttle_duration_sec=1.0)
            return
        stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in msg.markers]
        ids, xy = self.obstacles.arrays()
        # unstamped: in force from its arrival, as an unstamped intervention is (``parse``)
        stamp = max(stamps, default=0.0) or self.get_clock().now().nanoseconds * 1e-9
        self.builder.set_obstacles(ids, xy, stamp, time.monotonic())

    def on_pose(self, robot, msg: PoseStamped):
        try:
            state = rosmsg.pose_to_state(msg)
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            self.builder.pose(robot, stamp, state, time.monotonic())
        except ValueError as exc:
            self.get_logger().error(f'pose of {robot} rejected: {exc}', throttle_duration_sec=1.0)
            return
        self._drain_encounters()

    def _drain_encounters(self):
        for record in self.builder.pop_finished():
            if self.encounter_store.append(record, sync=False):
                self.new_encounters.append(record)
                self.dirty = True

    # -- refit -----------------------------------------------------------------------------
    dirty = False
    status_dirty = False
    status_note = ''
    _next_refit = 0.0

    def matched_inputs(self) -> dict:
        """Publishers each input subscription has matched (poses: the fewest over the robots)."""
        heard = {'interventions': self.interventions_sub.get_publisher_count()}
        if self.markers_sub is not None:
            heard['obstacle_markers'] = self.markers_sub.get_publisher_count()
            heard['poses'] = min((s.get_publisher_count() for s in self.pose_subs.values()), default=0)
        return heard

    def on_timer(self):
        heard = self.matched_inputs()
        if heard != self.inputs_heard:
            self.inputs_heard = heard
            self.inputs_pub.publish(rosmsg.make_diagnostic(
                'learner inputs', heard,
                'publishers matched: ' + ', '.join(f'{k} {v}' for k, v in heard.items()),
                0 if all(heard.values()) else 1))
        if self.builder is not None:
            self.builder.tick(time.monotonic())
            self._drain_encounters()
        self.store.sync()
        if self.encounter_store is not None:
            self.encounter_store.sync()
        now = time.monotonic()
        self.rejections.flush(now)      # each reason's summary on time, not with the next burst
        self.set_aside.flush(now)
        if self.dirty and now >= self._next_refit:
            # rclpy takes one message per subscription per wait: were a refit due every tick,
            # a burst would get one message per refit. Refits get at most a third of the time.
            self.dirty = self.status_dirty = False
            self.refit()
            self._next_refit = time.monotonic() + 2.0 * (time.monotonic() - now)
        elif self.status_dirty:
            self.status_dirty = False
            self.publish_status(self.status_note, level=1)

    def _paper_values(self):
        if self.new_interventions:
            new = np.asarray([e.state for e in self.new_interventions], dtype=float)
            self.values = np.concatenate([self.values, np.stack([e.value(new) for e in self.entries])], 1)
            self.values = self.values[:, -self.fit_window:]
            self.new_interventions = []
        return self.values

    def _encounter_intervals(self):
        """The encounters fitted: the newest that the library explains (``EncounterWindow``:
        one that no entry explains is set aside, else no fit could be made while it stays)."""
        records, self.new_encounters = self.new_encounters, []
        self.window.add(records)
        return self.window.intervals

    def fitted_counts(self):
        """(interventions the fit would use, encounters or None), computing new values."""
        if self.estimator == 'paper':
            return self._paper_values().shape[1], None
        iv = self._encounter_intervals()
        if iv is None:
            return 0, 0
        return int(iv.intervened.sum()), len(iv.intervened)

    def refit(self):
        n_int, n_enc = self.fitted_counts()
        if n_int < self.min_interventions:
            what = 'interventions' if n_enc is None else f'encounters ending in an intervention (of {n_enc})'
            self.publish_status(f'{n_int} of {self.min_interventions} {what} needed before a fit', level=0)
            return None
        t0 = time.perf_counter()
        try:
            if self.estimator == 'paper':
                fit = fit_paper_values(self.entries, self.values, alpha_k=self.alpha_k,
                                       admissible=self.admissible)
            else:
                # the previous fit's (mu, sigma) per entry: a few Newton steps from there
                start = None
                if self.fit is not None and self.fit.candidates:
                    start = (np.array([c['mu'] for c in self.fit.candidates]),
                             np.array([c['sigma'] for c in self.fit.candidates]))
                fit = fit_first_passage_intervals(self.entries, self.window.intervals, alpha_k=self.alpha_k,
                                                  admissible=self.admissible, start=start)
        except ValueError as exc:
            self.get_logger().error(f'fit failed: {exc}; keeping the previous fit', throttle_duration_sec=5.0)
            self.publish_status(f'fit failed: {exc}', level=2)
            return None
        self.timing['fit_s'] = time.perf_counter() - t0
        self.counts['refits'] += 1
        self.fit = fit
        verdict = check_learned_set(self.true_vf, self.standard_alpha, fit.value_function, fit.alpha)
        self.verdict = verdict.reason
        summary = (f'omega_max {fit.omega_max:g}, mu {fit.mu:.4g}, sigma {fit.sigma:.4g}, '
                   f'alpha {fit.alpha:.4g} on {fit.interventions} interventions'
                   + (f' in {fit.encounters} encounters' if fit.encounters is not None else ''))
        if not verdict.ok:
            self.counts['refused'] += 1
            self.get_logger().error(f'fit not published ({summary}): {verdict.reason}')
            self.publish_status(f'fit not published: {verdict.reason}', level=2)
            return fit
        key = (fit.index, fit.alpha, fit.mu, fit.sigma)
        changed = (self.published is None or key[0] != self.published[0]
                   or any(abs(a - b) > self.level_tolerance for a, b in zip(key[1:], self.published[1:])))
        if changed:
            t1 = time.perf_counter()
            extra = {k: v for k, v in fit.to_dict().items() if k not in ('candidates', 'notes')}
            extra.update(source='learned', alpha_k=self.alpha_k, conservative_prior=self.prior,
                         stored_interventions=len(self.store), stamp_ns=self.get_clock().now().nanoseconds)
            self.vf_pub.publish(value_function_to_msg(fit.value_function, **extra))
            self.timing['publish_s'] = time.perf_counter() - t1
            self.published = key
            self.counts['published'] += 1
            self.get_logger().info(f'fit published: {summary}')
        else:
            self.get_logger().debug(f'fit unchanged: {summary}')
        self.publish_status(f'fit {"published" if changed else "unchanged, set in force"}: {summary}',
                            level=1 if fit.notes else 0)
        return fit

    def publish_status(self, message: str, level: int = 0):
        f = self.fit
        nan = math.nan
        values = {
            'omega_max': f.omega_max if f else nan, 'mu': f.mu if f else nan,
            'sigma': f.sigma if f else nan, 'alpha': f.alpha if f else nan,
            'interventions': len(self.store), 'log_likelihood': f.log_likelihood if f else nan,
            'estimator': self.estimator, 'fitted_interventions': f.interventions if f else 0,
            'index': f.index if f else -1, 'store': self.store.path,
            'published_index': self.published[0] if self.published else -1,
            'published_alpha': self.published[1] if self.published else nan,
            'admissibility': self.verdict, 'last_rejection': self.rejections.latest,
            'last_set_aside': self.set_aside.latest,
            'notes': '; '.join(f.notes) if f else '',
        }
        values.update(self.counts)
        if self.encounter_store is not None:
            values.update(encounters=len(self.encounter_store),
                          fitted_encounters=f.encounters if f and f.encounters is not None else 0,
                          open_encounters=self.builder.open_count,
                          unmatched_interventions=self.builder.counts['unmatched_interventions'],
                          encounter_store=self.encounter_store.path)
        values.update({k: (str(v) if isinstance(v, int) else f'{v:.6f}') for k, v in self.timing.items()})
        self.fit_pub.publish(rosmsg.make_diagnostic('learner', values, message, level))

    # -- reset ---------------------------------------------------------------------------------
    def on_reset(self, request, response):
        archived = self.store.archive()
        if self.encounter_store is not None:
            self.encounter_store.archive()
        self._reset_caches()
        self.dirty = False
        self.get_logger().info(f'reset for a new subject: data archived to {archived or "(nothing)"}; '
                               'publishing the standard set')
        self.vf_pub.publish(value_function_to_msg(self.true_vf, source='standard', alpha=self.standard_alpha,
                                                  interventions=0, estimator=self.estimator,
                                                  stamp_ns=self.get_clock().now().nanoseconds))
        self.publish_status(f'reset: no data (previous archived to {archived or "nothing"})', level=0)
        return response


def main(args=None):
    try:
        return run_node(LearnerNode, args)
    except KeyboardInterrupt:   # a Ctrl-C that lands during shutdown: data are fsynced already
        return 0


if __name__ == '__main__':
    raise SystemExit(main())
