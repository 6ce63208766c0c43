"""The vectorised ``step_many`` decides exactly as the per-robot implementation it replaced.

``filter_oracle.step_many_reference`` is the robot-by-robot code of commit
003abdd, kept verbatim. Both run on identical fleets (built twice from one seed) over
several closed-loop ticks: random poses near obstacles, detections with clusters of
close obstacles (shared arrays, as the fleet node's batched detections, and per-robot
ones), commands beyond w_max, silent and missing planners, delayed, stale, rejected and
missing poses and detections (fail safe with and without a last valid state),
hysteresis, head-on ties and duplicate obstacles (ties in the smallest value), mixed
robot configurations, and cluster stores whose union values are solved, pending or
solved inline at the request. Every field of every output (turn rate, action, the
full reason, governing obstacle, V, level, source, pose age, lookahead, clusters
being solved), the overriding state and the commands remembered must be identical,
bit for bit; and the fleets must have exercised every kind of decision.
"""
import math

import numpy as np
import pytest

from filter_oracle import step_many_reference
from supersafe_ros.filter.clusters.geometry import ClusterSettings, ClusterValue
from supersafe_ros.filter.clusters.store import ClusterStore, solve_cluster
from supersafe_ros.filter import FilterConfig, RobotFilter, SafeSet, step_many
from supersafe_ros.filter.sent import record_sent
from supersafe_ros.reach.dynamics import DubinsCar
from supersafe_ros.reach.grid import Grid
from supersafe_ros.reach.sets import Disc
from supersafe_ros.reach.solver import solve_avoid

# a coarse union solve (fast); the filter reads its link distance, radius and margin from it
SETTINGS = ClusterSettings(cell=0.8, headings=12, reach=5.0, disk_cache=False)
LAYOUT = np.array([[0.0, 0.0], [4.5, 0.0], [9.0, 0.0],          # a row 4.5 m apart
                   [0.0, 14.0], [3.3, 15.5], [6.6, 14.0],       # a cup
                   [20.0, 0.0], [20.0, 0.0],                    # a duplicate (ties in the min)
                   [-15.0, 10.0], [30.0, 30.0]])                # lone obstacles


@pytest.fixture(scope='module')
def standard():
    vf = solve_avoid(Grid((-8, -8), (8, 8), (41, 41, 24)), DubinsCar(3.0, 1.0), Disc(0, 0, 1.8), horizon=3.0)
    return SafeSet(vf, 0.0, 'standard')


class PendingStore(ClusterStore):
    """Requests are queued but never solved: the fallback stays in force, and robots count
    the clusters being solved."""

    def request(self, key, centres):
        with self._lock:
            if key not in self.values:
                self.requested.setdefault(key, 0.0)


@pytest.fixture(scope='module')
def solved_values():
    """Union values of the row's first pair and of the cup (solved once, shared by the stores)."""
    from supersafe_ros.filter.clusters.geometry import canonical
    out = {}
    for members in ([0, 1], [3, 4, 5]):
        key, _, _, centres = canonical(LAYOUT[members], SETTINGS.key_resolution)
        vf, seconds = solve_cluster(SETTINGS, centres)
        out[key] = ClusterValue(vf, centres, seconds, lower=SETTINGS.lower_bound)
    return out


def make_store(kind, solved_values):
    if kind == 'inline':        # solves at the request: robots after the first see the value
        return ClusterStore(SETTINGS, background=False)
    store = PendingStore(SETTINGS) if kind == 'pending' else ClusterStore(SETTINGS, fallback_only=True)
    for key, value in solved_values.items():
        store.values[key] = value
    return store


def build_fleet(seed, n):
    """n robot filters and the shared detection arrays, all from ``seed`` (call twice: two
    identical fleets)."""
    rng = np.random.default_rng(seed)
    shared = [LAYOUT.copy(), LAYOUT[[0, 1, 2, 9]].copy(), LAYOUT[[3, 4, 5, 6, 7]].copy(), np.zeros((0, 2))]
    filters = []
    t = 10.0
    # half the robots have a configuration of their own, half share one of a few (as a fleet node's
    # robots share one): robots given one configuration and one detections array join their
    # clusters by one lookup in step_many
    pool = []
    for i in range(n):
        if pool and rng.random() < 0.5:
            cfg = pool[rng.integers(len(pool))]
        else:
            cfg = FilterConfig(omega_max=float(rng.choice([1.0, 1.0, 0.5])),
                               clear_margin=float(rng.choice([0.2, 0.0, 0.5])),
                               lookahead=float(rng.choice([0.1, 0.0, 0.2])),
                               control_period=float(rng.choice([0.0, 0.0, 0.05])),
                               compensate_delay=bool(rng.random() < 0.85),
                               clusters=bool(rng.random() < 0.8),
                               cluster_alpha=float(rng.choice([0.0, 0.0, 0.2])),
                               fail_safe_command=str(rng.choice(['stop', 'stop_turn'])))
            if len(pool) < 4:
                pool.append(cfg)
        f = RobotFilter(cfg, name=f'r{i}')
        centre = LAYOUT[rng.integers(len(LAYOUT))]
        if rng.random() < 0.08:      # head on to an obstacle: dV/dtheta is a tie, the turn is left
            pose = (centre[0] - 3.0, centre[1], 0.0)
            dets = centre[None].copy()
        else:
            pose = (centre[0] + rng.uniform(-7, 7), centre[1] + rng.uniform(-7, 7), rng.uniform(-4, 4))
            choice = rng.random()
            dets = (shared[rng.integers(len(shared))] if choice < 0.6 else
                    LAYOUT[rng.choice(len(LAYOUT), rng.integers(1, 6), replace=False)].copy())
        pose_kind = rng.choice(['fresh'] * 6 + ['delayed', 'stale', 'lost', 'rejected', 'never'])
        if pose_kind != 'never':
            # a history of poses and commands: the control period is measured from it
            for k in range(int(rng.integers(1, 5))):
                tk = t - 0.02 * (4 - k)
                f.update_pose(pose, tk, stamp=tk - rng.uniform(0.0, 0.01))
                record_sent(f, float(rng.uniform(-1, 1)), tk, float(rng.choice([0.0, 1.5, 3.0])))
            age = {'fresh': 0.0, 'delayed': rng.uniform(0.01, 0.3), 'stale': rng.uniform(0.6, 0.95),
                   'lost': 1.5, 'rejected': 0.0}[pose_kind]
            f.update_pose(pose, t - age, stamp=t - age - rng.uniform(0.0, 0.12))
            if pose_kind == 'rejected':
                f.reject_pose('wrong frame', t)
        det_kind = rng.choice(['fresh'] * 8 + ['stale', 'rejected', 'never'])
        if det_kind != 'never':
            f.update_detections(dets, t - (rng.uniform(1.05, 1.5) if det_kind == 'stale' else rng.uniform(0, 0.5)))
            if det_kind == 'rejected':
                f.reject_detections('bad frame', t)
        cmd_kind = rng.choice(['fresh'] * 6 + ['wide', 'silent', 'none'])
        if cmd_kind != 'none':
            w = float(rng.uniform(-3, 3) if cmd_kind == 'wide' else rng.uniform(-1, 1))
            linear = rng.choice([None, 3.0, float(rng.uniform(-1.0, 4.0)), 0.0])     # the planner's speed
            f.update_command(w, t - (0.8 if cmd_kind == 'silent' else rng.uniform(0, 0.1)), linear)
        f.overriding = bool(rng.random() < 0.3)
        filters.append(f)
    return filters, t


