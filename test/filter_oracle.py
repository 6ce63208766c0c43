"""The filter's equivalence oracle (not a test module): the per-robot implementation of
``filter.step_many`` before it was vectorised (commit 003abdd), kept verbatim as the
reference the vectorised one must equal decision for decision (test_filter_vectorised.py),
and ``govern_one``, the per-robot rule the fleet's ``law.govern`` replaced. Only the imports differ, the control
period is computed from the filter's interval deques here (as it was), not from its cache,
and propagate_poses wraps theta when no robot has an arc (as filter.propagation does since: a
robot's state must not depend on the other robots' plans). Since issue 31 it also follows the
planner's speed (``_drive``: the holds at the speed the robot drives, the arcs at the speeds
sent) and a robot that can stop (fail_safe_command 'stop': a zero twist, the avoid turn at
the speed last sent where the law would act on its last valid state, in place on a loiter
fallback); a constant-speed robot ('stop_turn') decides as before.
"""
from __future__ import annotations

import math

import numpy as np

from supersafe_ros.filter import FAIL_SAFE, FilterOutput, OVERRIDE, PASS, SafeSet, default_cluster_store

from supersafe_ros.filter.commands import clip, planned_turn
from supersafe_ros.filter.sent import record_sent, segments_since

from supersafe_ros.filter.propagation import arc_flow
from supersafe_ros.filter.law import evaluate_pairs, tie_tolerance
from supersafe_ros.reach.grid import wrap_angle
from supersafe_ros.reach.value_function import ValueFunction


def _problem(f, t) -> str:
    """Why the filter cannot judge the planner's command now ('' if it can): ``RobotFilter.problem``
    as it was (the one answer is ``gather.problem`` since), in the words of issue 36, and a
    refused planner command of a robot that can stop (issue 36: it stops at once)."""
    cfg = f.config
    for label, inp, timeout in (('pose', f.pose, cfg.pose_timeout),
                                ('detections', f.detections, cfg.detections_timeout)):
        if inp.rejected:
            return f'{label} rejected: {inp.rejected}'
        if inp.value is None:
            return f'no {label} received yet'
        age = t - inp.t     # since arrival: a pose that keeps coming is not lost
        if age > timeout:
            return f'blind for {age:.3g} s ({label} stale: none newer; timeout {timeout:g} s)'
    if f.command.rejected and cfg.fail_safe_command != 'stop_turn':
        return f'planner command rejected: {f.command.rejected}'
    return ''


def _turning(omega) -> str:
    return 'turning left' if omega > 0.0 else 'turning right' if omega < 0.0 else 'steering straight'


def _control_period(f) -> float:
    if f.config.control_period > 0.0:
        return f.config.control_period
    medians = [float(np.median(d)) for d in (f.pose_intervals, f.command_intervals) if d]
    return max(medians) if medians else 0.0


def _lookahead(f) -> float:
    cfg = f.config
    return max(cfg.lookahead, _control_period(f)) if cfg.compensate_delay else cfg.lookahead


def propagate_poses(filters, use, t):
    """Each robot's state at ``t`` (rows in the order of ``use``) and the pose ages.

    The pose is moved from its stamp to ``t`` along the arcs of the commands sent
    (at most ``hold_timeout`` of them: older poses only feed the stop-turn).
    """
    states = np.array([filters[i].pose.value for i in use], dtype=float).reshape(-1, 3)
    ages = np.zeros(len(use))
    plans = []
    for row, i in enumerate(use):
        f = filters[i]
        if not f.config.compensate_delay:
            plans.append([])
            continue
        t0 = min(f.pose.t, f.pose.stamp)
        ages[row] = max(0.0, min(t - t0, f.config.hold_timeout))
        plans.append(segments_since(f, t - ages[row], t))
    depth = max((len(p) for p in plans), default=0)
    if depth == 0:      # (added later: theta wrapped as a zero-length arc would, see filter.propagation)
        states[:, 2] = wrap_angle(states[:, 2])
        return states, ages
    for k in range(depth):
        omega = np.array([p[k][0] if k < len(p) else 0.0 for p in plans])
        dt = np.array([p[k][1] if k < len(p) else 0.0 for p in plans])
        speed = np.array([p[k][2] if k < len(p) else 0.0 for p in plans])
        states = arc_flow(states, speed, omega, dt)
    return states, ages


def _held(f) -> float:
    """The speed the robot drives under the last command sent."""
    cfg = f.config
    if cfg.fail_safe_command == 'stop_turn':
        return cfg.speed
    return f.sent[-1][2] if f.sent else 0.0


