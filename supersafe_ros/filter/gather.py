"""Step 1 of a decision: every robot's inputs read once, into columns (``RobotColumns``).

``gather(filters, t)`` says which robots can be judged now (``problem``: fresh, valid pose and
detections), which fail safe but still have a state young enough to avoid from
(``hold_timeout``), and for those (the rows the law sees) their state now (the pose
propagated along the arcs held since its stamp, ``filter.propagation``), the planner's command
clipped to the robot's bound (0 if silent), the lookahead (at least the control period) and
the configuration fields the law needs, as numpy columns: the column forms of the per-robot
formulas, each written beside its scalar one (``commands.planned_turns``, ``planned_speeds``,
``drive_speeds``; ``propagation.plan_columns``), so the same values bit for bit.

Everything the rest of the decision reads is in the columns (``decide.decide`` is a function of
them): no later step reads a ``RobotFilter``.

``gather_one_fast`` is ``gather`` for a lone robot with a state to judge, in Python floats
(numpy's cost per call would be most of a robot's own filter's decision).
"""
from __future__ import annotations

import itertools
import math
from operator import attrgetter, is_, is_not
from typing import NamedTuple

import numpy as np

from .commands import command_fresh, drive_speed, drive_speeds, held_speed, planned_speeds, planned_turn, planned_turns
from .elementwise import py_max
from .propagation import NEVER_SENT, arc, follow, plan, plan_columns, wrap


class RobotColumns(NamedTuple):
    """A fleet's inputs at one decision, as columns (``gather``): what every robot of the N
    filters gets (``all_*``, its problem, its inputs' notes), and for the M robots whose (last
    valid) state enters the law, the rows, everything the law needs. Per-row arrays are (M,)
    unless said. A NamedTuple, as every record of a decision: typed and immutable as a frozen
    dataclass, and built in 1.7 us where a frozen dataclass takes 4.6 (its ``__init__`` sets each
    field through ``object.__setattr__``: a lone robot's decision builds eight such records).
    What a step reads of a few robots' inputs (a run's ``solve_clusters``, ``kept`` where discs were
    split or dropped) or an explanation reads when built (the inputs' notes) stays in the inputs'
    records, read there: a column of them for every robot each tick would cost a fleet of robots
    with detections of their own more than the rest (6 % of bench_core.py's dense-1000)."""

    t: float                        # the decision's time
    # -- every robot (N, in the filters' order)
    problems: list                  # why it cannot be judged now ('' if it can)
    all_configs: list               # its configuration, as at the decision
    all_omega_max: np.ndarray       # its turn bound w_max
    all_sent_kept: np.ndarray       # how long its commands sent are remembered (FilterConfig.sent_kept)
    all_constant_speed: np.ndarray  # bool: a constant-speed robot (its fail safe the stop-turn)
    all_detection_inputs: list      # its detections' input record (inputs._Input): its message's notes
    # -- the rows: the robots whose (last valid) state enters the law
    robot_index: np.ndarray         # each row's robot: its index in the filters
    configs: list                   # its configuration
    failing: np.ndarray             # bool: inputs stale or invalid, judged from its last valid state
    states: np.ndarray              # (M, 3): its state now (the pose propagated to t)
    lone_state: tuple | None        # the one robot's (x, y, theta) in Python floats (gather_one_fast), else None
    pose_age: np.ndarray            # how long its pose was propagated over
    last_sent: np.ndarray           # (M, 3): the last command sent (time, turn, speed; propagation.NEVER_SENT)
    detections: list                # its detected discs' centres (K_i, 2)
    detection_radii: list           # their radii (K_i,), None: all its configuration's radius
    detection_inputs: list          # their input record: ``kept`` (their rows in the message, None: row i
    #                                 is row i; filter.constraints.discs), ``solve_clusters`` (whether their clusters'
    #                                 union values may be solved), ``derived`` (what earlier decisions
    #                                 derived from them: filter.derived; read, never written here)
    lookahead: np.ndarray           # the hold H the planner's command is judged over (>= the control period)
    command_fresh: np.ndarray       # bool: the planner's command is recent enough to forward
    command_t: np.ndarray           # when the planner's command arrived (-inf: none yet)
    command_inputs: list            # the command's input record: ``note``, what was beyond its limits
    planned_turn: np.ndarray        # the planner's turn rate clipped to +-w_max, 0 if silent
    max_speed: np.ndarray           # the configuration's speed
    omega_max: np.ndarray           # the turn bound w_max
    overriding: np.ndarray          # bool: the filter overrode at the last decision sent
    clear_margin: np.ndarray        # the hysteresis margin
    cluster_alpha: np.ndarray       # the level of cluster rows (union values)
    drive_speed: np.ndarray         # the speed of the command judged (commands.drive_speed)
    held_speed: np.ndarray          # the speed last sent (a constant-speed robot's speed)
    constant_speed: np.ndarray      # bool: a constant-speed robot
    map_views: list | None          # a robot judged by its local map: its MapView (else None); None: no such robot
    map_values: list | None         # its map's solved value as gathered (None: none yet)


