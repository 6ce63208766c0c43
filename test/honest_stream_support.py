"""A Phase II session as a foreign but honest publisher sends it (issue 21): the stream the
learner must read back into the hidden supervisor.

Scenes: one disc at the origin per scene, a new obstacle id each, the robot driving
straight from (-8, y0) heading 0 at 3 m/s; offsets the session's 42 in [-2.25, 2.25], three
times over (126 scenes). Stamps on a sim clock consistent with the speed: a pose every
0.05 s (20 Hz); each obstacle set stamped when it takes effect. A hidden supervisor
(``W, MU, SIGMA``: V_S the library entry of turn rate W, one noise draw per scene) judges
each pose and intervenes at the first with V_S <= MU + w: the intervention is stamped 1 ms
after that pose and carries its state; the obstacle is cleared 10 ms after the
intervention (10 ms after the last pose of a pass without one); 1 s later the robot is
parked (teleported) at the next scene's start, with that scene's obstacle set.
"""
import numpy as np

W, MU, SIGMA = 0.5, 1.0, 0.3
RATE = 20.0
SPEED = 3.0
OFFSETS = np.linspace(-2.25, 2.25, 42)
REPEATS = 3


def honest_stream(vf_s, mu=MU, sigma=SIGMA, seed=0, repeats=REPEATS, robot='robot_0', first_obstacle=0,
                  t0=1.0):
    """(events in publication order, the hidden thresholds mu + w per scene). Events:
    ('pose', robot, stamp, state), ('obstacles', stamp, ids, xy), ('intervention', id, stamp, state)."""
    rng = np.random.default_rng(seed)
    events, thresholds = [], []
    t, oid, empty = float(t0), int(first_obstacle), np.zeros((0, 2))
    for _ in range(repeats):
        for y0 in OFFSETS:
            events.append(('obstacles', t, [oid], np.zeros((1, 2))))
            threshold = mu + sigma * float(rng.standard_normal())
            thresholds.append(threshold)
            j = 0
            while True:
                stamp = t + j / RATE
                state = (-8.0 + SPEED * j / RATE, float(y0), 0.0)
                events.append(('pose', robot, stamp, state))
                if float(vf_s.value(np.array([state]))[0]) <= threshold:
                    events.append(('intervention', oid, stamp + 0.001, state))
                    events.append(('obstacles', stamp + 0.011, [], empty))
                    break
                if state[0] > 2.5:
                    events.append(('obstacles', stamp + 0.010, [], empty))
                    break
                j += 1
            t, oid = stamp + 1.0, oid + 1
    return events, thresholds


def event_stamp(ev):
    return ev[2] if ev[0] in ('pose', 'intervention') else ev[1]


def shuffled_across_topics(events, seed=0, max_delay=0.5):
    """The same events in an arrival order where each topic keeps its own order (DDS orders
    within a topic) but the topics interleave by independent delays up to ``max_delay``
    seconds of stamp time."""
    rng = np.random.default_rng(seed)
    arrivals, last = [], {}
    for k, ev in enumerate(events):
        topic = ev[0]
        a = max(event_stamp(ev) + float(rng.uniform(0, max_delay)), last.get(topic, -np.inf))
        last[topic] = a
        arrivals.append((a, k))
    return [events[k] for _, k in sorted(arrivals)]
