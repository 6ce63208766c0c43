"""Step 1 of a decision: every robot's inputs read once, into columns (``RobotColumns``).

``gather(filters, t)`` says which robots can be judged now (``problem``: fresh, valid pose and
detections), which fail safe but still have a state young enough to avoid from
(``hold_timeout``), and for those (the rows the law sees) their state now (the pose
propagated along the arcs held since its stamp, ``filter.propagation``), the planner's command
clipped to the robot's bound (0 if silent), the lookahead (at least the control period) and
the configuration fields the law needs, as numpy columns: the column forms of the per-robot
formulas, each written beside its scalar one (``commands.planned_turns``, ``planned_speeds``,
``drive_speeds``; ``propagation.plan_columns``), so the same values bit for bit.

``gather_one_fast`` is ``gather`` for a lone robot with a state to judge, in Python floats
(numpy's cost per call would be most of a robot's own filter's decision).
"""
from __future__ import annotations

import itertools
import math
from operator import attrgetter, is_, is_not

import numpy as np

from .commands import command_fresh, drive_speed, drive_speeds, held_speed, planned_speeds, planned_turn, planned_turns
from .elementwise import py_max
from .propagation import arc, follow, plan, plan_columns, wrap


class RobotColumns:
    """The inputs of a fleet's robots as columns (``gather``): for all N robots, their
    configurations, problems ('' if judged), turn bound and history kept; for the M robots
    whose (last valid) state enters the law (``use``, their rows), everything the law needs:
    ``states`` (M, 3) their states now; ``lone`` the one robot's (x, y, theta) in Python floats
    when ``gather_one_fast`` read it (else None)."""

    __slots__ = ('filters', 'use', 'problems', 'all_configs', 'all_bang', 'all_keep', 'all_constant', 'configs',
                 'failing', 'states', 'lone', 'age', 'dets', 'horizon', 'planned', 'speed', 'bang', 'overriding',
                 'margin', 'fresh', 'cluster_alpha', 'radii', 'drive', 'held', 'constant', 'views', 'map_values')


_VALUE, _T, _STAMP, _REJECTED, _RADII, _LINEAR, _VIEW = (attrgetter(a) for a in (
    'value', 't', 'stamp', 'rejected', 'radii', 'linear', 'view'))


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
    cols = RobotColumns()
    n = len(filters)
    configs = [f.config for f in filters]
    (pose_timeout, det_timeout, hold, bang_all, compensate, cmd_timeout, look, period, speed, margin,
     cluster_alpha, cols.all_keep, constant_all) = _config_columns(configs, (
        'pose_timeout', 'detections_timeout', 'hold_timeout', 'omega_max', 'compensate_delay', 'cmd_timeout',
        'lookahead', 'control_period', 'speed', 'clear_margin', 'cluster_alpha', 'sent_kept', 'constant_speed'))
    cols.all_constant = constant_all != 0.0
    cols.all_configs, cols.all_bang = configs, bang_all
    poses, dets = [f.pose for f in filters], [f.detections for f in filters]
    pose_t = np.fromiter(map(_T, poses), dtype=float, count=n)
    det_t = np.fromiter(map(_T, dets), dtype=float, count=n)
    pose_values, det_values = list(map(_VALUE, poses)), list(map(_VALUE, dets))
    has = (np.fromiter(map(is_not, pose_values, itertools.repeat(None)), dtype=bool, count=n)
           & np.fromiter(map(is_not, det_values, itertools.repeat(None)), dtype=bool, count=n))
    clean = np.ones(n, bool)
    for inputs in (poses, dets):
        if any(map(_REJECTED, inputs)):
            clean &= ~np.fromiter(map(bool, map(_REJECTED, inputs)), dtype=bool, count=n)
    commands = [f.command for f in filters]
    if any(map(_REJECTED, commands)):       # a robot that can stop stops on a refused command
        clean &= ~(np.fromiter(map(bool, map(_REJECTED, commands)), dtype=bool, count=n) & ~cols.all_constant)
    views = list(map(_VIEW, filters))
    values = None
    if any(map(is_not, views, itertools.repeat(None))):     # robots judged by their maps' values
        values = [None if v is None else v.value() for v in views]
        pending = (v is not None and mv is None and v.local_map.holds_any() for v, mv in zip(views, values))
        clean &= ~np.fromiter(pending, dtype=bool, count=n)
    judged = has & clean & ~(t - pose_t > pose_timeout) & ~(t - det_t > det_timeout)
    cols.problems = [''] * n
    for i in np.flatnonzero(~judged).tolist():
        cols.problems[i] = problem(filters[i], t)[0]
    use = np.flatnonzero(judged | (has & (t - pose_t <= hold) & (t - det_t <= hold)))
    cols.use, m = use, len(use)
    if m < n:
        filters, configs, poses, pose_values, det_values = (
            [x[i] for i in use.tolist()] for x in (filters, configs, poses, pose_values, det_values))
        pose_t = pose_t[use]
        (hold, compensate, cmd_timeout, look, period, speed, bang, margin, cluster_alpha, constant) = (
            c[use] for c in (hold, compensate, cmd_timeout, look, period, speed, bang_all, margin, cluster_alpha,
                             cols.all_constant))
    else:
        bang, constant = bang_all, cols.all_constant
    cols.filters, cols.configs, cols.failing = filters, configs, ~judged[use]
    cols.views = None if values is None else [views[i] for i in use.tolist()]
    cols.map_values = None if values is None else [values[i] for i in use.tolist()]
    cols.speed, cols.bang, cols.margin, cols.cluster_alpha = speed, bang, margin, cluster_alpha
    cols.dets = det_values
    cols.radii = list(map(_RADII, dets)) if m == n else [d.radii for d in map(attrgetter('detections'), filters)]
    poses_now = np.array(pose_values, dtype=float).reshape(m, 3)
    cols.overriding = np.fromiter((f.overriding for f in filters), dtype=bool, count=m)
    compensate = compensate != 0.0

    # propagation.plan: the pose's age, and the arcs held since its stamp
    stamp = np.fromiter(map(_STAMP, poses), dtype=float, count=m)
    cols.age, last, omegas, dts, speeds = plan_columns(filters, t, pose_t, stamp, compensate, hold)
    cols.states, cols.lone = follow(poses_now, omegas, dts, speeds), None

    # command_fresh, planned_turn (clipped as clip) and the lookahead
    commands = [f.command for f in filters]
    value = list(map(_VALUE, commands))
    cols.fresh = fresh = (np.fromiter(map(is_not, value, itertools.repeat(None)), dtype=bool, count=m)
                          & (t - np.fromiter(map(_T, commands), dtype=float, count=m) <= cmd_timeout))
    value = np.array([0.0 if v is None else v for v in value] if None in value else value, dtype=float)
    cols.planned = planned_turns(value, fresh, bang)
    # the speeds: the planner's clipped to [0, speed] (planned_speed), driven (drive_speed), last sent
    # (a robot with nothing sent shows _NEVER's speed, 0; linear.x not given: the speed)
    linear = list(map(_LINEAR, commands))
    if linear.count(None) == m:
        planned_v = speed
    else:
        linear = np.array([math.inf if v is None else v for v in linear] if None in linear else linear, dtype=float)
        planned_v = planned_speeds(linear, speed)
    cols.constant, cols.held = constant, np.where(constant, speed, last[:, 2])
    cols.drive = drive_speeds(constant, speed, cols.failing, cols.held, fresh, planned_v)
    # measured period: the larger median of the pose and command intervals (each > 0; none: 0)
    windows = ([f.pose_intervals for f in filters], [f.command_intervals for f in filters])
    measured = py_max(*(np.array([0.0 if w.middle is None else w.middle for w in ws], dtype=float)
                        for ws in windows))
    period = np.where(period > 0.0, period, measured)
    cols.horizon = np.where(compensate, py_max(look, period), look)
    return cols


