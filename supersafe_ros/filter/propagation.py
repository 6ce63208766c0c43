"""Delay compensation: where a robot is now, given its pose and the commands it was sent.

A pose describes the robot at its stamp, not at the decision: in a lockstep graph the
filter may decide at step k on the pose of step k-1, and a real robot's pose is some
milliseconds old. The filter knows what the robot did since: it sent the commands, each
with the speed the robot drives under it (``sent.record``: the linear.x sent,
or a constant-speed robot's speed). So it propagates the pose over its age (decision time -
stamp, at most ``hold_timeout``) along exact Dubins arcs under the commands it sent, each at
its own speed (``plan``, ``follow``), and judges the robot's state *now*. The same arcs give
the lookahead's holds (``bang_ends``).

Dubins arc of turn rate w held for dt from (x, y, th), speed v:

    th1 = th + w dt
    x1  = x + v (sin th1 - sin th) / w,    y1 = y + v (cos th - cos th1) / w    (w dt != 0)
    x1  = x + v cos th dt,                 y1 = y + v sin th dt                  (straight)

``arc_flow`` over arrays; ``arc`` and ``wrap`` the same operations on Python floats
(the same bits: a robot's own filter decides without numpy's per-call cost, about 40 us less a
decision). ``plan`` is one robot's age and arcs, ``plan_columns`` a fleet's, with the same
comparisons and arithmetic (test/test_filter_vectorised.py compares a fleet's states with each
robot's own).
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from ..reach.grid import TWO_PI, wrap_angle
from .elementwise import py_max, py_min
from .sent import segments_since

# the (time, turn, speed) a robot with no such command sent shows: no arc starts then
NEVER_SENT = (math.inf, 0.0, 0.0)


def arc_flow(states, speed, omega, dt) -> np.ndarray:
    """Exact Dubins arcs for arrays of states (N, 3), speeds, turn rates and durations (N,)."""
    s = np.asarray(states, dtype=float)
    x, y, th = s[:, 0], s[:, 1], s[:, 2]
    th1 = th + omega * dt
    turning = np.abs(omega * dt) > 1e-9
    safe = np.where(turning, omega, 1.0)
    c0, s0 = np.cos(th), np.sin(th)      # both branches use them: computed once
    ax = np.where(turning, (np.sin(th1) - s0) / safe, c0 * dt)
    ay = np.where(turning, (c0 - np.cos(th1)) / safe, s0 * dt)
    return np.stack([x + speed * ax, y + speed * ay, wrap_angle(th1)], axis=1)


def bang_ends(states, speed, bang, hold) -> np.ndarray:
    """Where holding +bang, then -bang, for ``hold`` from ``states`` (k, 3) ends: (2k, 3), the
    left turns' ends first."""
    return arc_flow(np.concatenate([states, states]), np.tile(speed, 2), np.concatenate([bang, -bang]),
                    np.tile(hold, 2))


def follow(states, omegas, dts, speeds) -> np.ndarray:
    """``states`` (N, 3) moved along their robots' plans: arc k of robot i holds ``omegas[k, i]``
    for ``dts[k, i]`` at ``speeds[k, i]`` (``gather``'s arcs; shorter plans padded with
    zero-length arcs, which only wrap theta); with no arcs at all, theta wrapped all the same
    (a robot's state does not depend on the other robots' plans)."""
    if len(omegas) == 0:
        states[:, 2] = wrap_angle(states[:, 2])
        return states
    for omega, dt, speed in zip(omegas, dts, speeds):
        states = arc_flow(states, speed, omega, dt)
    return states


def arc(x, y, th, speed, omega, dt):
    """``arc_flow`` of one state, in Python floats (the same operations, the same bits)."""
    th1 = th + omega * dt
    if abs(omega * dt) > 1e-9:
        ax = (math.sin(th1) - math.sin(th)) / omega
        ay = (math.cos(th) - math.cos(th1)) / omega
    else:
        ax, ay = math.cos(th) * dt, math.sin(th) * dt
    return x + speed * ax, y + speed * ay, wrap(th1)


def wrap(theta):
    """``wrap_angle`` of one angle, in Python floats (the same operations, the same bits)."""
    return (theta + math.pi) % TWO_PI - math.pi


def plan(f, t):
    """(pose age, [(turn rate, duration, speed)] held from the pose's stamp to ``t``) of one
    robot (``sent.segments_since``); (0, ()) without delay compensation."""
    if not f.config.compensate_delay:
        return 0.0, ()
    pose = f.pose
    age = max(0.0, min(t - min(pose.t, pose.stamp), f.config.hold_timeout))
    return age, segments_since(f, t - age, t)


def plan_columns(filters, t, pose_t, stamp, compensate, hold):
    """``plan`` of every robot of ``filters`` over columns (``pose_t``, ``stamp``: their poses'
    arrival and stamp times; ``compensate``, ``hold``: their configurations'): (ages (m,), the last
    command sent (m, 3: time, turn, speed; ``NEVER_SENT`` if none), and the arcs as ``follow`` takes them:
    omegas, dts, speeds (depth, m)). The two common cases over columns (nothing sent since the
    pose: one arc; one command sent since: two), ``sent.segments_since`` itself for the others
    (a pose older than two commands sent)."""
    m = len(filters)
    age = t - np.where(stamp < pose_t, stamp, pose_t)
    age = np.where(compensate, py_max(0.0, py_min(age, hold)), 0.0)
    t0 = t - age
    sents = [f.sent for f in filters]
    last = np.fromiter(itertools.chain.from_iterable(s[-1] if s else NEVER_SENT for s in sents), dtype=float,
                       count=3 * m).reshape(m, 3)
    moving = compensate & (t > t0)
    one = moving & (last[:, 0] <= t0)                        # nothing sent since the pose: one arc
    # the command before the last, read only for the robots that may need it (most need none)
    others = np.flatnonzero(moving & ~one)
    prev = np.zeros((m, 3))
    prev[others] = np.fromiter(itertools.chain.from_iterable(
        sents[i][-2] if len(sents[i]) > 1 else NEVER_SENT for i in others.tolist()), dtype=float,
        count=3 * len(others)).reshape(-1, 3)
    two = moving & ~one & (prev[:, 0] <= t0) & (t0 < last[:, 0]) & (last[:, 0] < t)   # one command since
    rest = np.flatnonzero(moving & ~one & ~two).tolist()
    plans = [segments_since(filters[i], float(t0[i]), t) for i in rest]
    depth = max([len(p) for p in plans] + [2 if two.any() else 1 if one.any() else 0])
    omegas, dts, speeds = np.zeros((depth, m)), np.zeros((depth, m)), np.zeros((depth, m))
    if depth:
        omegas[0, one], dts[0, one], speeds[0, one] = last[one, 1], t - t0[one], last[one, 2]
        omegas[0, two], dts[0, two], speeds[0, two] = prev[two, 1], last[two, 0] - t0[two], prev[two, 2]
    if depth > 1:
        omegas[1, two], dts[1, two], speeds[1, two] = last[two, 1], t - last[two, 0], last[two, 2]
    for i, arcs in zip(rest, plans):
        for k, (w, d, v) in enumerate(arcs):
            omegas[k, i], dts[k, i], speeds[k, i] = w, d, v
    return age, last, omegas, dts, speeds
