"""LockstepAnswers (runtime.lockstep): when a lockstepped filter answers a pose, without ROS.

The promise (docs/graph_safety.md): each pose is answered once, on that pose; a pose
the clock has passed is skipped; while a cluster near the robot is being solved the
answer is held (sim time waits) until the value is in force, at most hold_timeout
steady seconds, and after a hold that timed out there is no other hold until nothing
is solving; the watchdog keeps quiet for ``silence`` seconds after a pose.
"""
import pytest

from supersafe_ros.runtime.lockstep import ANSWER, GIVE_UP, HOLD, LockstepAnswers, Verdict

SOLVING, NONE_SOLVING = 1, 0


def answers(hold_timeout=10.0, silence=2.0, now=100.0):
    return LockstepAnswers(hold_timeout, silence, now)


# -- skipping poses the clock has passed --------------------------------------------------------
def test_a_pose_the_clock_has_passed_is_skipped_and_counted():
    a = answers()
    assert a.clock_passed(stamp_ns=11_000_000_000, clock_ns=12_000_000_000)
    assert a.clock_passed(stamp_ns=1, clock_ns=2)
    assert a.poses_skipped == 2


@pytest.mark.parametrize('stamp_ns, clock_ns, why', [
    (12_000_000_000, 12_000_000_000, 'the current step'),
    (13_000_000_000, 12_000_000_000, 'ahead of the clock'),
    (0, 12_000_000_000, 'unstamped'),
    (-5, 12_000_000_000, 'unusable stamp'),
    (11_000_000_000, None, 'wall time'),
])
def test_other_poses_are_answered(stamp_ns, clock_ns, why):
    a = answers()
    assert not a.clock_passed(stamp_ns, clock_ns), why
    assert a.poses_skipped == 0


# -- the watchdog's silence ---------------------------------------------------------------------
def test_the_watchdog_keeps_quiet_for_silence_seconds_after_a_pose():
    a = answers(silence=2.0, now=100.0)
    assert a.quiet(101.9)               # counted from the start, before any pose
    assert not a.quiet(102.0)
    a.new_pose(150.0)
    assert a.quiet(150.0) and a.quiet(151.99)
    assert not a.quiet(152.0) and not a.quiet(160.0)


# -- judging a decision -------------------------------------------------------------------------
def test_nothing_solving_answers_now():
    a = answers()
    v = a.judge(5.0, 100.0, NONE_SOLVING, answers_pose=True)
    assert v == Verdict(ANSWER, 'no cluster is being solved') and v.publish and v.held_for is None
    assert a.holds == 0 and a.held_pose_time is None


def test_the_answer_to_a_pose_is_held_while_a_cluster_is_solved():
    a = answers(hold_timeout=10.0)
    a.new_pose(100.0)
    v = a.judge(5.0, 100.0, SOLVING, answers_pose=True)
    assert v.action == HOLD and not v.publish and v.held_for is None
    assert a.holds == 1 and a.held_pose_time == 5.0


def test_a_held_answer_is_held_again_while_solving_within_the_timeout():
    a = answers(hold_timeout=10.0)
    a.judge(5.0, 100.0, SOLVING, answers_pose=True)
    for now in (100.02, 105.0, 109.99):
        v = a.judge(a.held_pose_time, now, SOLVING, answers_pose=False)   # the watchdog's decision again
        assert v.action == HOLD
    assert a.holds == 1 and a.held_pose_time == 5.0      # one hold, on the pose's own time


def test_a_held_answer_goes_out_once_the_value_is_in_force():
    a = answers(hold_timeout=10.0)
    a.judge(5.0, 100.0, SOLVING, answers_pose=True)
    v = a.judge(5.0, 100.31, NONE_SOLVING, answers_pose=False)
    assert v.action == ANSWER and v.publish and v.why == 'the cluster value is in force'
    assert v.held_for == pytest.approx(0.31)
    assert a.held_pose_time is None


