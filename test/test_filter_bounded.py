"""Bounded work on any detections message (issue 22), ROS-free.

* clustering is near-linear and exact: ``geometry.components`` equals a union-find over all
  pairs on small random sets (duplicates, pairs exactly at the link distance) and labels
  100,000 centres as an independent sweep does; the spatial index's cluster search
  (``nearby.DetectionIndex``) finds the same clusters, or marks those too large to solve;
* far detections change nothing: with 1,000 / 10,000 / 100,000 detections far away, every
  decision (command, action, reason, named obstacle, V, level, source, clusters solving)
  over several closed-loop ticks equals the decision on the near detections alone, for a
  robot's own filter and for a fleet sharing one array or given arrays of its own;
* a message beyond ``max_detections`` keeps the nearest, and says what was dropped and
  whether that was safe;
* a planner command beyond the robot's limits is clipped and said (the raw value), alone
  and batched.

Collision counts of the decision path for many detections: test_filter_bounded_collisions.py.
"""
import math
import re

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from supersafe_ros.filter import FilterConfig, RobotFilter, SafeSet, step_many, update_commands, update_detections_all
from supersafe_ros.filter.clusters.geometry import ClusterSettings, components
from supersafe_ros.filter.clusters.store import SOLVE_MEMBERS_MAX, ClusterStore
from supersafe_ros.filter.constraints.nearby import NEAR_QUERY_MIN, OVERSIZE, DetectionIndex, judged_radius
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.sets import Disc
from supersafe_ros.reach.solver import solve_avoid

LINK = 9.6
# near the origin: a cluster of five (a pair 4.5 m apart, a duplicate: ties in the min), and a
# chain 8 m apart from 9.7 m out to 74 m (a cluster reaching far beyond the robots' radius:
# judged whole); robots west of the origin (POSES) have every one within their radius
NEAR = np.concatenate([[[0.0, 0.0], [4.5, 0.0], [1.0, 5.0], [1.0, 5.0], [3.0, -4.0]],
                       np.column_stack([-9.7 - 8.0 * np.arange(9), np.zeros(9)])])
POSES = ((-4.0, -1.0), (-3.0, 3.0))       # x, y ranges


@pytest.fixture(scope='module')
def standard():
    vf = solve_avoid(Grid((-8, -8), (8, 8), (41, 41, 24)), DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=3.0)
    return SafeSet(vf, 0.0, 'standard')


class PendingStore(ClusterStore):
    """Requests are kept but never solved: the fallback stays in force, robots count the
    clusters being solved, and ``requested`` shows which were asked for."""

    def request(self, key, centres):
        with self._lock:
            if key not in self.values:
                self.requested.setdefault(key, 0.0)


def all_pairs_groups(c, link):
    """Union-find over the all-pairs distance matrix (the implementation before issue 22)."""
    n = len(c)
    parent = list(range(n))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i
    d = np.hypot(c[:, None, 0] - c[None, :, 0], c[:, None, 1] - c[None, :, 1])
    for i, j in zip(*np.nonzero(np.triu(d <= link, 1))):
        parent[find(i)] = find(j)
    groups = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    return [list(g) for g in groups.values()]


def sweep_labels(c, link):
    """Cluster labels by an x-sorted sweep (no tree): the pairs within ``link`` in x, then by hypot."""
    order = np.argsort(c[:, 0], kind='stable')
    x = c[order, 0]
    src, dst = [], []
    end = np.searchsorted(x, x + link, side='right')
    for k in range(1, int((end - np.arange(len(x))).max())):
        i = np.flatnonzero(np.arange(len(x)) + k < end)
        a, b = order[i], order[i + k]
        close = np.hypot(c[a, 0] - c[b, 0], c[a, 1] - c[b, 1]) <= link
        src.append(a[close])
        dst.append(b[close])
    src, dst = np.concatenate(src), np.concatenate(dst)
    _, label = connected_components(coo_matrix((np.ones(len(src)), (src, dst)), shape=(len(c), len(c))),
                                    directed=False)
    return label