_VALUE, _T, _STAMP, _REJECTED, _RADII, _LINEAR, _VIEW = (
    attrgetter(a) for a in ('value', 't', 'stamp', 'rejected', 'radii', 'linear', 'view'))
_DETECTIONS, _COMMAND, _POSE = attrgetter('detections'), attrgetter('command'), attrgetter('pose')
_OVERRIDING, _POSE_WINDOW, _COMMAND_WINDOW = attrgetter('overriding'), attrgetter('pose_intervals'), \
    attrgetter('command_intervals')


def _given(values) -> np.ndarray:
    """Per value, whether it is not None (bool array)."""
    if not any(map(is_, values, itertools.repeat(None))):      # (most ticks: found in C)
        return np.ones(len(values), bool)
    return np.fromiter(map(is_not, values, itertools.repeat(None)), dtype=bool, count=len(values))


def _medians(windows) -> np.ndarray:
    """Per window of intervals (``inputs._Intervals``), its median, 0 if empty: one read per window
    when robots share one (fed by one message)."""
    w0 = windows[0] if windows else None
    if w0 is not None and all(map(is_, windows, itertools.repeat(w0))):
        return np.full(len(windows), 0.0 if w0.middle is None else w0.middle)
    return np.array([0.0 if w.middle is None else w.middle for w in windows], dtype=float)


def problem(f, t):
    """(why ``f`` cannot be judged now, '' if it can; whether its (last valid) state enters
    the law: judged, or failing safe with a pose and detections younger than hold_timeout).
    The one answer to both questions (``gather`` asks it of the robots its columns find not
    judged, for the words)."""
    cfg, pose, det, view = f.config, f.pose, f.detections, f.view
    refused = f.command.rejected and not cfg.constant_speed     # a robot that can stop stops on it
    unsolved = view is not None and view.value() is None and view.local_map.holds_any()
    if not (pose.rejected or det.rejected or pose.value is None or det.value is None
            or t - pose.t > cfg.pose_timeout or t - det.t > cfg.detections_timeout or refused or unsolved):
        return '', True
    why = ''
    sensor = 'detections' if view is None else view.sensor
    for label, inp, timeout in (('pose', pose, cfg.pose_timeout), (sensor, det, cfg.detections_timeout)):
        if inp.rejected:
            why = f'{label} rejected: {inp.rejected}'
        elif inp.value is None:
            why = f'no {label} received yet'
        elif t - inp.t > timeout:     # since arrival: a pose that keeps coming is not lost
            since = (f'{inp.refusals} unusable since, the latest: {inp.refused}' if inp.refusals else 'none newer')
            why = f'blind for {t - inp.t:.3g} s ({label} stale: {since}; timeout {timeout:g} s)'
        if why:
            break
    if not why:
        why = (f'planner command rejected: {f.command.rejected}' if refused else
               f'waiting for the first value of the {sensor} map (being solved)')
    return why, (pose.value is not None and det.value is not None
                 and t - pose.t <= cfg.hold_timeout and t - det.t <= cfg.hold_timeout)


def _config_columns(configs, names):
    """Per robot, the configuration fields ``names`` as float columns (robots share a few
    configurations: each field is read once per distinct one)."""
    c = configs[0] if configs else None
    if c is not None and all(map(is_, configs, itertools.repeat(c))):   # one configuration (not just equal ones:
        # 0.0 == -0.0, and a zero's sign shows in the commands)
        return [np.full(len(configs), float(getattr(c, a))) for a in names]
    distinct = {id(c): c for c in configs}
    index = {k: i for i, k in enumerate(distinct)}
    row = np.fromiter((index[id(c)] for c in configs), dtype=np.intp, count=len(configs))
    return [np.array([float(getattr(c, a)) for c in distinct.values()])[row] for a in names]


