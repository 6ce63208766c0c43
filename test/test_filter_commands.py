"""The planner's command read as the filter reads it: each formula's column form (a fleet's,
``commands.planned_turns``, ``planned_speeds``, ``drive_speeds``) gives the bits of its scalar form
(a lone robot's ``planned_turn``, ``planned_speed``, ``drive_speed``) on every robot, ties and
signed zeros included."""
import itertools
import math

import numpy as np

from supersafe_ros.filter import FilterConfig, RobotFilter
from supersafe_ros.filter.commands import (command_fresh, drive_speed, drive_speeds, held_speed, planned_speed,
                                           planned_speeds, planned_turn, planned_turns)
from supersafe_ros.filter.sent import record_sent

TURNS = [0.0, -0.0, 0.3, -0.3, 1.0, -1.0, 1.7, -2.5, 1e-12]
LINEARS = [None, 0.0, -0.0, 0.2, 0.5, 0.7, -0.4, 3.0]


def robots():
    """Robots over every mix of turn, linear.x, fresh or silent, constant speed or not, something
    sent or not, with the (fresh, failing) each is judged with."""
    out = []
    for turn, linear, silent, constant, sent, failing in itertools.product(
            TURNS, LINEARS, (False, True), (False, True), (False, True), (False, True)):
        f = RobotFilter(FilterConfig(speed=0.5, omega_max=1.0, cmd_timeout=0.5,
                                     fail_safe_command='stop_turn' if constant else 'stop'))
        f.update_command(turn, 0.0, linear)
        if sent:
            record_sent(f, 0.2, 0.1, speed=0.35)
        t = 1.0 if silent else 0.2
        out.append((f, t, command_fresh(f, t), failing))
    return out


def same_bits(a, b):
    return np.array_equal(np.asarray(a, float).view(np.uint64), np.asarray(b, float).view(np.uint64))


def test_the_column_forms_give_the_scalar_forms_bits():
    cases = robots()
    fs = [c[0] for c in cases]
    fresh = np.array([c[2] for c in cases])
    failing = np.array([c[3] for c in cases])
    speed = np.array([f.config.speed for f in fs])
    bound = np.array([f.config.omega_max for f in fs])
    constant = np.array([f.config.constant_speed for f in fs])
    value = np.array([f.command.value for f in fs])
    linear = np.array([math.inf if f.command.linear is None else f.command.linear for f in fs])
    held = np.array([held_speed(f) for f in fs])

    assert same_bits(planned_turns(value, fresh, bound), [planned_turn(f, t) for f, t, _, _ in cases])
    can_stop = ~constant
    assert same_bits(planned_speeds(linear, speed)[can_stop],
                     [planned_speed(f.command.linear, f.config) for f in fs if not f.config.constant_speed])
    planned_v = planned_speeds(linear, speed)
    assert same_bits(drive_speeds(constant, speed, failing, held, fresh, planned_v),
                     [drive_speed(f, fr, fail) for f, _, fr, fail in cases])
    # (the cases reach every branch: silent, failing, constant, reverse, beyond the bounds)
    assert fresh.any() and (~fresh).any() and failing.any() and constant.any() and (value > bound).any()