def test_components_equal_the_all_pairs_union_on_small_random_sets():
    rng = np.random.default_rng(0)
    for trial in range(300):
        n = int(rng.integers(0, 160))
        half = float(rng.choice([4.0, 15.0, 40.0, 150.0]))
        c = rng.uniform(-half, half, (n, 2))
        if trial % 4 == 0:
            c = np.round(c / 2.0) * 2.0          # duplicates and pairs exactly 4, 8, ... apart
        if trial % 4 == 1 and n > 1:
            c[1] = c[0] + [LINK, 0.0]            # a pair exactly at the link distance (linked)
        got = [g.tolist() for g in components(c, LINK)]
        assert got == all_pairs_groups(c, LINK), trial


def test_components_of_100000_centres_are_the_sweeps():
    """100,000 centres over 4 x 4 km (some 270 neighbours within the link each... of 1 per
    160 m2: a mix of lone discs and chains): the same partition as an independent sweep,
    clusters in the order of their first members, members ascending."""
    rng = np.random.default_rng(1)
    c = rng.uniform(-2000.0, 2000.0, (100_000, 2))
    groups = components(c, LINK)
    label = np.empty(len(c), np.intp)
    for k, g in enumerate(groups):
        label[g] = k
        assert np.all(np.diff(g) > 0)
    assert [int(g[0]) for g in groups] == sorted(int(g[0]) for g in groups)
    ref = sweep_labels(c, LINK)
    # the same partition: each of our clusters is one of the sweep's, and as many
    assert len(groups) == ref.max() + 1
    assert all(len(set(ref[g].tolist())) == 1 for g in groups)
    assert 1_000 < sum(len(g) > 1 for g in groups) < len(groups)      # chains and lone discs both


def test_the_index_finds_each_cluster_or_marks_it_too_large_to_solve():
    rng = np.random.default_rng(2)
    for half in (30.0, 60.0, 120.0):
        c = rng.uniform(-half, half, (400, 2))
        index = DetectionIndex(c, LINK)
        for i in rng.choice(len(c), 40, replace=False).tolist():
            index.pick(np.array([i]), 0.05)
        for g in components(c, LINK):
            labels = set(index.label[g].tolist())
            if len(g) > SOLVE_MEMBERS_MAX:
                assert labels <= {OVERSIZE, -1}
            elif labels != {-1}:
                (k,) = labels
                assert k >= 0 and index.members[k].tolist() == g.tolist()


def shifted(reason, offset):
    """A near-only decision's reason with its obstacle indices as in the array with ``offset``
    far detections first."""
    return re.sub(r'(obstacle|nearest) (\d+)', lambda m: f'{m.group(1)} {int(m.group(2)) + offset}', reason)


def record(o, f, offset=0):
    index = o.obstacle_index + offset if o.obstacle_index >= 0 else -1
    return repr((o.omega, o.linear, o.action, shifted(o.reason, offset), index, o.obstacle_xy, o.value, o.alpha,
                 o.source, o.pose_age, o.lookahead, o.clusters_solving, o.cmd_clipped, f.overriding, list(f.sent)))


def far_detections(rng, n):
    """``n`` centres 150 m to 3 km from the origin: beyond any robot near NEAR and its clusters."""
    phi, r = rng.uniform(-math.pi, math.pi, n), np.sqrt(rng.uniform(150.0 ** 2, 3000.0 ** 2, n))
    return np.column_stack([r * np.cos(phi), r * np.sin(phi)])