def _drive(f, t, failing) -> float:
    """The speed of the command judged: a constant-speed robot's speed; failing safe, the speed
    last sent; else the planner's clipped to [0, speed] (not given: the speed), 0 if silent."""
    cfg = f.config
    if cfg.fail_safe_command == 'stop_turn':
        return cfg.speed
    if failing:
        return _held(f)
    if f.command.value is None or t - f.command.t > cfg.cmd_timeout:
        return 0.0
    v = f.command.linear
    return cfg.speed if v is None else max(0.0, min(cfg.speed, v))


def _pairs(filters, use, states):
    """Relative states of every (robot, obstacle) pair for the robots in ``use``."""
    rel, robot, obstacle = [], [], []
    for row, i in enumerate(use):
        f = filters[i]
        x = states[row]
        c = f.detections.value
        if len(c) == 0:
            continue
        r = np.empty((len(c), 3))
        r[:, 0] = x[0] - c[:, 0]
        r[:, 1] = x[1] - c[:, 1]
        r[:, 2] = x[2]
        rel.append(r)
        robot.append(np.full(len(c), i))
        obstacle.append(np.arange(len(c)))
    if not rel:
        return np.zeros((0, 3)), np.zeros(0, int), np.zeros(0, int)
    return np.concatenate(rel), np.concatenate(robot), np.concatenate(obstacle)


def step_many_reference(filters, safe_set: SafeSet, t, clusters=None) -> list:
    """One decision per robot filter, with one vectorised evaluation of the law.

    Robots that can be judged use their current pose and detections; robots that
    fail safe use their last valid pose and detections if younger than
    ``hold_timeout``, else the stop-turn policy. ``clusters``: the ClusterStore
    for obstacles judged together (None: the process's shared store for the
    robots' configuration; see ``filter.clusters``).
    """
    n = len(filters)  # noqa: F841  (unused, kept: the reference is the old code verbatim)
    problems = [_problem(f, t) for f in filters]
    usable = []   # robots whose (last valid) state enters the law
    for i, f in enumerate(filters):
        if not problems[i]:
            usable.append(i)
        elif (f.pose.value is not None and f.detections.value is not None
              and t - f.pose.t <= f.config.hold_timeout and t - f.detections.t <= f.config.hold_timeout):
            usable.append(i)
    states, ages = propagate_poses(filters, usable, t)
    state_of = {i: states[row] for row, i in enumerate(usable)}
    age_of = dict(zip(usable, ages))
    rel, robot, obstacle = _pairs(filters, usable, states)
    value, turn = evaluate_pairs(safe_set.vf, rel)
    horizons = {i: _lookahead(filters[i]) for i in usable}
    drives = {i: _drive(filters[i], t, bool(problems[i])) for i in usable}
    turn, value_next = _sampled_control(filters, safe_set.vf, rel, robot, t, horizons, turn, drives)
    # pairs are grouped by robot, in order: robot i's pairs are [first[i], last[i])
    first = {int(i): int(k) for i, k in zip(*np.unique(robot, return_index=True))} if len(robot) else {}

    alpha = float(safe_set.alpha)
    set_omega = safe_set.omega_max
    set_omega = float(set_omega) if set_omega is not None else math.nan
    out = []
    for i, f in enumerate(filters):
        cfg = f.config
        c = _Constraints.of_pairs(f, i, first, value, turn, value_next, obstacle, alpha, safe_set.source)
        if i in state_of and cfg.clusters and len(f.detections.value) > 1:
            _add_cluster_constraints(c, f, state_of[i], horizons[i], t, clusters, drives[i])
        common = dict(alpha=alpha, source=safe_set.source, omega_max_set=set_omega,
                      pose_age=float(age_of.get(i, 0.0)), lookahead=float(horizons.get(i, 0.0)),
                      clusters_solving=c.solving)
        constant = cfg.fail_safe_command == 'stop_turn'
        silent = f.command.value is None or t - f.command.t > cfg.cmd_timeout
        if problems[i]:
            k = c.smallest()
            f.overriding = False   # re-enter by the law once inputs are back
            common.update(c.describe(k, f))
            if not constant:       # issue 36: a robot that can stop stops
                out.append(FilterOutput(0.0, 0.0, FAIL_SAFE, f'stopped: {problems[i]}', **common))
            elif k >= 0:
                omega = cfg.omega_max * c.turn[k]
                out.append(FilterOutput(omega, cfg.speed, FAIL_SAFE,
                                        f'{_turning(omega)} away from {c.label(k)} at speed: {problems[i]}; '
                                        f'from the last valid state (V={c.value[k]:.3g})', **common))
            else:
                why = 'no recent valid state' if i not in usable else 'no obstacle near the last valid state'
                out.append(FilterOutput(cfg.omega_max, 0.0, FAIL_SAFE, f'circling (stop-turn): {problems[i]}; {why}',
                                        **common))
            continue
        k, kind = c.governing(f.overriding, cfg.clear_margin)
        if kind and not (silent and not constant):
            common.update(c.describe(k, f))
            f.overriding = True
            lv = c.level[k]
            omega = cfg.omega_max * c.turn[k]
            in_place = not constant and c.source[k] == 'cluster-fallback'
            doing = f'{_turning(omega)} in place' if in_place else _turning(omega)
            if kind == 'enter':
                why = f'{doing}: {c.label(k)} is too close (V={c.value[k]:.3g} <= alpha={lv:.3g})'
            elif kind == 'ahead':
                why = (f'{doing}: the planner\'s command would bring {c.label(k)} too close within '
                       f'{horizons[i]:.3g} s (V={c.value_next[k]:.3g} <= alpha={lv:.3g})')
            else:
                why = (f'{doing}: not yet clear of {c.label(k)} (V={c.value[k]:.3g} <= '
                       f'alpha+margin={lv + cfg.clear_margin:.3g})')
            speed = drives[i]
            if in_place:
                why += '; its union value is being solved and its loiter circle is drawn at full speed'
                speed = 0.0
            out.append(FilterOutput(omega, speed, OVERRIDE, why, **common))
            continue
        f.overriding = False
        if kind:      # a silent planner: the constraint the law would have acted on is not named
            k = c.smallest()
        common.update(c.describe(k, f))
        if silent:
            # Nav2 style: no input, zero twist (a Dubins robot drives straight on;
            # the filter still guards it against every detected obstacle)
            quiet = ('planner silent' if f.command.value is None else
                     f'planner silent for {t - f.command.t:.2g} s (cmd_timeout {cfg.cmd_timeout:g} s)')
            out.append(FilterOutput(0.0, 0.0, PASS,
                                    f'driving straight on: {quiet}' if constant else f'stopped: {quiet}', **common))
        else:
            why = ('passing the planner\'s command: nothing near' if k < 0 else
                   f'passing the planner\'s command: clear of {c.label(k)} (V={c.value[k]:.3g} > '
                   f'alpha={c.level[k]:.3g})')
            # the robot's bound, whatever the planner asked (angular.z = 1e30 goes out as w_max)
            omega = clip(f.command.value, cfg.omega_max)
            out.append(FilterOutput(omega, drives[i], PASS, why, **common))
    for f, o in zip(filters, out):
        record_sent(f, o.omega, t, f.config.speed if f.config.fail_safe_command == 'stop_turn' else o.linear)
    return out


