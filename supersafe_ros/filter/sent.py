"""What the filter sent, and what the robot did under it since: the one writer of a robot's
``sent`` commands, ``overriding`` flag and a decision's caches (``record``, ``record_decisions``:
the last step of every decision), and
the one reader that turns them into the arcs the robot held (``segments_since``).

A command sent at ts holds until the next one; each is remembered with the speed the robot
drives under it (the linear.x sent, a constant-speed robot's speed), ``sent_kept`` seconds
of them (the oldest one before that window stays: it is the command held at its start).
"""
from __future__ import annotations

from .commands import clip, idle_speed, planned_speed


def record(filters, decisions, t, keep) -> None:
    """The decision at ``t`` written into each robot's filter: ``overriding``, and the command
    sent with the speed the robot drives under it; commands older than ``keep`` (each robot's
    ``config.sent_kept``, a column) forgotten but the one held at ``t - keep``. One loop over
    the fleet (a method call and its configuration lookups per robot cost more than the work)."""
    ts = float(t)
    for f, w, o, cut, v in zip(filters, decisions.omega, decisions.overriding, (t - keep).tolist(),
                               decisions.driven):
        f.overriding = o  # failing safe clears it: re-enter by the law once inputs are back
        sent = f.sent
        sent.append((ts, w, v))
        while len(sent) > 1 and sent[1][0] <= cut:
            sent.popleft()


def record_decisions(filters, decisions) -> None:
    """``record`` of ``decisions`` (``decide.decide_many``'s), at their time: what went out, and the
    caches the decision filled (``decisions.derived``, ``filter.derived``) put into the filters."""
    record(filters, decisions, decisions.t, decisions.keep)
    if decisions.derived is not None:
        decisions.derived.apply(filters)


def record_sent(f, omega, t, speed=None) -> None:
    """``record`` of one command sent by other means than a decision (a test's, a replay's):
    ``omega`` at ``t``, the robot driving at ``speed`` (None: the configured speed)."""
    cfg = f.config
    f.sent.append((float(t), float(omega), float(cfg.speed if speed is None else speed)))
    while len(f.sent) > 1 and f.sent[1][0] <= t - cfg.sent_kept:
        f.sent.popleft()


def segments_since(f, t0, t1):
    """[(turn rate, duration, speed)] the robot held from ``t0`` to ``t1``, by the commands
    sent.

    A command counts from the time it was sent until the next one. Before the first
    command remembered: the planner's current command (clipped, ``commands.planned_speed``),
    else a turn of 0 at the speed of a robot never commanded (``commands.idle_speed``).
    """
    if t1 <= t0:
        return []
    sent = f.sent
    # the two common cases first: nothing sent since t0 (one arc), or one command sent since
    # (a robot deciding on a pose older than its last decision); the walk below gives the same
    if sent and sent[-1][0] <= t0:
        return [(sent[-1][1], t1 - t0, sent[-1][2])]
    if len(sent) > 1 and sent[-2][0] <= t0 < sent[-1][0] < t1:
        ts = sent[-1][0]
        return [(sent[-2][1], ts - t0, sent[-2][2]), (sent[-1][1], t1 - ts, sent[-1][2])]
    cfg = f.config
    if f.command.value is not None:
        before = (clip(f.command.value, cfg.omega_max), planned_speed(f.command.linear, cfg))
    else:
        before = (0.0, idle_speed(cfg))
    inside = []      # commands sent in (t0, t1), newest first
    current = before
    for ts, omega, speed in reversed(sent):
        if ts >= t1:
            continue
        if ts <= t0:
            current = (omega, speed)
            break
        inside.append((ts, (omega, speed)))
    segments, start = [], t0
    for ts, command in reversed(inside):
        segments.append((current[0], ts - start, current[1]))
        start, current = ts, command
    segments.append((current[0], t1 - start, current[1]))
    return segments