@pytest.mark.parametrize('n_far', [1_000, 10_000, 100_000])
def test_far_detections_leave_every_decision_as_the_near_ones_alone(standard, n_far):
    """Robots near NEAR (in POSES), in closed loop for 8 ticks: with ``n_far``
    far detections in front of the near ones (each robot's own filter; a fleet sharing one
    array; a fleet with arrays of its own) every decision is the near detections' alone."""
    rng = np.random.default_rng(n_far)
    huge = np.concatenate([far_detections(rng, n_far), NEAR])
    poses = [(rng.uniform(*POSES[0]), rng.uniform(*POSES[1]), rng.uniform(-4, 4)) for _ in range(8)]
    cmds = rng.uniform(-1.5, 1.5, (8, len(poses)))
    for mode in ('alone', 'shared', 'own'):
        runs = []
        for det, offset in ((NEAR, n_far), (huge, 0)):
            store = PendingStore(ClusterSettings(cell=0.8, headings=12, reach=5.0, disk_cache=False))
            filters = [RobotFilter(FilterConfig(max_detections=200_000), f'r{i}') for i in range(len(poses))]
            if mode == 'shared':
                update_detections_all(filters, det, 0.0)
            else:
                for f in filters:
                    f.update_detections(det.copy() if mode == 'own' else det, 0.0)
            states, out = np.array(poses), []
            for k in range(8):
                t = 0.05 * k
                for f, s, w in zip(filters, states, cmds[k]):
                    f.update_pose(s, t)
                    f.update_command(float(w), t)
                decided = ([f.step(standard, t + 0.01, store) for f in filters] if mode == 'alone'
                           else step_many(filters, standard, t + 0.01, store))
                out.append([record(o, f, offset) for o, f in zip(decided, filters)])
                omega = np.array([o.omega for o in decided])
                states = states + 0.05 * np.column_stack([3.0 * np.cos(states[:, 2]), 3.0 * np.sin(states[:, 2]),
                                                          omega])
            runs.append(out)
            assert sorted(map(len, store.requested)) == [5, 9], mode      # the chain asked for whole
        assert runs[0] == runs[1], mode
        text = repr(runs[1])
        assert 'override' in text and 'pass' in text and 'cluster-fallback' in text, mode


def test_a_robot_with_many_detections_judges_only_those_within_its_radius(standard):
    """The radius covers the pairs' grid, the holds, a cluster's grid and its loiter circles;
    a detection just beyond it is not judged, one just within is."""
    f = RobotFilter(FilterConfig())
    settings = ClusterSettings()
    radius = float(judged_radius(standard.vf.grid, 3.0, f.lookahead(), 0.2, settings))
    assert radius >= math.hypot(8.0 + 2 * 3.0 * 0.1 + 1.0, 8.0 + 2 * 3.0 * 0.1 + 1.0)
    assert radius >= 2 * settings.turning_radius + settings.radius + settings.margin + 0.2
    ring = radius + 0.5 + 60.0 * np.arange(NEAR_QUERY_MIN + 1)[:, None] * np.array([[1.0, 0.0]])
    index = DetectionIndex(np.vstack([ring, [[radius - 0.5, 0.0]]]), None)
    assert index.within(np.zeros((1, 2)), radius)[0].tolist() == [NEAR_QUERY_MIN + 1]


