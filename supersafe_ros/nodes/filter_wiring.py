"""What safety_filter_node and fleet_safety_filter_node share (wiring, no node here).

``FilterWiring(node, names)`` gives a node:

* every filter parameter, declared with its descriptor; those that can change at
  run time (levels, margins, lookahead, control period, timeouts, use_learned,
  rates, the value-function size limit, the clock-stall timeout) take effect when
  set (``LiveParameters``), everything else is ``read_only``;
* one ``RobotFilter`` per robot name, all sharing the live ``FilterConfig``;
* the standard set (true dynamics, from the cache or solved at start);
* the set in force (``filter.set_selector``): ``/safe_set/value_function`` is taken as
  serialized bytes (so an oversize message is refused by its length before anything
  is decoded), then decoded and checked for admissibility on a worker thread, off the
  control path; the state messages say what became of each set (``set_update``,
  ``set_update_reason``);
* the filter's time base (``filter.timebase.FilterTime``): ages on sim time while
  /clock advances, on the steady clock when ``use_sim_time`` is false or ROS time
  stands still (no /clock), so a stale input is detected either way;
* state messages and throttled complaints (``filter_state``).
"""
from __future__ import annotations

from contextlib import nullcontext
from dataclasses import replace
import time

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from std_msgs.msg import Float32MultiArray

from ..filter.core import FilterConfig, RobotFilter, default_cluster_store
from ..filter.set_selector import LearnedSetSelector
from ..filter.timebase import FilterTime
from ..ros_io import rosmsg
from ..ros_io.vfcdr import serialized_to_value_function
from .common import LiveParameters, declare
from .filter_state import Complaints, StateReporter

VALUE_FUNCTION_TOPIC = '/safe_set/value_function'

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


def learned_alpha(meta: dict, k: float) -> float:
    """alpha = mu + k sigma from the fit's metadata, else its alpha, else 0."""
    mu, sigma = meta.get('mu'), meta.get('sigma')
    if mu is not None and sigma is not None:
        return float(mu) + k * float(sigma)
    return float(meta.get('alpha') or 0.0)


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
        alpha_offset = p('alpha_offset', 0.0, 'k in alpha = mu + k sigma for a learned set (paper: 0)',
                         -5.0, 10.0)
        use_learned = p('use_learned', True, 'take the learner\'s sets (each checked against the '
                        'standard set first)')
        values = {name: p(name, default, desc, lo, hi) for name, default, desc, lo, hi in _CONFIG_PARAMS}
        # clusters of close obstacles are judged with the true radius at the standard level
        self.config = FilterConfig(speed=speed, omega_max=omega_max, radius=radius,
                                   cluster_alpha=self.standard_alpha, **values)
        self.rate = p('rate', 50.0, 'decision rate [Hz, steady clock]: watchdog (one robot) or tick '
                      '(fleet)', 0.1, 1000.0)
        self.state_period = 1.0 / p('state_rate', 10.0, 'most state messages per second and robot '
                                    'while the action does not change [Hz]', 0.1, 1000.0)
        max_vf_bytes = p('max_value_function_bytes', 64 * 1024 * 1024,
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
        sim = bool(node.get_parameter('use_sim_time').value)
        self.time = FilterTime(sim, stall)
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)

        t0 = time.perf_counter()
        vf = standard_value_function(lo, hi, shape, speed, omega_max, radius, horizon, cache_dir)
        self.selector = LearnedSetSelector(
            vf, self.standard_alpha, alpha_offset=alpha_offset, use_learned=use_learned, max_bytes=max_vf_bytes,
            decode=serialized_to_value_function, level=learned_alpha, log=self.log, lock=lock)
        self.log.info(
            f'standard set ready in {time.perf_counter() - t0:.2f} s: grid {tuple(shape)}, speed {speed}, '
            f'w_max {omega_max}, radius {radius}, horizon {horizon}, alpha {self.standard_alpha}; '
            f'{"sim time (wall clock when /clock stands still)" if sim else "wall time"}')
        self.complain = Complaints(self.log).complain
        self._reporter = StateReporter(self.log, self.selector, self.time, lambda: self.config)
        self.state_message = self._reporter.state_message
        # its own callback group: a multi-threaded executor may take it in parallel
        node.create_subscription(Float32MultiArray, VALUE_FUNCTION_TOPIC, self.selector.offer,
                                 rosmsg.QOS_LATCHED, raw=True, callback_group=MutuallyExclusiveCallbackGroup())
        self._live_parameters()

    # what the nodes read (the selector holds it)
    @property
    def safe_set(self):
        return self.selector.safe_set

    @property
    def standard(self):
        return self.selector.standard

    @property
    def set_update(self):
        return self.selector.set_update

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
            self.selector.set_standard_alpha(self.standard_alpha)

        def set_rate(value):
            self.rate = float(value)
            if self._on_rate is not None:
                self._on_rate(self.rate)

        def set_stall(value):
            self.time.stall_timeout = float(value)

        def set_sim(value):
            self.time.sim = bool(value)

        live.add('standard_alpha', set_standard_alpha)
        live.add('alpha_offset', self.selector.set_alpha_offset)
        live.add('use_learned', self.selector.set_use_learned)
        live.add('rate', set_rate)
        live.add('state_rate', lambda v: setattr(self, 'state_period', 1.0 / float(v)))
        live.add('max_value_function_bytes', lambda v: setattr(self.selector, 'max_bytes', int(v)))
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

    def close(self):
        self.selector.close()