# phrases of the reasons (outputs.explain): each kind of decision the fleets must exercise
REASON_TAGS = ('too close', 'would bring', 'not yet clear', "passing the planner's command", 'planner silent', 'pose',
               'detections', 'stopped: ', 'away from', 'circling')


def advance(filters, outs, rng, t, dt):
    """One closed-loop step: each robot moves under the command it got; some inputs arrive."""
    for f, o in zip(filters, outs):
        r = rng.random(4)
        if f.pose.value is not None and r[0] < 0.9:
            x, y, th = f.pose.value
            th2 = th + o.omega * dt
            moved = (x + 3.0 * dt * math.cos(th), y + 3.0 * dt * math.sin(th), th2)
            f.update_pose(moved, t, stamp=t - (0.02 if r[1] < 0.3 else 0.0))
        if r[2] < 0.5:
            f.update_command(float(rng.uniform(-1.5, 1.5)), t, float(rng.uniform(-0.5, 3.5)))
        if r[3] < 0.05 and f.detections.value is not None:
            f.update_detections(f.detections.value.copy(), t)   # a new detections array, same centres


def record(o, f):
    return repr((o.omega, o.linear, o.action, o.reason, o.obstacle_index, o.obstacle_xy, o.value, o.alpha,
                 o.source, o.omega_max_set, o.pose_age, o.lookahead, o.clusters_solving, f.overriding,
                 list(f.sent)))


@pytest.mark.parametrize('seed, store_kind, alpha, source', [
    (1, 'solved', 0.0, 'standard'), (2, 'pending', 0.0, 'standard'), (3, 'solved', 0.3, 'learned'),
    (4, 'inline', 0.0, 'standard'), (5, 'pending', -0.2, 'learned')])
def test_vectorised_step_many_decides_as_the_per_robot_reference(standard, solved_values, seed, store_kind,
                                                                 alpha, source):
    safe = SafeSet(standard.vf, alpha, source)
    fleets = [build_fleet(seed, 320) for _ in range(2)]
    stores = [make_store(store_kind, solved_values) for _ in range(2)]
    rngs = [np.random.default_rng(100 + seed) for _ in range(2)]
    seen = {'actions': set(), 'reasons': set(), 'sources': set(), 'solving': 0, 'ties': 0}
    t = fleets[0][1]
    for tick in range(6):
        new = step_many(fleets[0][0], safe, t, stores[0])
        ref = step_many_reference(fleets[1][0], safe, t, stores[1])
        # the commands as lists (what the fleet node sends without building the outputs)
        assert repr((new.omega, new.linear, new.action)) == repr(([o.omega for o in ref], [o.linear for o in ref],
                                                                  [o.action for o in ref]))
        for i, (a, b, fa, fb) in enumerate(zip(new, ref, fleets[0][0], fleets[1][0])):
            assert record(a, fa) == record(b, fb), f'tick {tick}, robot {i}'
            seen['actions'].add(a.action)
            seen['reasons'].update(tag for tag in REASON_TAGS if tag in a.reason)
            seen['sources'].add(a.source)
            seen['solving'] += a.clusters_solving
            assert new.clusters_solving(i) == a.clusters_solving       # (read without the output)
            seen['ties'] += ('obstacle 7' in a.reason or 'obstacle 6' in a.reason)
        t += 0.02
        for (filters, _), rng, outs in zip(fleets, rngs, (new, ref)):
            advance(filters, outs, rng, t, 0.02)
    # the fleets exercised every kind of decision (so the comparison cannot pass vacuously)
    assert seen['actions'] == {'pass', 'override', 'fail_safe'}, seen
    assert {'too close', 'would bring', "passing the planner's command", 'pose', 'detections', 'stopped: '} \
        <= seen['reasons'], seen['reasons']
    assert 'cluster-fallback' in seen['sources'] or 'cluster' in seen['sources'], seen['sources']
    if store_kind in ('solved', 'inline'):
        assert 'cluster' in seen['sources'], seen['sources']
    if store_kind == 'pending':
        assert seen['solving'] > 0


def test_control_period_median_is_numpys():
    """The control period's median (sorted, in Python) equals np.median bit for bit."""
    from supersafe_ros.filter.inputs import _median_of_sorted
    rng = np.random.default_rng(0)
    for n in range(1, 17):
        for _ in range(200):
            d = list(rng.choice([0.02, 0.05, 0.1, 1 / 3], n) + rng.normal(0, 1e-3, n) * (rng.random() < 0.5))
            assert repr(_median_of_sorted(sorted(d))) == repr(float(np.median(d)))


