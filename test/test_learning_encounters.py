"""The ROS-free encounter builder (supersafe_ros.learning.encounters)."""
import math

import numpy as np
import pytest

from supersafe_ros.learning.data import PHASE2_OFFSETS
from supersafe_ros.learning.encounters import EncounterBuilder, EncounterRecord
from supersafe_ros.learning.phase2_stream import feed, phase2_events
from supersafe_ros.learning.intervention_store import RecordStore
from supersafe_ros.reach.library import LibrarySpec, load_or_build_library
from supersafe_ros.sim.watcher import Watcher

LO, HI = (-8.0, -8.0), (8.0, 8.0)


@pytest.fixture(scope='module')
def supervisor_vf():
    return load_or_build_library(LibrarySpec(shape=(41, 41, 24), omegas=(0.25, 0.5, 1.0, 2.0))).entry(0.5)


def builder(**kw):
    return EncounterBuilder(LO, HI, 3.0, **kw)


def drive(b, robot, t0, x0, y, n, dt=0.2, speed=3.0, theta=0.0):
    """n poses driving along +x (theta 0) from (x0, y); returns the last stamp."""
    t = t0
    for k in range(n):
        t = t0 + k * dt
        b.pose(robot, t, (x0 + speed * dt * k * math.cos(theta), y + speed * dt * k * math.sin(theta), theta))
    return t


def test_phase2_stream_gives_one_encounter_per_scene_ending_where_the_supervisor_intervened(supervisor_vf):
    watcher = Watcher(supervisor_vf, mu=0.6, sigma=0.3, seed=4)
    decisions = []
    judge = watcher.judge

    def spy(*a, **k):
        d = judge(*a, **k)
        if d is not None:
            decisions.append(d)
        return d
    watcher.judge = spy
    events = list(phase2_events(watcher, PHASE2_OFFSETS, dt=0.2))
    b = builder()
    n = feed(b, events)
    b.finish_all()
    records = b.pop_finished()
    assert len(records) == len(PHASE2_OFFSETS) and n == len(decisions) > 3
    assert sum(r.intervened for r in records) == n and 0 < n < len(records)
    assert b.counts['unmatched_interventions'] == 0
    poses = {ev[2]: ev[3] for ev in events if ev[0] == 'pose'}
    for r, d in zip([r for r in records if r.intervened], decisions):
        assert r.obstacle == d.obstacle_id
        # the intervention frame is the first pose at or after the intervention, and every
        # earlier frame is before it
        assert r.t[-1] >= d.time and all(t < d.time for t in r.t[:-1])
        assert r.t[-1] == min(t for t in poses if t >= d.time)
    for r in records:
        f = np.asarray(r.frames)
        assert np.all((f[:, :2] >= LO) & (f[:, :2] <= HI))
        assert r.reason == ('intervention' if r.intervened else 'passed')


def test_inputs_out_of_order_are_ordered_by_their_stamps(supervisor_vf):
    """Every scene's messages moved within the scene (poses kept in order per robot):
    interventions anywhere, obstacle sets earlier than the poses they precede (a removal
    read while older poses still wait; the node reads sets before poses). The same
    encounters as in order."""
    events = list(phase2_events(Watcher(supervisor_vf, mu=0.6, sigma=0.3, seed=5), PHASE2_OFFSETS, dt=0.2))
    ordered = builder()
    feed(ordered, events)
    ordered.finish_all()
    rng = np.random.default_rng(0)
    shuffled, scene = [], []
    for ev in events:
        scene.append(ev)
        if ev[0] == 'pose' and ev[3][0] < -20:
            poses = [e for e in scene if e[0] == 'pose']
            others, slots = [], []
            for i, e in enumerate(scene):
                if e[0] != 'pose':
                    before = sum(1 for x in scene[:i] if x[0] == 'pose')
                    top = before if e[0] == 'obstacles' else len(poses)
                    others.append(e)
                    slots.append(int(rng.integers(0, top + 1)))
            merged = []
            for i, p in enumerate(poses):
                merged += [others[k] for k, s in enumerate(slots) if s == i] + [p]
            merged += [others[k] for k, s in enumerate(slots) if s == len(poses)]
            shuffled += merged
            scene = []
    b = builder()
    feed(b, shuffled + scene)
    b.finish_all()
    a = [(r.obstacle, r.intervened, r.t) for r in ordered.pop_finished()]
    c = [(r.obstacle, r.intervened, r.t) for r in b.pop_finished()]
    assert sorted(a) == sorted(c) and b.counts['unmatched_interventions'] == 0


