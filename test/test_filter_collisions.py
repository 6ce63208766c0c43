"""Collision counts of the filter in closed loop (ROS-free): the promise of issue 9.

No collision deeper than 1 cm with a detected obstacle, and no robot trapped for
30 s of sim time, for stale poses at a coarse step and for obstacles closer than a
turning diameter (rows, cups, random dense layouts). Each layout test also runs
the rule it replaces where that rule fails, so the count can fail.
CI-sized; bench/bench_collisions.py runs the same loops bigger.
"""
import numpy as np
import pytest

from supersafe_ros.filter.clusters.geometry import ClusterSettings, canonical, components, to_frame
from supersafe_ros.filter.clusters.store import ClusterStore
from supersafe_ros.filter import FilterConfig, RobotFilter, SafeSet, step_many
from supersafe_ros.sim.trials import (cup_layout, layout_trials, random_layout, row_layout, run_trials,
                                      single_disc_trials, speed_profiles, standard_guard)
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.sets import Disc
from supersafe_ros.reach.solver import solve_avoid

STALE = 0.073     # share of decisions on the previous step's pose, as measured in the team graph


@pytest.fixture(scope='module')
def standard():
    vf = solve_avoid(Grid((-8, -8), (8, 8), (41, 41, 24)), DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=3.0)
    return SafeSet(vf, 0.0, 'standard')


@pytest.fixture(scope='module')
def store():
    """Solved inline: the union's value is in force from the first decision (the
    background thread and its fallback are tested separately)."""
    return ClusterStore(ClusterSettings(), background=False)


def cluster_guard(safe_set, store):
    return lambda filters, t: step_many(filters, safe_set, t, store)


def test_stale_poses_at_a_coarse_step_never_collide(standard):
    """The issue's replay at a 0.2 s step: 7.3 % of decisions on the previous pose.
    Judged as if current with a fixed 0.1 s lookahead, robots crash; compensated, none."""
    encounters = single_disc_trials(150, np.random.default_rng(1))
    run = lambda cfg: run_trials(encounters, standard_guard(standard), step=0.2,  # noqa: E731
                                 stale_probability=STALE, config=cfg, rng=np.random.default_rng(2))
    before = run(FilterConfig(lookahead=0.1, compensate_delay=False))
    after = run(FilterConfig(lookahead=0.1))
    assert before.collisions > 10 and before.stale_decisions > 0
    assert after.collisions == 0 and after.trapped == 0, after.summary()
    assert 0.05 < after.stale_decisions / after.decisions < 0.1


def test_row_of_three_discs(standard, store):
    """Centres 4.5 m apart (0.9 m gaps): the smallest per-obstacle value crashes, the
    union's value does not."""
    encounters = layout_trials([row_layout(4.5)] * 80, np.random.default_rng(3))
    rule = dict(step=0.2, stale_probability=STALE, rng=np.random.default_rng(4))
    old = run_trials(encounters, standard_guard(standard), config=FilterConfig(clusters=False), **rule)
    assert old.collisions > 0
    rule['rng'] = np.random.default_rng(4)
    new = run_trials(encounters, cluster_guard(standard, store), config=FilterConfig(), **rule)
    assert new.collisions == 0 and new.trapped == 0, new.summary()


@pytest.mark.parametrize('step', [0.05, 0.2])
def test_cups_of_three_discs(standard, store, step):
    rng = np.random.default_rng(5)
    layouts = [cup_layout(rng) for _ in range(3)] * (6 if step < 0.1 else 15)
    res = run_trials(layout_trials(layouts, rng, offset=2.0), cluster_guard(standard, store),
                     step=step, stale_probability=STALE, rng=np.random.default_rng(6))
    assert res.collisions == 0 and res.trapped == 0, res.summary()


def test_random_dense_layouts(standard, store):
    rng = np.random.default_rng(7)
    layouts = [random_layout(rng, k, half=5.0, min_gap=0.3) for k in (3, 4, 5)] * 20
    res = run_trials(layout_trials(layouts, rng), cluster_guard(standard, store),
                     step=0.2, stale_probability=STALE, rng=np.random.default_rng(8))
    assert res.collisions == 0 and res.trapped == 0, res.summary()


