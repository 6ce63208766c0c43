"""The filter node's shared parts, put together (no node here).

``FilterWiring(node, params, names)`` gives a node, from its parameters (``filter_parameters``):

* the live parameters in force when set;
* one ``RobotFilter`` per robot name, all sharing the live ``FilterConfig``;
* the standard set (true dynamics, from the cache or solved at start);
* the set in force (``runtime.set_selector``): ``/safe_set/value_function`` is taken as
  serialized bytes by a thread of its own on a helper node ``<name>_sets``, with the GIL
  released while the bytes are copied (``ros_io.direct_take``, ``gil_free``: rclpy's take
  held it for the whole copy, 0.2-0.8 s for 50 MB, and the control path stood still; the
  ``take_path`` parameter: ``public`` = rclpy's public API, the GIL held), so
  an oversize message is refused by its length before anything is decoded; then it is
  decoded and checked for admissibility on a worker thread, off the control path; the
  state messages say what became of each set (``set_update``, ``set_update_reason``);
* the filter's time base (``runtime.timebase.FilterTime``): ages on sim time while
  /clock advances, on the steady clock when ``use_sim_time`` is false or ROS time
  stands still (no /clock), so a stale input is detected either way;
* state messages and throttled complaints (``filter_state``).
"""
from __future__ import annotations

import time

from contextlib import nullcontext

from rclpy.clock import Clock, ClockType
from std_msgs.msg import Float32MultiArray

from ..filter import RobotFilter, default_cluster_store
from ..runtime.set_selector import LearnedSetSelector
from ..runtime.timebase import FilterTime
from ..learning.levels import learned_alpha
from ..ros_io import rosmsg
from ..ros_io.direct_take import DirectTake
from ..ros_io.cdr import serialized_to_value_function
from .filter_state import Complaints, StateReporter

VALUE_FUNCTION_TOPIC = '/safe_set/value_function'


def standard_value_function(lo, hi, shape, speed, omega_max, radius, horizon, cache_dir=None):
    """The standard set's V: true dynamics and radius, from the cache or solved now.

    horizon <= 0 means "to convergence".
    """
    from ..reach.grid import Grid
    from ..reach.library import load_or_solve
    return load_or_solve(Grid(tuple(lo), tuple(hi), tuple(int(n) for n in shape)), speed, omega_max,
                         radius, horizon if horizon > 0 else None, cache_dir=cache_dir or None)


def describe_age(age: float) -> str:
    """A stamp's age in words an operator reads: '1.0 h in the past', '2.5 s in the future',
    '57 years in the past' (a stamp of another clock against the system's)."""
    a = abs(age)
    if a < 60.0:
        size = f'{a:.2g} s'
    elif a < 3600.0:
        size = f'{a / 60.0:.1f} min'
    elif a < 172800.0:
        size = f'{a / 3600.0:.1f} h'
    elif a < 3.0e7:
        size = f'{a / 86400.0:.0f} days'
    else:
        size = f'{a / 31557600.0:.0f} years'
    return f'{size} in the {"past" if age >= 0.0 else "future"}'