class _Constraints:
    """What one robot must respect: per obstacle (the safe set in force) and per cluster.

    Each constraint has a value V, its level, the unit avoid turn, V after the
    planner's command is held for the lookahead, the obstacle it names and whether
    it is *sound for its layout* (a cluster's union value or the loiter fallback;
    these govern first whenever they act, see ``governing``).
    """

    def __init__(self):
        self.value, self.level, self.turn, self.value_next = [], [], [], []
        self.obstacle, self.sound, self.source, self.members, self.group = [], [], [], [], []
        self.solving = 0     # clusters of this robot whose union value is being solved

    @classmethod
    def of_pairs(cls, f, i, first, value, turn, value_next, obstacle, alpha, source):
        c = cls()
        if i in first:
            a = first[i]
            b = a + len(f.detections.value)
            c.value = value[a:b].tolist()
            c.turn = turn[a:b].tolist()
            c.value_next = value_next[a:b].tolist()
            c.obstacle = obstacle[a:b].tolist()
            m = b - a
            c.level, c.sound, c.source, c.members = [alpha] * m, [False] * m, [source] * m, [1] * m
            c.group = list(range(m))    # each obstacle its own group until clustered
        return c

    def add(self, value, level, turn, value_next, obstacle, source, members, group):
        self.value.append(float(value))
        self.level.append(float(level))
        self.turn.append(float(turn))
        self.value_next.append(float(value_next))
        self.obstacle.append(int(obstacle))
        self.sound.append(True)
        self.source.append(source)
        self.members.append(int(members))
        self.group.append(group)

    def margins(self, idx):
        return [self.value[k] - self.level[k] for k in idx]

    def smallest(self, idx=None) -> int:
        """The constraint with the smallest V - level (-1 if none is finite)."""
        idx = list(range(len(self.value))) if idx is None else idx
        finite = [k for k in idx if math.isfinite(self.value[k])]
        if not finite:
            return -1
        return min(finite, key=lambda k: self.value[k] - self.level[k])

    def governing(self, overriding, clear_margin):
        """(constraint, why) that makes the filter override, or (smallest, '') to pass.

        Within a cluster its sound constraint (union value or fallback) comes first: if
        it enters, looks ahead to its level or holds its hysteresis, the cluster's
        members' own constraints are set aside, so the union's avoid turn is never
        traded for a single member's. Between clusters and lone obstacles (farther
        apart than the link distance) the smallest value governs, as per obstacle.
        """
        n = len(self.value)
        enter = [self.value[k] <= self.level[k] for k in range(n)]
        ahead = [self.value_next[k] <= self.level[k] for k in range(n)]
        stay = [overriding and self.value[k] <= self.level[k] + clear_margin for k in range(n)]
        acts = [enter[k] or ahead[k] or stay[k] for k in range(n)]
        governed = {self.group[k] for k in range(n) if self.sound[k] and acts[k]}
        use = [k for k in range(n) if self.sound[k] or self.group[k] not in governed]
        for flags, why, score in ((enter, 'enter', self.value), (ahead, 'ahead', self.value_next),
                                  (stay, 'stay', self.value)):
            hit = [k for k in use if flags[k]]
            if hit:
                return min(hit, key=lambda q: score[q] - self.level[q]), why
        return self.smallest(), ''

    def label(self, k) -> str:
        if self.members[k] > 1:
            return f'a cluster of {self.members[k]} obstacles (nearest {self.obstacle[k]})'
        return f'obstacle {self.obstacle[k]}'

    def describe(self, k, f) -> dict:
        if k < 0:
            return dict(obstacle_index=-1, obstacle_xy=(math.nan, math.nan), value=math.inf)
        j = self.obstacle[k]
        d = dict(obstacle_index=j, obstacle_xy=tuple(float(v) for v in f.detections.value[j]),
                 value=self.value[k], alpha=self.level[k])
        if self.sound[k]:
            d['source'] = self.source[k]
        return d