def test_learned_set_with_clusters_keeps_the_promise(store):
    """A learned set (w = 0.5, level 0.3) per obstacle, the union at the standard level
    for the cluster: the cluster governs where it acts, no collision."""
    learned = SafeSet(solve_avoid(Grid((-8, -8), (8, 8), (41, 41, 24)), DubinsCar(3.0, 0.5),
                                  Disc(0, 0, 1.8), horizon=3.0), 0.3, 'learned')
    encounters = layout_trials([row_layout(4.5)] * 30, np.random.default_rng(9))
    res = run_trials(encounters, cluster_guard(learned, store), step=0.2, stale_probability=STALE,
                     rng=np.random.default_rng(10))
    assert res.collisions == 0 and res.trapped == 0, res.summary()


def test_loiter_fallback_alone_never_collides(standard):
    """Until a cluster's value is solved the loiter-circle fallback is in force: sound
    on its own (it may be slow to get through, so only collisions are counted)."""
    never = ClusterStore(ClusterSettings(), fallback_only=True)
    rng = np.random.default_rng(11)
    layouts = [row_layout(4.5)] * 20 + [cup_layout(rng) for _ in range(20)]
    res = run_trials(layout_trials(layouts, rng), cluster_guard(standard, never), step=0.2,
                     stale_probability=STALE, rng=np.random.default_rng(12), time_limit=15.0)
    assert res.collisions == 0, res.summary()
    assert not never.values and res.overrides > 0


def test_clusters_and_their_canonical_keys():
    row = row_layout(4.5)
    far = np.vstack([row, [[30.0, 0.0]]])
    groups = components(far, 9.6)
    assert sorted(map(len, groups)) == [1, 3]
    # the same geometry moved and turned anywhere on the map has the same key, and a
    # robot state maps to the same canonical state (an asymmetric layout: one frame)
    layout = random_layout(np.random.default_rng(0), 4, half=5.0)
    key, origin, angle, centres = canonical(layout, 0.05)
    a = 0.7
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    moved = layout[[2, 0, 3, 1]] @ rot.T + np.array([12.0, -3.0])
    key2, origin2, angle2, _ = canonical(moved, 0.05)
    assert key2 == key
    state = np.array([[1.0, 2.0, 0.3]])
    moved_state = np.hstack([state[:, :2] @ rot.T + np.array([12.0, -3.0]), state[:, 2:] + a])
    f1, f2 = to_frame(state, origin, angle), to_frame(moved_state, origin2, angle2)
    np.testing.assert_allclose(f1[:, :2], f2[:, :2], atol=1e-9)
    np.testing.assert_allclose(np.cos(f1[:, 2] - f2[:, 2]), 1.0)
    # the canonical centres are the layout's, rounded
    np.testing.assert_allclose(np.sort(to_frame(np.hstack([layout, np.zeros((4, 1))]), origin, angle)[:, 0]),
                               np.sort(centres[:, 0]), atol=0.05)
    key, *_ = canonical(row, 0.05)
    assert canonical(row * 1.1, 0.05)[0] != key


def test_background_solve_never_blocks_and_then_takes_over(standard):
    """The first decision near a new cluster uses the fallback (no wait); once solved,
    the union's value is in force, and the time from request to in force is recorded."""
    st = ClusterStore(ClusterSettings(), background=True)
    f = RobotFilter(FilterConfig())
    f.update_pose((-8.0, 0.5, 0.0), 0.0)
    f.update_detections(row_layout(4.5), 0.0)
    f.update_command(0.0, 0.0)
    out = f.step(standard, 0.0, clusters=st)
    assert out.source == 'cluster-fallback' and st.pending() == 1
    assert st.wait_idle(120.0)
    out = f.step(standard, 0.05, clusters=st)
    assert out.source == 'cluster' and len(st.latencies) == 1
    assert list(st.latencies.values())[0] > 0.0 and not st.errors


