"""The supervisor models' rules on hand-made approaches (sim.supervisor_models via sim.watcher).

Every approach is a Dubins path built here (poses 0.1 s apart at 3 m/s) toward a disc of
radius 1.8 at the origin, judged by a supervisor believing w_max 0.5 with mu 0.8 and no
noise, so the memoryless rule's alarm frame is known and each case asks only what the
robot's motion changes.
"""
import math

import numpy as np
import pytest

from supersafe_ros.learning.phase2_stream import phase2_events
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.library import load_or_solve
from supersafe_ros.sim.supervisor_models import (MODELS, AttentiveParams, check_model,
                                                 heading_off_line_of_sight, time_to_disc)
from supersafe_ros.sim.watcher import Watcher

DT, SPEED, MU = 0.1, 3.0, 0.8


@pytest.fixture(scope='module')
def vf():
    return load_or_solve(Grid((-8.0, -8.0), (8.0, 8.0), (41, 41, 24)), SPEED, 0.5, 1.8, 2.0)


def path(y0, turn_rates, x0=-8.0):
    """Poses (t, (x, y, theta)) from (x0, y0) heading +x, one per DT, turning at each rate."""
    x, y, th = x0, float(y0), 0.0
    out = [(0.0, (x, y, th))]
    for k, w in enumerate(turn_rates):
        th += w * DT
        x += SPEED * DT * math.cos(th)
        y += SPEED * DT * math.sin(th)
        out.append(((k + 1) * DT, (x, y, th)))
    return out


def judge(vf, model, poses, obstacles=((0.0, 0.0),)):
    """(the first decision or None, the watcher) of one robot's poses."""
    w = Watcher(vf, mu=MU, sigma=0.0, seed=1, model=model)
    ids, xy = list(range(len(obstacles))), np.array(obstacles, dtype=float)
    for t, s in poses:
        d = w.judge('robot_0', s, t, ids, xy)
        if d is not None:
            return d, w
    return None, w


def test_a_robot_that_keeps_straight_into_the_obstacle_meets_the_same_intervention(vf):
    poses = path(0.3, [0.0] * 60)
    got = {m: judge(vf, m, poses)[0] for m in MODELS}
    assert got['memoryless'] is not None
    for m in MODELS:
        assert got[m].time == pytest.approx(got['memoryless'].time)
        np.testing.assert_allclose(got[m].rel_state, got['memoryless'].rel_state)
        assert got[m].value == pytest.approx(MU, abs=1e-6)        # at the crossing of its level


def test_a_robot_that_turns_away_convinces_the_attentive_supervisor(vf):
    # straight for 0.3 s, then a steady turn away (left, the side it passes on) at 0.3 rad/s
    poses = path(0.3, [0.0] * 3 + [0.3] * 57)
    paper, _ = judge(vf, 'memoryless', poses)
    assert paper is not None                   # the paper's supervisor intervenes all the same
    turned = float(paper.rel_state[2])
    assert turned >= AttentiveParams().convince_angle      # after the robot turned 0.3 rad
    attentive, w = judge(vf, 'attentive', poses)
    assert attentive is None
    assert w.withheld > 0                      # its alarm was on, and it held back
    # the same supervisor watching a robot that turned the other way (toward the
    # obstacle's side first) is not convinced by that turn
    toward = path(-0.3, [0.0] * 3 + [0.3] * 57)
    assert judge(vf, 'attentive', toward)[0] is not None


def test_a_turn_meant_for_another_obstacle_does_not_count_for_this_one(vf):
    # robot_0 swerves left, away from obstacle B (below, the more pressing one), then turns
    # back and drives on straight into A's disc
    a, b = (0.0, 0.0), (-5.5, -3.5)
    poses = path(-0.3, [0.0] * 4 + [1.0] * 5 + [-1.0] * 5 + [0.0] * 60)
    paper, _ = judge(vf, 'memoryless', poses, (a, b))
    attentive, _ = judge(vf, 'attentive', poses, (a, b))
    assert paper is not None and paper.obstacle_id == 0
    assert attentive is not None and attentive.obstacle_id == 0
    assert attentive.time == pytest.approx(paper.time)          # not held back by B's swerve
    np.testing.assert_allclose(attentive.rel_state, paper.rel_state)
    # without B the same swerve is A's: it convinces, and only the doubt (the robot heading
    # back into A) brings the intervention, later
    alone, _ = judge(vf, 'attentive', poses, (a,))
    assert alone is not None and alone.time > paper.time + DT


def test_a_convinced_supervisor_doubts_a_robot_that_turns_back_into_the_obstacle(vf):
    # a clear turn away (0.6 rad), then back toward the disc and straight into it
    poses = path(0.3, [0.0] * 3 + [1.0] * 6 + [-1.5] * 6 + [0.0] * 60)
    paper, _ = judge(vf, 'memoryless', poses)
    attentive, w = judge(vf, 'attentive', poses)
    assert attentive is not None and attentive.obstacle_id == 0
    assert attentive.time >= paper.time
    # caught before the disc: at most doubt_horizon (0.5 s) from it on its straight course
    p = AttentiveParams()
    assert 0.0 < time_to_disc(attentive.rel_state, p.radius, p.speed) <= p.doubt_horizon + DT
    assert math.hypot(*attentive.rel_state[:2]) > 1.8


def test_phase2_straight_passes_are_the_same_under_every_model(vf):
    offsets = [-2.0, -1.0, 0.0, 0.5, 1.5]
    streams = {}
    for m in MODELS:
        w = Watcher(vf, mu=0.3, sigma=0.4, seed=3, model=m)
        streams[m] = [(e[0], e[1], e[2]) + tuple(np.round(np.asarray(e[3], dtype=float), 12).ravel())
                      for e in phase2_events(w, offsets, dt=0.2)]
    assert any(e[0] == 'intervention' for e in streams['memoryless'])
    for m in MODELS:
        assert streams[m] == streams['memoryless']


def test_geometry_and_bad_input():
    # heading straight at the centre from 5 m: 3.2 m to the rim at 3 m/s
    assert time_to_disc((-5.0, 0.0, 0.0), 1.8, 3.0) == pytest.approx(3.2 / 3.0)
    assert time_to_disc((-5.0, 2.0, 0.0), 1.8, 3.0) == math.inf       # passes beside it
    assert time_to_disc((-5.0, 0.0, math.pi), 1.8, 3.0) == math.inf   # moving away
    assert time_to_disc((1.0, 0.0, 0.0), 1.8, 3.0) == 0.0             # inside
    assert heading_off_line_of_sight((-5.0, 0.0, 0.2)) == pytest.approx(0.2)
    with pytest.raises(ValueError, match='memoryless'):
        check_model('telepathic')
    with pytest.raises(ValueError):
        Watcher(load_or_solve(Grid((-8.0, -8.0), (8.0, 8.0), (41, 41, 24)), SPEED, 0.5, 1.8, 2.0),
                model='telepathic')
    with pytest.raises(ValueError):
        AttentiveParams(doubt_horizon=float('nan'))
