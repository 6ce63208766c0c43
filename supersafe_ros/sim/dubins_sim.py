"""One simulated robot: exact Dubins integration, command handling and a lossy sensor.

Dynamics (the paper's eq. (dubins)):  x' = v cos(th), y' = v sin(th), th' = u,
|u| <= w_max, v fixed. A step holds the latest accepted command constant and
moves along the exact arc (``DubinsCar.flow``), so a coarse or uneven step
changes only when the command is sampled, never the path taken under it.

Commands: angular.z is clipped to +-w_max; non-finite commands are rejected and
the previous command stays in force. Fail-safe without commands:
  * before the first command the robot is *parked* (it does not move): a team
    that is still starting up does not drive blind;
  * once commands stop for longer than ``command_timeout`` the robot *loiters*,
    turning at +w_max on a circle of radius v / w_max. A fixed-speed car cannot
    stop; loitering keeps it within 2 v / w_max of where its controller went
    silent instead of driving straight across the field into unseen obstacles.
    (``timeout_behavior='straight'`` holds u = 0 instead, for experiments.)

Sim-time jumps: one step integrates at most ``max_step`` (the control period)
under the command in force. When sim time jumps further (the robot missed clock
steps, e.g. its host's link to the clock was down), the rest of the jump is a
*pause*: the robot does not move, and the age of its command does not grow
either (the robot's own clock skips the jump). Why: the filter judged each
command for at most one control period of motion (its lookahead); integrating a
whole jump under one command would move the robot unfiltered for as long as the
jump lasted (0.5-0.7 s, 1.5-2.1 m were seen after a 2 s link fault). The next
step again needs the command that answers the pose published after the jump.

Sensor: every obstacle within ``sensor_range`` of the robot is reported, except
that each (trip, obstacle) pair is missed with probability ``miss_probability``;
the draw is kept for the whole trip (a robot that missed an obstacle keeps missing
it, as in the paper's task) and made again when a new trip starts. Each draw is
keyed by (seed, trip, obstacle id), so it does not depend on when the obstacle
was first seen.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
import zlib

import numpy as np

from ..reach.dynamics import DubinsCar
from ..reach.grid import wrap_angle

TIMEOUT_BEHAVIORS = ('loiter', 'straight', 'stop')


def base_seed(seed: int | None) -> int:
    """``seed`` itself, or fresh OS entropy when None (or negative)."""
    if seed is None or seed < 0:
        return int(np.random.SeedSequence().entropy)
    return int(seed)


def keyed_rng(seed: int, *key) -> np.random.Generator:
    """A generator determined by (seed, key...) alone; strings are keyed by their CRC32.

    Draws keyed by what they are about (robot, obstacle, trip, encounter) do not
    depend on the order in which messages happen to be processed, so a run with a
    given seed does not change with the real-time factor or the machine's load.
    """
    words = [zlib.crc32(k.encode()) if isinstance(k, str) else int(k) for k in key]
    return np.random.default_rng([int(seed), *words])


@dataclass
class RobotSim:
    """State and command handling of one Dubins robot (times in seconds of sim time)."""

    state: np.ndarray
    speed: float = 3.0
    omega_max: float = 1.0
    command_timeout: float = 0.5
    timeout_behavior: str = 'loiter'
    last_command: float | None = None       # turn rate of the last accepted command
    last_command_time: float | None = None
    time: float | None = None               # sim time of ``state``
    max_step: float | None = None           # most sim time integrated per step (None: no cap)
    paused: float = 0.0                     # sim time skipped in pauses so far
    last_pause: float = 0.0                 # sim time skipped by the last advance()
    follow_speed: bool = False              # drive at the commanded linear.x (in [0, speed]), not at speed
    last_linear: float | None = None        # linear.x of the last accepted command (clipped)

    def __post_init__(self):
        self.state = np.asarray(self.state, dtype=float).reshape(3).copy()
        if not np.all(np.isfinite(self.state)):
            raise ValueError(f'initial state must be finite, got {self.state}')
        self.state[2] = wrap_angle(self.state[2])
        self.dynamics = DubinsCar(self.speed, self.omega_max)  # validates speed, omega_max
        if not (math.isfinite(self.command_timeout) and self.command_timeout > 0):
            raise ValueError(f'command_timeout must be positive, got {self.command_timeout}')
        if self.max_step is not None and not (math.isfinite(self.max_step) and self.max_step > 0):
            raise ValueError(f'max_step must be positive, got {self.max_step}')
        if self.timeout_behavior not in TIMEOUT_BEHAVIORS:
            raise ValueError(f'timeout_behavior must be one of {TIMEOUT_BEHAVIORS}, '
                             f'got {self.timeout_behavior!r}')

    def command(self, omega: float, now: float, linear: float | None = None) -> float:
        """Accept a turn-rate command (and ``linear``.x, used with ``follow_speed``, clipped to
        [0, speed]) at sim time ``now``; returns the clipped rate.

        Raises ValueError for a non-finite rate or linear.x (the previous command stays).
        """
        if not math.isfinite(omega) or (linear is not None and not math.isfinite(linear)):
            raise ValueError(f'command is not finite (angular.z {omega}, linear.x {linear})')
        clipped = float(np.clip(omega, -self.omega_max, self.omega_max))
        if linear is not None:
            self.last_linear = float(np.clip(linear, 0.0, self.speed))
        self.last_command = clipped
        self.last_command_time = float(now)
        return clipped

    def teleport(self, state) -> None:
        """Put the robot at ``state`` (a scene reset); the clock and command stay as they are."""
        state = np.asarray(state, dtype=float).reshape(3)
        if not np.all(np.isfinite(state)):
            raise ValueError(f'teleport state must be finite, got {state}')
        self.state = state.copy()
        self.state[2] = wrap_angle(self.state[2])

    def mode(self, now: float) -> str:
        """'parked' (no command yet), 'commanded', or 'timeout' (commands went stale)."""
        if self.last_command_time is None:
            return 'parked'
        if now - self.last_command_time > self.command_timeout:
            return 'timeout'
        return 'commanded'

    def control(self, now: float) -> float | None:
        """Turn rate applied at ``now``; None when parked."""
        mode = self.mode(now)
        if mode == 'parked':
            return None
        if mode == 'timeout':
            return self.omega_max if self.timeout_behavior == 'loiter' else 0.0
        return self.last_command

    def linear(self, now: float) -> float:
        """Forward speed at ``now``: ``speed``; with ``follow_speed`` the commanded linear.x while
        commanded; 0 timed out with timeout_behavior 'stop'."""
        mode = self.mode(now)
        if mode == 'timeout' and self.timeout_behavior == 'stop':
            return 0.0
        if mode != 'commanded' or not self.follow_speed or self.last_linear is None:
            return self.speed
        return self.last_linear

    def advance(self, now: float) -> np.ndarray:
        """Integrate from the last step time to ``now`` under the current control.

        The first call only sets the clock. Time going backwards (a restarted
        /clock) resets the clock without moving. At most ``max_step`` is
        integrated; the rest of a longer step is a pause (``last_pause``): no
        motion, and the command's age skips it too. Returns the new state.
        """
        now = float(now)
        self.last_pause = 0.0
        if self.time is None or now <= self.time:
            self.time = now
            return self.state
        dt = now - self.time
        u = self.control(self.time)  # the command in force during the step
        v = self.linear(self.time)
        # (a relative 1e-6 of slack: clock steps in ns do not pause on rounding)
        if self.max_step is not None and dt > self.max_step * (1.0 + 1e-6):
            self.last_pause = dt - self.max_step
            self.paused += self.last_pause
            dt = self.max_step
            if self.last_command_time is not None:
                self.last_command_time += self.last_pause
        if u is not None:
            moved = self.dynamics.flow(self.state, u, dt)
            if v != self.speed:     # the arc's displacement scales with the speed, its turn does not
                moved[:2] = self.state[:2] + (moved[:2] - self.state[:2]) * (v / self.speed)
            self.state = moved
        self.time = now
        return self.state


@dataclass
class LossySensor:
    """Range-limited obstacle sensor that misses each obstacle once per trip with prob p."""

    sensor_range: float = 10.0
    miss_probability: float = 0.2
    seed: int | None = None
    trip: int = 0
    _missed: dict = field(default_factory=dict)   # obstacle id -> bool, this trip

    def __post_init__(self):
        if not (self.sensor_range > 0 and math.isfinite(self.sensor_range)):
            raise ValueError(f'sensor_range must be positive, got {self.sensor_range}')
        if not 0.0 <= self.miss_probability <= 1.0:
            raise ValueError(f'miss_probability must be in [0, 1], got {self.miss_probability}')
        self.seed = base_seed(self.seed)

    def new_trip(self) -> None:
        """Forget this trip's draws: every obstacle gets a fresh miss draw."""
        self.trip += 1
        self._missed.clear()

    def is_missed(self, obstacle_id: int) -> bool:
        oid = int(obstacle_id)
        if oid not in self._missed:
            draw = keyed_rng(self.seed, self.trip, oid).random()
            self._missed[oid] = bool(draw < self.miss_probability)
        return self._missed[oid]

    def sense(self, position, obstacle_ids, obstacle_xy) -> tuple[np.ndarray, np.ndarray]:
        """(ids, xy) of the obstacles seen from ``position`` (obstacle centres, map frame)."""
        ids = np.asarray(obstacle_ids, dtype=int).reshape(-1)
        xy = np.asarray(obstacle_xy, dtype=float).reshape(-1, 2)
        if len(ids) != len(xy):
            raise ValueError(f'{len(ids)} obstacle ids for {len(xy)} positions')
        if len(ids) == 0:
            return ids, xy
        dist = np.hypot(xy[:, 0] - position[0], xy[:, 1] - position[1])
        in_range = dist <= self.sensor_range
        seen = np.array([r and not self.is_missed(i) for i, r in zip(ids, in_range)], dtype=bool)
        return ids[seen], xy[seen]