def test_a_half_written_cluster_file_is_solved_again_not_left_on_the_fallback(tmp_path, monkeypatch):
    """A cluster file cut short (a copy or a write interrupted) must not put its cluster on
    the fallback rule for good: the store solves it again. A solve that really fails is
    kept with its reason (the filter nodes log it and count it on their state topic)."""
    from supersafe_ros.filter.clusters import store as cluster_store
    monkeypatch.setenv('SUPERSAFE_CACHE', str(tmp_path))
    settings = ClusterSettings(cell=0.7, headings=16, reach=4.0)
    pair = np.array([[0.0, 0.0], [4.5, 0.0]])
    key, _, _, centres = canonical(pair, settings.key_resolution)
    first = ClusterStore(settings, background=False)
    first.request(key, centres)
    path = cluster_store.cache_path(settings, key)
    assert first.get(key) is not None and path.exists()
    path.write_bytes(path.read_bytes()[:300])
    second = ClusterStore(settings, background=False)
    second.request(key, centres)
    assert second.errors == {}
    assert second.get(key) is not None and second.get(key).solve_time > 0.0     # solved, not read
    np.testing.assert_allclose(second.get(key).vf.values, first.get(key).vf.values)

    def broken(*args):
        raise RuntimeError('solver broke')
    monkeypatch.setattr(cluster_store, 'solve_cluster', broken)
    third = ClusterStore(settings, background=False)
    other, _, _, other_centres = canonical(pair * 1.2, settings.key_resolution)
    third.request(other, other_centres)
    assert third.get(other) is None and not third.solving(other)
    assert 'solver broke' in third.errors[other]


def test_the_disk_cache_of_cluster_values_stays_within_its_bound(tmp_path, monkeypatch):
    """Every new detection pattern adds a cluster file; the folder keeps the most recently
    used ones within $SUPERSAFE_CLUSTER_CACHE_MB (a read counts as a use), and a pruned
    cluster is simply solved again."""
    import os
    from supersafe_ros.filter.clusters.store import cache_path, prune_disk_cache
    monkeypatch.setenv('SUPERSAFE_CACHE', str(tmp_path))
    settings = ClusterSettings(cell=0.7, headings=16, reach=4.0)
    keys = []
    for gap in (4.0, 4.5, 5.0):
        key, _, _, centres = canonical(np.array([[0.0, 0.0], [gap, 0.0]]), settings.key_resolution)
        ClusterStore(settings, background=False).request(key, centres)
        keys.append((key, centres, cache_path(settings, key)))
    sizes = [p.stat().st_size for _, _, p in keys]
    for k, (_, _, p) in enumerate(keys):          # oldest first: 4.0, 4.5, 5.0
        os.utime(p, (1000.0 + k, 1000.0 + k))
    # a read of the oldest makes it the most recent
    reader = ClusterStore(settings, background=False)
    reader.request(keys[0][0], keys[0][1])
    assert reader.get(keys[0][0]).solve_time == 0.0          # read, not solved
    # room for two files: the least recently used (4.5) goes
    limit = sizes[0] + sizes[2] + 10
    assert prune_disk_cache(keys[0][2].parent, limit) == 1
    assert [p.exists() for _, _, p in keys] == [True, False, True]
    # the store prunes by itself at its first write: a bound of 0 leaves only what it
    # writes after that check... and nothing of the old files
    monkeypatch.setenv('SUPERSAFE_CLUSTER_CACHE_MB', '0')
    writer = ClusterStore(settings, background=False)
    key, _, _, centres = canonical(np.array([[0.0, 0.0], [5.5, 0.0]]), settings.key_resolution)
    writer.request(key, centres)
    assert writer.get(key) is not None and not writer.errors
    assert list(keys[0][2].parent.glob('cluster-*.npz')) == []
    # pruned values are solved again
    again = ClusterStore(settings, background=False)
    again.request(keys[1][0], keys[1][1])
    assert again.get(keys[1][0]).solve_time > 0.0


