"""What safety_filter_node and fleet_safety_filter_node share (wiring, no node here).

``FilterWiring(node, names)`` gives a node:

* every filter parameter, declared with its descriptor; those that can change at
  run time (levels, margins, lookahead, control period, timeouts, use_learned,
  rates, the value-function size limit, the clock-stall timeout) take effect when
  set (``LiveParameters``), everything else is ``read_only``;
* one ``RobotFilter`` per robot name, all sharing the live ``FilterConfig``;
* the standard set (true dynamics, from the cache or solved at start);
* the learned set: ``/safe_set/value_function`` is taken as serialized bytes (so an
  oversize message is refused by its length before anything is decoded), then
  decoded and checked for admissibility (``filter.admissibility``: its unsafe region
  must contain the standard one at ``standard_alpha``) on a worker thread, off the
  control path. A set that fails is rejected with the reason; the set in force is
  kept, and the state messages say so (``set_update``, ``set_update_reason``);
* the filter's time base (``filter.timebase.FilterTime``): ages on sim time while
  /clock advances, on the steady clock when ``use_sim_time`` is false or ROS time
  stands still (no /clock), so a stale input is detected either way;
* state messages (diagnostic_msgs/DiagnosticStatus) and throttled complaints.
"""
from __future__ import annotations

from contextlib import nullcontext
from dataclasses import replace
import math
from operator import ne
import threading
import time

import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from std_msgs.msg import Float32MultiArray

from ..filter.admissibility import check_learned_set
from ..filter.core import FilterConfig, RobotFilter, SafeSet, default_cluster_store
from ..filter.timebase import FilterTime
from ..learning.levels import learned_alpha
from ..ros_io import rosmsg
from ..filter.law import evaluate_pairs
from ..ros_io.vfcdr import serialized_to_value_function
from ..ros_io.vfmsg import ValueFunctionMessageError
from .common import LiveParameters, declare

VALUE_FUNCTION_TOPIC = '/safe_set/value_function'
LOG_THROTTLE_S = 2.0   # the same kind of complaint at most this often

# FilterConfig fields set from parameters of the same name, all changeable at run time
_CONFIG_PARAMS = (
    ('pose_timeout', 0.5, 'a pose older than this is stale [s]', 0.001, 60.0),
    ('detections_timeout', 1.0, 'detections older than this are stale [s]', 0.001, 60.0),
    ('hold_timeout', 1.0, 'fail safe with the avoid control of the last valid state while it is '
     'younger than this, then stop-turn [s]', 0.0, 60.0),
    ('cmd_timeout', 0.5, 'planner silent longer than this: zero command [s]', 0.001, 60.0),
    ('clear_margin', 0.2, 'hysteresis: keep overriding until V > alpha + margin', 0.0, 10.0),
    ('lookahead', 0.1, 'also override when the planner\'s command, held this long, would reach '
     'V <= alpha; never less than the control period [s]', 0.0, 10.0),
    ('control_period', 0.0, 'the robot\'s command hold time [s]; 0 = measure it from pose stamps and '
     'planner commands', 0.0, 10.0),
)


def standard_value_function(lo, hi, shape, speed, omega_max, radius, horizon, cache_dir=None):
    """The standard set's V: true dynamics and radius, from the cache or solved now.

    horizon <= 0 means "to convergence".
    """
    from ..reach.grid import Grid
    from ..reach.library import load_or_solve
    return load_or_solve(Grid(tuple(lo), tuple(hi), tuple(int(n) for n in shape)), speed, omega_max,
                         radius, horizon if horizon > 0 else None, cache_dir=cache_dir or None)


