"""The study's Phase II as the learner sees it on topics: a stream of events, and its feeder.

``phase2_events`` plays the conductor's scenes (study/conductor.py) judged by a simulated
supervisor (``sim.watcher.Watcher``) as the events the learner node receives: stamped
obstacle sets, robot poses and interventions; ``feed`` applies such a stream to an
``encounters.EncounterBuilder``.
"""
from __future__ import annotations

import numpy as np


# -- a Phase II session as the learner sees it on topics ---------------------------------
def phase2_events(watcher, offsets, *, speed=3.0, dt=0.05, x0=-8.0, x_end=2.5, robot='robot_0',
                  first_obstacle=1, t0=1.0, park=(-30.0, 0.0)):
    """The event stream of the study's Phase II scenes (study/conductor.py) judged by a
    simulated supervisor (``sim.watcher.Watcher``, the supervisor node's own rule).

    Per offset y0: the obstacle set becomes one disc at the origin with a new id; the
    robot appears at (x0, y0) heading 0 and drives straight at ``speed``, a pose every
    ``dt``, until the supervisor intervenes (the world then removes the obstacle) or the
    robot is past x_end; then the set is emptied and the robot is parked far away (a jump).
    Yields ('obstacles', stamp, ids, xy), ('pose', robot, stamp, (x, y, theta)) and
    ('intervention', obstacle_id, stamp, rel_state), in publication order.
    """
    t = float(t0)
    oid = int(first_obstacle)
    empty = np.zeros((0, 2))
    yield ('pose', robot, t, (park[0], park[1], 0.0))
    for y0 in offsets:
        t += dt
        yield ('obstacles', t, [oid], np.zeros((1, 2)))
        watcher.obstacles_changed([oid])
        x = x0
        while True:
            t += dt
            state = (x, float(y0), 0.0)
            yield ('pose', robot, t, state)
            decision = watcher.judge(robot, state, t, [oid], np.zeros((1, 2)))
            if decision is not None:
                yield ('intervention', oid, decision.time, tuple(decision.rel_state))
                break
            if x > x_end:
                break
            x += speed * dt
        t += dt
        yield ('obstacles', t, [], empty)
        watcher.obstacles_changed([])
        t += dt
        yield ('pose', robot, t, (park[0], park[1], 0.0))
        watcher.judge(robot, (park[0], park[1], 0.0), t, [], empty)
        oid += 1


def feed(builder, events) -> int:
    """Apply an event stream (``phase2_events``) to ``builder`` (an ``encounters.EncounterBuilder``);
    returns the interventions fed."""
    n = 0
    for ev in events:
        if ev[0] == 'pose':
            builder.pose(ev[1], ev[2], ev[3])
        elif ev[0] == 'obstacles':
            builder.set_obstacles(ev[2], ev[3], ev[1])
        else:
            builder.intervention(ev[1], ev[2], ev[3])
            n += 1
    return n