def test_interval_windows_keep_numpys_median_as_they_slide():
    """The filter's interval windows (the last 16, kept sorted as they slide) give np.median of
    the last 16 intervals after every new one, with ties and repeats. A window is never changed:
    the next one is new (robots share windows), and the one before still reads as it did."""
    from supersafe_ros.filter.inputs import PERIOD_SAMPLES, _Intervals
    rng = np.random.default_rng(1)
    for _ in range(100):
        window, history = _Intervals(), []
        assert window.middle is None and list(window) == []
        for x in rng.choice([0.02, 0.05, 0.1, 1 / 3], 40) + rng.normal(0, 1e-3, 40) * (rng.random() < 0.5):
            before, seen = window, (list(window), list(window.ordered), window.middle)
            window = window.then(float(x))
            assert (list(before), list(before.ordered), before.middle) == seen
            history.append(float(x))
            last = history[-PERIOD_SAMPLES:]
            assert list(window) == last and list(window.ordered) == sorted(last)
            assert repr(window.middle) == repr(float(np.median(last)))


def test_batched_input_updates_equal_the_per_robot_ones(standard, solved_values):
    """update_poses / update_commands / update_detections_all (the fleet node's batched
    messages) leave every filter as update_pose / update_command / update_detections would, and
    so decide the same."""
    from supersafe_ros.filter import update_commands, update_detections_all, update_poses
    rng = np.random.default_rng(7)
    fleets = [build_fleet(11, 60)[0] for _ in range(2)]
    stores = [make_store('pending', solved_values) for _ in range(2)]
    t = 10.0
    for tick in range(4):
        t += 0.02
        states = np.stack([rng.uniform(-5, 25, 60), rng.uniform(-5, 20, 60), rng.uniform(-4, 4, 60)], axis=1)
        skip = ['bad row' if rng.random() < 0.1 else '' for _ in range(60)]
        stamp = t - 0.01 * tick
        for f, s, why in zip(fleets[1], states, skip):
            if not why:
                f.update_pose(s, t, stamp=stamp)
        update_poses(fleets[0], states, t, stamp=stamp, skip=skip)
        omegas = rng.uniform(-2, 2, 60)
        silent = ['silent' if rng.random() < 0.2 else '' for _ in range(60)]
        for f, w, why in zip(fleets[1], omegas, silent):
            if not why:
                f.update_command(w, t)
        update_commands(fleets[0], omegas, t, skip=silent)
        if tick == 2:      # the same message again at the same time: no zero interval is measured
            for f, w, why in zip(fleets[1], omegas, silent):
                if not why:
                    f.update_command(w, t)
            update_commands(fleets[0], omegas, t, skip=silent)
        if tick % 2:
            dets = LAYOUT[rng.choice(len(LAYOUT), 6, replace=False)]
            update_detections_all(fleets[0], dets, t)
            for f in fleets[1]:
                f.update_detections(dets, t)
        outs = [step_many(fs, standard, t + 0.005, st) for fs, st in zip(fleets, stores)]
        for a, b, fa, fb in zip(*outs, *fleets):
            assert record(a, fa) == record(b, fb)
            assert (fa.pose.t, fa.pose.stamp, list(fa.pose_intervals)) == (fb.pose.t, fb.pose.stamp,
                                                                           list(fb.pose_intervals))
            assert (fa.command.value, fa.command.t, list(fa.command_intervals)) == (
                fb.command.value, fb.command.t, list(fb.command_intervals))
    with pytest.raises(ValueError):
        update_poses(fleets[0], np.full((60, 3), np.nan), t)
    before = [f.command.value for f in fleets[0]]
    with pytest.raises(ValueError):
        update_commands(fleets[0], np.r_[np.zeros(59), np.inf], t + 1.0)
    assert [f.command.value for f in fleets[0]] == before     # nobody updated
    update_commands(fleets[0], np.r_[np.zeros(59), np.inf], t + 1.0, skip=[''] * 59 + ['not finite'])
    assert fleets[0][-1].command.value == before[-1] and fleets[0][0].command.t == t + 1.0


def test_cluster_instances_left_out_are_off_their_grid_for_every_hold(solved_values):
    """The batched step leaves out (robot, cluster) instances whose union value is in force but
    whose grid no hold reaches (``_beyond_grid``): from each such robot, the arcs the law reads
    (both bangs from now, the planner's hold, both bangs after it) all end off the grid, so the
    rows left out would have read V = +inf. Robots sampled in a ring around the grid's corners,
    where the bound is tight, and everywhere else."""
    from supersafe_ros.filter.constraints.cluster_rows import _beyond_grid
    from supersafe_ros.filter.propagation import arc_flow
    from types import SimpleNamespace
    rng = np.random.default_rng(5)
    # the solved clusters' grids, and lopsided ones (a bound read from the wrong axis shows there)
    values = list(solved_values.values()) + [SimpleNamespace(vf=SimpleNamespace(grid=Grid(lo, hi, (5, 5, 4))))
                                             for lo, hi in (((-2.0, -15.0), (20.0, 3.0)), ((-18.0, -1.0), (2.0, 9.0)))]
    n = 20000
    val = rng.integers(-1, len(values), n)
    corner = np.array([max(np.hypot(x, y) for x in (v.vf.grid.lo[0], v.vf.grid.hi[0])
                           for y in (v.vf.grid.lo[1], v.vf.grid.hi[1])) for v in values])
    speed, horizon = rng.choice([1.0, 3.0], n), rng.choice([0.02, 0.1, 0.3], n)
    reach = 2.0 * speed * horizon + 1.0
    r = np.where(val >= 0, corner[val], 10.0) + reach + rng.uniform(-3, 3, n)
    a = rng.uniform(-np.pi, np.pi, n)
    offset = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    far = _beyond_grid(values, val, offset, reach)
    assert not far[val < 0].any()                  # no value in force: never left out
    assert 0.3 * n < far.sum() < 0.6 * n           # both sides of the bound were sampled
    state = np.column_stack([offset, rng.uniform(-np.pi, np.pi, n)])
    planned, bang = rng.uniform(-1, 1, n), np.ones(n)
    ahead = arc_flow(state, speed, planned * bang, horizon)
    ends = [state, ahead]
    for start in (state, ahead):
        for w in (bang, -bang):
            ends.append(arc_flow(start, speed, w, horizon))
    for j, v in enumerate(values):
        sel = far & (val == j)
        assert sel.sum() > 100
        for s in ends:   # in any frame rotated about the origin: the grid test is on the radius bound
            for beta in (0.0, 0.7, 2.0):
                c, sn = np.cos(beta), np.sin(beta)
                rot = np.column_stack([c * s[sel, 0] + sn * s[sel, 1], -sn * s[sel, 0] + c * s[sel, 1], s[sel, 2]])
                assert not v.vf.grid.contains(rot).any()