class FilterWiring:
    """A filter node's parts put together: parameters, filters, the set in force (selector),
    time base and state messages (see the module)."""

    def __init__(self, node, params, names, on_rate=None, lock=None):
        self.node = node
        self.log = node.get_logger()
        self.params = p = params
        self.frame = p.frame
        self.names = list(names)
        self.filters = [RobotFilter(p.config, name) for name in self.names]
        # cluster values: solver process ready before obstacles
        default_cluster_store(p.config).start()
        self.time = FilterTime(p.use_sim_time, p.clock_stall_timeout)
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)

        t0 = time.perf_counter()
        c = p.config
        vf = standard_value_function(p.standard_lo, p.standard_hi, p.standard_shape, c.speed, c.omega_max,
                                     c.radius, p.standard_horizon, p.cache_dir)
        self.selector = LearnedSetSelector(
            vf, p.standard_alpha, alpha_offset=p.alpha_offset, use_learned=p.use_learned,
            max_bytes=p.max_value_function_bytes, decode=serialized_to_value_function, level=learned_alpha,
            log=self.log, lock=lock)
        how = 'loaded from the cache' if getattr(vf, 'from_cache', False) else 'solved and cached'
        self.log.info(
            f'standard set {how} in {time.perf_counter() - t0:.2f} s ({getattr(vf, "cache_path", "no file")}): '
            f'grid {tuple(p.standard_shape)}, speed {c.speed}, w_max {c.omega_max}, radius {c.radius}, '
            f'horizon {p.standard_horizon}, alpha {p.standard_alpha}; '
            f'{"sim time (wall clock when /clock stands still)" if p.use_sim_time else "wall time"}')
        self.complain = Complaints(self.log).complain
        self._reporter = StateReporter(self.log, self.selector, self.time, lambda: self.params.config)
        self.state_message = self._reporter.state_message
        self.shared_state_values = self._reporter.shared_values
        # a thread of its own, never the executor's: a 50 MB message is copied there without the GIL
        self.sets = DirectTake(node, nullcontext(), suffix='_sets', path=p.take_path)
        try:
            self.sets.add(Float32MultiArray, VALUE_FUNCTION_TOPIC, self.selector.offer, rosmsg.QOS_LATCHED,
                          raw=True, gil_free=True)
        except BaseException:
            self.sets.close()
            raise
        self.sets.start()
        # held while parameters change (the node's callbacks hold it too)
        self.live = p.keep_current(lock, {
            'config': self._use_config,
            'standard_alpha': self.selector.set_standard_alpha,
            'alpha_offset': self.selector.set_alpha_offset,
            'use_learned': self.selector.set_use_learned,
            'max_value_function_bytes': lambda n: setattr(self.selector, 'max_bytes', n),
            'rate': on_rate,
            'clock_stall_timeout': lambda s: setattr(self.time, 'stall_timeout', s),
            'use_sim_time': lambda sim: setattr(self.time, 'sim', sim),
        })

    def _use_config(self, config):
        for f in self.filters:
            f.config = config

    # what the nodes read (the parameter and the selector hold them)
    @property
    def config(self):
        return self.params.config

    @property
    def rate(self) -> float:
        return self.params.rate

    @property
    def state_period(self) -> float:
        return self.params.state_period

    @property
    def safe_set(self):
        return self.selector.safe_set

    @property
    def standard(self):
        return self.selector.standard

    @property
    def set_update(self):
        return self.selector.set_update

    # -- time ------------------------------------------------------------------------------------------
    def now(self) -> float:
        """tau: the filter's time (see runtime.timebase). Wall mode reads no ROS clock (the
        steady clock is time.monotonic, CLOCK_MONOTONIC like rclpy's STEADY_TIME, cheaper)."""
        ros = self.node.get_clock().now().nanoseconds * 1e-9 if self.time.sim else 0.0
        return self.time.now(ros, time.monotonic())

    def stamp(self, header_stamp, tau) -> float | None:
        """A message's header stamp on the filter's time base (None: unstamped or unusable).
        In wall mode the ROS clock is the system clock (time.time). MessageError if the stamp
        is farther than ``stamp_tolerance`` from that clock (another clock: ``sec: 100``
        against the wall's 1.7e9, or a clock that jumped): such a message describes no time
        the filter knows."""
        stamp_s = header_stamp.sec + header_stamp.nanosec * 1e-9
        ros = self.node.get_clock().now().nanoseconds * 1e-9 if self.time.sim else time.time()
        tau_stamp = self.time.stamp_to_tau(stamp_s, ros, tau)
        tolerance = self.params.stamp_tolerance
        if tau_stamp is not None and abs(ros - stamp_s) > tolerance:
            raise rosmsg.MessageError(
                f'stamped {describe_age(ros - stamp_s)} by the node\'s {"sim" if self.time.sim else "system"} '
                f'clock: another clock or a clock jump (stamp_tolerance {tolerance:g} s)')
        return tau_stamp

    def close(self):
        self.sets.close()
        self.selector.close()