def _add_cluster_constraints(c: _Constraints, f, state, horizon, t, store, drive) -> None:
    """Cluster constraints of robot ``f`` at its (propagated) ``state``."""
    from supersafe_ros.filter.clusters.geometry import canonical, components, orbit_value, to_frame
    cfg = f.config
    store = store if store is not None else default_cluster_store(cfg)
    st = store.settings
    key_det = f.detections.value
    cache = f.__dict__.get('_reference_cluster_cache')
    if cache is None or cache[0] is not key_det:
        groups = [g for g in components(key_det, st.link_distance) if len(g) > 1]
        frames = [canonical(key_det[g], st.key_resolution) for g in groups]
        cache = (key_det, groups, frames)
        f._reference_cluster_cache = cache
    _, groups, frames = cache
    if not groups:
        return
    # sampled control: each command holds for ``horizon``. The union's turn is the bang
    # (+-w_max) with the larger V at the end of its hold, and the planner's command is
    # judged by what the filter can still do after it: the better bang held for one more
    # period (a pass never leaves the robot where no held turn keeps V above the level)
    u = planned_turn(f, t)
    w = cfg.omega_max
    speed = np.full(3, drive)
    hold = np.full(3, horizon)
    ahead = arc_flow(state[None], speed[:1], np.array([u]), hold[:1])[0]
    # (added later: the turn's bangs are held at least st.turn_hold, one heading cell of the
    # cluster grid: a shorter hold's two ends read alike between its nodes)
    turn_hold = max(horizon, st.turn_hold)
    points = arc_flow(np.stack([state, state, ahead, ahead]), np.full(4, drive),
                      np.array([w, -w, w, -w]), np.array([turn_hold, turn_hold, horizon, horizon]))
    for gi, (g, (key, origin, angle, centres)) in enumerate(zip(groups, frames)):
        group = ('cluster', gi)
        for j in g:                 # the members' own constraints belong to the cluster
            if j < len(c.group):
                c.group[j] = group
        nearest = int(g[np.argmin(np.hypot(*(key_det[g] - state[:2]).T))])
        solved = store.get(key)
        if solved is None:
            store.request(key, centres)
            if store.solving(key):
                c.solving += 1
        if solved is not None:
            v, _ = solved.evaluate(to_frame(np.vstack([state[None], points, ahead[None]]), origin, angle))
            turn = 1.0 if v[1] >= v[2] - solved.tie else -1.0
            c.add(v[0], cfg.cluster_alpha, turn, min(v[5], max(v[3], v[4])), nearest, 'cluster', len(g),
                  group)
        else:
            # the loiter-circle fallback keeps its invariant only from a state with a clear
            # circle; from any other state the per-obstacle rule (always in the list) is the
            # best known until the union's value is in force
            v, turn = orbit_value(np.stack([state, ahead]), key_det[g], st.radius + st.margin,
                                  st.turning_radius)
            if v[0] > 0.0:
                c.add(v[0], 0.0, turn[0], v[1], nearest, 'cluster-fallback', len(g), group)