class FilterWiring:
    """Parameters, filters, safe sets, time base and state messages of a filter node."""

    def __init__(self, node, names, on_rate=None, lock=None):
        self.node = node
        self.log = node.get_logger()
        self._on_rate = on_rate
        # held while parameters change and a checked set goes in force (the node's callbacks hold it too)
        self._lock = lock if lock is not None else nullcontext()
        p = lambda *a, **k: declare(node, *a, **k)  # noqa: E731
        fixed = dict(read_only=True)
        speed = p('speed', 3.0, 'robot speed, true dynamics [m/s] (standard set; linear.x)', 0.01, 100.0,
                  **fixed)
        omega_max = p('omega_max', 1.0, 'robot turn-rate bound, true dynamics [rad/s]; |u*|', 0.01, 20.0,
                      **fixed)
        radius = p('radius', 1.8, 'true obstacle radius [m] (standard set)', 0.01, 100.0, **fixed)
        self.standard_alpha = p('standard_alpha', 0.0, 'alpha of the standard set [value units, m]',
                                -10.0, 10.0)
        self.alpha_offset = p('alpha_offset', 0.0,
                              'k in alpha = mu + k sigma for a learned set (paper: 0)', -5.0, 10.0)
        self.use_learned = p('use_learned', True, 'take the learner\'s sets (each checked against the '
                             'standard set first)')
        values = {name: p(name, default, desc, lo, hi) for name, default, desc, lo, hi in _CONFIG_PARAMS}
        # clusters of close obstacles are judged with the true radius at the standard level
        self.config = FilterConfig(speed=speed, omega_max=omega_max, radius=radius,
                                   cluster_alpha=self.standard_alpha, **values)
        self.rate = p('rate', 50.0, 'decision rate [Hz, steady clock]: watchdog (one robot) or tick '
                      '(fleet)', 0.1, 1000.0)
        self.state_period = 1.0 / p('state_rate', 10.0, 'most state messages per second and robot '
                                    'while the action does not change [Hz]', 0.1, 1000.0)
        self.max_vf_bytes = p('max_value_function_bytes', 64 * 1024 * 1024,
                              'a value-function message larger than this is rejected unread [bytes]',
                              1024, 2 ** 31 - 1)
        stall = p('clock_stall_timeout', 2.0, 'with use_sim_time: ROS time standing still longer than '
                  'this [steady s] counts as stopped, and ages follow the wall clock', 0.01, 600.0)
        self.frame = p('frame_id', rosmsg.MAP_FRAME, 'frame of pose and detections', **fixed)
        cache_dir = p('cache_dir', '', 'value-function cache ("" = $SUPERSAFE_CACHE or '
                      '~/.cache/supersafe_ros)', **fixed)
        lo = p('standard_lo', [-8.0, -8.0], 'standard set grid: (xmin, ymin) relative to the obstacle [m]',
               **fixed)
        hi = p('standard_hi', [8.0, 8.0], 'standard set grid: (xmax, ymax) [m]', **fixed)
        shape = p('standard_shape', [65, 65, 42], 'standard set grid: nodes (nx, ny, ntheta)', **fixed)
        horizon = p('standard_horizon', 3.0, 'standard set horizon [s] (as the library; 0 = to '
                    'convergence)', 0.0, 1000.0, **fixed)

        self.names = list(names)
        self.filters = [RobotFilter(self.config, name) for name in self.names]
        # cluster values: solver process ready before obstacles
        default_cluster_store(self.config).start()
        self._cluster_errors_told = {}     # id(store) -> failed solves already logged
        self._store, self._store_config = None, None
        sim = bool(node.get_parameter('use_sim_time').value)
        self.time = FilterTime(sim, stall)
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)

        t0 = time.perf_counter()
        vf = standard_value_function(lo, hi, shape, speed, omega_max, radius, horizon, cache_dir)
        self.standard = SafeSet(vf, self.standard_alpha, 'standard')
        self.safe_set = self.standard       # the control path reads this reference only
        self.log.info(
            f'standard set ready in {time.perf_counter() - t0:.2f} s: grid {tuple(shape)}, speed {speed}, '
            f'w_max {omega_max}, radius {radius}, horizon {horizon}, alpha {self.standard_alpha}; '
            f'{"sim time (wall clock when /clock stands still)" if sim else "wall time"}')

        self._last_log = {}
        self.set_update = ('none', 'no value function received')   # (accepted|rejected|ignored|none, why)
        self.set_updates = {'accepted': 0, 'rejected': 0}
        self._state_msgs = {}    # robot name -> its state status, refilled (rosmsg.refill_diagnostic)
        self._learned = None               # the newest well-formed learned value function
        self._work = threading.Condition()
        self._pending = None               # newest unprocessed job: ('message', bytes) | ('reselect',)
        self._closing = False
        self.vf_busy = False
        self._worker = threading.Thread(target=self._run_worker, name='value_function_worker', daemon=True)
        self._worker.start()
        # its own callback group: a multi-threaded executor may take it in parallel
        node.create_subscription(Float32MultiArray, VALUE_FUNCTION_TOPIC, self._on_value_function_bytes,
                                 rosmsg.QOS_LATCHED, raw=True,
                                 callback_group=MutuallyExclusiveCallbackGroup())
        self._live_parameters()

    # -- parameters at run time ----------------------------------------------------------------
    def _live_parameters(self):
        live = LiveParameters(self.node, lock=self._lock)

        def config_check(name):
            def check(value):
                try:
                    replace(self.config, **{name: float(value)})
                except ValueError as exc:
                    return str(exc)
                return None
            return check

        def config_apply(name):
            def apply(value):
                self.config = replace(self.config, **{name: float(value)})
                for f in self.filters:
                    f.config = self.config
            return apply

        for name, *_ in _CONFIG_PARAMS:
            live.add(name, config_apply(name), config_check(name))

        def set_standard_alpha(value):
            self.standard_alpha = float(value)
            self.config = replace(self.config, cluster_alpha=self.standard_alpha)
            for f in self.filters:
                f.config = self.config
            self.standard = SafeSet(self.standard.vf, self.standard_alpha, 'standard')
            if self.safe_set.source == 'standard':
                self.safe_set = self.standard
            else:
                self._submit(('reselect',))   # the learned set must pass again at the new level

        def set_alpha_offset(value):
            self.alpha_offset = float(value)
            if self._learned is not None and self.use_learned:
                self._submit(('reselect',))

        def set_use_learned(value):
            self.use_learned = bool(value)
            if not self.use_learned:
                self.safe_set = self.standard
            elif self._learned is not None:
                self._submit(('reselect',))

        def set_rate(value):
            self.rate = float(value)
            if self._on_rate is not None:
                self._on_rate(self.rate)

        def set_stall(value):
            self.time.stall_timeout = float(value)

        def set_sim(value):
            self.time.sim = bool(value)

        live.add('standard_alpha', set_standard_alpha)
        live.add('alpha_offset', set_alpha_offset)
        live.add('use_learned', set_use_learned)
        live.add('rate', set_rate)
        live.add('state_rate', lambda v: setattr(self, 'state_period', 1.0 / float(v)))
        live.add('max_value_function_bytes', lambda v: setattr(self, 'max_vf_bytes', int(v)))
        live.add('clock_stall_timeout', set_stall)
        live.add('use_sim_time', set_sim)   # rclpy switches the node clock; ages follow
        self.live = live

    # -- time ------------------------------------------------------------------------------------------
    def now(self) -> float:
        """tau: the filter's time (see filter.timebase). Wall mode reads no ROS clock (the
        steady clock is time.monotonic, CLOCK_MONOTONIC like rclpy's STEADY_TIME, cheaper)."""
        ros = self.node.get_clock().now().nanoseconds * 1e-9 if self.time.sim else 0.0
        return self.time.now(ros, time.monotonic())

    def stamp(self, header_stamp, tau) -> float | None:
        """A message's header stamp on the filter's time base (None: unstamped or unusable).
        In wall mode the ROS clock is the system clock (time.time)."""
        stamp_s = header_stamp.sec + header_stamp.nanosec * 1e-9
        ros = self.node.get_clock().now().nanoseconds * 1e-9 if self.time.sim else time.time()
        return self.time.stamp_to_tau(stamp_s, ros, tau)

    # -- logging ---------------------------------------------------------------------------------------
    def complain(self, kind: str, text: str, level='warn'):
        """Log ``text`` at most every LOG_THROTTLE_S per ``kind``."""
        now = time.monotonic()
        if now - self._last_log.get(kind, -math.inf) >= LOG_THROTTLE_S:
            self._last_log[kind] = now
            # rclpy ties a severity to each call site: one call per level
            if level == 'error':
                self.log.error(text)
            elif level == 'info':
                self.log.info(text)
            else:
                self.log.warn(text)

    # -- value functions (off the control path) --------------------------------------------------------
    def _on_value_function_bytes(self, data: bytes):
        size = len(data)
        if size > self.max_vf_bytes:
            self._reject(f'value function message of {size} bytes exceeds max_value_function_bytes '
                         f'({self.max_vf_bytes}); not decoded')
            return
        self.log.info(f'value function message received ({size} bytes): decoding and checking it off the '
                      f'control path')
        self._submit(('message', data))

    def _submit(self, job):
        with self._work:
            if self._pending is not None and self._pending[0] == 'message' and job[0] == 'reselect':
                return   # the queued message selects anew anyway
            self._pending = job    # only the newest set matters: a newer one supersedes
            self._work.notify()

    def _run_worker(self):
        while True:
            with self._work:
                while self._pending is None and not self._closing:
                    self._work.wait()
                if self._closing:
                    return
                job, self._pending = self._pending, None
                self.vf_busy = True
            try:
                if job[0] == 'message':
                    self._take_message(job[1])
                else:
                    self._select(revert_on_failure=True)
            except Exception as exc:   # never let the worker die: say why and keep the set
                self._reject(f'value function handling failed: {type(exc).__name__}: {exc}')
            finally:
                self.vf_busy = False

    def _take_message(self, data: bytes):
        t0 = time.perf_counter()
        try:
            vf = serialized_to_value_function(data)
        except (ValueFunctionMessageError, ValueError, TypeError) as exc:
            self._reject(f'value function rejected: {exc}')
            return
        del data
        if str(vf.meta.get('source', 'learned')) == 'standard':
            # a reset to the standard set: ours, computed locally (a received copy is not trusted)
            self._learned = None
            self.safe_set = self.standard
            self._accept(f'standard set requested by the publisher: the local standard set is in force '
                         f'(alpha {self.standard_alpha:.4g})')
            return
        self._learned = vf
        self._select(revert_on_failure=False, decode_s=time.perf_counter() - t0)

    def _select(self, revert_on_failure, decode_s=None):
        """Put the newest learned set in force if it is admissible at the current levels."""
        vf = self._learned
        if vf is None:
            return
        if not self.use_learned:
            self.set_update = ('ignored', 'learned set received but use_learned is false: the standard '
                                          'set stays in force')
            self.log.info(self.set_update[1])
            return
        settings = (self.use_learned, self.standard_alpha, self.alpha_offset)
        alpha = learned_alpha(vf.meta, self.alpha_offset)
        try:
            candidate = SafeSet(vf, alpha, 'learned')
        except ValueError as exc:
            self._reject(f'learned set rejected: {exc}', revert=revert_on_failure)
            return
        t0 = time.perf_counter()
        verdict = check_learned_set(self.standard.vf, self.standard_alpha, vf, alpha)
        check_s = time.perf_counter() - t0
        if not verdict.ok:
            self._reject(f'learned set (alpha {alpha:.4g}) rejected: {verdict.reason}',
                         revert=revert_on_failure)
            return
        # the law's lazily cached arrays (node gradients: 3 x the values) are built here, not
        # on the first decision that uses the set
        evaluate_pairs(vf, np.zeros((1, 3)))
        with self._lock:
            if (self.use_learned, self.standard_alpha, self.alpha_offset) != settings or self._learned is not vf:
                # the levels or the set changed while it was checked: check again with the new ones
                if self.use_learned:
                    self._submit(('reselect',))
                return
            self.safe_set = candidate
        timing = f'decoded in {decode_s:.3f} s, ' if decode_s is not None else ''
        self._accept(
            f'learned set in force: omega_max {vf.meta.get("omega_max")}, alpha {alpha:.4g} '
            f'(mu {vf.meta.get("mu")}, sigma {vf.meta.get("sigma")}), grid {vf.grid.shape}, '
            f'{vf.meta.get("interventions", "?")} interventions; {timing}checked in {check_s:.3f} s: '
            f'{verdict.reason}')

    def _accept(self, reason):
        self.set_updates['accepted'] += 1
        self.set_update = ('accepted', reason)
        self.log.info(reason)

    def _reject(self, reason, revert=False):
        self.set_updates['rejected'] += 1
        with self._lock:
            if revert and self.safe_set is not self.standard:
                self.safe_set = self.standard
                reason += '; back to the standard set'
            else:
                reason += f'; keeping the {self.safe_set.source} set'
        self.set_update = ('rejected', reason)
        self.log.error(reason)

    def close(self):
        with self._work:
            self._closing = True
            self._work.notify()
        self._worker.join(timeout=5.0)

    # -- state messages --------------------------------------------------------------------------------
    def state_values(self, out) -> dict:
        values = out.record()
        values['set_update'], values['set_update_reason'] = self.set_update
        values['sets_accepted'] = str(self.set_updates['accepted'])
        values['sets_rejected'] = str(self.set_updates['rejected'])
        values['time_base'] = ('wall (steady)' if not self.time.sim else
                               'wall (sim time stands still)' if self.time.stalled else 'sim')
        values['cluster_solves_failed'] = str(self.report_cluster_errors())
        return values

    def report_cluster_errors(self) -> int:
        """Log each cluster solve that failed (its cluster stays on the fallback); the count."""
        # called for every state message (1,000 robots in a fleet tick): the store is looked up
        # only when the config changed (cluster_link is live), the errors listed only when new
        if self._store_config is not self.config:
            self._store, self._store_config = default_cluster_store(self.config), self.config
        store = self._store
        told, failed = self._cluster_errors_told.get(id(store), 0), len(store.errors)
        if failed > told:
            with store._lock:
                new = list(store.errors.items())[told:]
            for key, why in new:
                self.node.get_logger().error(f'cluster value {key} could not be solved ({why}): that '
                                             'cluster stays on the fallback rule')
            self._cluster_errors_told[id(store)] = told + len(new)
        return failed

    def state_message(self, name: str, out):
        """The state of robot ``name`` (one status object per robot, refilled each time)."""
        cache = self._state_msgs
        old = cache.get(name)
        values, message = self.state_values(out), f'{out.action}: {out.reason}'
        status = (rosmsg.make_diagnostic(name, values, message, out.level) if old is None else
                  rosmsg.refill_diagnostic(old, name, values, message, out.level))
        cache[name] = status
        return status