def test_a_message_beyond_max_detections_keeps_the_nearest_and_says_why(standard):
    rng = np.random.default_rng(3)
    f = RobotFilter(FilterConfig(max_detections=1000))
    f.update_pose((0.0, 0.0, 0.0), 0.0)
    near = rng.uniform(-30, 30, (900, 2))
    far = far_detections(rng, 19_100) + [0.0, 0.0]
    msg = np.concatenate([far[:5000], near, far[5000:]])
    f.update_detections(msg, 0.0, standard)
    d = f.detections
    assert len(d.value) == 1000 and d.dropped == 19_000 and d.dropped_safely
    assert np.array_equal(msg[d.kept], d.value) and np.all(np.diff(d.kept) > 0)
    assert set(range(5000, 5900)) <= set(d.kept.tolist())         # the near ones are all kept
    kept_from = np.hypot(*d.value.T).max()
    assert np.hypot(*np.delete(msg, d.kept, axis=0).T).min() >= kept_from
    assert '19000 of 20000 detections dropped (max_detections 1000)' in d.note and 'safe to drop' in d.note
    f.update_command(0.2, 0.0)
    out = f.step(standard, 0.01)
    assert out.detections_dropped == 19_000 and out.record()['detections_dropped'] == '19000'
    assert 'safe to drop' in out.record()['detections_dropped_reason']
    # the obstacle named is the message's index
    if out.obstacle_index >= 0:
        assert tuple(msg[out.obstacle_index]) == out.obstacle_xy
    # obstacles within reach dropped: said, not called safe
    f.update_detections(rng.uniform(-10, 10, (1500, 2)), 0.1, standard)
    assert not f.detections.dropped_safely and 'WITHIN' in f.detections.note
    # no pose to measure from: the first kept
    g = RobotFilter(FilterConfig(max_detections=100))
    g.update_detections(msg[:300], 0.0, standard)
    assert np.array_equal(g.detections.value, msg[:100]) and 'no pose yet' in g.detections.note
    # a later message within the limit says nothing
    f.update_detections(near[:10], 0.2, standard)
    assert (f.detections.dropped, f.detections.note, f.detections.kept) == (0, '', None)
    # a fleet's shared array: the nearest to any robot
    fleet = [RobotFilter(FilterConfig(max_detections=100)) for _ in range(3)]
    for r, xy in zip(fleet[:2], ((0.0, 0.0), (500.0, 0.0))):
        r.update_pose((*xy, 0.0), 0.0)
    cloud = np.concatenate([rng.uniform(-5, 5, (50, 2)), rng.uniform(-5, 5, (50, 2)) + [500.0, 0.0],
                            far_detections(rng, 400) + [0.0, 1e4]])
    update_detections_all(fleet, cloud, 0.0, standard)
    assert all(r.detections.value is fleet[0].detections.value for r in fleet)
    assert fleet[0].detections.kept.tolist() == list(range(100)) and fleet[0].detections.dropped_safely


def test_commands_beyond_the_robots_limits_are_clipped_and_said(standard):
    f = RobotFilter(FilterConfig())
    f.update_pose((100.0, 100.0, 0.0), 0.0)
    f.update_detections(np.zeros((0, 2)), 0.0)
    for raw, sent in ((1e30, 1.0), (-1e30, -1.0), (2.5, 1.0)):
        f.update_command(raw, 0.0, 3.0)
        out = f.step(standard, 0.01)
        assert out.omega == sent and out.action == 'pass'
        assert f'angular.z={raw:.6g} beyond w_max=1: clipped to {sent:g}' == out.cmd_clipped
        assert out.record()['cmd_clipped'] == out.cmd_clipped
    # the planner's speed, clipped to [0, speed]; a reverse command is sent as 0
    cases = ((0.0, 0.0, ''), (1.2, 1.2, ''), (3.0, 3.0, ''), (7.5, 3.0, 'linear.x=7.5 beyond speed=3: clipped to 3'),
             (-0.4, 0.0, 'linear.x=-0.4 is reverse: sent as 0'))
    for raw, sent, said in cases:
        f.update_command(0.5, 0.0, raw)
        out = f.step(standard, 0.01)
        assert out.omega == 0.5 and out.linear == sent and out.cmd_clipped.startswith(said), (raw, out)
        assert bool(out.cmd_clipped) == bool(said)
    f.update_command(0.5, 0.0)                  # linear.x not given: the speed
    assert f.step(standard, 0.01).linear == 3.0
    dubins = RobotFilter(FilterConfig(fail_safe_command='stop_turn'))
    dubins.update_pose((100.0, 100.0, 0.0), 0.0)
    dubins.update_detections(np.zeros((0, 2)), 0.0)
    dubins.update_command(0.5, 0.0, 0.0)        # a stop the constant-speed Dubins robot cannot make
    out = dubins.step(standard, 0.01)
    assert out.omega == 0.5 and out.linear == 3.0 and "linear.x=0 is not the robot's speed 3" in out.cmd_clipped
    f.update_command(0.5, 0.0, 3.0)
    assert f.step(standard, 0.01).cmd_clipped == ''
    with pytest.raises(ValueError):
        f.update_command(math.inf, 0.02, 3.0)
    out = f.step(standard, 0.03)      # a robot that can stop: stopped until a valid command comes
    assert (out.omega, out.linear) == (0.0, 0.0) and 'angular.z=inf' in out.reason
    assert 'robot stops' in f.command.note
    for bad in ((math.inf, 3.0), (0.1, math.nan)):     # a constant-speed robot keeps the previous command
        dubins.update_command(0.5, 0.0, 3.0)
        with pytest.raises(ValueError):
            dubins.update_command(*bad[:1], 0.02, bad[1])
        out = dubins.step(standard, 0.03)
        assert out.omega == 0.5 and out.linear == 3.0 and 'rejected, the previous command kept' in dubins.command.note
    # batched: only the rows beyond their robot's limits are said, the next command clears them
    fleet = [RobotFilter(FilterConfig(omega_max=w, fail_safe_command='stop_turn')) for w in (1.0, 0.5, 1.0, 1.0)]
    for r in fleet:
        r.update_pose((100.0, 100.0, 0.0), 0.0)
        r.update_detections(np.zeros((0, 2)), 0.0)
    beyond = update_commands(fleet, [0.9, 0.9, -7.0, 0.1], 0.0, linears=[3.0, 3.0, 3.0, 2.0])
    assert beyond == [1, 2, 3]
    outs = step_many(fleet, standard, 0.01)
    assert outs.omega == [0.9, 0.5, -1.0, 0.1]
    assert [o.cmd_clipped.split(':')[0] for o in outs] == ['', 'angular.z=0.9 beyond w_max=0.5',
                                                           'angular.z=-7 beyond w_max=1',
                                                           "linear.x=2 is not the robot's speed 3"]
    assert update_commands(fleet, [0.1] * 4, 0.02, linears=[3.0] * 4) == []
    assert [o.cmd_clipped for o in step_many(fleet, standard, 0.03)] == [''] * 4