def test_decisions_read_as_a_sequence_of_outputs(standard):
    """step_many's Decisions: outputs by index (negative too) and by slice, built once each,
    and a repr that shows them."""
    fleet, t = build_fleet(21, 12)
    out = step_many(fleet, standard, t, make_store('pending', {}))
    assert len(out) == 12 and out[-1] is out[11] and out[3] is out[3]
    assert out[2:5] == [out[2], out[3], out[4]] and out[::-5] == [out[11], out[6], out[1]]
    assert [o.omega for o in out] == out.omega and [o.action for o in out] == out.action
    assert repr(out).startswith('Decisions([FilterOutput(') and repr(out).count('FilterOutput(') == 12
    with pytest.raises(IndexError):
        out[12]


def robot_at(cfg, pose, dets, cmd, t=10.0):
    f = RobotFilter(cfg)
    f.update_pose(pose, t)
    f.update_detections(dets, t)
    f.update_command(cmd, t)
    return f


def decide_as_the_reference(fleet, standard, solved_values, t=10.0):
    """step_many and the reference on two fleets from ``fleet()`` with solved cluster stores:
    the same turn, action, reason, V and source for every robot; the new outputs."""
    stores = [make_store('solved', solved_values) for _ in range(2)]
    new = step_many(fleet(), standard, t, stores[0])
    ref = step_many_reference(fleet(), standard, t, stores[1])
    for i, (a, b) in enumerate(zip(new, ref)):
        assert repr((a.omega, a.action, a.reason, a.value, a.source)) == repr((b.omega, b.action, b.reason, b.value,
                                                                               b.source)), i
    return new


def test_long_holds_around_solved_clusters_decide_as_the_reference(standard, solved_values):
    """Robots up to 30 m from a cluster whose union value is in force, with 1-2 s holds at 3 m/s
    (up to 12 m in two holds) and a high cluster level (4 m, so holds that reach the union's
    grid from outside it make the filter act): the (robot, cluster) instances left out as out
    of reach (``_beyond_grid``) change no decision (kills a reach that does not grow with
    speed x hold)."""
    configs = [FilterConfig(lookahead=h, cluster_alpha=4.0) for h in (1.0, 2.0, 2.0)]
    centroids = [LAYOUT[[0, 1]].mean(axis=0), LAYOUT[[3, 4, 5]].mean(axis=0)]
    dets = LAYOUT[[0, 1, 3, 4, 5]].copy()          # the row's pair and the cup, both solved

    def fleet():
        r = np.random.default_rng(32)
        out = []
        for i in range(900):
            c = centroids[i % 2]
            d, a = r.uniform(3.0, 30.0), r.uniform(-np.pi, np.pi)
            pose = (c[0] + d * np.cos(a), c[1] + d * np.sin(a), a + np.pi + r.uniform(-0.4, 0.4))
            out.append(robot_at(configs[i % 3], pose, dets, float(r.uniform(-1, 1))))
        return out
    outs = decide_as_the_reference(fleet, standard, solved_values)
    assert sum("the planner's command would bring a cluster" in o.reason for o in outs) > 20


def test_far_robots_on_the_loiter_fallback_decide_as_the_reference(standard):
    """Robots 1-40 m from clusters judged by the loiter fallback alone (a store that never solves):
    the fallback rows left out as unable to act and above their robot's smallest row
    (``cluster_rows._fallback_bound``) change no decision: the same command, reason, named row
    and value as the reference, for robots whose smallest row is a far cluster's (no obstacle
    near), near and far ones, overriding ones with wide margins, long holds, and constant-speed
    robots failing safe from their last valid state (they turn by their smallest row)."""
    configs = [FilterConfig(), FilterConfig(lookahead=1.0, clear_margin=3.0),
               FilterConfig(fail_safe_command='stop_turn', detections_timeout=0.2, hold_timeout=1.0)]
    centroids = [LAYOUT[[0, 1, 2]].mean(axis=0), LAYOUT[[3, 4, 5]].mean(axis=0)]

    def fleet():
        r = np.random.default_rng(41)
        out = []
        for i in range(600):
            c = centroids[i % 2]
            d, a = r.uniform(1.0, 40.0), r.uniform(-np.pi, np.pi)
            pose = (c[0] + d * np.cos(a), c[1] + d * np.sin(a), a + np.pi + r.uniform(-1.0, 1.0))
            f = robot_at(configs[i % 3], pose, LAYOUT.copy(), float(r.uniform(-1, 1)))
            if i % 3 == 2:          # its detections stale: failing safe from the last valid state
                f.update_detections(LAYOUT.copy(), 9.5)
            f.overriding = bool(r.random() < 0.5)
            out.append(f)
        return out
    stores = [ClusterStore(SETTINGS, fallback_only=True) for _ in range(2)]
    new = step_many(fleet(), standard, 10.0, stores[0])
    ref = step_many_reference(fleet(), standard, 10.0, stores[1])
    kinds = {'named far': 0, 'fallback acts': 0, 'fails safe by it': 0}
    for i, (a, b) in enumerate(zip(new, ref)):
        assert repr((a.omega, a.linear, a.action, a.reason, a.obstacle_index, a.value, a.source)) == repr(
            (b.omega, b.linear, b.action, b.reason, b.obstacle_index, b.value, b.source)), i
        kinds['named far'] += a.action == 'pass' and a.source == 'cluster-fallback' and a.value > 5.0
        kinds['fallback acts'] += a.action == 'override' and a.source == 'cluster-fallback'
        kinds['fails safe by it'] += a.action == 'fail_safe' and a.source == 'cluster-fallback'
    assert min(kinds.values()) > 10, kinds


