"""How a simulated supervisor decides, per approach: the paper's memoryless rule, or one
that infers from the robot's motion whether it has seen the obstacle.

Both models share the paper's noisy threshold (``sim.watcher``): per approach of robot r
to obstacle o one draw w ~ N(0, sigma^2), and the *alarm* at frame k is

    V_S(x_k) <= mu + w                                                       (1)

with x_k the robot's state relative to o and V_S the supervisor's own value function.

``memoryless`` (the paper's model, Sec. III-B): intervene at the first alarm, whatever the
robot has done.

``attentive``: the paper's Sec. IV says the supervisor "must infer this information
[whether a robot detected the obstacle] from the robots' motion". A person who has just
seen a robot swerve away from an obstacle knows it saw it; one who sees a robot turn for
something else, or straighten into the obstacle again, does not. Per approach the model
keeps one belief, *convinced* (the robot has seen o), and intervenes at an alarm (1) only
while not convinced. Its evidence, from consecutive poses of the approach (time step
dt_k = t_k - t_{k-1}, heading change dtheta_k = wrap(theta_k - theta_{k-1})):

* the robot's heading relative to its line of sight to o, psi = wrap(theta - beta),
  beta = atan2(-y, -x) for the relative position (x, y); the robot turns *away* from o by

      a_k = sign(psi_{k-1}) * dtheta_k                                       (2)

  (a_k > 0: the turn opens the angle between heading and obstacle; straight: 0);
* **convinced** once the turn away from o *attributable to o* in this approach reaches an
  angle phi_c:

      A_k = A_{k-1} + max(0, a_k) [o urgent at k, approached at k-1],   convinced iff A_k >= phi_c

  *urgent*: o has the lowest V_S of the obstacles near the robot (a turn when another
  obstacle is more pressing is explained by that one); *approached*: |psi_{k-1}| < pi/2,
  the robot was heading toward o (a turn while it moves away from o, e.g. toward its
  goal behind it, says nothing about o);
* **doubt**: a convinced belief is dropped (A = 0, convinced again only by new turns) when
  the robot is on a collision course with o and not turning away: its straight course
  reaches o's disc (the supervisor's believed radius R) within T_c,

      cos(psi) > 0,  c = d |sin(psi)| < R,  (d cos(psi) - sqrt(R^2 - c^2)) / v <= T_c,

  with d the distance to o's centre and v the speed, and the net turn away over the last
  W seconds, sum of a_j over t_j > t_k - W, is <= 0. A robot that turned for something
  else and then heads into o is so caught in time (T_c = 0.5 s is 1.5 m at 3 m/s); the
  intervention then comes at once (its alarm has been on).

The probe of issue 28 (no intervention once the heading turned 0.3 rad in the approach,
any turn) is this model without attribution and doubt; it cut false positives and cost
ten times the crashes. On Phase II's straight passes dtheta = 0, A stays 0 and the
attentive model is the memoryless one (``test_sim_supervisor_models.py``,
``study.calibrate``).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
import math

MODELS = ('memoryless', 'attentive')
# the default of the node and the study, chosen on the held-out Phase III comparison
# (docs/study.md, "Supervisor models"): closer to the paper's false-positive ratios than the
# memoryless model, with no more crashes
DEFAULT_MODEL = 'attentive'


@dataclass(frozen=True)
class AttentiveParams:
    """The attentive supervisor's constants (see the module docstring)."""

    convince_angle: float = 0.3      # phi_c [rad]: attributable turn away that convinces
    doubt_horizon: float = 0.5       # T_c [s]: straight course into the disc this soon: doubt
    doubt_window: float = 0.6        # W [s]: net turn over this window decides "turning away"
    radius: float = 1.8              # R [m]: the supervisor's believed obstacle radius
    speed: float = 3.0               # v [m/s]: the supervisor's believed robot speed

    def __post_init__(self):
        for name in self.__dataclass_fields__:
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {v}')


def check_model(model: str) -> str:
    """``model`` if it is one of MODELS, else ValueError naming them."""
    if model not in MODELS:
        raise ValueError(f"unknown supervisor model {model!r}; one of {', '.join(MODELS)}")
    return model


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def heading_off_line_of_sight(rel) -> float:
    """psi: the robot's heading relative to its line of sight to the obstacle [rad]."""
    x, y, theta = float(rel[0]), float(rel[1]), float(rel[2])
    return _wrap(theta - math.atan2(-y, -x))


def time_to_disc(rel, radius: float, speed: float) -> float:
    """Seconds until the straight course from ``rel`` enters the disc of ``radius`` at the
    origin (0 inside it; inf if the course misses it or points away)."""
    d = math.hypot(float(rel[0]), float(rel[1]))
    if d <= radius:
        return 0.0
    psi = heading_off_line_of_sight(rel)
    c = d * abs(math.sin(psi))
    if math.cos(psi) <= 0.0 or c >= radius or speed <= 0.0:
        return math.inf
    return max(0.0, d * math.cos(psi) - math.sqrt(radius * radius - c * c)) / speed


@dataclass
class DetectionBelief:
    """One approach's belief that the robot has seen the obstacle (attentive model)."""

    params: AttentiveParams
    turned_away: float = 0.0         # A: attributable turn away so far [rad]
    convinced: bool = False
    recent: deque = field(default_factory=deque)   # (t, a) of the last W seconds
    doubts: int = 0                  # how often a conviction was dropped in this approach

    def update(self, rel_prev, rel, t: float, urgent: bool) -> bool:
        """Take the motion from ``rel_prev`` to ``rel`` (at t); ``urgent``: o has the lowest
        V_S of the robot's obstacles at t. Returns convinced."""
        p = self.params
        psi = heading_off_line_of_sight(rel_prev)
        a = math.copysign(1.0, psi) * _wrap(float(rel[2]) - float(rel_prev[2]))
        self.recent.append((float(t), a))
        while self.recent and self.recent[0][0] <= t - p.doubt_window:
            self.recent.popleft()
        if urgent and abs(psi) < 0.5 * math.pi and a > 0.0:
            self.turned_away += a
        if self.turned_away >= p.convince_angle:
            self.convinced = True
        if self.convinced and sum(v for _, v in self.recent) <= 0.0 \
                and time_to_disc(rel, p.radius, p.speed) <= p.doubt_horizon:
            self.convinced = False
            self.turned_away = 0.0
            self.doubts += 1
        return self.convinced
