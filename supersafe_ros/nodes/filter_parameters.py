"""The parameters both filter nodes share: one table, read in one place, live ones kept current.

``FILTER_PARAMETERS`` lists each parameter with its description and range. The
defaults of ``FilterConfig``'s fields (speed, omega_max, radius, the timeouts,
margins, lookahead, control period) are read from ``FilterConfig`` itself, so they
have one source; config/safety_filter.yaml and config/fleet_safety_filter.yaml
repeat every default (test/test_nodes_filter_parameters.py fails when they drift).

``FilterParameters(node)`` declares them and holds their values (the config, the
standard set's grid, the levels, rates and limits). ``keep_current(lock, effects)``
registers the live ones (``live``: take effect when set at run time; the rest are
read-only): a set is first checked (``check``: would ``FilterConfig`` take it?), then
applied under ``lock``: the value is stored here, then ``effects[name](value)`` puts
it into force (``effects['config'](config)`` for a new ``FilterConfig``).
"""
from __future__ import annotations

from dataclasses import fields, replace

from ..filter import FilterConfig
from ..filter.types import MAX_DETECTIONS_LEAST
from ..ros_io import rosmsg
from ..ros_io.direct_take import TAKE_PATHS
from .common import LiveParameters, ParameterSpec, declare_all

_CONFIG_DEFAULTS = {f.name: f.default for f in fields(FilterConfig)}


def config_parameter(name, description, lo, hi, live) -> ParameterSpec:
    """A parameter that sets the ``FilterConfig`` field of the same name, with its default
    (a float: a parameter declared with 3 would take only integers)."""
    return ParameterSpec(name, float(_CONFIG_DEFAULTS[name]), description, lo, hi, live)


# FilterConfig fields set from parameters of the same name, all changeable at run time
CONFIG_PARAMETERS = (
    config_parameter('pose_timeout', 'a pose older than this is stale [s]', 0.001, 60.0, live=True),
    config_parameter('detections_timeout', 'detections older than this are stale [s]', 0.001, 60.0, live=True),
    config_parameter('hold_timeout', 'fail safe with the avoid control of the last valid state while it is '
                     'younger than this, then fail_safe_command [s]', 0.0, 60.0, live=True),
    config_parameter('cmd_timeout', 'planner silent longer than this: zero command [s]', 0.001, 60.0, live=True),
    config_parameter('clear_margin', 'hysteresis: keep overriding until V > alpha + margin', 0.0, 10.0,
                     live=True),
    config_parameter('lookahead', 'also override when the planner\'s command, held this long, would reach '
                     'V <= alpha; never less than the control period [s]', 0.0, 10.0, live=True),
    config_parameter('control_period', 'the robot\'s command hold time [s]; 0 = measure it from pose stamps '
                     'and planner commands', 0.0, 10.0, live=True),
    # an integer (rclpy refuses 10000.0 for it): FilterConfig takes either
    ParameterSpec('max_detections', _CONFIG_DEFAULTS['max_detections'], 'a detections message keeps at most this '
                  'many, the nearest to the robot (to any robot: fleet/detections); the state and a WARN say how '
                  'many were dropped and whether all were beyond the filter\'s reach (else ERROR)',
                  MAX_DETECTIONS_LEAST, 10_000_000, live=True),
)
LIVE_CONFIG_FIELDS = tuple(p.name for p in CONFIG_PARAMETERS)

# a stamp from another clock (issue 31, the nodes' half; a block of its own)
STAMP_PARAMETERS = (
    ParameterSpec('stamp_tolerance', 1.0, 'a pose or sensor message stamped farther than this from the node\'s '
                  'clock is refused with an ERROR (another clock, a clock jump): failing safe [s]',
                  0.001, 1e9, live=True),
)