def test_obstacle_sets_arriving_after_the_poses_they_precede_lose_no_encounter(supervisor_vf):
    """An obstacle set read after poses stamped later than it (DDS orders messages within a
    topic, not across topics), up to the reorder window late, and interventions read
    together with it: poses are judged a window after they arrive, so the set is in force
    for them. The same encounters as in order, none unmatched."""
    events = list(phase2_events(Watcher(supervisor_vf, mu=0.6, sigma=0.3, seed=5), PHASE2_OFFSETS, dt=0.2))
    ordered = builder()
    feed(ordered, events)
    ordered.finish_all()
    expected = sorted((r.obstacle, r.intervened, r.t) for r in ordered.pop_finished())
    assert sum(e[1] for e in expected) >= 3
    rng = np.random.default_rng(1)
    for trial in range(20):
        late, held, poses, release = [], [], 0, 0
        for ev in events:
            if ev[0] == 'obstacles':
                # read after 1 to 5 of the poses stamped after it (at most 1.0 s late), in the
                # order published (one topic)
                release = max(release, poses + int(rng.integers(1, 6)))
                held.append((release, ev))
                continue
            if ev[0] == 'intervention' and held and rng.random() < 0.5:
                held.append((release, ev))      # read together with the set still on its way
                continue
            late.append(ev)
            if ev[0] == 'pose':
                poses += 1
                while held and held[0][0] <= poses:
                    late.append(held.pop(0)[1])
        late += [h[1] for h in held]
        b = builder(reorder=1.0)
        feed(b, late)
        b.finish_all()
        got = sorted((r.obstacle, r.intervened, r.t) for r in b.pop_finished())
        assert b.counts['unmatched_interventions'] == 0, trial
        assert got == expected, trial


def test_held_poses_are_judged_when_the_robot_stops_resets_or_the_run_ends():
    b = builder(reorder=1.0, stale_wall=2.0)
    b.set_obstacles([1], [(0.0, 0.0)], 0.5)
    for k in range(4):                                       # 1.0 .. 1.6, arrived at wall 10 .. 11.5
        b.pose('r', 1.0 + 0.2 * k, (-7.0 + 0.6 * k, 0.5, 0.0), wall=10.0 + 0.5 * k)
    b.intervention(1, 1.3, (-5.8, 0.5, 0.0), wall=13.0)
    b.tick(11.9)
    assert b.open_count == 1 and not b.pop_finished()       # no pose judged: the intervention waits
    b.tick(12.6)                                             # 1.0 and 1.2 waited stale_wall
    assert b.open_count == 2 and not b.pop_finished()       # an encounter, the intervention waiting
    b.tick(13.0)                                             # 1.4, the frame after the intervention
    (r,) = b.pop_finished()
    assert r.intervened and list(r.t) == pytest.approx([1.0, 1.2, 1.4])
    # a reset (stamps going back) judges what came before it at once
    c = builder(reorder=1.0)
    c.set_obstacles([1], [(0.0, 0.0)], 0.0)
    drive(c, 'r', 5.0, -7.0, 0.5, 4)
    c.pose('r', 0.5, (-30.0, 0.0, 0.0))
    (r,) = c.pop_finished() or [None]
    assert r is None and c.counts['jump'] == 0 and c.open_count == 1
    c.pose('r', 2.0, (-30.0, 0.0, 0.0))                      # ... the jump itself, a window later
    c.finish_all()
    (r,) = c.pop_finished()
    assert r.reason == 'jump' and list(r.t) == pytest.approx([5.0, 5.2, 5.4, 5.6])
    # the end of a run judges every held pose
    d = builder(reorder=1.0)
    d.set_obstacles([1], [(0.0, 0.0)], 0.0)
    drive(d, 'r', 1.0, -7.0, 0.5, 15)                        # passes the obstacle at 3.4 (x > 0)
    assert not d.pop_finished()
    d.finish_all()
    (r,) = d.pop_finished()
    assert r.reason == 'passed' and len(r.t) == 13