def _sampled_control(filters, vf: ValueFunction, rel, robot, t, horizons, turn, drives):
    """The avoid turn and the lookahead value of every pair, for commands held over H.

    H is the robot's lookahead (>= its control period). A command holds for H, so:

    * the avoid turn is the bang (+-w_max) whose hold ends at the larger V (ties
      left, within the law's tie tolerance); as H -> 0 this is sign(dV/dtheta), the
      continuous law, which it keeps where both ends are off the grid;
    * the planner's command is judged by what the filter can still do after it:
      V where the command's hold ends, and after the better bang held for one more
      period from there (the smaller of the two). A pass therefore never leaves the
      robot below the level, nor where no held turn keeps V above it (the filter
      acts one hold early rather than one hold late).

    A silent planner counts as a zero command (what the filter would forward).
    Translation invariance: the relative state moves like the robot itself.
    Returns (unit turn, V after the planner's hold and the best bang's).
    """
    if len(rel) == 0:
        return turn, np.zeros(0)
    # per-robot values, repeated over each robot's pairs (pairs are grouped by robot)
    robots, counts = np.unique(robot, return_counts=True)
    per = np.array([(planned_turn(filters[i], t), horizons[i], drives[i],
                     filters[i].config.omega_max) for i in robots], dtype=float).reshape(-1, 4)
    omega, horizon, speed, bang = (np.repeat(per[:, c], counts) for c in range(4))
    if not np.any(horizon > 0):
        return turn, np.full(len(rel), np.inf)
    ahead = arc_flow(rel, speed, omega, horizon)
    starts = np.concatenate([rel, rel, ahead, ahead])
    ends = arc_flow(starts, np.tile(speed, 4), np.concatenate([bang, -bang, bang, -bang]),
                    np.tile(horizon, 4))
    v = vf.value(np.concatenate([ends, ahead]), outside=np.inf).reshape(5, len(rel))
    left, right = v[0], v[1]
    held = np.where(left >= right - tie_tolerance(vf), 1.0, -1.0)
    use = (horizon > 0) & (np.isfinite(left) | np.isfinite(right))
    value_next = np.where(horizon > 0, np.minimum(v[4], np.maximum(v[2], v[3])), np.inf)
    return np.where(use, held, turn), value_next


def govern_one(tab, overriding, margin):
    """The governing rule for one robot whose table columns are lists, as the filter's scalar
    path wrote it before the rule was written once (law.govern): (the row that makes it
    override and why, or -1 and 0 to pass; the row with the smallest finite V - level, or -1).
    Within a cluster its sound row first, then enter, ahead, stay, each by the smallest score
    and the first in the robot's list on ties. An oracle for law.govern and law.smallest."""
    rows = range(len(tab.value))
    enter = [tab.value[r] <= tab.level[r] for r in rows]
    ahead = [tab.value_next[r] <= tab.level[r] for r in rows]
    stay = [overriding and tab.value[r] <= tab.level[r] + margin for r in rows]
    governed = {tab.group[r] for r in rows if tab.sound[r] and (enter[r] or ahead[r] or stay[r])}
    usable = [tab.sound[r] or tab.group[r] not in governed for r in rows]
    k_gov, kind = -1, 0
    for code, flags, values in ((1, enter, tab.value), (2, ahead, tab.value_next), (3, stay, tab.value)):
        hits = [(values[r] - tab.level[r], tab.position[r], r) for r in rows if usable[r] and flags[r]]
        if hits:
            k_gov, kind = min(hits)[2], code
            break
    finite = [(tab.value[r] - tab.level[r], tab.position[r], r) for r in rows if math.isfinite(tab.value[r])]
    return k_gov, kind, min(finite)[2] if finite else -1