_ONE = np.zeros(1, np.intp)
_ONE.flags.writeable = False


def gather_one_fast(f, t):
    """``gather`` of one robot, in Python floats (numpy's cost per call would be most of a lone
    robot's decision), its state now propagated as ``propagation.follow`` does (the same
    bits); None if its state does not enter the law (then ``gather`` gives its fail safe).
    Kept for: 7-10 us against 102-115 us for ``gather([f])`` (12-14x; timeit, 2026-12-04, the
    2-core development machine); the filter tests that take the ``decision_path`` fixture
    (test/conftest.py) run each case alone and beside an idle robot: both paths."""
    why, usable = problem(f, t)
    if not usable:
        return None
    cfg = f.config
    cols = RobotColumns()
    age, arcs = plan(f, t)
    x, y, th = f.pose.value.tolist()
    for omega, dt, v in arcs:
        x, y, th = arc(x, y, th, v, omega, dt)
    if not arcs:
        th = wrap(th)
    fresh = command_fresh(f, t)
    # the one row's float columns, made in one call (views of one array)
    (cols.bang, cols.all_keep, cols.speed, cols.margin, cols.cluster_alpha, cols.age, cols.horizon, cols.planned,
     cols.drive, cols.held) = np.array(
        [[cfg.omega_max], [cfg.sent_kept], [cfg.speed], [cfg.clear_margin], [cfg.cluster_alpha], [age],
         [f.lookahead()], [planned_turn(f, t, fresh)], [drive_speed(f, fresh, bool(why))], [held_speed(f)]],
        dtype=float)
    cols.all_bang = cols.bang
    cols.failing, cols.overriding, cols.fresh, cols.constant = np.array(
        [[bool(why)], [f.overriding], [fresh], [cfg.constant_speed]])
    cols.all_constant = cols.constant
    cols.filters, cols.use, cols.problems, cols.configs, cols.all_configs = [f], _ONE, [why], [cfg], [cfg]
    cols.radii, cols.dets = [f.detections.radii], [f.detections.value]
    view = f.view
    cols.views, cols.map_values = (None, None) if view is None else ([view], [view.value()])
    cols.lone = (x, y, th)
    cols.states = np.array([cols.lone])
    return cols
