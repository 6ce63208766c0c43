"""What a decision sends and says: the commands of every robot, the state they leave in
their filters (overriding, the command remembered as sent), and each robot's
``FilterOutput`` with the reason, built only when read (``Decisions``: formatting a
thousand reasons costs more than deciding them, and most are never read).
"""
from __future__ import annotations

from collections.abc import Sequence
import math

import numpy as np

from . import approach
from .law import KINDS, decide_rows
from .types import FAIL_SAFE, OVERRIDE, PASS, FilterOutput


_ACTIONS = np.array([PASS, OVERRIDE, FAIL_SAFE], dtype=object)     # by code: 0 pass, 1 override, 2 fail safe


class Decisions(Sequence):
    """What ``decide.step_many`` decided, one entry per robot filter, in order.

    ``omega``, ``linear`` and ``action`` are lists: the commands to send, all a batched caller
    needs every tick. ``decisions[i]`` is robot i's ``FilterOutput`` with its reason, built on
    first access from values fixed at the decision (formatting a thousand reasons costs more
    than deciding them, and most are never read).
    """

    __slots__ = ('omega', 'linear', 'action', '_describe', '_built')

    def __init__(self, omega, linear, action, describe):
        self.omega, self.linear, self.action, self._describe = omega, linear, action, describe
        self._built = [None] * len(action)

    def __len__(self):
        return len(self._built)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        got = self._built[i]
        if got is None:
            got = self._built[i] = self._describe(range(len(self))[i])
        return got

    def __repr__(self):
        return f'Decisions({list(self)!r})'


def outputs(filters, rb, safe_set, t, tab, n_groups, solving, states=None, dets=None) -> Decisions:
    """Every robot's command (as lists), its filter's state (overriding, the command
    remembered as sent, with the speed the robot drives under it: the linear.x sent, a
    constant-speed robot's speed), and a builder of its FilterOutput: the law
    (``law.decide_rows``) over the table's rows, spread back to all robots (a robot with no
    recent valid state stops: a zero twist, or a constant-speed robot's stop-turn)."""
    n, use = len(filters), rb.use
    m = len(use)
    omega, linear, code, over, named, kind = decide_rows(
        tab, m, n_groups, rb.overriding, rb.margin, rb.failing, rb.fresh, rb.planned, rb.bang, rb.drive, rb.held,
        rb.constant)
    # time_before_collision: the speed cut so that the command's path enters no disc (filter.approach)
    limits = approach.limit(rb, states, dets, omega, linear, code) if states is not None else None
    if limits is not None:
        omega, linear = limits.omega, limits.linear
    moved = np.where(rb.constant, rb.speed, linear)
    if m < n:       # spread to every robot (rows of ``use`` in place; no recent valid state: stop)
        rows = np.full(n, -1, dtype=np.intp)
        rows[use] = np.arange(m)
        all_speed = np.fromiter((c.speed for c in rb.all_configs), dtype=float, count=n)
        spread = (np.where(rb.all_constant, rb.all_bang, 0.0), np.zeros(n), np.full(n, 2), np.zeros(n, bool),
                  np.where(rb.all_constant, all_speed, 0.0))
        for full, part in zip(spread, (omega, linear, code, over, moved)):
            full[use] = part
        omega, linear, code, over, moved = spread
        rows = rows.tolist()
    else:
        rows = range(n)
    omega, linear, over = omega.tolist(), linear.tolist(), over.tolist()
    action = _ACTIONS[code].tolist()
    record_all(filters, omega, over, t, rb.all_keep, moved.tolist())
    problems, configs = rb.problems, rb.all_configs      # configs as at the decision (a parameter change
    common = set_fields(safe_set)                        # replaces a robot's)
    fresh, kind, named, ages, horizon = rb.fresh.tolist(), kind.tolist(), named.tolist(), rb.age, rb.horizon

    def describe(i) -> FilterOutput:
        row = rows[i]
        if row < 0:
            out = explain(problems[i], configs[i], omega[i], linear[i], action[i], common, None, -1, 0, False,
                          0.0, 0.0, 0, True)
        else:
            out = explain(problems[i], configs[i], omega[i], linear[i], action[i], common, tab, named[row],
                          kind[row], fresh[row], float(horizon[row]), float(ages[row]), int(solving[row]), False)
        # the inputs' notes as when read (the nodes read them before new inputs come)
        f = filters[i]
        out.detections_dropped, out.detections_note = f.detections.dropped, f.detections.note
        if row >= 0 and fresh[row]:      # what of the planner's command was beyond the robot's limits
            out.cmd_clipped = f.command.note
        if limits is not None and row >= 0:
            out.reason += limits.note(row)
        return out

    return Decisions(omega, linear, action, describe)


