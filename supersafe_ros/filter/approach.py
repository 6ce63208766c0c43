"""Stop before collision: the speed a robot that can stop may drive without entering a disc.

The value-function law judges each detected disc alone (a union of a scan's pieces has no
union value) and a scan's discs move from message to message, so a state above every
disc's level now can be below the next message's (bench/results/sensors.md). A robot that
follows its commanded speed and can stop has a guarantee that needs neither: after the law
has chosen (speed s, turn u), drive at the largest speed s' <= s whose path over the next
``tau`` seconds stays outside every disc given (Nav2 collision_monitor's "approach" model,
with the path exact instead of simulated in steps).

**The path.** Held for tau, the command (s', u) moves a kinematic unicycle along the arc
    p(t) = o + (s'/u) (sin(theta + u t), -cos(theta + u t)),   o = p - (s'/u) n(theta)
(n = (-sin, cos): the turning centre, radius rho = s'/|u|), or the segment p + s' t h(theta)
when u = 0. The distance from a disc's centre c to that path is exact, no sampling
(``path_distance``): |c - p(t)|^2 = |c - o|^2 + rho^2 - 2 |c - o| rho cos(beta(t) - psi), with
beta the angle of p(t) - o (swept at the rate u) and psi that of c - o, is smallest where
beta = psi and grows with |beta - psi| (wrapped to [0, pi]): if the swept angles
[beta(0), beta(0) + u tau] pass psi, the path's closest point is at | |c - o| - rho |, else at
one of the arc's two ends. For |u| tau < ``STRAIGHT_TURN`` the segment is used (its
closest distance minus the largest gap between the arc and the segment, s' tau |u| tau / 2,
so still a lower bound; the arc formula would lose digits to a turning centre kilometres
away). A path whose distance to every disc centre is at least that disc's radius enters no
disc (the discs are inflated by the robot's radius already: ``sensing``, ``filter.constraints.discs``).

**The speed.** Lowering s' at a fixed u tightens the arc, so the clear speeds need not be an
interval: the candidates s (1, (J-1)/J, ..., 1/J, 0) are checked (J = ``CANDIDATES``) and the
largest clear one is sent. s' = 0 is always clear (the path is the robot's centre, outside
every disc, or see below): turning in place is always allowed, and the speed sent is never
above the law's (never above the planner's).

**Why tau is enough.** The state judged is the law's: the pose propagated over its age under
the commands sent (``filter.propagation``, ``compensate_delay``), so the robot is there now if
it follows its commands. The command holds until the next decision's command replaces it,
at most the control period later (plus the command's delivery); ``tau`` = max(the law's
horizon (the lookahead, never less than the control period), ``time_before_collision``).
By induction over decisions: decision k's path, clear of decision k's discs, is all the
robot drives until decision k+1 acts (within tau), whose path starts where it ends. So the
robot never enters a disc of the message in force when it drives there, whatever the
discs do between messages and however they cluster: every obstacle the discs hold
(``sensing``: what the scan saw) is never reached. Not covered: a robot whose speed lags its
command (it drives on after a stop is sent; add the lag to tau through lookahead or
time_before_collision), commands lost or late beyond tau, a state not propagated
(``compensate_delay`` false), obstacles not in the discs.

**Inside a disc.** The discs of a new message can cover the robot's own position (a covering
disc is larger than what it covers, and pieces change with every message). No path leaves
such a disc at once, so for a disc that holds the robot's centre the rule is: never get
closer to its centre than now (the path's distance to c at least |p - c|). The robot can
back out of a covering disc's slack but not drive deeper; it is not a proof that the object
inside that disc is missed (the counts in bench/results/sensors.md say how often it arises).

**Blocked.** A robot the limiter stops (s' = 0 < s) would keep the law's turn: the planner's,
often 0 (it steers at the goal behind the obstacle), or the avoid turn, which flips from one
of an object's pieces to the next at every decision (bench/results/sensors.md). At speed 0
every turn is safe, so it turns at omega_max in one direction until the law's command has a
clear path: the direction it was turning in place already, else away from the nearest disc
that blocks its path at s (left on a tie). (A robot the law itself stops, on a cluster's
loiter fallback, turns as the law says.)

**Work.** Per robot, only discs that the path at s can reach (|p - c| - r <= s tau) are
examined (one pass over its discs), and those against J + 1 candidate speeds: O(K + K' J),
bounded for any scan (its discs number at most its occupied cells). ``limit`` returns None
at once when no robot has it on.
"""
from __future__ import annotations