def test_the_fallback_bound_is_below_the_loiter_clearance_now_and_after_the_hold():
    """cluster_rows._fallback_bound is a lower bound of the loiter fallback's clearance
    (cluster.orbit_value) at the robot's state now and where the planner's hold ends, and tight
    where it can be (a robot midway between two members, heading across them): random clusters,
    states, speeds, turns and holds."""
    from supersafe_ros.filter.clusters.geometry import ClusterSettings, orbit_value
    from supersafe_ros.filter.clusters.store import ClusterStore
    from supersafe_ros.filter.constraints.cluster_rows import _fallback_bound
    from supersafe_ros.filter.propagation import arc_flow
    st = ClusterSettings()
    store = ClusterStore(st, fallback_only=True)
    r, radius = st.turning_radius, st.radius + st.margin
    rng = np.random.default_rng(43)
    tight = 0
    for trial in range(3000):
        members = rng.uniform(-6.0, 6.0, (int(rng.integers(2, 5)), 2))
        if trial % 4 == 0:      # midway between two members, heading across them
            a = rng.uniform(-np.pi, np.pi)
            d = rng.uniform(2 * r + radius, 30.0)
            p = rng.uniform(-20.0, 20.0, 2)
            members = np.array([p + d * np.array([np.cos(a), np.sin(a)]), p - d * np.array([np.cos(a), np.sin(a)])])
            state = np.array([[p[0], p[1], a + np.pi / 2]])
        else:
            state = np.array([[rng.uniform(-40, 40), rng.uniform(-40, 40), rng.uniform(-np.pi, np.pi)]])
        speed, horizon, turn = rng.choice([0.0, 1.5, 3.0]), rng.choice([0.0, 0.1, 1.0, 2.0]), rng.uniform(-1, 1)
        ahead = arc_flow(state, np.array([speed]), np.array([turn]), np.array([horizon]))
        nearest = np.hypot(*(members - state[0, :2]).T).min()
        bound = _fallback_bound(np.array([nearest]), np.zeros(1, np.intp), [store], np.array([speed * horizon]))
        now = orbit_value(state, members, radius, r)[0][0]
        later = orbit_value(ahead, members, radius, r)[0][0]
        assert bound[0, 0] <= now and bound[1, 0] <= later, trial
        tight += bool(now - bound[0, 0] < 1e-6)
    assert tight > 300, tight


def test_robots_just_inside_a_union_grids_corners_decide_as_the_reference(standard, solved_values):
    """Robots 0.2 m inside each corner of a solved cluster's grid (where the grid reaches
    farthest from the frame's origin, so a reach bound that is short by a metre leaves their
    own rows out), with short holds: the same decisions, reasons and values as the reference
    (kills a reach of 2 speed H - 1 in _cluster_rows)."""
    from supersafe_ros.filter.clusters.geometry import canonical
    cfg = FilterConfig(lookahead=0.1, control_period=0.1)
    dets = LAYOUT[[0, 1, 3, 4, 5]].copy()

    def fleet():
        out = []
        for members in ([0, 1], [3, 4, 5]):
            key, origin, angle, _ = canonical(LAYOUT[members], SETTINGS.key_resolution)
            g = solved_values[key].vf.grid
            cs, sn = np.cos(angle), np.sin(angle)
            for fx, fy in ((g.lo[0] + 0.2, g.lo[1] + 0.2), (g.lo[0] + 0.2, g.hi[1] - 0.2),
                           (g.hi[0] - 0.2, g.lo[1] + 0.2), (g.hi[0] - 0.2, g.hi[1] - 0.2)):
                for heading in np.linspace(-np.pi, np.pi, 8, endpoint=False):
                    pose = (origin[0] + cs * fx - sn * fy, origin[1] + sn * fx + cs * fy, heading)
                    out.append(robot_at(cfg, pose, dets, 0.0))
        return out
    outs = decide_as_the_reference(fleet, standard, solved_values)
    assert sum(o.source == 'cluster' for o in outs) > 10      # the union's V is the smallest at most of them


@pytest.mark.parametrize('seed, store_kind, alpha, source', [
    (15, 'solved', 0.0, 'standard'), (12, 'pending', 0.3, 'learned'), (13, 'inline', -0.2, 'standard'),
    (16, 'solved', 0.5, 'learned'), (17, 'pending', -0.3, 'standard')])