# the cup that a robot entered 9.8 cm deep at the team's step (0.05 s, look-ahead 0.1 s): the
# cluster value's two bang ends after a 0.1 s hold lay within one heading cell of its grid and
# read alike (a tie, turned left into the cup); the avoid turn's bangs are now held at least
# ClusterSettings.turn_hold (bench/bench_onset.py: trial 785 of its cups row)
CUP_ENTERED = (np.array([[3.14090601, 0.0], [-3.14090601, 3.48206514], [-3.14090601, -3.48206514]]),
               (-16.425712329916696, 2.0184082641057812, 0.1470473272338894), (17.408509021600732, 2.652614331936953),
               (0.9785741250204102, -0.20589483199084582))


def test_a_cluster_turn_is_chosen_over_a_hold_its_grid_resolves(monkeypatch):
    from supersafe_ros.sim.trials import CollisionTrial
    from supersafe_ros.reach.library import load_or_solve
    standard = SafeSet(load_or_solve(Grid((-8, -8), (8, 8), (65, 65, 42)), 3.0, 1.0, 1.8, 3.0), 0.0)
    trial = CollisionTrial(*CUP_ENTERED)
    lockstep = FilterConfig(control_period=0.05, lookahead=0.1)
    store = ClusterStore(ClusterSettings(disk_cache=False), background=False)
    after = run_trials([trial], cluster_guard(standard, store), step=0.05, config=lockstep)
    assert after.collisions == 0 and after.trapped == 0, after.summary()
    assert ClusterSettings().turn_hold == pytest.approx(2 * np.pi / 32)
    # the turn read over the look-ahead's own hold, as before: the robot enters the cup
    monkeypatch.setattr(ClusterSettings, 'turn_hold', property(lambda self: 0.0))
    store = ClusterStore(ClusterSettings(disk_cache=False), background=False)
    before = run_trials([trial], cluster_guard(standard, store), step=0.05, config=lockstep)
    assert before.collisions == 1 and before.max_depth > 0.05


@pytest.mark.parametrize('layout', ['row', 'cup', 'random'])
def test_the_lockstep_look_ahead_of_one_study_step_never_collides(standard, store, layout):
    """The study's step (0.2 s) with the lockstep team's look-ahead: one step (max(0.1 s, the
    step)), no stale pose, no late reply. Robots override closer to the level (V - alpha
    at onset: bench/bench_onset.py) and still never enter a detected disc."""
    rng = np.random.default_rng(21)
    lays = {'row': [row_layout(4.5)] * 60, 'cup': [cup_layout(rng) for _ in range(60)],
            'random': [random_layout(rng, int(rng.integers(3, 7)), half=6.0, min_gap=0.3) for _ in range(60)]}[layout]
    config = FilterConfig(control_period=0.2, lookahead=0.1)
    assert RobotFilter(config).lookahead() == 0.2
    r = run_trials(layout_trials(lays, np.random.default_rng(22)), cluster_guard(standard, store), step=0.2,
                   config=config, rng=np.random.default_rng(23))
    assert r.collisions == 0 and r.trapped == 0, r.summary()
    assert r.overrides > 0


@pytest.mark.parametrize('step', [0.05, 0.2])
def test_planners_that_slow_stop_wait_and_speed_up_never_collide(standard, store, step):
    """The value functions are solved at the largest speed; planners that slow, stop and wait,
    and speed up again (speed_profiles), at both step sizes of the trials and with stale
    poses: no collision with a detected obstacle (single discs, rows, cups and dense layouts,
    clusters by their union's value), and no robot sent faster than its planner asked."""
    rng = np.random.default_rng(31)
    n = 8 if step < 0.1 else 14
    layouts = ([np.zeros((1, 2))] * n + [row_layout(4.5)] * n + [cup_layout(rng) for _ in range(n)]
               + [random_layout(rng, 4, half=5.0, min_gap=0.3) for _ in range(n)])
    encounters = layout_trials(layouts, rng)
    speeds = speed_profiles(np.random.default_rng(32), len(encounters))
    res = run_trials(encounters, cluster_guard(standard, store), step=step, stale_probability=STALE,
                     rng=np.random.default_rng(33), speeds=speeds, time_limit=40.0)
    assert res.collisions == 0, res.summary()
    assert res.max_speed_excess == 0.0 and res.overrides > 0