@pytest.mark.parametrize('reorder', [0.0, 1.0])
def test_sets_read_before_the_first_pose_is_judged_all_apply_by_their_stamps(reorder):
    """A scene's set and its removal both read before any pose of the robot is judged (the
    first poses held by the window, or not arrived yet): the removal does not replace the
    set for the poses stamped between them."""
    b = builder(reorder=reorder)
    b.set_obstacles([1], [(0.0, 0.0)], 1.2)
    b.set_obstacles([], np.zeros((0, 2)), 3.2)
    b.intervention(1, 2.9, (-3.2, -2.25, 0.0))
    drive(b, 'r', 1.4, -8.0, -2.25, 9)                     # 1.4 .. 3.0
    b.pose('r', 3.4, (-30.0, 0.0, 0.0))
    b.finish_all()
    (r,) = b.pop_finished()
    assert r.intervened and r.obstacle == 1 and r.t[0] == pytest.approx(1.4) and r.t[-1] == pytest.approx(3.0)
    assert b.counts['unmatched_interventions'] == 0


def test_a_removal_stamped_by_a_lagging_clock_cuts_no_frame_before_it():
    b = builder(grace=0.0, removal_delay=1.0)
    b.set_obstacles([1], [(0.0, 0.0)], 0.5)
    drive(b, 'r', 1.0, -7.0, 1.0, 3)                       # 1.0, 1.2, 1.4
    b.set_obstacles([], np.zeros((0, 2)), 1.1)             # stamped 1.1, truly removed after 1.4
    drive(b, 'r', 1.6, -7.0 + 1.8, 1.0, 5)                 # 1.6 .. 2.4: frames go on until 2.1
    (r,) = b.pop_finished()
    assert r.reason == 'obstacle_gone' and list(r.t) == pytest.approx([1.0, 1.2, 1.4, 1.6, 1.8, 2.0])


def test_an_encounter_ends_when_the_robot_jumps_leaves_or_the_obstacle_goes():
    b = builder(grace=0.0, removal_delay=0.0)
    b.set_obstacles([1, 2], [(0.0, 0.0), (0.0, 30.0)], 0.5)
    drive(b, 'r', 1.0, -7.0, 1.0, 5)                      # approaching obstacle 1
    b.pose('r', 2.2, (-30.0, 1.0, 0.0))                   # teleport
    b.pose('r', 2.4, (-30.0, 1.0, 0.0))                   # grace 0: final at the next pose
    (jumped,) = b.pop_finished()
    assert jumped.reason == 'jump' and not jumped.intervened and len(jumped.frames) == 5
    drive(b, 'r', 3.0, -7.0, 1.0, 3)
    b.set_obstacles([2], [(0.0, 30.0)], 3.5)              # obstacle 1 removed at t = 3.5
    drive(b, 'r', 3.6, -7.0 + 3 * 0.6, 1.0, 2)
    (gone,) = b.pop_finished()
    assert gone.reason == 'obstacle_gone' and len(gone.frames) == 3
    b.pose('r', 10.0, (-7.0, 30.0, math.pi))              # heading away from obstacle 2: no encounter
    b.pose('r', 10.2, (-7.6, 30.0, math.pi))
    assert b.open_count == 0
    drive(b, 'r', 11.0, -7.9, 30.5, 30)                    # towards obstacle 2, then past it
    assert [r.reason for r in b.pop_finished()] == ['passed']
    b2 = builder(grace=0.0)
    b2.set_obstacles([1], [(0.0, 0.0)], 0.0)
    for t, x, y in ((1.0, -7.0, 7.5), (1.2, -6.5, 7.8), (1.4, -6.0, 8.2), (1.6, -5.5, 8.5)):
        b2.pose('r', t, (x, y, 0.3))                       # approaching, out through the grid's top edge
    assert [r.reason for r in b2.pop_finished()] == ['left_grid']