from itertools import repeat
import math
from operator import is_

import numpy as np

from .constraints.map_rows import cut_discs

CANDIDATES = 16          # the speeds checked: s (J, J - 1, ..., 0) / J
STRAIGHT_TURN = 1e-4     # |u| tau below this [rad]: the path is taken as a segment (see the module)
_DEEPER = 1e-9           # inside a disc: the distance to its centre may not fall by more than this [m]


def path_distance(x, y, theta, v, omega, tau, cx, cy):
    """The least distance from (cx, cy) to the path of (x, y, theta) driven at speed ``v`` and
    turn rate ``omega`` for ``tau`` seconds (exact for the arc; a lower bound within
    v tau |omega| tau / 2 of it for |omega| tau < STRAIGHT_TURN). Arrays broadcast together."""
    x, y, theta, v, omega, tau, cx, cy = np.broadcast_arrays(
        *(np.asarray(a, dtype=float) for a in (x, y, theta, v, omega, tau, cx, cy)))
    hx, hy = np.cos(theta), np.sin(theta)
    length = v * tau
    sweep = omega * tau
    straight = np.abs(sweep) < STRAIGHT_TURN
    # the segment: the closest point's parameter clipped to [0, length]
    along = np.clip((cx - x) * hx + (cy - y) * hy, 0.0, length)
    d_line = np.hypot(cx - x - along * hx, cy - y - along * hy) - length * np.abs(sweep) / 2.0
    # the arc (omega taken as 1 where straight, only to keep the arithmetic finite there)
    w = np.where(straight, 1.0, omega)
    r_signed = v / w
    ox, oy = x - r_signed * hy, y + r_signed * hx
    rho = np.abs(r_signed)
    sgn = np.where(w > 0, 1.0, -1.0)
    beta0 = theta - sgn * (math.pi / 2.0)
    psi = np.arctan2(cy - oy, cx - ox)
    passes = np.mod(sgn * (psi - beta0), 2.0 * math.pi) <= np.abs(sweep)
    d_oc = np.hypot(cx - ox, cy - oy)
    end = theta + sweep
    ex, ey = ox + r_signed * np.sin(end), oy - r_signed * np.cos(end)
    ends = np.minimum(np.hypot(cx - x, cy - y), np.hypot(cx - ex, cy - ey))
    d_arc = np.where(passes, np.minimum(np.abs(d_oc - rho), ends), ends)
    return np.where(straight, d_line, d_arc)


class Limits:
    """What ``limit`` did, per robot row: ``linear`` and ``omega`` to send, ``limited`` (the
    speed was cut), ``blocked`` (cut to 0: turning in place, ``blocked_turns``),
    ``tau`` and ``obstacle`` (the row in the robot's detections of the nearest disc that cut
    it, -1 if none)."""

    __slots__ = ('linear', 'omega', 'limited', 'blocked', 'tau', 'obstacle', 'asked', 'gap', 'mapped')

    def headline(self, row) -> str:
        """What the cut did to robot row ``row``, in words ('' if its speed was not cut)."""
        if not self.limited[row]:
            return ''
        # a map's cell has no name; a detection its row in the message
        name = 'an obstacle' if self.mapped[row] else f'obstacle {int(self.obstacle[row])}'
        what = f'{name} {max(0.0, float(self.gap[row])):.2g} m ahead'
        if self.blocked[row]:
            side = 'left' if self.omega[row] > 0.0 else 'right'
            return (f'stopped, turning {side} in place: {what} leaves no speed above 0 clear for '
                    f'{self.tau[row]:.2g} s')
        return (f'slowing to {self.linear[row]:.2g} m/s (planner {self.asked[row]:.2g}): {what} would be '
                f'reached within {self.tau[row]:.2g} s')