def gather(filters, t) -> RobotColumns:
    """The fleet's inputs as columns: ``problem``'s test, ``propagation.plan_columns`` and
    ``follow``, ``commands.command_fresh``, ``planned_turns``, ``planned_speeds`` and
    ``drive_speeds``, and ``RobotFilter.lookahead`` over them (the same comparisons and
    arithmetic as the per-robot forms, so the same values bit for bit)."""
    n = len(filters)
    all_configs = [f.config for f in filters]
    (pose_timeout, det_timeout, hold, omega_max_all, compensate, cmd_timeout, look, period, speed, margin,
     cluster_alpha, sent_kept_all, constant_all) = _config_columns(all_configs, (
        'pose_timeout', 'detections_timeout', 'hold_timeout', 'omega_max', 'compensate_delay', 'cmd_timeout',
        'lookahead', 'control_period', 'speed', 'clear_margin', 'cluster_alpha', 'sent_kept', 'constant_speed'))
    constant_all = constant_all != 0.0
    poses, dets = list(map(_POSE, filters)), list(map(_DETECTIONS, filters))
    commands = list(map(_COMMAND, filters))
    pose_t = np.fromiter(map(_T, poses), dtype=float, count=n)
    det_t = np.fromiter(map(_T, dets), dtype=float, count=n)
    pose_values, det_values = list(map(_VALUE, poses)), list(map(_VALUE, dets))
    has = _given(pose_values) & _given(det_values)
    clean = np.ones(n, bool)
    for inputs in (poses, dets):
        if any(map(_REJECTED, inputs)):
            clean &= ~np.fromiter(map(bool, map(_REJECTED, inputs)), dtype=bool, count=n)
    if any(map(_REJECTED, commands)):       # a robot that can stop stops on a refused command
        clean &= ~(np.fromiter(map(bool, map(_REJECTED, commands)), dtype=bool, count=n) & ~constant_all)
    views = list(map(_VIEW, filters))
    values = None
    if any(map(is_not, views, itertools.repeat(None))):     # robots judged by their maps' values
        values = [None if v is None else v.value() for v in views]
        pending = (v is not None and mv is None and v.local_map.holds_any() for v, mv in zip(views, values))
        clean &= ~np.fromiter(pending, dtype=bool, count=n)
    judged = has & clean & ~(t - pose_t > pose_timeout) & ~(t - det_t > det_timeout)
    problems = [''] * n
    for i in np.flatnonzero(~judged).tolist():
        problems[i] = problem(filters[i], t)[0]
    use = np.flatnonzero(judged | (has & (t - pose_t <= hold) & (t - det_t <= hold)))
    m = len(use)
    row_dets = dets
    if m < n:
        rows = use.tolist()
        filters, configs, poses, pose_values, det_values, row_dets, commands = (
            [x[i] for i in rows] for x in (filters, all_configs, poses, pose_values, det_values, dets, commands))
        pose_t = pose_t[use]
        (hold, compensate, cmd_timeout, look, period, speed, omega_max, margin, cluster_alpha, constant) = (
            c[use] for c in (hold, compensate, cmd_timeout, look, period, speed, omega_max_all, margin, cluster_alpha,
                             constant_all))
    else:
        configs, omega_max, constant = all_configs, omega_max_all, constant_all
    poses_now = np.concatenate(pose_values).reshape(m, 3) if m else np.zeros((0, 3))
    overriding = np.fromiter(map(_OVERRIDING, filters), dtype=bool, count=m)
    compensate = compensate != 0.0

    # propagation.plan: the pose's age, and the arcs held since its stamp
    stamp = np.fromiter(map(_STAMP, poses), dtype=float, count=m)
    age, last, omegas, dts, speeds = plan_columns(filters, t, pose_t, stamp, compensate, hold)
    states = follow(poses_now, omegas, dts, speeds)

    # command_fresh, planned_turn (clipped as clip) and the lookahead
    value = list(map(_VALUE, commands))
    command_t = np.fromiter(map(_T, commands), dtype=float, count=m)
    fresh = _given(value) & (t - command_t <= cmd_timeout)
    value = np.array([0.0 if v is None else v for v in value] if None in value else value, dtype=float)
    planned = planned_turns(value, fresh, omega_max)
    # the speeds: the planner's clipped to [0, speed] (planned_speed), driven (drive_speed), last sent
    # (a robot with nothing sent shows NEVER_SENT's speed, 0; linear.x not given: the speed)
    linear = list(map(_LINEAR, commands))
    if linear.count(None) == m:
        planned_v = speed
    else:
        linear = np.array([math.inf if v is None else v for v in linear] if None in linear else linear, dtype=float)
        planned_v = planned_speeds(linear, speed)
    failing = ~judged[use]
    held = np.where(constant, speed, last[:, 2])
    # measured period: the larger median of the pose and command intervals (each > 0; none: 0)
    measured = py_max(_medians(list(map(_POSE_WINDOW, filters))), _medians(list(map(_COMMAND_WINDOW, filters))))
    period = np.where(period > 0.0, period, measured)
    return RobotColumns(
        t=t, problems=problems, all_configs=all_configs, all_omega_max=omega_max_all, all_sent_kept=sent_kept_all,
        all_constant_speed=constant_all, all_detection_inputs=dets,
        robot_index=use, configs=configs, failing=failing, states=states, lone_state=None, pose_age=age,
        last_sent=last, detections=det_values, detection_radii=list(map(_RADII, row_dets)),
        detection_inputs=row_dets,
        lookahead=np.where(compensate, py_max(look, period), look),
        command_fresh=fresh, command_t=command_t, command_inputs=commands, planned_turn=planned,
        max_speed=speed, omega_max=omega_max, overriding=overriding, clear_margin=margin, cluster_alpha=cluster_alpha,
        drive_speed=drive_speeds(constant, speed, failing, held, fresh, planned_v), held_speed=held,
        constant_speed=constant, map_views=None if values is None else [views[i] for i in use.tolist()],
        map_values=None if values is None else [values[i] for i in use.tolist()])


