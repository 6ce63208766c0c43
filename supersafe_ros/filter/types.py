"""The filter's shared vocabulary: its configuration, the safe set in force, and what one
decision says (the ``types`` header of nav2_collision_monitor, for this filter).

* ``FilterConfig``: speed bound, timeouts, hysteresis margin, lookahead, cluster settings,
  fail-safe command of one robot;
* ``SafeSet``: a value function V and the level alpha at or below which the filter acts;
* ``FilterOutput``: the command of one decision and why (``record()`` for the state topic);
* the actions ``PASS``, ``OVERRIDE``, ``FAIL_SAFE`` and their diagnostic levels.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

from ..reach.value_function import ValueFunction

PASS = 'pass'
OVERRIDE = 'override'
FAIL_SAFE = 'fail_safe'

# fail_safe_command: a robot that can stop (a zero twist), or the study's constant-speed Dubins
# robot (the stop-turn v = 0, u = +omega_max, which it drives at its speed)
STOP, STOP_TURN = 'stop', 'stop_turn'
FAIL_SAFE_COMMANDS = (STOP, STOP_TURN)

# max_detections is at least this (more than filter.constraints.nearby.NEAR_QUERY_MIN: a message it cut is narrowed)
MAX_DETECTIONS_LEAST = 100

# diagnostic_msgs/DiagnosticStatus levels, by action
LEVEL_OK, LEVEL_WARN, LEVEL_ERROR = 0, 1, 2
LEVEL_OF_ACTION = {PASS: LEVEL_OK, OVERRIDE: LEVEL_WARN, FAIL_SAFE: LEVEL_ERROR}


@dataclass(frozen=True)
class FilterConfig:
    """Parameters of the filter (times in seconds, rates in rad/s)."""

    # the robot's largest forward speed, the v of the value functions: the planner's linear.x is
    # passed clipped to [0, speed] (fail_safe_command 'stop'; 'stop_turn': a constant-speed Dubins
    # robot, always at speed)
    speed: float = 3.0
    omega_max: float = 1.0           # the robot's turn-rate bound: |u*| = omega_max
    pose_timeout: float = 0.5        # a pose older than this is stale
    detections_timeout: float = 1.0  # detections older than this are stale
    hold_timeout: float = 1.0        # last valid state still usable for fail-safe avoidance
    cmd_timeout: float = 0.5         # planner silent longer than this: zero twist
    clear_margin: float = 0.2        # hysteresis: release override when V > alpha + margin
    lookahead: float = 0.1           # override if the planner's command would reach alpha this soon
    control_period: float = 0.0      # the robot's command hold time; 0 = measure it from arrivals
    # propagate each pose over its age under the commands sent, and keep the lookahead >= the
    # control period (False: judge the pose as if current and use ``lookahead`` as given, the
    # behaviour before issue 9; for ablation benchmarks only)
    compensate_delay: bool = True
    # obstacles closer than cluster_link (0 = 2 radius + a turning diameter) are judged by
    # their union's value (filter.clusters), at level cluster_alpha, with the true dynamics
    clusters: bool = True
    radius: float = 1.8              # obstacle radius (cluster values)
    cluster_link: float = 0.0
    cluster_alpha: float = 0.0       # the union's level (the standard set's alpha)
    # a detections message keeps at most this many, the nearest to the robot (filter.constraints.nearby)
    max_detections: int = 10000
    # what a robot that can stop does when the filter cannot judge (FAIL_SAFE_COMMANDS): 'stop', a
    # zero twist (the avoid turn at the speed last sent first, where the last valid state calls
    # for it); 'stop_turn', the study's constant-speed Dubins robot: v = 0, u = +omega_max (the
    # avoid turn at speed first, where an obstacle is near the last valid state), the robot
    # modelled at ``speed`` whatever linear.x says
    fail_safe_command: str = 'stop'
    # a robot that can stop (fail_safe_command 'stop'): > 0 cuts the speed so that the path of each
    # command, held max(this, the lookahead's horizon) seconds, enters no detected disc (filter.approach,
    # Nav2 collision_monitor's approach model); 0 = off (the value-function law alone)
    time_before_collision: float = 0.0

    def __post_init__(self):
        for name in ('speed', 'omega_max', 'pose_timeout', 'detections_timeout', 'hold_timeout',
                     'cmd_timeout', 'clear_margin', 'lookahead', 'control_period', 'radius',
                     'cluster_link', 'time_before_collision'):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {v}')
            object.__setattr__(self, name, float(v))   # floats in every command (speed=3 goes out as 3.0)
        if not math.isfinite(self.cluster_alpha):
            raise ValueError(f'cluster_alpha must be finite, got {self.cluster_alpha}')
        object.__setattr__(self, 'cluster_alpha', float(self.cluster_alpha))
        m = self.max_detections
        if not (math.isfinite(m) and m == int(m) and m >= MAX_DETECTIONS_LEAST):
            raise ValueError(f'max_detections must be an integer >= {MAX_DETECTIONS_LEAST}, got {self.max_detections}')
        object.__setattr__(self, 'max_detections', int(self.max_detections))
        if self.fail_safe_command not in FAIL_SAFE_COMMANDS:
            raise ValueError(f'fail_safe_command must be one of {", ".join(FAIL_SAFE_COMMANDS)}, got '
                             f'{self.fail_safe_command!r}')
        if self.time_before_collision > 0.0 and self.constant_speed:
            raise ValueError(f'time_before_collision {self.time_before_collision:g} needs a robot that can stop '
                             f'(fail_safe_command {STOP!r}): a constant-speed robot cannot slow down')

    @property
    def constant_speed(self) -> bool:
        """A constant-speed Dubins robot (``fail_safe_command`` 'stop_turn'): it drives at
        ``speed`` whatever linear.x says, and the fail safe is the stop-turn."""
        return self.fail_safe_command == STOP_TURN

    @property
    def sent_kept(self) -> float:
        """How long the commands sent are remembered: a pose is propagated over at most
        hold_timeout and judged stale after pose_timeout, plus a second."""
        return max(self.hold_timeout, self.pose_timeout) + 1.0


@dataclass(frozen=True)
class SafeSet:
    """A value function and the level alpha below which the filter overrides.

    ``source`` is 'standard' (true dynamics, computed locally) or 'learned'
    (received from the learner).
    """

    vf: ValueFunction
    alpha: float
    source: str = 'standard'

    def __post_init__(self):
        if not math.isfinite(self.alpha):
            raise ValueError(f'alpha must be finite, got {self.alpha}')

    @property
    def omega_max(self):
        return self.vf.meta.get('omega_max')


@dataclass
class FilterOutput:
    """What one step decided."""

    omega: float                 # turn rate to command (angular.z)
    linear: float                # linear.x to command (the planner's, clipped to [0, speed]; 0 to stop)
    action: str                  # pass | override | fail_safe
    reason: str
    obstacle_index: int = -1     # index in the last detections, -1 if none
    obstacle_xy: tuple = (math.nan, math.nan)
    value: float = math.inf      # smallest V over the detections (+inf: none near)
    alpha: float = math.nan
    source: str = ''
    omega_max_set: float = math.nan  # omega_max of the safe set's model
    pose_age: float = 0.0        # seconds the pose was propagated over before judging
    lookahead: float = 0.0       # hold time the planner's command was judged over [s]
    clusters_solving: int = 0    # clusters near the robot whose union value is still being solved
    cmd_clipped: str = ''        # what of the planner's command was beyond the robot's limits ('' if none)
    detections_dropped: int = 0  # detections of the last message beyond max_detections, not judged
    detections_note: str = ''    # which were dropped and whether that is safe ('' if none)

    @property
    def level(self) -> int:
        return LEVEL_OF_ACTION[self.action]

    def record(self) -> dict:
        """Flat key/value record (for the diagnostic state message)."""
        return {
            'action': self.action,
            'reason': self.reason,
            'cmd_angular_z': f'{self.omega:.6g}',
            'cmd_linear_x': f'{self.linear:.6g}',
            'obstacle_index': str(self.obstacle_index),
            'obstacle_x': f'{self.obstacle_xy[0]:.6g}',
            'obstacle_y': f'{self.obstacle_xy[1]:.6g}',
            'value': f'{self.value:.6g}',
            'alpha': f'{self.alpha:.6g}',
            'omega_max': f'{self.omega_max_set:.6g}',
            'source': self.source,
            'pose_age': f'{self.pose_age:.6g}',
            'lookahead': f'{self.lookahead:.6g}',
            'clusters_solving': str(self.clusters_solving),
            'cmd_clipped': self.cmd_clipped,
            'detections_dropped': str(self.detections_dropped),
            'detections_dropped_reason': self.detections_note,
        }