# in the order they are declared
FILTER_PARAMETERS = (
    # the true dynamics and obstacle: the standard set (read-only)
    config_parameter('speed', 'the robot\'s largest forward speed, true dynamics [m/s] (the standard set\'s v): '
                     'the planner\'s linear.x is passed clipped to [0, speed]', 0.01, 100.0, live=False),
    config_parameter('omega_max', 'robot turn-rate bound, true dynamics [rad/s]; |u*|', 0.01, 20.0, live=False),
    config_parameter('radius', 'true obstacle radius [m] (standard set)', 0.01, 100.0, live=False),
    ParameterSpec('fail_safe_command', _CONFIG_DEFAULTS['fail_safe_command'], 'what the robot is sent when the filter '
                  'cannot judge (no input yet, stale input, after hold_timeout): stop = a zero twist, the avoid turn '
                  'at the speed last sent first where the last valid state calls for it (a robot that can stop); '
                  'stop_turn = v 0, u +omega_max, the study\'s constant-speed Dubins robot (driven at speed '
                  'whatever linear.x says)'),
    # the levels
    ParameterSpec('standard_alpha', 0.0, 'alpha of the standard set [value units, m]', -10.0, 10.0, live=True),
    ParameterSpec('alpha_offset', 0.0, 'k in alpha = mu + k sigma for a learned set (paper: 0)', -5.0, 10.0,
                  live=True),
    ParameterSpec('use_learned', True, 'take the learner\'s sets (each checked against the standard set '
                  'first)', live=True),
    # staleness, fail safe, hysteresis, lookahead
    *CONFIG_PARAMETERS,
    # output and limits
    ParameterSpec('rate', 50.0, 'decision rate [Hz, steady clock]: watchdog (one robot) or tick (fleet)',
                  0.1, 1000.0, live=True),
    ParameterSpec('state_rate', 10.0, 'most state messages per second and robot while the action does not '
                  'change [Hz]', 0.1, 1000.0, live=True),
    ParameterSpec('max_value_function_bytes', 64 * 1024 * 1024,
                  'a value-function message larger than this is rejected unread [bytes]', 1024, 2 ** 31 - 1,
                  live=True),
    ParameterSpec('clock_stall_timeout', 2.0, 'with use_sim_time: ROS time standing still longer than this '
                  '[steady s] counts as stopped, and ages follow the wall clock', 0.01, 600.0, live=True),
    ParameterSpec('take_path', 'private', 'how the inputs taken off the executor (the value function; one '
                  'robot\'s pose, detections and cmd_vel_nav with direct_take) are taken: private = an rcl wait '
                  'set of their own and the value function copied without the GIL (rclpy\'s private '
                  '_rclpy.WaitSet, rcl through ctypes; falls back to public with a WARN when rclpy lacks them); '
                  'public = the helper node spun by a SingleThreadedExecutor of its own (bench/results/take.md)'),
    # frame and the standard set's grid (read-only)
    ParameterSpec('frame_id', rosmsg.MAP_FRAME, 'frame of pose and detections'),
    ParameterSpec('cache_dir', '', 'value-function cache ("" = $SUPERSAFE_CACHE or ~/.cache/supersafe_ros)'),
    ParameterSpec('standard_lo', [-8.0, -8.0], 'standard set grid: (xmin, ymin) relative to the obstacle [m]'),
    ParameterSpec('standard_hi', [8.0, 8.0], 'standard set grid: (xmax, ymax) [m]'),
    ParameterSpec('standard_shape', [65, 65, 42], 'standard set grid: nodes (nx, ny, ntheta)'),
    ParameterSpec('standard_horizon', 3.0, 'standard set horizon [s] (as the library; 0 = to convergence)',
                  0.0, 1000.0),
    *STAMP_PARAMETERS,
)


def check_config_field(config: FilterConfig, name: str, value) -> str | None:
    """Why ``config`` cannot take ``value`` for its field ``name`` (None: it can). rclpy has
    checked the type and range already; FilterConfig checks the rest."""
    try:
        replace(config, **{name: float(value)})
    except ValueError as exc:
        return str(exc)
    return None


class FilterParameters:
    """The shared filter parameters of a node, declared and read here (see the module)."""

    def __init__(self, node):
        self._node = node
        v = declare_all(node, FILTER_PARAMETERS)
        self.standard_alpha = v['standard_alpha']
        self.alpha_offset = v['alpha_offset']
        self.use_learned = v['use_learned']
        # clusters of close obstacles are judged with the true radius at the standard level
        self.config = FilterConfig(speed=v['speed'], omega_max=v['omega_max'], radius=v['radius'],
                                   fail_safe_command=v['fail_safe_command'], cluster_alpha=self.standard_alpha,
                                   **{name: v[name] for name in LIVE_CONFIG_FIELDS})
        self.rate = v['rate']
        self.state_period = 1.0 / v['state_rate']
        self.max_value_function_bytes = v['max_value_function_bytes']
        self.clock_stall_timeout = v['clock_stall_timeout']
        self.use_sim_time = bool(node.get_parameter('use_sim_time').value)
        self.frame = v['frame_id']
        self.cache_dir = v['cache_dir']
        self.standard_lo, self.standard_hi = v['standard_lo'], v['standard_hi']
        self.standard_shape, self.standard_horizon = v['standard_shape'], v['standard_horizon']
        self.stamp_tolerance = v['stamp_tolerance']
        self.take_path = v['take_path']
        if self.take_path not in TAKE_PATHS:
            raise ValueError(f'take_path must be one of {", ".join(TAKE_PATHS)}, got {self.take_path!r}')

    def keep_current(self, lock, effects: dict) -> LiveParameters:
        """Register every live parameter (and use_sim_time); ``effects``: name -> what puts a
        new value into force, 'config' -> what puts a new FilterConfig into force."""
        live = LiveParameters(self._node, lock=lock)
        for name in LIVE_CONFIG_FIELDS:
            live.add(name, self._config_setter(name, effects['config']), self._config_check(name))

        def set_standard_alpha(value):
            self.standard_alpha = float(value)
            self.config = replace(self.config, cluster_alpha=self.standard_alpha)
            effects['config'](self.config)
            effects['standard_alpha'](self.standard_alpha)

        live.add('standard_alpha', set_standard_alpha)
        live.add('alpha_offset', self._setter('alpha_offset', float, effects))
        live.add('use_learned', self._setter('use_learned', bool, effects))
        live.add('rate', self._setter('rate', float, effects))
        live.add('state_rate', lambda value: setattr(self, 'state_period', 1.0 / float(value)))
        live.add('max_value_function_bytes', self._setter('max_value_function_bytes', int, effects))
        live.add('clock_stall_timeout', self._setter('clock_stall_timeout', float, effects))
        live.add('use_sim_time', self._setter('use_sim_time', bool, effects))   # rclpy switches the node clock
        live.add('stamp_tolerance', self._setter('stamp_tolerance', float, effects))
        return live

    def _setter(self, name, kind, effects):
        def apply(value):
            setattr(self, name, kind(value))
            effect = effects.get(name)
            if effect is not None:
                effect(getattr(self, name))
        return apply

    def _config_check(self, name):
        return lambda value: check_config_field(self.config, name, value)

    def _config_setter(self, name, effect):
        def apply(value):
            self.config = replace(self.config, **{name: float(value)})     # (max_detections: made an int)
            effect(self.config)
        return apply
