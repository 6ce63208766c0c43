"""Collision counts on the decision path for many detections (issue 22), ROS-free.

Beyond 64 detections a robot judges only those within its reach (``filter.constraints.nearby``), and a
cluster of more than ``store.SOLVE_MEMBERS_MAX`` obstacles is never solved: the loiter
fallback and the per-obstacle rows judge it. The loops of test_filter_collisions.py
(0.2 s step, 7.3 % of decisions on the previous pose) count entries deeper than 1 cm:

* rows and cups with 1,000 far detections in each robot's array: none, none trapped;
* walls of 40 and 100 detections 0.5 m apart (too large to solve; the 100 through the index):
  none, where the per-obstacle rule alone (clusters off) enters them.
"""
import math

import numpy as np
import pytest

from supersafe_ros.filter import FilterConfig, SafeSet, step_many
from supersafe_ros.filter.clusters.geometry import ClusterSettings
from supersafe_ros.filter.clusters.store import ClusterStore
from supersafe_ros.sim.trials import CollisionTrial, cup_layout, layout_trials, row_layout, run_trials
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.sets import Disc
from supersafe_ros.reach.solver import solve_avoid

STALE = 0.073     # share of decisions on the previous step's pose, as measured in the team graph


@pytest.fixture(scope='module')
def standard():
    vf = solve_avoid(Grid((-8, -8), (8, 8), (41, 41, 24)), DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=3.0)
    return SafeSet(vf, 0.0, 'standard')


def guard(safe_set, store):
    return lambda filters, t: step_many(filters, safe_set, t, store)


def with_clutter(trials, rng, n=1000):
    """Each trial's discs with ``n`` detections 80 m to 2 km from its layout appended (never
    reached in a trial's 30 s: its array is judged through the index)."""
    out = []
    for e in trials:
        phi, r = rng.uniform(-math.pi, math.pi, n), rng.uniform(80.0, 2000.0, n)
        clutter = np.column_stack([r * np.cos(phi), r * np.sin(phi)])
        out.append(CollisionTrial(np.concatenate([e.discs, clutter]), e.start, e.goal, e.direction))
    return out


def test_rows_and_cups_among_far_clutter_never_collide(standard):
    rng = np.random.default_rng(21)
    layouts = [row_layout(4.5)] * 20 + [cup_layout(rng) for _ in range(3)] * 7
    trials = with_clutter(layout_trials(layouts, rng, offset=2.0), rng)
    assert min(len(e.discs) for e in trials) > 1000
    res = run_trials(trials, guard(standard, ClusterStore(ClusterSettings(), background=False)), step=0.2,
                     stale_probability=STALE, rng=np.random.default_rng(22))
    assert res.collisions == 0 and res.trapped == 0, res.summary()
    assert res.overrides > 0


@pytest.mark.parametrize('count', [40, 100])
def test_walls_too_large_to_solve_never_collide(standard, count):
    """A wall of ``count`` detections 0.5 m apart, met from either side at random angles: the
    loiter fallback keeps every robot out (it may hold robots back: only collisions count)."""
    wall = np.column_stack([np.zeros(count), 0.5 * (np.arange(count) - (count - 1) / 2)])
    rng = np.random.default_rng(23 + count)
    trials = layout_trials([wall] * 30, rng, offset=0.25 * count)
    rule = dict(step=0.2, stale_probability=STALE, time_limit=15.0)
    never = ClusterStore(ClusterSettings(), background=False)
    res = run_trials(trials, guard(standard, never), rng=np.random.default_rng(24), **rule)
    assert res.collisions == 0, res.summary()
    assert not never.requested and not never.values and res.overrides > 0
    old = run_trials(trials, guard(standard, never), rng=np.random.default_rng(24),
                     config=FilterConfig(clusters=False), **rule)
    assert old.collisions > 0, old.summary()