def test_a_hold_that_times_out_gives_up_with_the_fallback():
    a = answers(hold_timeout=10.0)
    a.judge(5.0, 100.0, SOLVING, answers_pose=True)
    v = a.judge(5.0, 110.0, SOLVING, answers_pose=False)
    assert v.action == GIVE_UP and v.publish
    assert v.why == 'a cluster value still solving after 10 s' and v.held_for == pytest.approx(10.0)
    assert a.held_pose_time is None


def test_after_a_timed_out_hold_no_other_hold_until_nothing_is_solving():
    a = answers(hold_timeout=10.0)
    a.judge(5.0, 100.0, SOLVING, answers_pose=True)
    a.judge(5.0, 110.0, SOLVING, answers_pose=False)          # gave up
    for k, t in enumerate((5.2, 5.4, 5.6)):                    # the next poses, the solve still running
        a.new_pose(110.0 + k)
        v = a.judge(t, 110.0 + k, SOLVING, answers_pose=True)
        assert v == Verdict(ANSWER, 'a hold already timed out while this solve runs')
    assert a.holds == 1
    a.new_pose(114.0)
    assert a.judge(5.8, 114.0, NONE_SOLVING, answers_pose=True).action == ANSWER   # the solve landed
    a.new_pose(115.0)
    assert a.judge(6.0, 115.0, SOLVING, answers_pose=True).action == HOLD        # a new solve: held again
    assert a.holds == 2


def test_decisions_that_do_not_answer_a_pose_are_never_held():
    """Planner commands and the watchdog without a held answer (not in lockstep, or after
    the silence) publish whatever is solving."""
    a = answers(hold_timeout=10.0)
    v = a.judge(5.0, 100.0, SOLVING, answers_pose=False)
    assert v == Verdict(ANSWER, 'not the answer to a pose: never held')
    assert a.holds == 0 and a.held_pose_time is None


def test_a_zero_hold_timeout_never_holds():
    a = answers(hold_timeout=0.0)
    v = a.judge(5.0, 100.0, SOLVING, answers_pose=True)
    assert v == Verdict(ANSWER, 'holding is off (hold timeout 0)')
    assert a.holds == 0


def test_a_new_pose_drops_the_held_answer_to_the_older_one():
    a = answers(hold_timeout=10.0)
    a.judge(5.0, 100.0, SOLVING, answers_pose=True)
    a.new_pose(101.0)
    assert a.held_pose_time is None
    v = a.judge(5.2, 101.0, SOLVING, answers_pose=True)         # the new pose's answer is held afresh
    assert v.action == HOLD and a.held_pose_time == 5.2 and a.holds == 2
    # its hold counts from the new pose, not from the first
    assert a.judge(5.2, 110.5, SOLVING, answers_pose=False).action == HOLD
    assert a.judge(5.2, 111.0, SOLVING, answers_pose=False).action == GIVE_UP


def test_a_node_like_run_holds_then_answers_each_pose_once():
    """As safety_filter_node drives it: a pose, its held answer retried by the watchdog
    every 20 ms, the value lands, one answer; the next pose answered at once."""
    a = answers(hold_timeout=15.0, silence=20.0, now=0.0)
    published = []
    solving = {'until': 0.5}

    def decide(t, now, answers_pose):
        v = a.judge(t, now, SOLVING if now < solving['until'] else NONE_SOLVING, answers_pose)
        if v.publish:
            published.append((t, v))

    a.new_pose(0.0)
    decide(1.0, 0.0, answers_pose=True)
    now = 0.0
    while a.held_pose_time is not None:
        now += 0.02
        assert a.quiet(now)
        decide(a.held_pose_time, now, answers_pose=False)
    assert len(published) == 1 and published[0][0] == 1.0
    assert published[0][1].held_for == pytest.approx(0.5, abs=0.021)
    a.new_pose(now + 0.01)
    decide(1.2, now + 0.01, answers_pose=True)
    assert [t for t, _ in published] == [1.0, 1.2] and a.holds == 1