def record_all(filters, omega, over, t, keep, moved) -> None:
    """Each robot's ``overriding = over[i]`` and ``record_sent(omega[i], t, moved[i])``, in one
    loop (a fleet's tick: the method's call and its configuration lookups cost more than its
    work); ``keep``: each robot's ``config.sent_kept``."""
    ts = float(t)
    for f, w, o, cut, v in zip(filters, omega, over, (t - keep).tolist(), moved):
        f.overriding = o  # failing safe clears it: re-enter by the law once inputs are back
        sent = f.sent
        sent.append((ts, w, v))
        while len(sent) > 1 and sent[1][0] <= cut:
            sent.popleft()


def set_fields(safe_set) -> dict:
    """The FilterOutput fields every robot's decision takes from the safe set in force."""
    set_omega = safe_set.omega_max
    return dict(alpha=float(safe_set.alpha), source=safe_set.source,
                omega_max_set=float(set_omega) if set_omega is not None else math.nan)


def explain(problem, cfg, w, v, a, set_fields, tab, k, kind, fresh, horizon, age, solving, lost) -> FilterOutput:
    """One robot's FilterOutput: its command (w, v, a) and why, from the table row ``k`` that it
    names (-1: none) and how it acted on it (``kind``, see ``law.govern``); ``lost``: no recent
    valid state (the fail-safe command)."""
    common = dict(set_fields, pose_age=age, lookahead=horizon, clusters_solving=solving)
    if k < 0:
        common.update(obstacle_index=-1, obstacle_xy=(math.nan, math.nan), value=math.inf)
        value = level = math.nan
    else:
        value, level = float(tab.value[k]), float(tab.level[k])
        members, obstacle = int(tab.members[k]), int(tab.obstacle[k])
        common.update(obstacle_index=obstacle, obstacle_xy=tuple(float(c) for c in tab.xy[k]), value=value,
                      alpha=level)
        source = 'cluster-fallback' if tab.fallback[k] else 'cluster'     # a cluster row's
        if tab.sound[k]:
            common['source'] = source
        label = (f'a cluster of {members} obstacles ({source}, nearest {obstacle})' if members > 1
                 else f'obstacle {obstacle}')
    if problem:
        stop = 'stop-turn' if cfg.constant_speed else 'stop (zero twist)'
        if k >= 0 and (cfg.constant_speed or kind > 0):     # (law.decide_rows: which fail safe avoids)
            why = f'{problem}; avoiding {label} from the last valid state (V={value:.3g}) at {v:g} m/s'
        elif k >= 0:
            why = f'{problem}; clear of {label} at the last valid state (V={value:.3g} > alpha={level:.3g}): {stop}'
        else:
            why = f'{problem}; {"no recent valid state" if lost else "no obstacle near the last valid state"}' \
                  f': {stop}'
    elif a == OVERRIDE:
        how = KINDS[kind]
        if how == 'enter':
            why = f'V={value:.3g} <= alpha={level:.3g} at {label}'
        elif how == 'ahead':
            why = (f'the planner\'s command would reach V={float(tab.value_next[k]):.3g} <= alpha={level:.3g} '
                   f'within {horizon:.3g} s ({label})')
        else:
            why = f'V={value:.3g} <= alpha+margin={level + cfg.clear_margin:.3g}: not clear yet'
        if not cfg.constant_speed and tab.fallback[k]:
            why += '; turning in place (the loiter circle is drawn at full speed)'
    elif not fresh:
        # Nav2 style: no input, zero twist (a constant-speed Dubins robot drives straight on; the
        # filter still guards it against every detected obstacle)
        why = 'clear; planner silent: zero command'
    else:
        # the robot's bound, whatever the planner asked (angular.z = 1e30 goes out as w_max)
        why = 'clear: no obstacle near' if k < 0 else f'clear: V={value:.3g} > alpha={level:.3g}'
    return FilterOutput(w, v, a, why, **common)