_ONE = np.zeros(1, np.intp)
_ONE.flags.writeable = False


def gather_one_fast(f, t):
    """``gather`` of one robot, in Python floats (numpy's cost per call would be most of a lone
    robot's decision), its state now propagated as ``propagation.follow`` does (the same
    bits); None if its state does not enter the law (then ``gather`` gives its fail safe).
    Kept for: 10 us against 134-138 us for ``gather([f])`` (13x; timeit, 2026-12-06, the
    2-core development machine, load 2.2);
    test_filter_vectorised compares both paths' columns, field by field, and the filter tests
    that take the ``decision_path`` fixture (test/conftest.py) run each case alone and beside an
    idle robot: both paths."""
    why, usable = problem(f, t)
    if not usable:
        return None
    cfg, det, command = f.config, f.detections, f.command
    age, arcs = plan(f, t)
    x, y, th = f.pose.value.tolist()
    for omega, dt, v in arcs:
        x, y, th = arc(x, y, th, v, omega, dt)
    if not arcs:
        th = wrap(th)
    fresh = command_fresh(f, t)
    last = f.sent[-1] if f.sent else NEVER_SENT
    # the one row's float columns, made in one call (views of one array; from a flat tuple: a third
    # of the cost of nested lists)
    floats = np.array(
        (cfg.omega_max, cfg.sent_kept, cfg.speed, cfg.clear_margin, cfg.cluster_alpha, age, f.lookahead(),
         planned_turn(f, t, fresh), drive_speed(f, fresh, bool(why)), held_speed(f), command.t, last[0], last[1],
         last[2]), dtype=float).reshape(14, 1)
    omega_max, sent_kept, speed, margin, cluster_alpha, age, lookahead, planned, drive, held, command_t = floats[:11]
    failing, overriding, fresh, constant = np.array((bool(why), f.overriding, fresh, cfg.constant_speed)).reshape(4, 1)
    view, configs, inputs = f.view, [cfg], [det]
    # (positional, in the fields' order: half the cost of keywords; the columns are compared with
    # gather's field by field in test_filter_vectorised)
    return RobotColumns(
        t, [why], configs, omega_max, sent_kept, constant, inputs,                                  # every robot
        _ONE, configs, failing, np.array([(x, y, th)]), (x, y, th), age, floats[11:].T,          # the rows
        [det.value], [det.radii], inputs,
        lookahead, fresh, command_t, [command], planned, speed, omega_max, overriding, margin, cluster_alpha,
        drive, held, constant, None if view is None else [view], None if view is None else [view.value()])