def allowed_speeds(states, speeds, turns, tau, dets, radii):
    """Per robot: (the largest clear candidate speed <= ``speeds``, the row in its discs of the
    nearest that blocks its path at ``speeds`` (-1: none), the unit turn away from it (0: none),
    that disc's clearance |p - c| - r (inf: none)).

    ``states`` (M, 3), ``speeds``, ``turns``, ``tau`` (M,); ``dets``: per robot its (K_i, 2)
    disc centres; ``radii``: per robot its (K_i,) radii.
    """
    m = len(speeds)
    out = np.asarray(speeds, dtype=float).copy()
    blocker = np.full(m, -1, dtype=np.intp)
    away = np.zeros(m)
    gap_of = np.full(m, np.inf)
    counts = np.fromiter(map(len, dets), dtype=np.intp, count=m)
    if m == 0 or counts.sum() == 0:
        return out, blocker, away, gap_of
    centres = np.concatenate([np.asarray(d, dtype=float).reshape(-1, 2) for d in dets])
    r = np.concatenate([np.broadcast_to(np.asarray(rr, dtype=float), (k,)) for rr, k in zip(radii, counts)])
    robot = np.repeat(np.arange(m), counts)
    index = np.arange(len(robot)) - np.repeat(np.cumsum(counts) - counts, counts)
    x, y = states[robot, 0], states[robot, 1]
    start = np.hypot(centres[:, 0] - x, centres[:, 1] - y)
    reach = out[robot] * tau[robot]
    near = start - r <= reach                      # a disc the path at s can reach (or the robot is inside)
    if not near.any():
        return out, blocker, away, gap_of
    p = np.flatnonzero(near)
    robot, index, start, r = robot[p], index[p], start[p], r[p]
    cx, cy = centres[p, 0], centres[p, 1]
    need = np.where(start < r, start - _DEEPER, r)     # inside: not deeper (see the module)
    fractions = np.arange(CANDIDATES, -1, -1) / CANDIDATES          # 1 .. 0
    v = out[robot][:, None] * fractions[None, :]
    d = path_distance(states[robot, 0][:, None], states[robot, 1][:, None], states[robot, 2][:, None], v,
                      turns[robot][:, None], tau[robot][:, None], cx[:, None], cy[:, None])
    clear = d >= need[:, None]
    clear[:, -1] = True                            # speed 0: the path is the robot's centre (see the module)
    rows, first = np.unique(robot, return_index=True)     # pairs are grouped by robot, in order
    ok = np.logical_and.reduceat(clear, first, axis=0)     # (robots with near discs, candidates)
    pick = np.argmax(ok, axis=1)                   # the first (largest) clear candidate
    out[rows] = out[rows] * fractions[pick]
    cut = pick > 0
    if cut.any():
        hit = ~clear[:, 0]
        # the nearest blocking disc of each cut robot (by clearance |p - c| - r), and the side it is on
        gap = np.where(hit, start - r, np.inf)
        for j in np.flatnonzero(cut).tolist():
            lo, hi = first[j], first[j + 1] if j + 1 < len(first) else len(robot)
            k = lo + int(np.argmin(gap[lo:hi]))
            i = rows[j]
            blocker[i] = index[k]
            gap_of[i] = gap[k]
            side = math.cos(states[i, 2]) * (cy[k] - states[i, 1]) - math.sin(states[i, 2]) * (cx[k] - states[i, 0])
            away[i] = -1.0 if side > 0.0 else 1.0
    return out, blocker, away, gap_of