def test_each_robot_decided_alone_decides_as_in_the_fleet(standard, solved_values, seed, store_kind, alpha, source,
                                                          monkeypatch):
    """A robot's own filter (step_many of one robot, the one-robot path ``gather.gather_one_fast``,
    V read in Python floats when few obstacles are near) decides as the vectorised fleet path
    decides that robot: over six closed-loop ticks, the same command, reason, values and state
    for every robot, with clusters solved, pending and solved at the request."""
    from supersafe_ros.filter import decide
    from supersafe_ros.filter.constraints import table
    alone_calls, python_reads = [], []
    gather_one_fast, pair_values_fast = decide.gather_one_fast, table.pair_values_fast

    def gather_one_spy(*a):
        got = gather_one_fast(*a)
        if got is not None:         # the one-robot path taken
            alone_calls.append(1)
        return got
    monkeypatch.setattr(decide, 'gather_one_fast', gather_one_spy)

    def pair_values_spy(*a):
        got = pair_values_fast(*a)
        python_reads.append(got is not None)
        return got
    monkeypatch.setattr(table, 'pair_values_fast', pair_values_spy)
    safe = SafeSet(standard.vf, alpha, source)
    fleets = [build_fleet(seed, 320) for _ in range(2)]
    stores = [make_store(store_kind, solved_values) for _ in range(2)]
    rngs = [np.random.default_rng(200 + seed) for _ in range(2)]
    seen = {'kinds': set(), 'sources': set()}
    t = fleets[0][1]
    for tick in range(6):
        alone_decisions = [step_many([f], safe, t, stores[0]) for f in fleets[0][0]]
        alone = [d[0] for d in alone_decisions]
        n_alone = len(alone_calls)
        fleet = step_many(fleets[1][0], safe, t, stores[1])
        assert len(alone_calls) == n_alone            # the fleet took the vectorised path
        # the command lists too (what the fleet node and the team loop read)
        assert repr([(d.omega, d.linear, d.action) for d in alone_decisions]) == repr(
            [([w], [v], [a]) for w, v, a in zip(fleet.omega, fleet.linear, fleet.action)])
        for i, (a, b, fa, fb) in enumerate(zip(alone, fleet, fleets[0][0], fleets[1][0])):
            assert record(a, fa) == record(b, fb), f'tick {tick}, robot {i}'
            seen['kinds'].update(a.action + ':' + tag for tag in REASON_TAGS if tag in a.reason)
            seen['sources'].add(a.source)
        t += 0.02
        for (filters, _), rng, outs in zip(fleets, rngs, (alone, fleet)):
            advance(filters, outs, rng, t, 0.02)
    assert len(alone_calls) > 6 * 320 * 0.6        # most robots had a state to judge alone
    # V read in Python floats (few pairs near) and by numpy (more), both compared
    assert python_reads.count(True) > 100 and python_reads.count(False) > 10, python_reads.count(False)
    assert {"pass:passing the planner's command", 'override:too close', 'override:would bring', 'fail_safe:pose'} \
        <= seen['kinds'], seen
    assert {'cluster', 'cluster-fallback'} & seen['sources'], seen['sources']


def test_one_arc_in_python_floats_is_arc_flows():
    """propagation.arc (one state, Python floats) equals arc_flow bit for bit: turning, nearly
    straight (|omega dt| <= 1e-9), zero-length, and headings far outside [-pi, pi)."""
    from supersafe_ros.filter.propagation import arc, arc_flow
    rng = np.random.default_rng(5)
    n = 4000
    states = np.column_stack([rng.uniform(-9, 9, n), rng.uniform(-9, 9, n), rng.uniform(-12, 12, n)])
    omega = rng.choice([0.0, 1e-12, -3e-10, 1.0, -1.0, 0.37], n) * rng.choice([1.0, -1.0], n)
    dt = rng.choice([0.0, 0.02, 0.1, 1.5], n)
    speed = rng.choice([3.0, 0.5], n)
    want = arc_flow(states, speed, omega, dt)
    got = np.array([arc(*s.tolist(), float(v), float(w), float(h)) for s, v, w, h in zip(states, speed, omega, dt)])
    assert repr(got.tolist()) == repr(want.tolist())


def test_a_robots_propagated_state_does_not_depend_on_the_other_robots_plans(standard):
    """Robots whose plans since their pose have 0, 1 and 2 arcs (a pose older than the last
    command sent), decided alone (their own arcs, in Python floats) and together (shorter
    plans padded with zero-length arcs, which wrap theta once more): the same decisions and
    values bit for bit."""
    cfg = FilterConfig(lookahead=0.1, control_period=0.05)

    def fleet():
        r = np.random.default_rng(42)
        out = []
        for i in range(60):
            f = RobotFilter(cfg)
            t = 10.0
            pose = (r.uniform(-4, 4), r.uniform(-4, 4), r.uniform(-np.pi, np.pi))
            arcs = i % 3
            if arcs == 2:       # a command sent after the pose's stamp
                f.update_pose(pose, t - 0.03, stamp=t - 0.05)
                record_sent(f, float(r.uniform(-1, 1)), t - 0.06)
                record_sent(f, float(r.uniform(-1, 1)), t - 0.02)
            elif arcs == 1:
                f.update_pose(pose, t - 0.01, stamp=t - 0.02)
                record_sent(f, float(r.uniform(-1, 1)), t - 0.04)
            else:
                f.update_pose(pose, t, stamp=t)
            f.update_detections(np.array([[0.5, 0.3]]), t)
            f.update_command(float(r.uniform(-1, 1)), t)
            out.append(f)
        return out
    alone = [step_many([f], standard, 10.0)[0] for f in fleet()]
    together = fleet()
    outs = step_many(together, standard, 10.0)
    for i, (a, b) in enumerate(zip(alone, outs)):
        assert repr((a.omega, a.action, a.reason, a.value)) == repr((b.omega, b.action, b.reason, b.value)), i
    assert {o.action for o in outs} == {'pass', 'override'}