class StateThrottle:
    """When to publish a robot's state: on every change of action or set update, and every
    ``period`` on a fixed phase (``phase`` in [0, 1) of a period), so that a fleet's periodic
    states are spread over the period instead of all falling on one tick."""

    __slots__ = ('t', 'action', 'update')

    def __init__(self, phase=0.0, now=None, period=1.0):
        self.t = -math.inf if now is None else now - period * (1.0 - phase)
        self.action, self.update = None, None

    def due(self, now, action, update, period) -> bool:
        changed = action != self.action or update is not self.update
        self.action, self.update = action, update
        if now - self.t >= period:
            # keep the phase; restart it after a long pause (or at start)
            self.t = self.t + period if now - self.t < 2.0 * period else now
            return True
        return changed


class FleetThrottle:
    """``StateThrottle`` for a fleet's n robots at once (robot i on phase i / n), as arrays: the
    same rule and the same arithmetic, without a call per robot each tick."""

    def __init__(self, n, now, period):
        self.t = now - period * (1.0 - np.arange(n) / n)
        self.action, self.update = [None] * n, None

    def due(self, now, actions, update, period) -> list:
        """The robots (indices) whose state is due, given every robot's action now."""
        n = len(self.t)
        changed = np.fromiter(map(ne, actions, self.action), dtype=bool, count=n)
        if update is not self.update:
            changed[:] = True
        self.action, self.update = list(actions), update
        late = now - self.t >= period
        if late.any():
            t = self.t[late]
            # keep the phase; restart it after a long pause (or at start)
            self.t[late] = np.where(now - t < 2.0 * period, t + period, now)
        return np.flatnonzero(late | changed).tolist()