def test_a_cluster_too_large_to_solve_is_never_requested_and_judged_by_its_fallback(standard):
    """A wall of 40 detections 0.5 m apart (one cluster beyond SOLVE_MEMBERS_MAX), and of 100
    (judged through the index): no solve is requested, the loiter fallback governs."""
    for count in (40, 100):
        wall = np.column_stack([np.zeros(count), 0.5 * np.arange(count) - 10.0])
        store = ClusterStore(ClusterSettings(disk_cache=False), background=False)
        f = RobotFilter(FilterConfig())
        f.update_pose((-5.0, 0.0, 0.0), 0.0)          # heading into the wall, a clear loiter circle
        f.update_detections(wall, 0.0)
        f.update_command(0.0, 0.0)
        out = f.step(standard, 0.01, store)
        assert not store.requested and not store.values and not store.errors
        assert out.action == 'override' and out.source == 'cluster-fallback', out
        members = count if count <= NEAR_QUERY_MIN else len(f.derived['near_pick'][2])
        assert f'a cluster of {members} obstacles' in out.reason
    # a robot that can stop: its speed passed, beyond [0, speed] clipped and said
    movers = [RobotFilter(FilterConfig()) for _ in range(4)]
    for r in movers:
        r.update_pose((100.0, 100.0, 0.0), 0.0)
        r.update_detections(np.zeros((0, 2)), 0.0)
    assert update_commands(movers, [0.1] * 4, 0.0, linears=[2.0, 4.0, -1.0, 0.0]) == [1, 2]
    outs = step_many(movers, standard, 0.01)
    assert outs.linear == [2.0, 3.0, 0.0, 0.0]
    said = [o.cmd_clipped.split(':')[0] for o in outs]
    assert said == ['', 'linear.x=4 beyond speed=3', 'linear.x=-1 is reverse', '']
    with pytest.raises(ValueError):
        update_commands(movers, [0.1] * 4, 0.02, linears=[1.0, math.inf, 1.0, 1.0])