def same_bits(a, b) -> bool:
    """``a`` and ``b`` hold the same values bit for bit (arrays: dtype, shape and bytes; lists and
    tuples: item by item; anything else: the same object or equal reprs)."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same_bits(x, y) for x, y in zip(a, b))
    return a is b or repr(a) == repr(b)


def test_one_robots_columns_in_python_floats_are_gathers():
    """gather_one_fast (one robot, Python floats) gives the columns gather gives for that robot
    alone, field by field, bit for bit (its ``lone_state`` is its state in floats, which gather
    leaves None), and None exactly where gather finds no state to judge: robots fresh, delayed,
    failing safe from a last valid state, lost, with commands sent since their poses, silent
    planners, commands beyond the bound, discs of their own radius and rings of larger ones."""
    from supersafe_ros.filter.gather import RobotColumns, gather, gather_one_fast
    filters, t = build_fleet(21, 300)
    rng = np.random.default_rng(22)
    for f in filters[::7]:          # discs of their own radius, some larger than the set's (rings)
        if f.detections.value is not None and len(f.detections.value):
            rows = np.column_stack([f.detections.value, rng.choice([0.5, 1.8, 4.0], len(f.detections.value))])
            f.update_detections(rows, f.detections.t)
    safe = SafeSet(solve_avoid(Grid((-8, -8), (8, 8), (21, 21, 12)), DubinsCar(3.0, 1.0), Disc(0, 0, 1.8),
                               horizon=1.0), 0.0)
    seen = {'fast': 0, 'none': 0, 'failing': 0, 'arcs': 0, 'radii': 0, 'kept': 0}
    for tick in range(3):
        for f in filters:
            fast, full = gather_one_fast(f, t), gather([f], t)
            if fast is None:
                assert len(full.robot_index) == 0
                seen['none'] += 1
                continue
            for name in RobotColumns._fields:
                a, b = getattr(fast, name), getattr(full, name)
                if name == 'lone_state':
                    assert b is None and same_bits(np.array(a), fast.states[0]), name
                else:
                    assert same_bits(a, b), (name, a, b)
            seen['fast'] += 1
            seen['failing'] += bool(fast.failing[0])
            seen['arcs'] += bool(fast.pose_age[0] > 0.0)
            seen['radii'] += fast.detection_radii[0] is not None
            seen['kept'] += fast.detection_inputs[0].kept is not None
        step_many(filters, safe, t)       # commands sent: the next tick's poses are propagated along them
        t += 0.02
        for f in filters:
            if f.pose.value is not None and rng.random() < 0.7:
                f.update_pose(f.pose.value, t, stamp=t - float(rng.choice([0.0, 0.01, 0.03])))
    assert min(seen.values()) > 5, seen


@pytest.mark.parametrize('kind', ['standard', 'lopsided, not symmetric'])
def test_one_robots_pair_values_in_python_floats_equal_numpys(standard, kind):
    """pair_values_fast and pair_turn_fast (one robot, Python floats) equal pair_values (numpy)
    bit for bit: V, the turn (the law's and the held one) and V after the hold, for pairs on,
    near and off the grid, holds of 0 (the law's turn) to 1.5 s, on the standard set and on a set
    whose grid is not square and whose V is not rotationally symmetric; None exactly when more
    than ``few`` pairs are near the grid."""
    from supersafe_ros.filter.constraints.pairs import pair_turn_fast, pair_values_fast
    from filter_support import pair_values
    from supersafe_ros.reach.value_function import ValueFunction
    vf = standard.vf
    if kind != 'standard':
        vf = ValueFunction(Grid((-6.0, -9.0), (12.0, 5.0), vf.grid.shape), vf.values, {'model': 'dubins'})
        assert not vf.rotationally_symmetric
    g = vf.grid
    rng = np.random.default_rng(7)
    seen = {'none': 0, 'held': 0, 'law': 0, 'off': 0}
    for trial in range(600):
        x, y, th = rng.uniform(-14, 14), rng.uniform(-14, 14), rng.uniform(-4, 4)
        n = int(rng.integers(1, 6))
        centres = [(x - rng.uniform(g.lo[0] - 4, g.hi[0] + 4), y - rng.uniform(g.lo[1] - 4, g.hi[1] + 4))
                   for _ in range(n)]
        planned = float(rng.choice([0.0, -0.4, 1.0]))
        horizon = float(rng.choice([0.0, 0.0, 0.05, 0.2, 1.5]))
        speed, bang = float(rng.choice([3.0, 1.0])), float(rng.choice([1.0, 0.5]))
        few = int(rng.integers(1, 4))
        got = pair_values_fast(vf, x, y, th, centres, planned, horizon, speed, bang, few)
        rel = np.array([(x - cx, y - cy, th) for cx, cy in centres])
        full = lambda v: np.full(n, v)      # noqa: E731
        want = [a.tolist() for a in pair_values(vf, rel, full(planned), full(horizon), full(speed), full(bang))]
        reach = 2.0 * speed * horizon + 1.0 if horizon > 0 else 0.0
        near = int(np.sum((rel[:, 0] >= g.lo[0] - reach) & (rel[:, 0] <= g.hi[0] + reach)
                          & (rel[:, 1] >= g.lo[1] - reach) & (rel[:, 1] <= g.hi[1] + reach)))
        if near > few:
            assert got is None
            seen['none'] += 1
            continue
        turns = [pair_turn_fast(vf, x - cx, y - cy, th, v, horizon, speed, bang)
                 for (cx, cy), v in zip(centres, got[0])]
        assert repr([got[0], turns, got[1]]) == repr(want), trial
        value, turn, value_next = want
        seen['held'] += sum(v != math.inf for v in value_next)
        seen['law'] += sum(v != math.inf and horizon == 0 and u < 0 for v, u in zip(value, turn))
        seen['off'] += sum(v == math.inf for v in value)
    assert min(seen.values()) > 20, seen


def test_the_governing_rule_is_the_per_robot_oracles():
    """law.govern and law.smallest pick what the oracle's rule for one robot (Python lists,
    filter_oracle.govern_one) picks over the same table: random rows with levels
    that differ (pairs at alpha, clusters at their own level), sound cluster rows and their
    members, values off the grid, exact ties, overriding or not."""
    from filter_oracle import govern_one as _govern_one
    from types import SimpleNamespace as Columns        # the table's columns govern reads
    from supersafe_ros.filter.law import first_min, govern
    rng = np.random.default_rng(8)
    kinds = set()
    for trial in range(3000):
        n_pairs, n_cl = int(rng.integers(0, 5)), int(rng.integers(0, 3))
        k = n_pairs + n_cl
        lists, arrays = Columns(), Columns()
        value = rng.choice([-0.5, 0.0, 0.1, 0.3, 0.8, math.inf], k) + rng.choice([0.0, 1e-3], k) * rng.random(k)
        value_next = np.where(rng.random(k) < 0.2, math.inf, value + rng.normal(0.0, 0.3, k))
        level = np.concatenate([np.full(n_pairs, rng.choice([0.0, 0.3, -0.2])), rng.choice([0.0, 0.2, 0.6], n_cl)])
        member_of = rng.integers(-1, n_cl, n_pairs) if n_cl else np.full(n_pairs, -1)
        group = np.concatenate([np.where(member_of >= 0, n_pairs + member_of, np.arange(n_pairs)),
                                n_pairs + np.arange(n_cl)])
        columns = dict(robot=np.zeros(k, np.intp), position=np.arange(k), value=value, level=level,
                       value_next=value_next, sound=np.arange(k) >= n_pairs, group=group)
        for name, col in columns.items():
            setattr(arrays, name, col)
            setattr(lists, name, col.tolist())
        overriding, margin = bool(rng.random() < 0.5), float(rng.choice([0.0, 0.2]))
        k_gov, kind = govern(arrays, np.array([overriding]), np.array([margin]), n_pairs + n_cl, 1)
        k_small = first_min(arrays.robot, arrays.position, value - level, np.isfinite(value), 1)
        got = _govern_one(lists, overriding, margin)
        assert got == (int(k_gov[0]), int(kind[0]), int(k_small[0])), trial
        kinds.add(got[1])
    assert kinds == {0, 1, 2, 3}


def test_first_min_over_many_rows_picks_what_a_sort_of_all_of_them_picks():
    """first_min over a fleet's many rows (each segment's smallest rank and score found first, the
    ties alone sorted) picks the row a sort of all rows by (segment, rank, score, position) puts
    first in each segment: many exact ties, -0.0 and 0.0, infinities, segments without rows, and
    NaN scores (then every row is sorted)."""
    from supersafe_ros.filter.law import FEW_ROWS, first_min

    def by_sort(segment, position, score, mask, n, rank=None):
        out = np.full(n, -1, dtype=np.intp)
        idx = np.flatnonzero(mask)
        keys = (position[idx], score[idx], segment[idx]) if rank is None else \
            (position[idx], score[idx], rank[idx], segment[idx])
        order = idx[np.lexsort(keys)]
        for i in order[::-1]:       # the first of each segment, last written
            out[segment[i]] = i
        return out
    rng = np.random.default_rng(31)
    ties = 0
    for trial in range(300):
        k, n = int(rng.integers(FEW_ROWS + 1, 3000)), int(rng.integers(1, 300))
        segment = rng.integers(0, n, k)
        position = rng.permutation(k)
        score = rng.choice([-1.0, -0.0, 0.0, 0.5, 0.5 + 1e-12, 2.0, np.inf, -np.inf], k)
        if trial % 10 == 0:
            score[rng.integers(0, k, 3)] = np.nan
        mask = rng.random(k) < rng.choice([0.05, 0.5, 1.0])
        rank = rng.integers(1, 4, k).astype(np.int8) if trial % 2 else None
        got, want = first_min(segment, position, score, mask, n, rank), by_sort(segment, position, score, mask, n, rank)
        assert np.array_equal(got, want), trial
        ties += int(np.sum(np.bincount(segment[mask], minlength=n) > 1))
    assert ties > 1000


def test_the_first_minimum_of_each_run_is_first_min_s():
    """first_min_of_runs (the nearest member of each cluster instance: runs of member rows, in
    their cluster's order) picks what first_min picks by position: the smallest score, the
    first on exact ties, runs of one row and one run alone included."""
    from supersafe_ros.filter.law import first_min, first_min_of_runs
    rng = np.random.default_rng(12)
    assert len(first_min_of_runs(np.zeros(0), np.zeros(0, np.intp), np.zeros(0, np.intp))) == 0
    ties = 0
    for trial in range(2000):
        size = rng.integers(1, 5, int(rng.integers(1, 7)))
        run = np.repeat(np.arange(len(size)), size)
        position = np.concatenate([np.arange(k) for k in size])
        score = rng.choice([0.0, 0.5, 1.0, 2.5], len(run)) + rng.choice([0.0, 0.25], len(run))
        want = first_min(run, position, score, np.ones(len(run), bool), len(size))
        got = first_min_of_runs(score, run, np.cumsum(size) - size)
        assert np.array_equal(got, want), trial
        ties += sum(int(np.sum(score[run == r] == score[want[r]]) > 1) for r in range(len(size)))
    assert ties > 500


def test_the_better_bang_turns_left_on_ties_within_the_tolerance():
    """better_bang (the held avoid turn of pairs and of cluster union values): left (+1) when
    V after the left turn is at least V after the right one less the tie tolerance, else right."""
    from supersafe_ros.filter.law import better_bang
    left = np.array([1.0, 1.0, 1.0, 0.5, -np.inf, np.inf])
    right = np.array([1.0, 1.05, 1.2, 0.4, 0.0, np.inf])
    assert better_bang(left, right, 0.1).tolist() == [1.0, 1.0, -1.0, 1.0, -1.0, 1.0]
    assert better_bang(left, right, np.array([0.0, 0.0, 0.3, 0.0, 0.0, 0.0])).tolist() == [
        1.0, -1.0, 1.0, 1.0, -1.0, 1.0]


def test_robots_with_equal_but_distinct_configurations_keep_their_own_fields(standard):
    """Two configurations that compare equal (0.0 == -0.0) are still two: each robot's command
    carries its own turn bound's sign, as when it is decided alone."""
    fleet = [RobotFilter(FilterConfig(omega_max=w, fail_safe_command='stop_turn'), name=n)
             for w, n in ((-0.0, 'a'), (0.0, 'b'))]
    assert fleet[0].config == fleet[1].config
    out = step_many(fleet, standard, 10.0)        # no inputs yet: stop-turn at +w_max
    alone = [step_many([RobotFilter(f.config)], standard, 10.0).omega[0] for f in fleet]
    assert repr(out.omega) == repr(alone) == repr([-0.0, 0.0])


def test_an_empty_fleet_decides_nothing(standard):
    out = step_many([], standard, 10.0)
    assert len(out) == 0 and out.omega == [] and out.linear == [] and out.action == []
