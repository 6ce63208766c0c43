"""Step 4 of a decision: what it sends and says. The law's answer for the robot rows spread
to every robot (``outputs``): the commands, whether each overrides and the speed it drives
under its command (what ``sent.record`` remembers), and each robot's ``FilterOutput`` with
the reason (``explain`` of its ``Reasons``), built only when read (``Decisions``: formatting
a thousand reasons costs more than deciding them, and most are never read). Nothing here
writes into a filter.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np

from .law import KINDS
from .types import FAIL_SAFE, OVERRIDE, PASS, FilterOutput


_ACTIONS = np.array([PASS, OVERRIDE, FAIL_SAFE], dtype=object)     # by code: 0 pass, 1 override, 2 fail safe


class Decisions(Sequence):
    """What ``decide.step_many`` decided, one entry per robot filter, in order.

    ``omega``, ``linear`` and ``action`` are lists: the commands to send, all a batched caller
    needs every tick; ``overriding`` and ``driven`` (the speed each robot drives under its
    command: the linear.x sent, a constant-speed robot's speed) are what ``sent.record``
    remembers, at ``t``, each robot's commands older than ``keep`` (a column) forgotten, with
    ``derived`` (``filter.derived.Derived``: the caches the decision filled).
    ``decisions[i]`` is robot i's ``FilterOutput`` with its reason, built on
    first access from values fixed at the decision (formatting a thousand reasons costs more
    than deciding them, and most are never read).
    """

    __slots__ = ('omega', 'linear', 'action', 'overriding', 'driven', 't', 'keep', 'derived', '_describe', '_built',
                 '_solving')

    def __init__(self, omega, linear, action, overriding, driven, describe, t=0.0, keep=None, solving=None):
        self.omega, self.linear, self.action, self._describe = omega, linear, action, describe
        self._solving = solving
        self.overriding, self.driven, self.t, self.keep = overriding, driven, t, keep
        self.derived = None     # what the decision keeps for the next (filter.derived), applied when recorded
        self._built = [None] * len(action)

    def __len__(self):
        return len(self._built)

    def clusters_solving(self, i) -> int:
        """Robot i's clusters near it whose union value is being solved (its output's
        ``clusters_solving``), without building its output."""
        return 0 if self._solving is None else self._solving(i)

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        got = self._built[i]
        if got is None:
            got = self._built[i] = self._describe(range(len(self))[i])
        return got

    def __repr__(self):
        return f'Decisions({list(self)!r})'


def outputs(cols, safe_set, table, ruling, solving, limits=None) -> Decisions:
    """Every robot's command (as lists), whether it overrides, the speed the robot drives under
    it (the linear.x sent, a constant-speed robot's speed), and a builder of its FilterOutput:
    the law's answer ``ruling`` (``law.command`` over ``table``) for the rows of ``cols``
    (``gather.RobotColumns``, at its time ``cols.t``) spread back to all robots (a robot with no
    recent valid state stops: a zero twist, or a constant-speed robot's stop-turn). ``solving``: per
    robot row its clusters being solved; ``limits``: ``approach.limit``'s speeds and turns, where
    time_before_collision cut them (None: the law's stand)."""
    n, use, t = len(cols.problems), cols.robot_index, cols.t
    m = len(use)
    omega, linear, code, over, named, kind = (ruling.omega, ruling.linear, ruling.code, ruling.overrides,
                                              ruling.named, ruling.kind)
    if limits is not None:
        omega, linear = limits.omega, limits.linear
    moved = np.where(cols.constant_speed, cols.max_speed, linear)
    if m < n:       # spread to every robot (rows of ``use`` in place; no recent valid state: stop)
        rows = np.full(n, -1, dtype=np.intp)
        rows[use] = np.arange(m)
        all_speed = np.fromiter((c.speed for c in cols.all_configs), dtype=float, count=n)
        spread = (np.where(cols.all_constant_speed, cols.all_omega_max, 0.0), np.zeros(n), np.full(n, 2),
                  np.zeros(n, bool), np.where(cols.all_constant_speed, all_speed, 0.0))
        for full, part in zip(spread, (omega, linear, code, over, moved)):
            full[use] = part
        omega, linear, code, over, moved = spread
        rows = rows.tolist()
    else:
        rows = range(n)
    omega, linear, over = omega.tolist(), linear.tolist(), over.tolist()
    action = _ACTIONS[code].tolist()
    problems, configs = cols.problems, cols.all_configs      # configs as at the decision (a parameter change
    common = set_fields(safe_set)                        # replaces a robot's)
    fresh, kind, named, ages, horizon = cols.command_fresh.tolist(), kind.tolist(), named.tolist(), cols.pose_age, \
        cols.lookahead
    command_t, detections, commands = cols.command_t, cols.all_detection_inputs, cols.command_inputs

    def describe(i) -> FilterOutput:
        row = rows[i]
        if row < 0:
            out = explain(Reasons(problems[i], configs[i], omega[i], linear[i], action[i], common, lost=True))
        else:
            since = float(command_t[row])
            out = explain(Reasons(problems[i], configs[i], omega[i], linear[i], action[i], common, table, named[row],
                                  kind[row], fresh[row], float(horizon[row]), float(ages[row]), int(solving[row]),
                                  silence=t - since if since > -math.inf else math.inf,
                                  limit='' if limits is None else limits.headline(row)))
        # the inputs' notes as when read (the nodes read them before new inputs come)
        out.detections_dropped, out.detections_note = detections[i].dropped, detections[i].note
        if row >= 0 and fresh[row]:      # what of the planner's command was beyond the robot's limits
            out.cmd_clipped = commands[row].note
        return out

    def solving_of(i) -> int:
        return int(solving[rows[i]]) if rows[i] >= 0 else 0

    return Decisions(omega, linear, action, over, moved.tolist(), describe, t, cols.all_sent_kept, solving_of)


def set_fields(safe_set) -> dict:
    """The FilterOutput fields every robot's decision takes from the safe set in force."""
    set_omega = safe_set.omega_max
    return dict(alpha=float(safe_set.alpha), source=safe_set.source,
                omega_max_set=float(set_omega) if set_omega is not None else math.nan)


@dataclass(slots=True)
class Reasons:
    """What one robot's FilterOutput says and why: its problem ('' if judged), configuration,
    command (``omega``, ``linear``, ``action``), the safe set's fields (``set_fields``), the
    table row it names (``row``, -1: none) and how it acted on it (``kind``, ``law.KINDS``),
    whether the planner's command was fresh, the hold, the pose's age, the clusters near it
    being solved; ``lost``: no recent valid state (the fail-safe command)."""

    problem: str
    cfg: object
    omega: float
    linear: float
    action: str
    set_fields: dict
    table: object = None
    row: int = -1
    kind: int = 0
    fresh: bool = False
    horizon: float = 0.0
    age: float = 0.0
    solving: int = 0
    lost: bool = False
    silence: float = math.inf    # seconds since the planner's last command (inf: none yet)
    limit: str = ''              # what the speed cut did (``approach.Limits.headline``; '' if nothing)


def explain(r: Reasons) -> FilterOutput:
    """One robot's FilterOutput: its command and why (``Reasons``), in words an operator reads
    (what the robot does, then why; the numbers behind it are the output's own fields)."""
    problem, cfg, v, a, table, k = r.problem, r.cfg, r.linear, r.action, r.table, r.row
    kind, horizon = r.kind, r.horizon
    common = dict(r.set_fields, pose_age=r.age, lookahead=horizon, clusters_solving=r.solving)
    if k < 0:
        common.update(obstacle_index=-1, obstacle_xy=(math.nan, math.nan), value=math.inf)
        value = level = math.nan
    else:
        value, level = float(table.value[k]), float(table.level[k])
        members, obstacle = int(table.members[k]), int(table.obstacle[k])
        common.update(obstacle_index=obstacle, obstacle_xy=tuple(float(c) for c in table.xy[k]), value=value,
                      alpha=level)
        source = 'map' if table.mapped[k] else 'cluster-fallback' if table.fallback[k] else 'cluster'   # a sound row's
        if table.sound[k]:
            common['source'] = source
        if table.mapped[k]:        # a local map's value: it names the nearest occupied cell (map_rows)
            gap = float(table.gap[k])
            label = (f'an obstacle {max(gap, 0.0):.2g} m away' if math.isfinite(gap) else
                     'the mapped obstacles')
        elif members > 1:
            label = f'a cluster of {members} obstacles (nearest {obstacle})'
        else:
            label = f'obstacle {obstacle}'
    turning = 'turning left' if r.omega > 0.0 else 'turning right' if r.omega < 0.0 else 'steering straight'
    if problem:
        if not cfg.constant_speed:
            why = f'stopped: {problem}'
        elif k >= 0:
            why = f'{turning} away from {label} at speed: {problem}; from the last valid state (V={value:.3g})'
        else:
            why = (f'circling (stop-turn): {problem}; '
                   f'{"no recent valid state" if r.lost else "no obstacle near the last valid state"}')
    elif a == OVERRIDE:
        how = KINDS[kind]
        in_place = not cfg.constant_speed and table.fallback[k]
        doing = f'{turning} in place' if in_place else turning
        if how == 'enter':
            why = f'{doing}: {label} is too close (V={value:.3g} <= alpha={level:.3g})'
        elif how == 'ahead':
            why = (f'{doing}: the planner\'s command would bring {label} too close within {horizon:.3g} s '
                   f'(V={float(table.value_next[k]):.3g} <= alpha={level:.3g})')
        else:
            why = f'{doing}: not yet clear of {label} (V={value:.3g} <= alpha+margin={level + cfg.clear_margin:.3g})'
        if in_place:
            why += '; its union value is being solved and its loiter circle is drawn at full speed'
    elif not r.fresh:
        # Nav2 style: no input, zero twist (a constant-speed Dubins robot drives straight on; the
        # filter still guards it against every detected obstacle)
        silent = ('planner silent' if r.silence == math.inf else
                  f'planner silent for {r.silence:.2g} s (cmd_timeout {cfg.cmd_timeout:g} s)')
        why = f'driving straight on: {silent}' if cfg.constant_speed else f'stopped: {silent}'
    else:
        # the robot's bound, whatever the planner asked (angular.z = 1e30 goes out as w_max)
        clear = 'nothing near' if k < 0 else f'clear of {label} (V={value:.3g} > alpha={level:.3g})'
        why = clear if r.limit else f'passing the planner\'s command: {clear}'
    if r.limit:
        why = f'{r.limit}; {why}'
    return FilterOutput(r.omega, v, a, why, **common)
