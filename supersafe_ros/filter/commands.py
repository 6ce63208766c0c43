"""The planner's command as the filter reads it: whether it is fresh, the turn rate and the
speed it asks within the robot's limits, and what of it is beyond them.

Every function reads one robot's inputs (``inputs.RobotFilter``) and configuration, never
writes. Beside each one a fleet needs, its column form (``planned_turns``, ``planned_speeds``,
``drive_speeds``: numpy arrays, one entry per robot, read by ``gather``), written with the same
comparisons and arithmetic so that both give the same bits (test/test_filter_commands.py runs
both). The scalar forms stay for a lone robot's decision: numpy's cost per call (a few us) would
be most of it.
"""
from __future__ import annotations

import numpy as np

from .elementwise import py_max

SPEED_TOLERANCE = 1e-9     # a linear.x this close (relatively) to the robot's speed is its speed


def clip(value, bound) -> float:
    """value clipped to +-bound (scalars; np.clip costs ~10 us a call)."""
    return max(-bound, min(bound, float(value)))


def command_fresh(f, t) -> bool:
    """Whether the planner's command is recent enough to forward."""
    return f.command.value is not None and t - f.command.t <= f.config.cmd_timeout


def planned_turn(f, t, fresh=None) -> float:
    """The command the filter would forward (a silent planner counts as 0), clipped;
    ``fresh``: ``command_fresh(f, t)`` if the caller has it."""
    if fresh is None:
        fresh = command_fresh(f, t)
    return clip(f.command.value, f.config.omega_max) if fresh else 0.0


def planned_turns(value, fresh, bound) -> np.ndarray:
    """``planned_turn`` over columns: each robot's command ``value`` clipped to +-``bound`` where
    ``fresh``, else 0."""
    clipped = np.where(value < bound, value, bound)
    clipped = np.where(clipped > -bound, clipped, -bound)
    return np.where(fresh, clipped, 0.0)


def planned_speed(linear, cfg) -> float:
    """The speed the filter passes for a planner's ``linear``.x: clipped to [0, speed] (a reverse
    command is sent as 0: the value functions model forward motion only); None (not given) or
    a constant-speed robot (``FilterConfig.constant_speed``): the speed."""
    speed = cfg.speed
    if linear is None or cfg.constant_speed:
        return speed
    return max(0.0, min(speed, linear))


def planned_speeds(linear, speed):
    """``planned_speed`` over columns for robots that can stop: ``linear`` (inf where not given)
    clipped to [0, ``speed``]."""
    return py_max(0.0, np.minimum(speed, linear))      # (min(speed, v): equal only when equal)


def idle_speed(cfg) -> float:
    """The speed of a robot never commanded: 0, or a constant-speed robot's speed."""
    return cfg.speed if cfg.constant_speed else 0.0


def held_speed(f) -> float:
    """The speed the robot drives under the last command sent (``idle_speed`` if none; a
    constant-speed robot's speed)."""
    cfg = f.config
    if cfg.constant_speed:
        return cfg.speed
    return f.sent[-1][2] if f.sent else 0.0


def drive_speed(f, fresh, failing) -> float:
    """The speed the robot drives at while the command judged holds: a constant-speed robot's
    speed; failing safe, the speed last sent (``held_speed``); else the planner's (``planned_speed``),
    0 if the planner is silent (a zero twist)."""
    cfg = f.config
    if cfg.constant_speed:
        return cfg.speed
    if failing:
        return held_speed(f)
    return planned_speed(f.command.linear, cfg) if fresh else 0.0


def drive_speeds(constant, speed, failing, held, fresh, planned) -> np.ndarray:
    """``drive_speed`` over columns: ``speed`` for a constant-speed robot, else ``held`` (the speed
    last sent) failing safe, else the ``planned`` speed where ``fresh``, 0 where the planner is silent."""
    return np.where(constant, speed, np.where(failing, held, np.where(fresh, planned, 0.0)))


def command_excess(omega, linear, cfg) -> str:
    """What of a planner command (turn rate ``omega``, ``linear``.x or None) is beyond the
    robot's limits ('' if nothing): a turn rate beyond +-omega_max (the decision clips it); a
    linear.x beyond ``speed`` (clipped to it) or below 0 (a reverse command: sent as 0, the
    value functions model forward motion only); for a constant-speed robot
    (``constant_speed``, the study's Dubins robot) a linear.x that is not its speed (it
    drives at its speed whatever the planner asks)."""
    bound, speed = cfg.omega_max, cfg.speed
    parts = []
    if omega > bound or omega < -bound:
        parts.append(f'angular.z={omega:.6g} beyond w_max={bound:g}: clipped to {clip(omega, bound):g}')
    if linear is None:
        pass
    elif cfg.constant_speed:
        if not abs(linear - speed) <= SPEED_TOLERANCE * max(1.0, speed):
            parts.append(f'linear.x={linear:.6g} is not the robot\'s speed {speed:g}: it drives at {speed:g}')
    elif linear > speed:
        parts.append(f'linear.x={linear:.6g} beyond speed={speed:g}: clipped to {speed:g}')
    elif linear < 0.0:
        parts.append(f'linear.x={linear:.6g} is reverse: sent as 0 (the value functions model forward motion '
                     f'only; the robot stops, turning as asked)')
    return '; '.join(parts)
