"""The filter node's parameters: one table, read in one place, live ones kept current.

``PARAMETERS`` is every parameter of the filter node (safety_filter_node; fleet_safety_filter_node
is the same node under another name), each with its description and range, in the order declared:

* ``FILTER_PARAMETERS``: the filter itself (the true dynamics, levels, timeouts, rates, the
  standard set's grid). The defaults of ``FilterConfig``'s fields (speed, omega_max, radius, the
  timeouts, margins, lookahead, control period) are read from ``FilterConfig`` itself, so they
  have one source;
* ``ROBOT_PARAMETERS``: which robots, on which topics, decided when (``robots``,
  ``per_robot_topics``, ``batched_topics``, ``decide_on``), the lockstep and the level-set markers;
* ``TYPE_PARAMETERS``: the message types a robot's stack sends (``pose_type``, ``detections_type``,
  ``cmd_vel_stamped``, ``require_detections``);
* ``MAP_PARAMETERS``: for a range sensor or a costmap, its mount, its local map and the map's value.

config/safety_filter.yaml, config/fleet_safety_filter.yaml repeat every default
(test/test_nodes_filter_parameters.py fails when they drift).

``FilterParameters(node)`` declares them all and holds their values (``values``, by name; the
config, the standard set's grid, the levels, rates and limits as attributes; ``robots`` resolved
and the decision trigger, ``mode``). ``keep_current(lock, effects)`` registers the live ones
(``live``: take effect when set at run time; the rest are read-only): a set is first checked
(``check``: would ``FilterConfig`` take it?), then applied under ``lock``: the value is stored
here, then ``effects[name](value)`` puts it into force (``effects['config'](config)`` for a new
``FilterConfig``).
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
    config_parameter('time_before_collision', 'a robot that can stop (fail_safe_command stop): cut the speed so '
                     'that the path of each command, held max(this, the lookahead) s, enters no detected disc '
                     '(Nav2 collision_monitor\'s approach model; turning in place is always allowed); 0 = off [s]',
                     0.0, 60.0, live=True),
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
    ParameterSpec('rate', 50.0, 'decision rate [Hz, steady clock]: the watchdog (decide_on input) or the tick '
                  '(decide_on tick)', 0.1, 1000.0, live=True),
    ParameterSpec('state_rate', 10.0, 'most state messages per second and robot while the action does not '
                  'change [Hz]', 0.1, 1000.0, live=True),
    ParameterSpec('max_value_function_bytes', 64 * 1024 * 1024,
                  'a value-function message larger than this is rejected unread [bytes]', 1024, 2 ** 31 - 1,
                  live=True),
    ParameterSpec('clock_stall_timeout', 2.0, 'with use_sim_time: ROS time standing still longer than this '
                  '[steady s] counts as stopped, and ages follow the wall clock', 0.01, 600.0, live=True),
    ParameterSpec('take_path', 'private', 'how the inputs taken off the executor (the value function; the '
                  'robots\' pose, detections and cmd_vel_nav with direct_take) are taken: private = an rcl wait '
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


POSE_TYPES = ('pose_stamped', 'odometry', 'pose_with_covariance')
DETECTIONS_TYPES = ('pose_array', 'marker_array', 'laser_scan', 'point_cloud2', 'occupancy_grid')
RANGE_SENSORS = ('laser_scan', 'point_cloud2')
MAP_SENSORS = RANGE_SENSORS + ('occupancy_grid',)     # the detections kept in a local map
DECIDE_ON = ('auto', 'input', 'tick')
INPUT, TICK = 'input', 'tick'                         # the decision triggers (``FilterParameters.mode``)

# which robots, on which topics, decided when
ROBOT_PARAMETERS = (
    ParameterSpec('robots', [''], 'the robots this node filters, each the namespace of its topics, resolved as '
                  'a topic name is (\'robot_0\': <node namespace>/robot_0/pose; \'/robot_0\': absolute); \'\' = '
                  'this node\'s own namespace (one robot); row i of the batched topics is robots[i]'),
    ParameterSpec('per_robot_topics', True, 'serve each robot\'s own topics: <robot>/pose, <robot>/detections, '
                  '<robot>/cmd_vel_nav -> <robot>/cmd_vel, <robot>/safety_filter/state, <robot>/safety_filter/ready'),
    ParameterSpec('batched_topics', False, 'serve fleet/poses, fleet/detections, fleet/cmd_vel_nav -> '
                  'fleet/cmd_vel, fleet/safety_filter/state (one message a tick for every robot)'),
    ParameterSpec('decide_on', 'auto', f'when a robot is decided, one of {DECIDE_ON}: input = at once on each '
                  'planner command and range-sensor message (each pose too with publish_on_pose or lockstep), that '
                  'robot alone, and by a watchdog at rate when nothing went out; tick = every robot at once at rate '
                  '(and on each fleet/poses), on the newest of each input: the most robots per core, a decision '
                  'waiting up to 1/rate; auto = input for one robot on its own topics, tick otherwise'),
    ParameterSpec('publish_on_pose', False, 'decide_on input: also decide and publish on every pose (not in a '
                  'lockstep graph)', live=True),
    ParameterSpec('lockstep', False, 'the robots are lockstepped (sim_clock_node): answer each pose once, on '
                  'that pose; planner commands and the watchdog do not publish (decide_on input)'),
    ParameterSpec('lockstep_silence', 2.0, 'lockstep: the watchdog publishes only after this long without '
                  'a pose [steady s]', 0.01, 3600.0),
    ParameterSpec('cluster_hold_timeout', 0.0, 'lockstep: hold the answer to a pose while a cluster\'s union '
                  'value is being solved, at most this long [steady s]; 0 = never hold (the fallback acts)',
                  0.0, 600.0),
    ParameterSpec('direct_take', True, 'decide_on input: pose, detections and cmd_vel_nav are taken by a thread '
                  'of their own that waits on them alone, off the executor\'s wake-up over every entity: about '
                  '0.3 ms less from pose to cmd_vel; false = the executor takes them. Not with lockstep (there a '
                  'pose must be read after the /clock before it)'),
    ParameterSpec('level_set_rate', 2.0, 'rate of <robot>/safety_filter/level_set markers [Hz, steady clock]',
                  0.1, 50.0),
    ParameterSpec('level_set_markers', True, 'publish the level set in force at each robot\'s heading around '
                  'each detected obstacle on <robot>/safety_filter/level_set (LINE_STRIPs, for RViz; computed only '
                  'while someone listens)'),
)

# the message types a robot's stack sends (nodes/filter_sources.py reads them)
TYPE_PARAMETERS = (
    ParameterSpec('pose_type', 'pose_stamped', f'message on pose: one of {POSE_TYPES}'),
    ParameterSpec('detections_type', 'pose_array', f'message on detections: one of {DETECTIONS_TYPES} '
                  '(pose_array: centres of radius; marker_array: CYLINDER discs of their own radius; '
                  'laser_scan / point_cloud2: returns in the sensor\'s frame, kept in a local map; '
                  'occupancy_grid: a costmap in frame_id, kept in the local map)'),
    ParameterSpec('cmd_vel_stamped', False, 'cmd_vel_nav and cmd_vel are geometry_msgs/TwistStamped (false: '
                  'Twist)'),
    ParameterSpec('require_detections', True, 'fail safe until detections arrive and whenever they are stale; '
                  'false = a robot without an obstacle sensor: every pose comes with "no obstacle" and '
                  'detections is not subscribed'),
)
# a range sensor's or a costmap's local map and its value (nodes/filter_sources.py: SensorMap)
MAP_PARAMETERS = (
    ParameterSpec('robot_radius', 0.3, 'laser_scan / point_cloud2 / occupancy_grid: the robot\'s own radius: it '
                  'keeps this far from every occupied cell of its local map [m]', 0.0, 100.0),
    ParameterSpec('sensor_x', 0.0, 'laser_scan / point_cloud2: the sensor\'s x in the robot\'s frame [m]',
                  -100.0, 100.0),
    ParameterSpec('sensor_y', 0.0, 'laser_scan / point_cloud2: the sensor\'s y in the robot\'s frame [m]',
                  -100.0, 100.0),
    ParameterSpec('sensor_yaw', 0.0, 'laser_scan / point_cloud2: the sensor\'s yaw in the robot\'s frame '
                  '[rad]', -7.0, 7.0),
    ParameterSpec('obstacle_depth', 0.0, 'laser_scan / point_cloud2: each return also marks its beam this far '
                  'behind it in the local map (the far side the sensor cannot see; a beam that later passes '
                  'there clears it; 0 = the surface alone) [m]', 0.0, 100.0),
    ParameterSpec('inf_is_valid', False, 'laser_scan: a +inf range is a beam that saw nothing up to range_max '
                  'and clears its cells (as Nav2\'s obstacle layer); false: it clears nothing (REP 117 leaves '
                  'it to the driver)'),
    ParameterSpec('map_cell', 0.05, 'laser_scan / point_cloud2 / occupancy_grid: the local map\'s cell side [m]',
                  0.005, 10.0),
    ParameterSpec('map_size', 10.0, 'the local map\'s window side, centred on the robot and moved with it '
                  '(what leaves it is forgotten) [m]', 0.5, 1000.0),
    ParameterSpec('value_cell', 0.0, 'the local map\'s value: its grid\'s spacing [m]; 0 = (value_reach + speed '
                  'x horizon) / 28 in whole map cells, about 60 x 60 nodes a heading (0.1 m for 0.5 m/s over 3 s)',
                  0.0, 10.0),
    ParameterSpec('value_headings', 32, 'the local map\'s value: headings of its grid', 8, 256),
    ParameterSpec('value_horizon', 0.0, 'the local map\'s value: its horizon [s] (0 = standard_horizon; a fast '
                  'robot\'s window grows with speed x horizon)', 0.0, 60.0),
    ParameterSpec('value_reach', 1.0, 'the local map\'s value: how far the robot may go from the solved window\'s '
                  'centre with its value sound (it is solved around the robot again once 0.5 m away) [m]', 0.1, 100.0),
    ParameterSpec('value_period', 0.5, 'the local map\'s value is solved again (in the background) at most every '
                  'this many seconds of the filter\'s time while the map changes, and not while inactive', 0.0, 60.0),
    ParameterSpec('occupied_threshold', 100, 'occupancy_grid: a cell of at least this value is occupied, 0 .. '
                  'this - 1 free, -1 unknown (leaves what the map held; Nav2\'s costmap: 100 lethal, 99 '
                  'inscribed)', 1, 100),
    ParameterSpec('max_sensor_points', 1_000_000, 'laser_scan / point_cloud2 / occupancy_grid: a message with more '
                  'beams, points or cells is refused unread (the map stays as it was) [points]', 1, 100_000_000),
)

# every parameter of the filter node, in the order declared
PARAMETERS = FILTER_PARAMETERS + ROBOT_PARAMETERS + TYPE_PARAMETERS + MAP_PARAMETERS


def robot_namespaces(own: str, robots) -> list:
    """Each entry of ``robots`` resolved as a namespace is, against the node's namespace ``own``
    ('robot_0' in '/': '/robot_0'; '/robot_0' absolute; '' the node's own). ValueError for none,
    or a namespace listed twice."""
    out = []
    for entry in robots:
        name = str(entry).strip()
        if name.startswith('/'):
            out.append('/' + name.strip('/'))
        elif name.strip('/'):
            out.append(own.rstrip('/') + '/' + name.strip('/'))
        else:
            out.append(own)
    if not out:
        raise ValueError('robots is empty: name at least one robot (\'\' = this node\'s own namespace)')
    if len(set(out)) != len(out):
        raise ValueError(f'robots lists a namespace twice: {out}')
    return out


def decision_mode(decide_on: str, robots: int, per_robot_topics: bool, batched_topics: bool) -> str:
    """INPUT or TICK (see ``decide_on``'s description): ``auto`` is INPUT for one robot on its own
    topics alone; ``input`` needs per-robot topics and no batched ones (a fleet/poses message is a
    tick of every robot). ValueError for a choice that does not hold."""
    if decide_on not in DECIDE_ON:
        raise ValueError(f'decide_on {decide_on!r} is not one of {DECIDE_ON}')
    if decide_on == 'auto':
        return INPUT if robots == 1 and per_robot_topics and not batched_topics else TICK
    if decide_on == INPUT and (batched_topics or not per_robot_topics):
        raise ValueError('decide_on input decides a robot on its own topics\' inputs: it needs per_robot_topics '
                         'true and batched_topics false (a fleet/poses message is a tick of every robot)')
    return decide_on


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
        self.values = v = declare_all(node, PARAMETERS)
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
        if v['pose_type'] not in POSE_TYPES:
            raise ValueError(f"pose_type {v['pose_type']!r} is not one of {POSE_TYPES}")
        if v['detections_type'] not in DETECTIONS_TYPES:
            raise ValueError(f"detections_type {v['detections_type']!r} is not one of {DETECTIONS_TYPES}")
        self.robots = robot_namespaces(node.get_namespace(), v['robots'])
        self.per_robot_topics, self.batched_topics = v['per_robot_topics'], v['batched_topics']
        if not (self.per_robot_topics or self.batched_topics):
            raise ValueError('per_robot_topics and batched_topics are both false: no topic to filter')
        self.mode = decision_mode(v['decide_on'], len(self.robots), self.per_robot_topics, self.batched_topics)
        self.lockstep = v['lockstep']
        if self.lockstep and self.mode != INPUT:
            raise ValueError('lockstep answers each robot\'s pose on that pose: it needs decide_on input (one robot '
                             'on its own topics with auto)')

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