def test_late_intervention_finds_its_encounter_within_the_grace_time():
    b = builder(grace=2.0)
    b.set_obstacles([7], [(0.0, 0.0)], 0.0)
    drive(b, 'r', 1.0, -7.0, 2.5, 20)                      # passes at y 2.5: 'passed' at x > 0
    assert b.open_count == 1 and not b.pop_finished()      # ended, held for the grace time
    b.intervention(7, 2.0, (-7.0 + 3.0 * 1.0, 2.5, 0.0))    # at t = 2.0 (frame 5), arriving late
    (r,) = b.pop_finished()
    assert r.intervened and r.t[-1] == pytest.approx(2.0) and len(r.frames) == 6
    # an intervention no encounter explains (another obstacle, or far from every frame)
    b.intervention(8, 3.0, (-3.0, 0.0, 0.0))
    b.intervention(7, 3.0, (5.0, -5.0, 0.0))
    drive(b, 'r', 10.0, -30.0, 0.0, 2)
    assert b.counts['unmatched_interventions'] == 2


def test_intervention_ahead_of_the_poses_waits_for_them():
    b = builder()
    b.set_obstacles([1], [(0.0, 0.0)], 0.0)
    b.pose('r', 1.0, (-7.0, 0.5, 0.0))
    b.intervention(1, 1.5, (-5.5, 0.5, 0.0))              # the poses up to 1.5 are still on their way
    assert not b.pop_finished() and b.counts['unmatched_interventions'] == 0
    drive(b, 'r', 1.2, -6.4, 0.5, 3)                       # 1.2, 1.4, 1.6
    (r,) = b.pop_finished()
    # its frame: the last pose of the pass (1.6) or the reported state at its stamp (1.61)
    assert r.intervened and list(r.t) == pytest.approx([1.0, 1.2, 1.4, 1.6], abs=0.011)
    # no new encounter with an intervened obstacle until it is removed
    drive(b, 'r', 1.8, -5.2, 0.5, 3)
    assert b.open_count == 0


def test_memory_stays_bounded_over_a_long_run():
    b = builder(max_frames=20, max_versions=20)
    rng = np.random.default_rng(1)
    t = 0.0
    held = []
    for scene in range(120):
        b.set_obstacles(np.arange(scene * 3, scene * 3 + 3), rng.uniform(-5, 5, (3, 2)), t + 0.01)
        for k in range(40):
            t += 0.05
            b.pose('a', t, (-5 + 0.02 * k, 0.0, 0.3))      # slow: encounters end at max_frames
            b.pose('b', t, (rng.uniform(-6, 6), rng.uniform(-6, 6), rng.uniform(-3, 3)))
        b.pop_finished()
        held.append(b.open_count)
    # what is held is what the grace time covers (robot b jumps every pose), not the run's length
    assert len(b._versions) <= 20 and max(held[60:]) <= max(held[:60]) + 10 and max(held) < 200
    assert b.counts['max_frames'] > 0


def test_records_round_trip_through_the_store(tmp_path):
    r = EncounterRecord('robot_3', 12, (1.0, 1.2), ((-7.0, 0.5, 0.0), (-6.4, 0.5, 0.01)), True, 'intervention')
    with RecordStore(tmp_path / 'e.jsonl', EncounterRecord) as store:
        assert store.append(r, sync=False) and not store.append(r)
        assert store.sync() == 1
    with RecordStore(tmp_path / 'e.jsonl', EncounterRecord, keep=1) as again:
        assert len(again) == 1 and again.entries[0] == r
    enc = r.to_encounter()
    assert enc.intervened and enc.states.shape == (2, 3)
    with pytest.raises(ValueError):
        EncounterRecord.from_json('{"robot": "r", "obstacle": 1, "t": [1.0], "frames": [[NaN, 0, 0]], '
                                  '"intervened": false, "reason": "passed"}')


# -- issue 21: an honest stream the learner did not make ---------------------------------------
def stream_fit(events, lr):
    from supersafe_ros.learning.estimators import encounter_intervals, fit_first_passage_intervals
    b = EncounterBuilder(lr.lo, lr.hi, **lr.builder_args)
    feed(b, events)
    b.finish_all()
    records = b.pop_finished()
    fit = fit_first_passage_intervals(lr.entries, encounter_intervals(lr.entries, [r.to_encounter() for r in records]),
                                      admissible=lr.admissible)
    return records, fit, b