def blocked_turns(last_sent, away) -> np.ndarray:
    """The unit turn of each blocked robot (see the module): the sign of the turn it was sent
    last (``last_sent``, (k, 3): time, turn, speed; ``propagation.NEVER_SENT``: none) if that
    command turned in place (speed 0), else ``away``."""
    in_place = (last_sent[:, 2] == 0.0) & (last_sent[:, 1] != 0.0)
    return np.where(in_place, np.where(last_sent[:, 1] > 0.0, 1.0, -1.0), np.asarray(away, dtype=float))


def limit(cols, omega, linear, action_code):
    """The law's commands ``omega``, ``linear`` (per robot row of ``cols``, ``gather.RobotColumns``:
    its state now ``cols.states`` and its detections ``cols.detections``, all of them, with
    ``cols.detection_radii``; a robot judged by its local map: the map's occupied cells,
    ``map_rows.cut_discs``) with each speed cut to what its path over tau allows (``allowed_speeds``), for the robots
    whose configuration has ``time_before_collision`` > 0 (robots that can stop); a robot cut to
    0 where the law passes or overrides (``action_code`` 0 or 1) turns in place
    (``blocked_turns``). None if no robot has it on (nothing changed)."""
    configs = cols.configs
    if not configs:
        return None
    c0 = configs[0]
    if all(map(is_, configs, repeat(c0))):     # (checked in C)
        if c0.time_before_collision <= 0.0:
            return None
        on = np.ones(len(configs), bool)
        tbc = np.full(len(configs), c0.time_before_collision)
    else:
        tbc = np.fromiter((c.time_before_collision for c in configs), dtype=float, count=len(configs))
        on = tbc > 0.0
        if not on.any():
            return None
    on &= ~cols.constant_speed & (np.asarray(linear) > 0.0)
    lim = Limits()
    lim.linear, lim.omega = np.array(linear, dtype=float), np.array(omega, dtype=float)
    lim.asked = lim.linear.copy()
    lim.tau = np.maximum(np.asarray(cols.lookahead, dtype=float), tbc)
    m = len(configs)
    lim.limited, lim.blocked = np.zeros(m, bool), np.zeros(m, bool)
    lim.obstacle = np.full(m, -1, dtype=np.intp)
    lim.gap = np.full(m, np.inf)
    lim.mapped = np.zeros(m, bool)
    idx = np.flatnonzero(on)
    if len(idx) == 0:
        return lim
    dets, radii = [], []
    views = cols.map_views
    for i in idx.tolist():
        view = None if views is None else views[i]
        if view is None:
            dets.append(cols.detections[i])
            radii.append(cols.configs[i].radius if cols.detection_radii[i] is None else cols.detection_radii[i])
        else:            # the live map's occupied cells, each cell's disc grown by the clearance
            reach = float(lim.linear[i]) * float(lim.tau[i])
            centres, radius = cut_discs(view, float(cols.states[i, 0]), float(cols.states[i, 1]), reach)
            dets.append(centres)
            radii.append(radius)
            lim.mapped[i] = True
    speed, blocker, away, gap = allowed_speeds(cols.states[idx], lim.linear[idx], lim.omega[idx], lim.tau[idx], dets,
                                               radii)
    cut = speed < lim.linear[idx]
    lim.limited[idx] = cut
    lim.obstacle[idx] = blocker
    lim.gap[idx] = gap
    lim.linear[idx] = speed
    blocked = cut & (speed == 0.0) & (np.asarray(action_code)[idx] < 2)
    lim.blocked[idx] = blocked
    if blocked.any():
        stuck = idx[blocked]
        turn = blocked_turns(cols.last_sent[stuck], away[blocked])
        lim.omega[stuck] = np.asarray(cols.omega_max, dtype=float)[stuck] * turn
    return lim