def test_an_honest_foreign_stream_gives_the_hidden_supervisor_back():
    """Poses at 20 Hz, each intervention 1 ms after the pose it judged, the obstacle cleared
    10 ms later, the robot teleported to the next scene 1 s later (test/honest_stream_support):
    every intervention frame is the pose judged (never the next scene's), whatever the
    cross-topic order, and the fit finds w 0.5 exactly and mu within 0.1."""
    from honest_stream_support import MU, W, honest_stream, shuffled_across_topics
    from supersafe_ros.study.engine import learners
    lr = learners()                                       # the learner node's library and parameters
    vf_s = next(e for e in lr.entries if e.meta['omega_max'] == W)
    results = []
    for seed in range(10):
        events, _ = honest_stream(vf_s, seed=seed)
        judged = {ev[1]: ev[3] for ev in events if ev[0] == 'intervention'}
        records, fit, b = stream_fit(events, lr)
        assert len(records) == 126 and b.counts['unmatched_interventions'] == 0
        assert sorted(r.obstacle for r in records if r.intervened) == sorted(judged)
        for r in records:
            if r.intervened:
                assert r.frames[-1] == pytest.approx(judged[r.obstacle], abs=1e-12)
                assert all(f[0] < judged[r.obstacle][0] for f in r.frames[:-1])     # frames judged safe before it
            else:
                assert r.reason == 'passed' and r.frames[-1][0] > 0
        if seed < 2:                                      # topics interleaved by delays up to 0.5 s
            shuffled, fit2, _ = stream_fit(shuffled_across_topics(events, seed), lr)
            assert sorted(r.to_json() for r in shuffled) == sorted(r.to_json() for r in records)
            assert (fit2.omega_max, fit2.mu) == (fit.omega_max, fit.mu)
        results.append((seed, fit.omega_max, round(fit.mu, 3)))
    good = [r for r in results if r[1] == W and abs(r[2] - MU) <= 0.1]
    # 126 straight passes, all intervened, barely tell w 0.5 from 0.625 in one draw of ten
    assert len(good) >= 9, results


def test_the_pose_after_a_removal_or_a_jump_is_never_the_intervention_frame():
    b = builder(same_pose=0.05)
    b.set_obstacles([1], [(0.0, 0.0)], 1.0)
    t = drive(b, 'r', 1.0, -7.0, 0.5, 5)                   # x -7 .. -4.6 at 1.0 .. 1.8
    b.intervention(1, t + 0.001, (-4.6, 0.5, 0.0))        # judged the last pose; reported 1 ms later
    b.set_obstacles([], np.zeros((0, 2)), t + 0.011)
    b.set_obstacles([2], [(0.0, 0.0)], t + 1.0)
    b.pose('r', t + 1.0, (-7.0, -0.5, 0.0))               # the next scene, 2.4 m away: no jump
    (r,) = b.pop_finished()
    assert r.intervened and r.frames[-1] == (-4.6, 0.5, 0.0) and len(r.frames) == 5
    assert r.t[-1] == pytest.approx(t + 0.001)            # the pose judged, merged with the report
    # a pose after a jump while the judged pose is awaited: the reported state stands in
    b = builder()
    b.set_obstacles([1], [(0.0, 0.0)], 1.0)
    drive(b, 'r', 1.0, -7.0, 0.5, 3)
    b.intervention(1, 1.5, (-5.5, 0.5, 0.0))
    b.pose('r', 1.6, (-30.0, 0.0, 0.0))
    (r,) = b.pop_finished()
    assert r.frames[-1] == (-5.5, 0.5, 0.0) and list(r.t) == pytest.approx([1.0, 1.2, 1.4, 1.5])
    # the world's coarse clock stamps the removal before the intervention that caused it, or
    # an exact clock with the pose judged: that pose (the first at or after the interpolated
    # crossing) is still the frame
    for reorder, removal in ((0.0, 1.45), (1.0, 1.45), (1.0, 1.6)):
        b = builder(reorder=reorder)
        b.set_obstacles([1], [(0.0, 0.0)], 1.0)
        drive(b, 'r', 1.0, -7.0, 0.5, 3)                   # 1.0, 1.2, 1.4
        b.intervention(1, 1.5, (-5.5, 0.5, 0.0))           # crossing between 1.4 and 1.6
        b.set_obstacles([], np.zeros((0, 2)), removal)
        drive(b, 'r', 1.6, -5.2, 0.5, 8)
        b.finish_all()
        (r,) = b.pop_finished()
        assert r.frames[-1] == pytest.approx((-5.2, 0.5, 0.0)) and r.t[-1] == pytest.approx(1.6)


def test_encounters_become_final_when_the_poses_stop_without_more_data():
    b = builder(grace=2.0, stale_wall=2.0)
    b.set_obstacles([7], [(0.0, 0.0)], 0.5)
    for k in range(20):                                    # passes at y 2.5, ends 'passed'
        b.pose('r', 1.0 + 0.2 * k, (-7.0 + 0.6 * k, 2.5, 0.0), wall=100.0 + 0.01 * k)
    assert b.open_count == 1 and not b.pop_finished()
    b.tick(101.0)                                          # the last pose arrived 0.81 s ago
    assert not b.pop_finished()
    b.tick(102.3)                                          # and now 2.1 s ago: the stream stopped
    (r,) = b.pop_finished()
    assert not r.intervened and r.reason == 'passed' and b.open_count == 0


def test_an_intervention_read_before_its_poses_is_matched_when_its_wall_time_runs_out():
    """Topics cross at the end of a stream: the intervention is read before the poses of its
    pass and no later pose comes. Its wall-time limit runs out before theirs: the poses up to
    its stamp are judged first, so it finds its encounter (a quiet CI run lost one this way)."""
    b = builder(reorder=1.0, stale_wall=2.0)
    b.set_obstacles([1], [(0.0, 0.0)], 0.5, wall=9.0)
    b.intervention(1, 1.61, (-5.2, 0.5, 0.0), wall=10.0)
    for k in range(4):                                       # 1.0 .. 1.6, read at wall 11 .. 11.3
        b.pose('r', 1.0 + 0.2 * k, (-7.0 + 0.6 * k, 0.5, 0.0), wall=11.0 + 0.1 * k)
    b.tick(12.5)              # the intervention waited 2.5 s, the poses 1.2-1.5 s
    assert b.counts['unmatched_interventions'] == 0
    b.tick(20.0)              # the stream has stopped: the encounter is final
    (r,) = b.pop_finished()
    # its frame: the last pose of the pass (1.6) or the reported state at its stamp (1.61)
    assert r.intervened and list(r.t) == pytest.approx([1.0, 1.2, 1.4, 1.6], abs=0.011)


@pytest.mark.parametrize('start', [-8.0 + 3e-14, -8.0 - 3e-14])
def test_a_robot_placed_on_the_grids_edge_starts_its_encounter_there(start):
    """A scene starts the robot at the library's lo (x = -8 from the obstacle), a float hair inside
    or outside by the arithmetic that put it there (-8.000000000000034 in a Phase II run): the
    encounter starts at that pose either way. (When the world's coarse removal stamp fell before
    the next pose, the intervention found no encounter.)"""
    b = builder()
    b.set_obstacles([1], [(0.0, 0.0)], 0.5)
    b.pose('r', 1.0, (start, 0.5, 0.0))
    b.set_obstacles([], np.zeros((0, 2)), 1.1)         # removed (its stamp coarse: before the next pose)
    for k in range(1, 4):
        b.pose('r', 1.0 + 0.2 * k, (start + 0.6 * k, 0.5, 0.0))
    b.intervention(1, 1.5, (start + 1.5, 0.5, 0.0))
    b.pose('r', 1.8, (start + 2.4, 0.5, 0.0))
    b.finish_all()
    (r,) = b.pop_finished()
    assert r.intervened and b.counts['unmatched_interventions'] == 0
    assert r.t[0] == pytest.approx(1.0)
